//! Issue 14 under a real MPI launcher (`mpirun --oversubscribe`, OpenMPI): the decomposition,
//! migration and halo exchange of `dustsph mpi-check` on 1–4 ranks, and the clean stop of every
//! rank when one fails. Built only with the `mpi` feature (scripts/features turns it on where
//! OpenMPI is installed).
#![cfg(feature = "mpi")]
mod common;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// `mpirun` with a session directory of its own: OpenMPI keeps each job's under
/// $TMPDIR/ompi.<host>.<uid>, and jobs started side by side (the tests run in parallel) race
/// when one removes that directory while another creates its own in it (seen on CI: "A call
/// to mkdir was unable to create the desired directory").
fn mpirun() -> Command {
    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let k = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("dustsph-mpirun-{}-{k}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut cmd = Command::new("mpirun");
    cmd.env("TMPDIR", &dir)
        .env("OMPI_MCA_orte_tmpdir_base", &dir);
    cmd
}

/// Run a command to its end, failing the test if it takes over three minutes (a rank left
/// waiting on another must not hang CI).
fn finish(mut cmd: Command, what: &str) -> std::process::Output {
    let mut child = cmd
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("mpirun (openmpi-bin; scripts/ensure-deps installs it)");
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(180) {
            child.kill().ok();
            panic!("{what} hung");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.wait_with_output().unwrap()
}

/// `mpirun -n ranks dustsph mpi-check args…`: exit code and output.
fn mpi_check(ranks: u32, args: &[&str]) -> (Option<i32>, String) {
    mpi_check_with(ranks, args, &[])
}

/// [`mpi_check`] with environment variables set.
fn mpi_check_with(ranks: u32, args: &[&str], env: &[(&str, &str)]) -> (Option<i32>, String) {
    let mut cmd = mpirun();
    cmd.envs(env.iter().copied());
    cmd.args(["--allow-run-as-root", "--oversubscribe", "-n"])
        .arg(ranks.to_string())
        .arg(env!("CARGO_BIN_EXE_dustsph"))
        .arg("mpi-check")
        .args(args);
    let o = finish(cmd, &format!("mpirun -n {ranks} mpi-check {args:?}"));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    (o.status.code(), text)
}

/// Every particle owned by exactly the rank owning its cell, counts as the partition says, and
/// every particle within the halo depth of an owned one present (brute force, minimum image):
/// on a periodic 3D slab, the open 3D ball (halo 1 and 2 supports deep), a 1D periodic wave and
/// the 1D shock tube with its walls, on 1 to 4 ranks.
#[test]
fn decomposition_and_halo_exchange_are_complete_on_1_to_4_ranks() {
    let cases: [&[&str]; 5] = [
        &["configs/dustywave_phantom.toml"],
        &["configs/dusty_ball.toml", "--set", "sph.n=12"],
        &[
            "configs/dusty_ball.toml",
            "--set",
            "sph.n=12",
            "--depth",
            "2",
        ],
        &["configs/dustywave.toml"],
        &["configs/dustyshock.toml"],
    ];
    for ranks in 1..=4 {
        for args in cases {
            let (code, text) = mpi_check(ranks, args);
            assert_eq!(code, Some(0), "-n {ranks} {args:?}:\n{text}");
            let rows = text.lines().filter(|l| l.ends_with("| ok |")).count();
            assert_eq!(rows, ranks as usize, "-n {ranks} {args:?}:\n{text}");
        }
    }
}

/// One rank failing stops every rank with that rank's message and a non-zero exit; none
/// waits forever.
#[test]
fn one_failing_rank_stops_every_rank_with_its_message() {
    let (code, text) = mpi_check(3, &["configs/dustywave_phantom.toml", "--fail-rank", "1"]);
    assert_ne!(code, Some(0), "{text}");
    assert!(
        text.contains("rank 1: failure requested by --fail-rank"),
        "{text}"
    );
}

/// The decomposition with physics: stepping over 1–4 ranks with the halo a run uses matches one
/// process to 1e-12 of each field's scale (velocities: at least the sound speed) for every
/// particle matched by id. The thin halo (ghosts one reach deep, refreshed from their owners
/// between the step's passes; the step retaken when particles outrun its margin): the box (also
/// with dust at 30 sound speeds, and one fraction drifting at 5 through a box of 1024 particles
/// a phase, where the halo's motion test gives the gas–dust pairs their own room), the 1D wave (also with IDIC cells of 4h, and with variable h,
/// whose output dust density must not depend on its warm start), the Phantom slab (leapfrog,
/// variable h, IAD, CFL), the shock tube (walls, adiabatic, heating), the settling column
/// (kernel coupling, IAD, gravity), the open 3D ball, the explicit drag baseline with its limit
/// setting the step. The deep halo (`--depth K`: the step's
/// chain of passes recomputed on a halo K supports deep, a fixed shell beyond; a run's fallback
/// when a rank holds no gas): the Phantom slab and the settling column at 4. Too thin a deep
/// halo is caught: three supports for the leapfrog's longer
/// chain, one for the first-order wave, two for the wave's 4h cells, three for the settling
/// column's kernel coupling.
#[test]
fn stepping_over_ranks_matches_one_process() {
    let cases: [&[&str]; 13] = [
        &["configs/dustybox.toml"],
        // One fraction drifting through the gas on a box 64 supports long: its halo holds
        // only where the gas–dust pairs' room (host/dist/motion.rs) is as the passes need it.
        &[
            "configs/dustybox.toml",
            "--set",
            "dust.fractions=[{eps=0.5,t_stop=1.0}]",
            "--set",
            "dustybox.u_dust=[5.0]",
            "--set",
            "sph.n=1024",
            "--set",
            "time.dt=0.001",
        ],
        // Dust at 30 sound speeds: the thin halo's margin is outrun and the step retaken.
        &[
            "configs/dustybox.toml",
            "--set",
            "dustybox.u_dust=[30.0,30.0,30.0,30.0]",
        ],
        // The deep halo (`--depth`): on the leapfrog (the nearest cell: with the kernel
        // coupling this stiff wave ends 5e-12 (v) and 9e-12 (ρ) off one process after 20
        // steps, above the check's 1e-12), and on the kernel coupling (the settling column).
        &[
            "configs/dustywave_phantom.toml",
            "--set",
            "sph.n=32",
            "--set",
            "idic.coupling=\"cell\"",
            "--depth",
            "4",
        ],
        &["configs/dustysettle.toml", "--depth", "4"],
        &["configs/dustysettle.toml"],
        // The explicit drag baseline, its limit setting the step: the least over the ranks of
        // their cells holding a particle of their own.
        &[
            "configs/dustywave.toml",
            "--set",
            "drag.method=\"explicit\"",
            "--set",
            "dust.fractions.0.t_stop=1e-3",
        ],
        &["configs/dustywave.toml"],
        &["configs/dustywave.toml", "--set", "idic.cell=4"],
        &["configs/dustywave.toml", "--set", "sph.variable_h=true"],
        &["configs/dustywave_phantom.toml", "--set", "sph.n=32"],
        &["configs/dustyshock.toml"],
        &["configs/dusty_ball.toml", "--set", "sph.n=12"],
    ];
    for ranks in 1..=4 {
        for args in cases {
            let mut a = args.to_vec();
            a.extend(["--steps", "20"]);
            let (code, text) = mpi_check(ranks, &a);
            assert_eq!(code, Some(0), "-n {ranks} {a:?}:\n{text}");
            assert!(text.contains("against one process"), "{text}");
            // The fast dust outruns the margin: the retake from the step's start is what
            // this case checks, so it must happen.
            if ranks > 1 && args.iter().any(|x| x.contains("u_dust=[30.0")) {
                assert!(
                    text.contains("retaken"),
                    "-n {ranks} {a:?}: no step retaken:\n{text}"
                );
            }
        }
    }
    for (depth, args) in [
        (
            "3",
            &["configs/dustywave_phantom.toml", "--set", "sph.n=32"][..],
        ),
        ("1", &["configs/dustywave.toml"][..]),
        // IDIC cells of 4h: a particle's drag reads cell-mates a support further away.
        ("2", &["configs/dustywave.toml", "--set", "idic.cell=4"][..]),
        // The kernel coupling's deposit and return, with IAD.
        ("3", &["configs/dustysettle.toml"][..]),
    ] {
        let mut a = args.to_vec();
        a.extend(["--depth", depth, "--steps", "20"]);
        let (code, text) = mpi_check(3, &a);
        assert_eq!(code, Some(1), "{a:?}: a halo too thin passed:\n{text}");
        assert!(text.contains("ABOVE 1e-12"), "{text}");
    }
}

/// Each halo refresh of the thin halo moves the fields the step's passes wrote since the last
/// one (named per refresh): with `DUSTSPH_HALO_CHECK` every refresh is followed by a full one,
/// and a ghost value that this changes (a field a refresh left out) stops the step. Every
/// scene kind and option, on 3 ranks; the mutation leaving the accelerations out of the
/// refresh after the forces fails here (and the wave then differs by 4e-8 from one process).
#[test]
// The check and the hook are compiled only with the feature `checks` (scripts/test).
#[cfg(feature = "checks")]
fn each_halo_refresh_moves_every_field_written_since_the_last() {
    let cases: &[&[&str]] = &[
        &["configs/dustybox.toml"],
        &["configs/dustysettle.toml"],
        &[
            "configs/dustywave.toml",
            "--set",
            "drag.method=\"explicit\"",
            "--set",
            "dust.fractions.0.t_stop=1e-3",
        ],
        &[
            "configs/dustywave.toml",
            "--set",
            "time.position_update=\"old\"",
        ],
        &[
            "configs/dustywave.toml",
            "--set",
            "sph.density=\"continuity\"",
        ],
        &["configs/dustywave.toml", "--set", "sph.variable_h=true"],
        &["configs/dustywave_phantom_poly.toml", "--set", "sph.n=32"],
        &[
            "configs/dustyshock.toml",
            "--set",
            "time.integrator=\"kdk\"",
        ],
        &[
            "configs/dustyshock.toml",
            "--set",
            "idic.coupling=\"kernel\"",
        ],
        &[
            "configs/dustywave_phantom.toml",
            "--set",
            "sph.n=32",
            "--set",
            "idic.coupling=\"kernel\"",
            "--set",
            "dustywave.dust_shift=0.5",
        ],
        &["configs/dusty_ball.toml", "--set", "sph.n=12"],
    ];
    for args in cases {
        let mut a = args.to_vec();
        a.extend(["--steps", "8"]);
        let (code, text) = mpi_check_with(3, &a, &[("DUSTSPH_HALO_CHECK", "1")]);
        assert_eq!(code, Some(0), "{a:?}:\n{text}");
        assert!(!text.contains("halo check"), "{a:?}:\n{text}");
    }
}

/// The last snapshot of a run directory, by particle: (phase, id) → (x, v, ρ), and the
/// velocity scale (largest |v| or sqrt(p/ρ)).
type ById = std::collections::BTreeMap<(u8, u64), ([f64; 3], [f64; 3], f64)>;

/// The dust's stopping times in a run's last snapshot, by (1 + fraction, id).
fn last_stopping_times(dir: &std::path::Path) -> std::collections::BTreeMap<(u8, u64), f64> {
    let mut snaps: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| {
            let p = e.ok()?.path();
            (p.extension().is_some_and(|x| x == "h5") && !p.ends_with("checkpoint.h5")).then_some(p)
        })
        .collect();
    snaps.sort();
    let s = dustsph::io::snapshot::read_snapshot(snaps.last().unwrap()).unwrap();
    let mut out = std::collections::BTreeMap::new();
    if let Some(d) = &s.dust {
        let ts = d
            .t_stop
            .as_ref()
            .expect("StoppingTime in every snapshot with dust");
        for i in 0..d.id.len() {
            let f = d.fraction.as_ref().map_or(0, |f| f[i]) as u8;
            out.insert((1 + f, d.id[i]), ts[i]);
        }
    }
    out
}
fn last_snapshot(dir: &std::path::Path) -> (ById, f64, f64) {
    let mut snaps: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| {
            let p = e.unwrap().path();
            (p.extension().is_some_and(|x| x == "h5") && !p.ends_with("checkpoint.h5")).then_some(p)
        })
        .collect();
    snaps.sort();
    let s = dustsph::io::snapshot::read_snapshot(snaps.last().unwrap()).unwrap();
    let mut out = ById::new();
    let mut vmax = 0.0f64;
    for (k, ph) in [(0u8, &s.gas), (1, &s.dust)] {
        let Some(ph) = ph else { continue };
        for i in 0..ph.id.len() {
            let f = ph.fraction.as_ref().map_or(0, |f| f[i]) as u8;
            out.insert((k + f, ph.id[i]), (ph.x[i], ph.v[i], ph.rho[i]));
            vmax = vmax.max(ph.v[i].iter().fold(0.0f64, |a, b| a.max(b.abs())));
            if let Some(p) = &ph.p {
                vmax = vmax.max((p[i] / ph.rho[i]).sqrt());
            }
        }
    }
    (out, vmax, s.time)
}

