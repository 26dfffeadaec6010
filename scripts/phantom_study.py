#!/usr/bin/env python3
"""Phantom's DUSTYWAVE, side by side: dustsph over K = 1e3 … 1e7 and three resolutions.

Runs `target/release/dustsph run configs/dustywave_phantom.toml` (and the polydisperse variant)
for every point, reads each run's summary.json, and writes to docs/phantom/:
  results.csv, results.md   error (L2 of v_x / rms of the exact v_x, Phantom's metric) and wall time
  error_vs_time.png         error against wall time, dustsph lines per K, Phantom's figures as markers

`dustsph study configs/studies/dustywave_phantom.toml` runs the same grid (docs/studies/); this
script adds Phantom's figures to the table and the plot, and times every run with 2 threads.
Needs python3 with matplotlib; build first (`cargo build --release`).

    scripts/phantom_study.py [--quick] [--threads N] [--out docs/phantom]
"""
import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "dustsph")

KS = [1e3, 1e4, 1e5, 1e6, 1e7]
NS = [32, 48, 64]

# Phantom's figures from the issue (2 cores, fp64): (K, mode, steps, wall s, error %, at t).
PHANTOM = [
    (1e3, "two-fluid explicit", 2230, 1177.0, 2.9, 1.0),
    (1e3, "two-fluid implicit", 240, 119.0, 3.5, 1.0),
    (1e3, "one-fluid", 240, 51.0, 0.44, 1.0),
    (1e4, "two-fluid explicit", None, 1.0e4, 3.1, 0.1),
    (1e4, "two-fluid implicit", 240, 126.0, 4.4, 1.0),
    (1e5, "two-fluid explicit", None, 1.0e5, 4.2, 0.01),
    (1e5, "two-fluid implicit", 2300, 1.2e3, 0.9, 0.1),
    (1e5, "one-fluid", 240, 49.0, 0.36, 1.0),
]


