//! Long runs are safe: a checkpointed and resumed run is bit-for-bit the uninterrupted one,
//! and Ctrl-C leaves a checkpoint that `dustsph resume` completes.
mod common;
use common::config;

/// One test of this file at a time. HDF5 opens its files without close-on-exec and locks them
/// (flock): a `dustsph` child spawned by one test while another test holds a checkpoint open
/// inherits that descriptor and its lock for its whole run, and the other test's next
/// read-write open then fails with EAGAIN (seen once in CI).
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}
use dustsph::particles::{Phase, State};
use dustsph::sim::run::{Run, RunOptions};
use std::process::Command;

fn bits(ph: &Phase) -> Vec<u64> {
    let mut b: Vec<u64> = Vec::new();
    for i in 0..ph.len() {
        b.extend(ph.x[i].iter().chain(&ph.v[i]).map(|v| v.to_bits()));
        b.push(ph.m[i].to_bits());
        b.push(ph.rho[i].to_bits());
        b.push(ph.id[i]);
    }
    b
}

fn assert_identical(a: &State, b: &State) {
    assert_eq!(a.step, b.step);
    assert_eq!(a.t.to_bits(), b.t.to_bits());
    assert_eq!(bits(&a.gas.ph), bits(&b.gas.ph), "gas");
    let e = |s: &State| {
        s.gas
            .e
            .as_ref()
            .map(|e| e.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
    };
    assert_eq!(e(a), e(b), "energy");
    assert_eq!(
        a.gas.p.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        b.gas.p.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
    for (k, (x, y)) in a.dust.iter().zip(&b.dust).enumerate() {
        assert_eq!(bits(x), bits(y), "dust fraction {k}");
    }
}

fn resume_is_bit_exact(scene: &str, sets: &[&str], n: u64) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let loaded = dustsph::scene::load(&config(scene), &sets).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let opts = |d: &str| RunOptions::quiet_on_cpu(tmp.path().join(d));
    let mut whole = Run::start(&loaded, &opts("whole")).unwrap();
    whole.advance(Some(2 * n), None, None).unwrap();
    let mut first = Run::start(&loaded, &opts("split")).unwrap();
    first.advance(Some(n), None, None).unwrap();
    first.checkpoint().unwrap();
    drop(first);
    let mut second = Run::resume(
        &tmp.path().join("split"),
        false,
        dustsph::step::backend::DeviceChoice::Cpu,
    )
    .unwrap();
    second.advance(Some(n), None, None).unwrap();
    let (a, b) = (
        whole.current_state().unwrap().clone(),
        second.current_state().unwrap(),
    );
    assert_eq!(a.step, 2 * n);
    assert_identical(&a, b);
}

#[test]
fn resumed_ball_is_bit_identical() {
    let _serial = serial();
    // Adiabatic gas, Epstein drag from cell means, an expanding unbounded grid.
    resume_is_bit_exact("dusty_ball", &["scene.dim=2", "sph.n=20", "sph.h=0.1"], 15);
}

#[test]
fn resumed_variable_h_wave_is_bit_identical() {
    let _serial = serial();
    // 3D close-packed slab, variable h (h and Ω travel in the checkpoint), constant-K drag.
    resume_is_bit_exact("dustywave_phantom", &["sph.n=16", "dustywave.layers=6"], 10);
}

#[test]
fn resumed_kernel_coupling_runs_are_bit_identical() {
    let _serial = serial();
    // The kernel coupling with external gravity, walls and IAD (its normalisers are rebuilt
    // from the positions on resume), and with offset dust, the leapfrog, variable h and the
    // variable-h dust densities of the Phantom wave.
    resume_is_bit_exact("dustysettle", &["sph.n=200"], 8);
    resume_is_bit_exact(
        "dustywave_phantom",
        &[
            "sph.n=16",
            "dustywave.layers=6",
            "dustywave.dust_shift=0.5",
            "idic.coupling=\"kernel\"",
        ],
        10,
    );
}

#[test]
fn resumed_shock_tube_is_bit_identical() {
    let _serial = serial();
    // Viscosity, drag heating, fixed walls, CFL time step.
    resume_is_bit_exact("dustyshock", &["sph.n=400"], 30);
}

#[test]
fn ctrl_c_checkpoints_and_resume_finishes_the_run() {
    let _serial = serial();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let out_s = out.display().to_string();
    let bin = env!("CARGO_BIN_EXE_dustsph");
    // A run of several seconds: the 3D ball at modest resolution.
    let mut child = Command::new(bin)
        .args([
            "run",
            "configs/dusty_ball.toml",
            "--set",
            "sph.n=14",
            "--set",
            "sph.h=0.15",
            "--set",
            "time.t_end=0.4",
            "--out",
            &out_s,
            "-q",
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .spawn()
        .unwrap();
    // Wait for the first snapshot, so the handler is installed and the loop is running.
    let t0 = std::time::Instant::now();
    while !out.join("snapshot_0000.h5").exists() {
        assert!(t0.elapsed().as_secs() < 60, "no first snapshot");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    // At once: the run (80 steps, ≈4 s on 2 cores) is then a few steps in at most.
    let killed = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let status = child.wait().unwrap();
    // The interrupt must have happened: a run that finished first would test nothing.
    assert_eq!(status.code(), Some(130), "interrupted run exits with 130");
    assert!(out.join("checkpoint.h5").exists());
    let (ck, _) = dustsph::io::checkpoint::read_checkpoint(&out.join("checkpoint.h5")).unwrap();
    assert!(
        ck.step < 80 && ck.t < 0.4,
        "interrupted at step {}",
        ck.step
    );
    // The summary of the state reached, saying so.
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let ending = s["ending"].as_str().unwrap();
    assert!(
        ending.starts_with(&format!("interrupted at step {}", ck.step))
            && ending.contains("dustsph resume"),
        "{ending}"
    );
    assert_eq!(s["t_final"], ck.t);
    let o = Command::new(bin)
        .args(["resume", &out_s, "-q"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["t_final"], 0.4);
    assert_eq!(s["ending"], "finished");
    assert_eq!(s["snapshots"].as_array().unwrap().len(), 9);
}

/// Run `scene` for `steps` steps into `dir` and leave a checkpoint there.
fn checkpointed(scene: &str, sets: &[&str], dir: &std::path::Path, steps: u64) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let loaded = dustsph::scene::load(&config(scene), &sets).unwrap();
    let opts = RunOptions::quiet_on_cpu(dir.to_path_buf());
    let mut r = Run::start(&loaded, &opts).unwrap();
    r.advance(Some(steps), None, None).unwrap();
    r.checkpoint().unwrap();
}

/// Every file of a directory with its bytes, to show that a refused resume changed nothing.
fn contents(dir: &std::path::Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| {
            (
                e.file_name().to_string_lossy().to_string(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

fn resume_refused(dir: &std::path::Path, why: &str) {
    let before = contents(dir);
    let o = Command::new(env!("CARGO_BIN_EXE_dustsph"))
        .args(["resume", &dir.display().to_string(), "-q"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(why), "expected «{why}» in: {err}");
    assert_eq!(
        contents(dir),
        before,
        "a refused resume changed the directory"
    );
}

/// Issue 13: resume continues only the run a whole checkpoint belongs to.
#[test]
fn resume_refuses_a_foreign_altered_or_inconsistent_checkpoint() {
    let _serial = serial();
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    checkpointed("dustywave", &["time.output_dt=0.05"], &a, 30);
    checkpointed("dustybox", &[], &b, 3);
    // Another scene's checkpoint among this run's snapshots.
    let ck = dustsph::io::checkpoint::CHECKPOINT_NAME;
    std::fs::copy(b.join(ck), a.join(ck)).unwrap();
    resume_refused(&a, "written by another run");
    // A checkpoint cut short or altered: the digest no longer matches.
    let (state, meta) = dustsph::io::checkpoint::read_checkpoint(&b.join(ck)).unwrap();
    {
        let f = hdf5::File::open_rw(b.join(ck)).unwrap();
        let ds = f.dataset("gas/m").unwrap();
        let mut m: Vec<f64> = ds.read_raw().unwrap();
        m[0] *= 1.0 + 1e-15;
        ds.write_raw(&m).unwrap();
    }
    resume_refused(&b, "checksum mismatch");
    // A whole checkpoint whose particles disagree with its own scene.
    let mut other = meta.clone();
    other.scene_text = other.scene_text.replace("n = ", "n = 1");
    assert_ne!(other.scene_text, meta.scene_text);
    dustsph::io::checkpoint::write_checkpoint(&b.join(ck), &state, &other).unwrap();
    for s in std::fs::read_dir(&b).unwrap().flatten() {
        if s.file_name().to_string_lossy().starts_with("snapshot_") {
            std::fs::remove_file(s.path()).unwrap();
        }
    }
    let mut prog: serde_json::Value = serde_json::from_str(&other.progress_json).unwrap();
    prog["outputs"]["snapshots"] = serde_json::json!([]);
    other.progress_json = prog.to_string();
    dustsph::io::checkpoint::write_checkpoint(&b.join(ck), &state, &other).unwrap();
    resume_refused(&b, "do not match its own scene");
}

/// A finished run is not resumed (its summary stays as it is), a snapshot replaced by another of
/// the same run is noticed, and a stopped-and-resumed run's summary carries the same
/// conservation sums and errors, to the bit, as an uninterrupted one (the checkpoint's progress
/// read back exactly).
#[test]
fn resume_refuses_a_finished_run_or_a_replaced_snapshot_and_resumes_the_summary_exactly() {
    let _serial = serial();
    let tmp = tempfile::tempdir().unwrap();
    let bin = env!("CARGO_BIN_EXE_dustsph");
    // The 1D wave, n particles per wavelength, outputs every 0.1 to t_end.
    let run = |dir: &std::path::Path, n: &str, t_end: &str, extra: &[&str]| {
        let o = Command::new(bin)
            .args([
                "run",
                "configs/dustywave.toml",
                "--set",
                &format!("sph.n={n}"),
            ])
            .args(["--set", &format!("time.t_end={t_end}")])
            .args(["--set", "time.output_dt=0.1", "-q"])
            .args(extra)
            .arg("--out")
            .arg(dir)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).to_string(),
        )
    };
    let whole = tmp.path().join("whole");
    assert_eq!(
        run(&whole, "32", "0.3", &["--checkpoint-every", "1"]).0,
        Some(0)
    );
    resume_refused(&whole, "already reached t_end");
    // Stopped after 4 of 9 steps with a checkpoint, then resumed: the same summary numbers (the
    // dust mass 0.10000000000000005 of this set-up read back as …03 without an exact parser).
    let part = tmp.path().join("part");
    let (code, err) = run(
        &part,
        "32",
        "0.3",
        &["--checkpoint-every", "4", "--stop-after", "4"],
    );
    assert_eq!(code, Some(130), "{err}");
    let o = Command::new(bin)
        .args(["resume", &part.display().to_string(), "-q"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary = |d: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join("summary.json")).unwrap()).unwrap()
    };
    let (a, b) = (summary(&whole), summary(&part));
    for key in ["conservation", "errors", "steps", "t_final", "snapshots"] {
        assert_eq!(a[key], b[key], "summary.json «{key}» after resume");
    }
    // A snapshot of the run replaced by an earlier one of the same run.
    let again = tmp.path().join("again");
    let (code, err) = run(
        &again,
        "64",
        "0.6",
        &["--checkpoint-every", "25", "--stop-after", "25"],
    );
    assert_eq!(code, Some(130), "{err}");
    std::fs::copy(
        again.join("snapshot_0000.h5"),
        again.join("snapshot_0001.h5"),
    )
    .unwrap();
    resume_refused(&again, "it was replaced");
}

/// A small 2D ball with a snapshot every few steps (its error norms and core checks too).
fn small_ball(sets: &[&str]) -> dustsph::scene::LoadedScene {
    let mut all = vec![
        "scene.dim=2",
        "sph.n=20",
        "sph.h=0.1",
        "time.t_end=0.04",
        "time.output_dt=0.01",
    ];
    all.extend_from_slice(sets);
    let sets: Vec<String> = all.iter().map(|s| s.to_string()).collect();
    dustsph::scene::load(&config("dusty_ball"), &sets).unwrap()
}

/// The snapshots written on the writer thread from a copy of the state, while the run steps
/// on, are byte for byte those written before stepping on (`--inline-outputs`): the copy is
/// the state of the output's time, in the output's order, and each file gets its own name and
/// its place in the series; the error norms, core checks and time-bin censuses made on the
/// writer are the same. On the ball (a fixed step; its core checks) and the shock tube (CFL
/// steps: the census at every snapshot after the first).
#[test]
fn snapshots_written_beside_the_steps_are_those_written_before_them() {
    let _serial = serial();
    let shock: Vec<String> = ["sph.n=400", "time.t_end=0.1", "time.output_dt=0.02"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let shock = dustsph::scene::load(&config("dustyshock"), &shock).unwrap();
    for (loaded, census) in [(small_ball(&[]), false), (shock, true)] {
        let tmp = tempfile::tempdir().unwrap();
        let run = |dir: &str, inline: bool| {
            let mut opts = RunOptions::quiet_on_cpu(tmp.path().join(dir));
            opts.inline_outputs = inline;
            dustsph::sim::run::run(&loaded, &opts).unwrap().0
        };
        let (beside, before) = (run("beside", false), run("before", true));
        assert!(beside.snapshots.len() >= 5, "{:?}", beside.snapshots);
        assert_eq!(beside.snapshots, before.snapshots);
        fn json(v: &impl serde::Serialize) -> String {
            serde_json::to_string(v).unwrap()
        }
        assert!(!beside.errors.is_empty());
        assert_eq!(json(&beside.errors), json(&before.errors));
        let bins = if census {
            beside.snapshots.len() - 1
        } else {
            0
        };
        assert_eq!(beside.time_bins.len(), bins);
        assert_eq!(json(&beside.time_bins), json(&before.time_bins));
        let core = |s: &dustsph::sim::run::Summary| s.ball.as_ref().map(|b| json(&b.core));
        assert_eq!(core(&beside), core(&before));
        let mut files: Vec<String> = beside.snapshots.clone();
        files.extend(beside.snapshots.iter().map(|s| s.replace(".h5", ".xmf")));
        files.push("snapshots.xmf".into());
        for f in files {
            let read = |d: &str| std::fs::read(tmp.path().join(d).join(&f)).unwrap();
            assert!(read("beside") == read("before"), "{f} differs");
        }
    }
}

/// A checkpoint taken while a snapshot is being written waits for it: the checkpoint's record
/// lists it, and its file is whole (Ctrl-C before the first step, the t = 0 snapshot pending).
#[test]
fn a_checkpoint_waits_for_the_snapshot_being_written_and_lists_it() {
    let _serial = serial();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut r = Run::start(&small_ball(&[]), &RunOptions::quiet_on_cpu(&out)).unwrap();
    let ctrl_c = std::sync::atomic::AtomicBool::new(true);
    let stop = r.advance(None, None, Some(&ctrl_c)).unwrap();
    assert_eq!(stop, dustsph::sim::Stop::Interrupted { checkpointed: true });
    let (_, _, progress) = dustsph::sim::checkpoint::read(&out).unwrap();
    assert_eq!(progress.outputs.snapshots, ["snapshot_0000.h5"]);
    assert!(
        !progress.outputs.errors.is_empty() && progress.outputs.errors.iter().all(|e| e.t == 0.0)
    );
    dustsph::io::read_snapshot(&out.join("snapshot_0000.h5")).unwrap();
}

/// A snapshot the writer thread cannot write fails the run, naming the file, even when it is
/// the run's last output; it is not listed as written, and no part of it is left.
#[test]
fn a_snapshot_the_writer_cannot_write_fails_the_run_naming_it() {
    let _serial = serial();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    // Two outputs: t = 0, then t_end, whose name is taken by a directory (the file's rename
    // onto it fails after the whole file is written).
    let loaded = small_ball(&["time.output_dt=1.0"]);
    let mut r = Run::start(&loaded, &RunOptions::quiet_on_cpu(&out)).unwrap();
    std::fs::create_dir(out.join("snapshot_0001.h5")).unwrap();
    let err = r.advance(None, None, None).unwrap_err();
    assert!(
        matches!(err, dustsph::sim::RunError::Io(_))
            && err.to_string().contains("snapshot_0001.h5"),
        "{err}"
    );
    let left: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("snapshot_0001") && n != "snapshot_0001.h5")
        .collect();
    assert!(left.is_empty(), "{left:?}");
    let (s, _) = r.finish_as("failed".into()).unwrap();
    assert_eq!(s.snapshots, ["snapshot_0000.h5"]);
}