/// Every particle of `got` within 1e-12 of `reference`: positions relative to the largest |x|,
/// velocities to `vscale`, each density relative to itself.
fn assert_same(reference: &ById, got: &ById, vscale: f64, what: &str) {
    assert_eq!(got.len(), reference.len(), "{what}");
    let xs = reference.values().fold(0.0f64, |a, (x, _, _)| {
        x.iter().fold(a, |m, v| m.max(v.abs()))
    });
    for (k, (x, v, r)) in reference {
        let (gx, gv, gr) = got.get(k).expect("every particle present");
        for d in 0..3 {
            assert!((gx[d] - x[d]).abs() <= 1e-12 * xs, "{what}: x {k:?}");
            assert!((gv[d] - v[d]).abs() <= 1e-12 * vscale, "{what}: v {k:?}");
        }
        assert!((gr - r).abs() <= 1e-12 * r.abs(), "{what}: rho {k:?}");
    }
}

/// `mpirun -n 2/3/4 dustsph run` on the box, the 1D wave, the Phantom slab (leapfrog, variable
/// h, IAD), the shock tube, the settling column (kernel coupling), the small ball, the ball
/// continued from one of its snapshots as initial conditions from a file, and a small disc (h
/// at its edges several times the reference), ends where one process ends: every particle of
/// the last snapshot (rank 0 writes it, matched by ParticleIDs) within 1e-12 of the field's
/// scale, the dust's stopping times (which the ranks' engines compute for an output) within
/// 1e-12 of each, and one summary. Each rank keeps its engine across steps: fewer halos built
/// than steps taken (but on the disc). On 3 ranks each rank's output streams to rank 0 in
/// messages of 7 records, and the snapshots' chunks of 5 rows are deflated on every rank. The
/// file of initial conditions is read by share, in blocks of 64 rows: every rank reads some.
/// The disc's cuts are weighted by the ranks' measured cost.
#[test]
fn a_run_over_ranks_ends_where_one_process_ends() {
    let tmp = tempfile::tempdir().unwrap();
    let bin = env!("CARGO_BIN_EXE_dustsph");
    // The ball's snapshot at t = 0.01 as a file of initial conditions.
    let ball = tmp.path().join("ball");
    let mut cmd = Command::new(bin);
    cmd.args([
        "run",
        "configs/dusty_ball.toml",
        "--set",
        "sph.n=12",
        "--set",
    ])
    .args([
        "sph.h=0.17",
        "--set",
        "time.t_end=0.01",
        "--set",
        "time.output_dt=0.01",
    ])
    .args(["-q", "--out"])
    .arg(&ball);
    assert!(finish(cmd, "the ball's initial conditions")
        .status
        .success());
    let from_file = tmp.path().join("from_file.toml");
    std::fs::write(
        &from_file,
        format!(
            "[scene]\nname = \"from_file\"\nproblem = \"file\"\ndim = 3\n\n[file]\npath = {:?}\n\n\
             [gas]\neos = \"adiabatic\"\ngamma = 1.4\n\n[dust]\nlaw = \"epstein\"\n\
             [[dust.fractions]]\ns_rho = 1e-3\n\n[sph]\nh = 0.17\n\n[idic]\ncell = 0.5\n\n\
             [time]\nt_end = 0.04\ndt = 0.005\noutput_dt = 0.03\n",
            ball.join("snapshot_0001.h5")
        ),
    )
    .unwrap();
    let from_file = from_file.display().to_string();
    let cases: [&[&str]; 8] = [
        &["configs/dustybox.toml", "--set", "time.t_end=0.2"],
        &["configs/dustywave.toml", "--set", "time.t_end=0.3"],
        &[
            "configs/dustywave_phantom.toml",
            "--set",
            "sph.n=32",
            "--set",
            "time.t_end=0.05",
        ],
        &["configs/dustyshock.toml", "--set", "time.t_end=0.02"],
        &["configs/dustysettle.toml", "--set", "time.t_end=0.02"],
        &[
            "configs/dusty_ball.toml",
            "--set",
            "sph.n=12",
            "--set",
            "time.t_end=0.02",
        ],
        &[&from_file],
        // A disc: its tapered edges solve h several times the reference at the start (the
        // first layer computed again on a halo that reaches it), a star's gravity, a locally
        // isothermal gas, three dust fractions; the damped dispersion runs on one process.
        &[
            "configs/dustydisc.toml",
            "--set",
            "sph.n=16",
            "--set",
            "time.t_end=0.5",
            "--set",
            "idic.dispersion=kept",
        ],
    ];
    for (c, args) in cases.iter().enumerate() {
        let one = tmp.path().join(format!("one{c}"));
        let mut cmd = Command::new(bin);
        cmd.arg("run").args(*args).args(["-q", "--out"]).arg(&one);
        let o = finish(cmd, &format!("run {args:?}"));
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let (reference, vscale, t1) = last_snapshot(&one);
        let stops = last_stopping_times(&one);
        let summary_one = std::fs::read_to_string(one.join("summary.json")).unwrap();
        assert!(
            !summary_one.contains("rank_traffic"),
            "one process sends nothing"
        );
        for ranks in 2..=4usize {
            let dir = tmp.path().join(format!("r{c}_{ranks}"));
            let mut cmd = mpirun();
            cmd.args(["--allow-run-as-root", "--oversubscribe", "-n"])
                .arg(ranks.to_string())
                .arg(bin)
                .arg("run")
                .args(*args)
                .args(["-q", "--out"])
                .arg(&dir)
                .env("DUSTSPH_ROW_BLOCK", "64");
            let disc = args[0].contains("dustydisc");
            if disc {
                // Every judgement of the ranks' balance re-weights the cut by their measured
                // cost (the disc's halo is rebuilt every few steps, on cuts by cost).
                cmd.args(["--set", "numerics.rebalance_at=0"]);
            }
            if ranks == 3 {
                // The outputs' streams to rank 0 in many short messages, the last of each
                // rank's shorter; the snapshots in chunks of 5 rows, deflated on every rank.
                cmd.env("DUSTSPH_STREAM_RECORDS", "7");
                cmd.env("DUSTSPH_CHUNK_ROWS", "5");
            }
            let o = finish(cmd, &format!("mpirun -n {ranks} run {args:?}"));
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(o.status.success(), "-n {ranks} {args:?}: {err}");
            // The thin halo, not the deep one it falls back to when a rank holds no gas.
            let summary = std::fs::read_to_string(dir.join("summary.json")).unwrap();
            assert!(summary.contains("thin halo"), "{args:?}: {summary}");
            // Each rank's traffic: at least one exchange per step, some bytes sent (a rank
            // always has neighbours here), the gathers onto rank 0 from the others only.
            let s: serde_json::Value = serde_json::from_str(&summary).unwrap();
            let steps = s["steps"].as_u64().unwrap();
            let traffic = s["rank_traffic"].as_array().expect("rank_traffic");
            assert_eq!(traffic.len(), ranks, "{args:?}");
            for (r, t) in traffic.iter().enumerate() {
                let n = |k: &str| t[k].as_f64().unwrap();
                assert!(n("exchanges") >= steps as f64, "{args:?} rank {r}: {t}");
                assert!(n("exchange_bytes") > 0.0, "{args:?} rank {r}: {t}");
                assert_eq!(n("gather_bytes") > 0.0, r > 0, "{args:?} rank {r}: {t}");
            }
            // The resident engine: built at the start and rebuilt only where the motion used up
            // its halo's margin (not every step). The small disc's inner orbits use it up within
            // one to three steps, by a margin the measured build and step times choose, so
            // that it may be rebuilt every step on a slower machine (docs/scaling.md).
            let backend = s["backend"].as_str().unwrap();
            let built: u64 = (backend.split(" built ").nth(1))
                .and_then(|b| b.split(' ').next()?.parse().ok())
                .unwrap_or_else(|| panic!("{args:?}: {backend}"));
            assert!(disc || built < steps, "{args:?} -n {ranks}: {backend}");
            assert!(
                !disc || backend.contains("on a cut by the ranks' measured cost"),
                "{args:?} -n {ranks}: {backend}"
            );
            let (got, _, t) = last_snapshot(&dir);
            assert_eq!(t, t1, "-n {ranks} {args:?}");
            assert_same(&reference, &got, vscale, &format!("-n {ranks} {args:?}"));
            // The errors against the exact solutions, the ball's core and radii and the
            // conservation sums, reduced over the ranks (no rank gathers the whole state but
            // on the settling column), as one process computes them.
            let one_s: serde_json::Value = serde_json::from_str(&summary_one).unwrap();
            for key in ["errors", "ball", "conservation"] {
                same_numbers(&one_s[key], &s[key], &format!("-n {ranks} {args:?} {key}"));
            }
            let got = last_stopping_times(&dir);
            assert_eq!(got.len(), stops.len(), "{args:?}");
            for (k, t) in &stops {
                let d = (got[k] - t).abs() / t.abs().max(1e-300);
                assert!(
                    d < 1e-12 || (t.is_infinite() && got[k] == *t),
                    "-n {ranks} {args:?}: stopping time of {k:?} {} against {t}",
                    got[k]
                );
            }
        }
    }
}