def run(scene, sets, threads):
    out = tempfile.mkdtemp(prefix="phantom_study_")
    cmd = [BIN, "run", scene, "--out", out, "--force", "-q", "--device", "cpu"]
    for s in sets:
        cmd += ["--set", s]
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    t0 = time.monotonic()
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    total = time.monotonic() - t0
    with open(os.path.join(out, "summary.json")) as f:
        s = json.load(f)
    subprocess.run(["rm", "-rf", out], check=True)
    errs = next(
        e for e in s["errors"] if e["t"] == s["t_final"] and "Phantom" in e["reference"]
    )
    l2 = {f["field"]: f["l2"] for f in errs["fields"]}
    n_part = s["particles"]["gas"] + sum(s["particles"]["dust"])
    return {
        "steps": s["steps"],
        "wall_s": s["wall_seconds"],
        "process_s": total,
        "particles": n_part,
        "psteps_per_s": s["particle_steps_per_second"],
        "err_gas": l2["v_g"],
        "err_dust_max": max(v for k, v in l2.items() if k.startswith("u_d")),
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="n = 32 only (a smoke test)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "phantom"))
    ap.add_argument("--plot-only", action="store_true", help="redraw results.md and the plot from results.csv")
    a = ap.parse_args()
    if a.plot_only:
        with open(os.path.join(a.out, "results.csv")) as f:
            rows = list(csv.DictReader(f))
        for r in rows:
            r["K"] = float(r["K"]) if r["K"] else None
            for k in ["n", "particles", "steps"]:
                r[k] = int(r[k])
            for k in ["wall_s", "process_s", "psteps_per_s", "err_gas", "err_dust_max"]:
                r[k] = float(r[k])
        write_md(a.out, rows, a.threads)
        plot(a.out, rows)
        return
    ns = [32] if a.quick else NS
    os.makedirs(a.out, exist_ok=True)
    rows = []
    mono = os.path.join(ROOT, "configs", "dustywave_phantom.toml")
    poly = os.path.join(ROOT, "configs", "dustywave_phantom_poly.toml")
    points = [("two-fluid", K, n, mono, [f"dust.fractions.0.k={K:g}", f"sph.n={n}"]) for n in ns for K in KS]
    points += [("fixed h", 1e5, 64, mono, ["dust.fractions.0.k=1e5", "sph.variable_h=false"])] if not a.quick else []
    points += [("4 fractions", None, n, poly, [f"sph.n={n}"]) for n in ns]
    for case, K, n, scene, sets in points:
        r = run(scene, sets, a.threads)
        r.update(case=case, K=K, n=n)
        rows.append(r)
        print(
            f"{case:12s} K={K if K else '-':>8} n={n:3d}: {r['steps']:4d} steps, {r['wall_s']:7.2f} s, "
            f"{r['psteps_per_s']:.3e} p-steps/s, error gas {100 * r['err_gas']:.2f}%, "
            f"dust max {100 * r['err_dust_max']:.2f}%",
            flush=True,
        )
    keys = ["case", "K", "n", "particles", "steps", "wall_s", "process_s", "psteps_per_s", "err_gas", "err_dust_max"]
    with open(os.path.join(a.out, "results.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in keys})
    write_md(a.out, rows, a.threads)
    plot(a.out, rows)


def write_md(out, rows, threads):
    cpu = subprocess.run(["sh", "-c", "lscpu | sed -n 's/^Model name: *//p'"], capture_output=True, text=True).stdout.strip()
    lines = [
        "# Phantom's DUSTYWAVE, side by side (generated by scripts/phantom_study.py)",
        "",
        f"Machine: {cpu or 'unknown CPU'}, {os.cpu_count()} cores; {threads} threads, fp64, CPU engine. "
        "Error: L2 of v_x − exact over the gas particles divided by the rms of the exact v_x, at t = 1 "
        "(Phantom's metric); the dust column is the largest over the dust fractions. Wall: the run's "
        "own wall time (set-up to last snapshot). `n` particles per wavelength along x "
        "(n × 12 × 12 per phase).",
        "",
        "## dustsph",
        "",
        "| case | K | Phantom t_s | n | particles | steps | wall (s) | particle-steps/s | error gas | error dust |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        K = f"{r['K']:.0e}" if r["K"] else "—"
        ts = f"{1 / (2 * r['K']):.0e}" if r['K'] else "— (t_k = 1e-6, 1e-4, 1e-2, 1)"
        lines.append(
            f"| {r['case']} | {K} | {ts} | {r['n']} | {r['particles']} | {r['steps']} | {r['wall_s']:.2f} | "
            f"{r['psteps_per_s']:.3e} | {100 * r['err_gas']:.2f}% | {100 * r['err_dust_max']:.2f}% |"
        )
    lines += [
        "",
        "## Phantom (the issue's figures, 2 cores, fp64)",
        "",
        "| K | mode | steps | wall (s) | error | at t |",
        "|---|---|---|---|---|---|",
    ]
    for K, mode, steps, wall, err, t in PHANTOM:
        lines.append(f"| {K:.0e} | {mode} | {steps or '—'} | {wall:g} | {err}% | {t} |")
    with open(os.path.join(out, "results.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


def plot(out, rows):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 7))
    colors = {1e3: "C0", 1e4: "C1", 1e5: "C2", 1e6: "C3", 1e7: "C4"}
    for K in KS:
        pts = sorted((r["wall_s"], 100 * r["err_gas"]) for r in rows if r["case"] == "two-fluid" and r["K"] == K)
        if pts:
            ax.plot(*zip(*pts), "o-", color=colors[K], label=f"dustsph IDIC, K = {K:.0e} (n = 32, 48, 64)")
    poly = sorted((r["wall_s"], 100 * r["err_gas"]) for r in rows if r["case"] == "4 fractions")
    if poly:
        ax.plot(*zip(*poly), "D--", color="k", label="dustsph IDIC, 4 fractions t = 1e-6 … 1")
    fixed = [(r["wall_s"], 100 * r["err_gas"]) for r in rows if r["case"] == "fixed h"]
    if fixed:
        ax.plot(*zip(*fixed), "x", color="C2", ms=9, label="dustsph, fixed h, K = 1e5, n = 64")
    marker = {"two-fluid explicit": "^", "two-fluid implicit": "s", "one-fluid": "*"}
    for K, mode, steps, wall, err, t in PHANTOM:
        face = colors[K] if t == 1.0 else "none"
        ax.plot(wall, err, marker[mode], color=colors[K], mfc=face, ms=10)
    for mode, m in marker.items():
        ax.plot([], [], m, color="gray", ms=9, label=f"Phantom {mode} (hollow: error at t < 1)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time to t = 1 (s, 2 cores)")
    ax.set_ylabel("L2(v_x − exact) / rms(exact v_x)  (%)")
    ax.set_title("DUSTYWAVE 3D (64×12×12 per phase at n = 64): error vs wall time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "error_vs_time.png"), dpi=110)


if __name__ == "__main__":
    sys.exit(main())
