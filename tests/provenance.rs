//! Every output says how it was made: the snapshots carry the effective scene (the file with the
//! `--set` overrides applied) and every reader (profile, the ball's figures, resume) uses it.
use std::path::Path;
use std::process::Command;

fn dustsph(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dustsph"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap()
}

/// The ball run with `--set gas.p=2` is profiled against the p = 2 reference, not the file's
/// p = 1: the profile of its last snapshot reports the errors the run itself computed (from
/// the scene in memory), and those differ from the errors against the p = 1 reference.
#[test]
fn a_ball_run_with_overrides_is_profiled_against_its_own_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ball");
    let sets = ["sph.n=8", "sph.h=0.25", "gas.p=2", "time.t_end=0.05"];
    let mut args = vec!["run", "configs/dusty_ball.toml"];
    for s in &sets {
        args.extend(["--set", s]);
    }
    let out_s = out.display().to_string();
    args.extend(["--set", "time.output_dt=", "--out", &out_s, "-q"]);
    let o = dustsph(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let last = out.join("snapshot_0001.h5");
    let h = dustsph::io::snapshot::read_header(&last).unwrap();
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let mut with_output = sets.clone();
    with_output.push("time.output_dt=".into());
    assert_eq!(h.overrides.as_ref(), Some(&with_output));
    let file_text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/dusty_ball.toml"),
    )
    .unwrap();
    assert_eq!(h.source_text.as_deref(), Some(file_text.as_str()));
    // The effective scene parses, alone, to the overridden values.
    let scene = dustsph::scene::parse(&h.scene_text, &last, &[]).unwrap();
    assert_eq!(scene.ball().map(|b| b.background.p), Some(2.0));
    assert_eq!(scene.sph.n, 8);

    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(
        summary["scene_effective"].as_str(),
        Some(h.scene_text.as_str())
    );
    let run_errors = &summary["errors"];
    // The pressure's L1 error inside r < R0 − 2h, away from the kernel-truncated edge, at the
    // last output.
    let inner = |errors: &serde_json::Value| -> f64 {
        let e = errors
            .as_array()
            .unwrap()
            .iter()
            .rfind(|e| e["reference"].as_str().unwrap().contains("r < R0"))
            .expect("errors inside r < R0 − 2h");
        e["fields"]
            .as_array()
            .unwrap()
            .iter()
            .find(|f| f["field"] == "p")
            .unwrap()["l1"]
            .as_f64()
            .unwrap()
    };
    let p_run = inner(run_errors);
    let post = dustsph::commands::profile::post_process(&last, 50).unwrap();
    let p_post = inner(&serde_json::to_value(&post.errors).unwrap());
    assert!(
        (p_post - p_run).abs() <= 1e-9 * p_run,
        "profile's p error {p_post:e} against the run's {p_run:e}"
    );
    // Against the file's own p = 1 the pressure error is of order 1.
    let p1 = dustsph::scene::parse(&file_text, &last, &sets[..2]).unwrap();
    let snap = dustsph::io::read_snapshot(&last).unwrap();
    let state = dustsph::commands::profile::state_from_snapshot(&snap);
    let wrong = dustsph::analysis::exact_errors(&p1, &state, None);
    let p_wrong = inner(&serde_json::to_value(&wrong).unwrap());
    assert!(
        p_wrong > 10.0 * p_run,
        "p = 1 reference: {p_wrong:e}, run's: {p_run:e}"
    );
}

/// Resume tells apart two runs of one scene file with different overrides: a snapshot of the
/// other run put in place of this run's is refused as another run's, and nothing changes.
#[test]
fn resume_refuses_snapshots_of_the_same_file_with_other_overrides() {
    let tmp = tempfile::tempdir().unwrap();
    let run = |dir: &Path, n: &str, extra: &[&str]| {
        let d = dir.display().to_string();
        let n = format!("sph.n={n}");
        let mut args = vec!["run", "configs/dustywave.toml", "--set", &n];
        args.extend(["--set", "time.t_end=0.3", "--set", "time.output_dt=0.1"]);
        args.extend(extra);
        args.extend(["--out", &d, "-q"]);
        dustsph(&args)
    };
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let o = run(&a, "32", &["--checkpoint-every", "4", "--stop-after", "4"]);
    assert_eq!(
        o.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // Same file, same particle count, other overrides (a different amplitude).
    let o = run(&b, "32", &["--set", "dustywave.amplitude=2e-4"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::copy(b.join("snapshot_0000.h5"), a.join("snapshot_0000.h5")).unwrap();
    let before: Vec<u8> = std::fs::read(a.join("snapshot_0000.h5")).unwrap();
    let o = dustsph(&["resume", &a.display().to_string(), "-q"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("written by another run"), "{err}");
    assert_eq!(std::fs::read(a.join("snapshot_0000.h5")).unwrap(), before);
}

/// `--precision f32` sets the model's field and shows in what the outputs record: the
/// snapshot's effective scene (which parses back to the f32 scene that ran), its overrides,
/// its `SceneModel`, and the summary's `scene_model`.
#[test]
fn a_precision_option_shows_in_the_effective_scene_and_the_model() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("wave");
    let out_s = out.display().to_string();
    let o = dustsph(&[
        "run",
        "configs/dustywave.toml",
        "--set",
        "sph.n=16",
        "--set",
        "time.t_end=0.01",
        "--set",
        "time.output_dt=",
        "--precision",
        "f32",
        "--out",
        &out_s,
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let last = out.join("snapshot_0001.h5");
    let h = dustsph::io::snapshot::read_header(&last).unwrap();
    let scene = dustsph::scene::parse(&h.scene_text, &last, &[]).unwrap();
    assert_eq!(scene.numerics.precision, dustsph::scene::Precision::F32);
    assert!(
        h.overrides
            .as_ref()
            .is_some_and(|o| o.last().map(String::as_str) == Some("numerics.precision=\"f32\"")),
        "{:?}",
        h.overrides
    );
    let model = h.scene_model.expect("the snapshot's SceneModel");
    assert_eq!(model, scene.to_toml());
    assert!(model.contains("precision = \"f32\""), "{model}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["scene_model"].as_str(), Some(model.as_str()));
    assert_eq!(summary["precision"].as_str(), Some("f32"));
}

/// The resolved model in the outputs says which step rule ran: `--set time.cfl= --set
/// time.dt=0.01` is a fixed step of 0.01, in the snapshots' `SceneModel` and the summary's
/// `scene_model` alike.
#[test]
fn the_outputs_carry_the_model_with_the_step_rule_that_ran() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("wave");
    let out_s = out.display().to_string();
    let o = dustsph(&[
        "run",
        "configs/dustywave.toml",
        "--set",
        "sph.n=16",
        "--set",
        "time.t_end=0.02",
        "--set",
        "time.output_dt=",
        "--set",
        "time.cfl=",
        "--set",
        "time.dt=0.01",
        "--out",
        &out_s,
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let model = summary["scene_model"]
        .as_str()
        .expect("summary's scene_model");
    assert!(model.contains("\ndt = 0.01\n"), "{model}");
    assert!(!model.contains("cfl"), "{model}");
    for snap in ["snapshot_0000.h5", "snapshot_0001.h5"] {
        let h = dustsph::io::snapshot::read_header(&out.join(snap)).unwrap();
        assert_eq!(h.scene_model.as_deref(), Some(model), "{snap}");
    }
    assert_eq!(summary["steps"].as_u64(), Some(2));
}