/// Every number of `want` in `got` at the same place, within 1e-6 of its size and 1e-12, and
/// every other value equal: the particles agree to 1e-12 of their fields' scales, which the
/// wave's Phantom metric divides by the amplitude (1e-4 of ρ0: its norms agree to 2e-9), and
/// the sums' order differs over ranks; a share's sums alone are off by the other shares.
fn same_numbers(want: &serde_json::Value, got: &serde_json::Value, what: &str) {
    use serde_json::Value;
    match (want, got) {
        (Value::Number(a), Value::Number(b)) => {
            let (a, b) = (a.as_f64().unwrap(), b.as_f64().unwrap());
            assert!(
                (a - b).abs() <= 1e-6 * a.abs() + 1e-12,
                "{what}: {b} against {a}"
            );
        }
        (Value::Array(a), Value::Array(b)) => {
            assert_eq!(a.len(), b.len(), "{what}");
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                same_numbers(x, y, &format!("{what}[{i}]"));
            }
        }
        (Value::Object(a), Value::Object(b)) => {
            assert_eq!(a.len(), b.len(), "{what}: {b:?}");
            for (k, x) in a {
                same_numbers(x, &b[k], &format!("{what}.{k}"));
            }
        }
        (a, b) => assert_eq!(a, b, "{what}"),
    }
}

