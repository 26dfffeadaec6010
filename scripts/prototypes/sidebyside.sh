#!/bin/bash
# Old and new binaries side by side on one machine, alternating (docs/performance.md).
#   scripts/prototypes/sidebyside.sh OLD_BINARY [NEW_BINARY]
# Build the old one from a commit with: git worktree add /tmp/old REV &&
#   (cd /tmp/old && CARGO_TARGET_DIR=/tmp/oldtarget cargo build --release)
set -u
OLD=${1:?old binary}
NEW=${2:-target/release/dustsph}
cd "$(dirname "$0")/../.."
for round in 1 2; do
  for which in OLD NEW; do
    bin=${!which}
    echo "== $which round $round"
    "$bin" bench --threads 2 --steps 10 2>&1 | grep -E 'box|ball'
    "$bin" run configs/dustywave_phantom.toml --out "/tmp/sbs_wave_$which" --force -q 2>&1 | grep 'steps to'
  done
done
for which in OLD NEW; do
  bin=${!which}
  echo "== $which seed ball at ≈57 neighbours"
  "$bin" run configs/dusty_ball.toml --set sph.h=0.0308 --out "/tmp/sbs_ball_$which" --force -q 2>&1 | grep 'steps to'
  python3 -c "import json,sys; s=json.load(open(sys.argv[1])); print('step loop', sum(x[1] for x in s['stage_seconds']), s['stage_seconds'])" "/tmp/sbs_ball_$which/summary.json"
done