/// A checkpoint written by a run over 3 ranks (stopped after 20 steps) resumes on 2 ranks and
/// on one process, and both end where an uninterrupted one-process run ends: every particle of
/// the last snapshot within 1e-12 of the field's scale (the Phantom slab: leapfrog, variable h).
/// Each of the 2 ranks reads its share of the checkpoint's rows; one altered row stops both.
#[test]
fn a_checkpoint_written_over_3_ranks_resumes_on_2_and_on_1() {
    let tmp = tempfile::tempdir().unwrap();
    let bin = env!("CARGO_BIN_EXE_dustsph");
    let scene = [
        "configs/dustywave_phantom.toml",
        "--set",
        "sph.n=32",
        "--set",
        "time.t_end=0.3",
        "-q",
    ];
    let one = tmp.path().join("one");
    let mut cmd = Command::new(bin);
    cmd.arg("run").args(scene).arg("--out").arg(&one);
    assert!(finish(cmd, "run").status.success());
    let (reference, vscale, t1) = last_snapshot(&one);
    let three = tmp.path().join("three");
    let mut cmd = mpirun();
    cmd.args([
        "--allow-run-as-root",
        "--oversubscribe",
        "-n",
        "3",
        bin,
        "run",
    ])
    .args(scene)
    .arg("--out")
    .arg(&three)
    .args(["--checkpoint-every", "20", "--stop-after", "20"]);
    let o = finish(cmd, "mpirun -n 3 run --stop-after 20");
    assert!(!o.status.success(), "the run was to stop early");
    assert!(three.join("checkpoint.h5").exists());
    for ranks in [1u32, 2] {
        let dir = tmp.path().join(format!("resumed{ranks}"));
        let copy = Command::new("cp")
            .arg("-r")
            .arg(&three)
            .arg(&dir)
            .status()
            .unwrap();
        assert!(copy.success());
        let mut cmd = if ranks == 1 {
            Command::new(bin)
        } else {
            let mut c = mpirun();
            c.args(["--allow-run-as-root", "--oversubscribe", "-n", "2", bin]);
            // Each rank reads its share of each phase's rows, in blocks of 64.
            c.env("DUSTSPH_ROW_BLOCK", "64");
            c
        };
        cmd.arg("resume").arg(&dir).arg("-q");
        let o = finish(cmd, "resume");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let (got, _, t) = last_snapshot(&dir);
        assert_eq!(t, t1);
        assert_same(&reference, &got, vscale, &format!("resumed on {ranks}"));
    }
    // A mass altered in the last row, which rank 1 reads: rank 0's digest of the file finds
    // it, and no rank resumes (exit 2, the directory as it was).
    let ck = three.join("checkpoint.h5");
    {
        let f = hdf5::File::open_rw(&ck).unwrap();
        let ds = f.dataset("gas/m").unwrap();
        let mut m: Vec<f64> = ds.read_raw().unwrap();
        *m.last_mut().unwrap() *= 1.0 + 1e-15;
        ds.write_raw(&m).unwrap();
    }
    let listing = |d: &std::path::Path| {
        let mut v: Vec<(String, Vec<u8>)> = (std::fs::read_dir(d).unwrap().flatten())
            .map(|e| {
                let name = e.file_name().to_string_lossy().to_string();
                (name, std::fs::read(e.path()).unwrap())
            })
            .collect();
        v.sort();
        v
    };
    let before = listing(&three);
    let mut cmd = mpirun();
    cmd.args(["--allow-run-as-root", "--oversubscribe", "-n", "2", bin])
        .env("DUSTSPH_ROW_BLOCK", "64")
        .arg("resume")
        .arg(&three)
        .arg("-q");
    let o = finish(cmd, "resume of an altered checkpoint");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("checksum mismatch"), "{err}");
    assert!(
        listing(&three) == before,
        "a refused resume changed the directory"
    );
}

/// Killing one rank mid-run stops the job (mpirun says which rank died) and the snapshots
/// written before stay readable; no summary is written.
#[test]
fn killing_one_rank_stops_the_job_and_keeps_the_snapshots() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("killed");
    let mut child = mpirun()
        .args(["--allow-run-as-root", "--oversubscribe", "-n", "3"])
        .arg(env!("CARGO_BIN_EXE_dustsph"))
        .args([
            "run",
            "configs/dustywave_phantom.toml",
            "--set",
            "sph.n=32",
            "--set",
            "time.t_end=100",
            "--set",
            "time.output_dt=0.1",
            "-q",
            "--out",
        ])
        .arg(&dir)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !dir.join("snapshot_0001.h5").exists() {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no second snapshot"
        );
        assert!(child.try_wait().unwrap().is_none(), "the run ended early");
        std::thread::sleep(Duration::from_millis(50));
    }
    // One of mpirun's ranks (its children), not the first.
    let ranks = String::from_utf8(
        Command::new("pgrep")
            .args(["-P", &child.id().to_string()])
            .output()
            .unwrap()
            .stdout,
    )
    .unwrap();
    let victim = ranks.lines().nth(1).expect("three ranks");
    assert!(Command::new("kill")
        .args(["-9", victim])
        .status()
        .unwrap()
        .success());
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(180) {
            child.kill().ok();
            panic!("the job went on after a rank was killed");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let o = child.wait_with_output().unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("signal 9"), "{err}");
    assert!(!dir.join("summary.json").exists());
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "h5") {
            dustsph::io::snapshot::read_snapshot(&p)
                .expect("a snapshot written before stays readable");
            n += 1;
        }
    }
    assert!(n >= 2, "{n} snapshots");
}

/// Each rank steps on the device asked for (`--device`, rank r on GPU r mod count): where no
/// GPU is usable, `cuda` stops every rank before anything is written, naming the option, and
/// `auto` steps on the CPU and says so in summary.json's backend. (On a machine with a GPU the
/// ranks' CUDA steps are checked by scripts/gpu-check, not here.)
#[test]
fn each_rank_steps_on_the_device_asked_for() {
    let bin = env!("CARGO_BIN_EXE_dustsph");
    let probe = Command::new(bin).arg("gpu").output().unwrap();
    if !String::from_utf8_lossy(&probe.stdout).contains("device: none") {
        eprintln!("a GPU is usable here: the no-GPU contract is not what this machine has");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let run = |device: &str, dir: &std::path::Path| {
        let mut cmd = mpirun();
        cmd.args(["--allow-run-as-root", "--oversubscribe", "-n", "2"])
            .arg(bin)
            .args(["run", "configs/dustybox.toml", "--set", "time.t_end=0.05"])
            .args(["--device", device, "--out"])
            .arg(dir);
        finish(cmd, &format!("mpirun -n 2 run --device {device}"))
    };
    let cuda = tmp.path().join("cuda");
    let o = run("cuda", &cuda);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success(),
        "--device cuda without a GPU ran: {err}"
    );
    assert!(err.contains("--device cuda"), "{err}");
    assert!(!cuda.exists(), "--device cuda without a GPU wrote output");
    let auto = tmp.path().join("auto");
    let o = run("auto", &auto);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("no GPU used"), "{err}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(auto.join("summary.json")).unwrap()).unwrap();
    let backend = summary["backend"].as_str().unwrap();
    assert!(
        backend.starts_with("2 MPI ranks") && backend.contains("each stepping on cpu"),
        "{backend}"
    );
}

/// A failure inside a step on one rank, where the thin halo's other ranks wait in a refresh it
/// will not reach: the job stops (MPI_Abort) within the time limit with that rank's message,
/// and the snapshots written before stay readable; no summary.
#[test]
// The check and the hook are compiled only with the feature `checks` (scripts/test).
#[cfg(feature = "checks")]
fn a_failure_inside_a_step_stops_the_job_with_its_message() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("failed");
    let mut cmd = mpirun();
    cmd.args(["--allow-run-as-root", "--oversubscribe", "-n", "3"])
        .args(["-x", "DUSTSPH_FAIL_IN_STEP=1:3"])
        .arg(env!("CARGO_BIN_EXE_dustsph"))
        .args([
            "run",
            "configs/dustywave_phantom.toml",
            "--set",
            "sph.n=32",
            "-q",
            "--out",
        ])
        .arg(&dir)
        .env("DUSTSPH_FAIL_IN_STEP", "1:3");
    let o = finish(cmd, "a run with a rank failing inside a step");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("step 3: rank 1:") && err.contains("failure requested"),
        "{err}"
    );
    assert!(!dir.join("summary.json").exists());
    dustsph::io::snapshot::read_snapshot(&dir.join("snapshot_0000.h5"))
        .expect("the first snapshot stays readable");
}

/// Rank 0 alone builds the engine on the whole scene and checks the first step: a step that
/// collapses at t = 0 is refused on every rank (exit 2, rank 0's message, no output directory),
/// none left waiting.
#[test]
fn a_first_step_refused_on_rank_0_stops_every_rank_before_any_output() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("refused");
    let mut cmd = mpirun();
    cmd.args(["--allow-run-as-root", "--oversubscribe", "-n", "3"])
        .arg(env!("CARGO_BIN_EXE_dustsph"))
        .args([
            "run",
            "configs/dustywave.toml",
            "--set",
            "gas.cs=1e12",
            "--out",
        ])
        .arg(&dir);
    let o = finish(cmd, "a run refused by rank 0");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("the first step cannot be taken"), "{err}");
    assert!(!dir.exists());
}

/// Initial conditions read by share over 3 ranks (`DUSTSPH_ROW_BLOCK=8`: rank 0 reads the
/// gas's rows 0–7, rank 1 rows 8–23, rank 2 rows 24–35): a value no rank but rank 1 reads, an
/// ID that rank 2's dust repeats from rank 0's gas, and two bad columns on different ranks
/// (the first column's named, as one process names it), stop every rank with exit 2, rank 0
/// naming the row in the file once, and nothing written; the good file runs, each rank
/// reading its own rows, to where one process ends.
#[test]
fn a_file_read_by_share_over_ranks_names_a_bad_row_in_the_file() {
    use common::ics::*;
    let bin = env!("CARGO_BIN_EXE_dustsph");
    let l = dustsph::scene::load(
        &common::config("dustybox"),
        &["scene.dim=2", "sph.n=6", "sph.hfact=1.2"].map(String::from),
    )
    .unwrap();
    let su = dustsph::setup::build(&l.scene).unwrap();
    let good = || IcFile::of_state(&su.state, su.h, 2, Some([1.0, 1.0, 0.0]));
    assert_eq!(su.state.gas.ph.len(), 36);
    let rest = "[gas]\neos = \"isothermal\"\ncs = 1.0\n\n[dust]\nlaw = \"constant_t\"\n\
        [[dust.fractions]]\nt_stop = 0.1\n[[dust.fractions]]\nt_stop = 0.215443\n\
        [[dust.fractions]]\nt_stop = 0.464159\n[[dust.fractions]]\nt_stop = 1.0\n\n\
        [sph]\nhfact = 1.2\n\n[idic]\ncoupling = \"cell\"\ncell = 0.5\n\n[time]\nt_end = 0.03\n\
        dt = 0.01\n";
    let run = |f: &IcFile, ranks: Option<u32>| {
        let dir = tempfile::tempdir().unwrap();
        f.write(&dir.path().join("ics.h5"));
        let scene = file_scene(dir.path(), 2, "ics.h5", "[true, true, false]", rest);
        let out = dir.path().join("out");
        let mut cmd = match ranks {
            Some(n) => {
                let mut c = mpirun();
                c.args(["--allow-run-as-root", "--oversubscribe", "-n"])
                    .arg(n.to_string())
                    .arg(bin);
                c
            }
            None => Command::new(bin),
        };
        cmd.args(["run", scene.path.to_str().unwrap(), "-q", "--out"])
            .arg(&out)
            .env("DUSTSPH_ROW_BLOCK", "8");
        let o = finish(cmd, "a run from a file");
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        let last = out.exists().then(|| last_snapshot(&out));
        (o.status.code(), err, last, dir)
    };
    let bad = |spoil: &dyn Fn(&mut IcFile)| {
        let mut f = good();
        spoil(&mut f);
        let (code, err, last, _dir) = run(&f, Some(3));
        assert_eq!(code, Some(2), "{err}");
        assert!(last.is_none(), "nothing written: {err}");
        err
    };
    let err = bad(&|f| {
        if let Column::F(v, w) = f.column("PartType0", "Velocities") {
            v[20 * *w] = f64::NAN;
        }
    });
    assert_eq!(
        err.matches("/PartType0/Velocities[20] holds NaN").count(),
        1,
        "{err}"
    );
    let err = bad(&|f| {
        let gas_id = match f.column("PartType0", "ParticleIDs") {
            Column::I(v) => v[2],
            _ => unreachable!(),
        };
        if let Column::I(v) = f.column("PartType3", "ParticleIDs") {
            let last = v.len() - 1;
            v[last] = gas_id;
        }
    });
    let dust_rows = 4 * 36 - 1;
    let named =
        format!("/PartType0/ParticleIDs[2] and /PartType3/ParticleIDs[{dust_rows}] are both");
    assert_eq!(err.matches(&named).count(), 1, "{err}");
    // Two bad rows: one process checks the whole of Coordinates before Masses, and so names
    // rank 2's row 30, not rank 0's row 3.
    let err = bad(&|f| {
        if let Column::F(v, w) = f.column("PartType0", "Coordinates") {
            v[30 * *w] = f64::INFINITY;
        }
        if let Column::F(v, _) = f.column("PartType0", "Masses") {
            v[3] = -1.0;
        }
    });
    assert_eq!(
        err.matches("/PartType0/Coordinates[30] holds inf").count(),
        1,
        "{err}"
    );
    let (code, err1, one, _d1) = run(&good(), None);
    assert_eq!(code, Some(0), "{err1}");
    let (code, err, three, _d3) = run(&good(), Some(3));
    assert_eq!(code, Some(0), "{err}");
    // The start-up note (the file's digest, counts, each fraction's ε, h) as one process's.
    let note = |e: &str| -> String {
        let line = e.lines().find(|l| l.contains("initial conditions:"));
        let line = line.unwrap_or_else(|| panic!("no note: {e}"));
        line.split("(SHA-256").nth(1).unwrap().to_string()
    };
    assert_eq!(note(&err), note(&err1));
    let ((reference, vscale, t1), (got, _, t3)) = (one.unwrap(), three.unwrap());
    assert_eq!(t1, t3);
    assert_same(&reference, &got, vscale, "the box from a file over 3 ranks");
    // The dust shifted off the gas's cells: no rank sees every particle, and the ranks'
    // count of dust without gas in its cell warns as one process's does, once.
    let l = dustsph::scene::load(
        &common::config("dustybox"),
        &[
            "scene.dim=2",
            "sph.n=6",
            "sph.hfact=1.2",
            "dustybox.dust_shift=0.2",
        ]
        .map(String::from),
    )
    .unwrap();
    let su = dustsph::setup::build(&l.scene).unwrap();
    let shifted = IcFile::of_state(&su.state, su.h, 2, Some([1.0, 1.0, 0.0]));
    let warning = |err: &str| -> Vec<String> {
        (err.lines())
            .filter(|l| l.contains("share no IDIC cell with a gas particle"))
            .map(String::from)
            .collect()
    };
    let (_, err1, _, _d1) = run(&shifted, None);
    let (code, err3, _, _d3) = run(&shifted, Some(3));
    assert_eq!(code, Some(0), "{err3}");
    assert_eq!(warning(&err1).len(), 1, "{err1}");
    assert_eq!(warning(&err3), warning(&err1), "{err3}");
}
