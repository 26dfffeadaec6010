//! `dustsph study`: a small grid runs in-process and writes results.csv, results.md and the
//! plots; its numbers obey the physics (first-order convergence in τ on the dusty box, for both
//! drag methods); bad study files exit with code 2 naming file and key and write nothing; an
//! existing output is refused without --force.
use std::path::{Path, PathBuf};
use std::process::Command;

fn dustsph(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dustsph"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap()
}

fn scene_path() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("configs/dustybox.toml")
        .display()
        .to_string()
        .replace('\\', "/")
}

/// A study of the dusty box: two methods × three fixed steps.
fn study_text(extra: &str) -> String {
    format!(
        r#"[study]
name = "box"
scene = "{}"
set = ["time.output_dt="]
series = ["drag.method"]
metrics = ["max.l1", "u_d3.linf"]
targets = [1e-1, 1e-6]
plot_against = ["time.dt"]
{extra}
[[axis]]
key = "drag.method"
values = ["idic", "explicit"]
[[axis]]
key = "time.dt"
values = [0.02, 0.01, 0.005]
"#,
        scene_path()
    )
}

fn write_study(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("s.toml");
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn a_study_runs_in_process_and_writes_its_tables_and_plots() {
    let tmp = tempfile::tempdir().unwrap();
    let file = write_study(tmp.path(), &study_text(""));
    let st = dustsph::commands::study::load(&file).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(st.points.len(), 6);
    let out = tmp.path().join("out");
    let (res, files) = dustsph::commands::study::run(&st, &out, false, true, "test").unwrap();
    for r in &res {
        assert_eq!(r.status, dustsph::commands::study::Status::Ok);
        assert!(r.step_seconds > 0.0 && r.total_seconds >= r.step_seconds);
        assert!(r.momentum_drift < 1e-12);
    }
    // First order in τ for both methods (the 4-fraction box; no step is drag-limited here).
    for m in 0..2 {
        let e: Vec<f64> = (0..3).map(|i| res[3 * m + i].metrics[0]).collect();
        for w in e.windows(2) {
            let p = (w[0] / w[1]).log2();
            assert!((0.9..1.1).contains(&p), "method {m}: order {p} from {e:?}");
        }
        assert_eq!(res[3 * m + 2].steps, 200); // t_end = 1, τ = 0.005
    }
    let names: Vec<String> = files
        .iter()
        .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    for n in [
        "results.csv",
        "results.md",
        "error_vs_time.png",
        "error_vs_time_dt.png",
    ] {
        assert!(names.iter().any(|x| x == n), "{n} missing from {names:?}");
        assert!(std::fs::metadata(out.join(n)).unwrap().len() > 100, "{n}");
    }
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 7, "{csv}");
    assert!(csv.lines().next().unwrap().contains("max.l1"));
    let md = std::fs::read_to_string(out.join("results.md")).unwrap();
    assert!(
        md.contains("| idic | 0.005 |") && md.contains("not reached"),
        "{md}"
    );
    let png = std::fs::read(out.join("error_vs_time.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
}

#[test]
fn points_that_would_need_too_many_steps_are_listed_not_run() {
    let tmp = tempfile::tempdir().unwrap();
    // Explicit at t_stop = 1e-6: τ ≤ 0.9e-6/2 → ≈2.2e6 steps to t = 1.
    let text = study_text("max_steps = 1000")
        .replace("set = [\"time.output_dt=\"]", "set = [\"time.output_dt=\", \"dust.fractions=[{eps=1.0, t_stop=1e-6}]\", \"dustybox.u_dust=[1.0]\"]")
        .replace("metrics = [\"max.l1\", \"u_d3.linf\"]", "metrics = [\"max.l1\"]");
    let st = dustsph::commands::study::load(&write_study(tmp.path(), &text)).unwrap();
    let (res, _) =
        dustsph::commands::study::run(&st, &tmp.path().join("o"), false, true, "t").unwrap();
    for r in &res[..3] {
        assert_eq!(r.status, dustsph::commands::study::Status::Ok);
    }
    for r in &res[3..] {
        match r.status {
            dustsph::commands::study::Status::Skipped(n) => {
                assert!((2_000_000..2_300_000).contains(&n), "{n}")
            }
            ref s => panic!("{s:?}"),
        }
    }
    let md = std::fs::read_to_string(tmp.path().join("o/results.md")).unwrap();
    assert!(md.contains("skipped: would need ≈"), "{md}");
}

#[test]
fn bad_study_files_exit_2_naming_file_and_key_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let base = study_text("");
    let cases = [
        (
            base.replace("name = \"box\"", "name = \"box\"\nfoo = 1"),
            "study.foo",
        ),
        (
            base.replace("[0.02, 0.01, 0.005]", "[0.02, -1.0]"),
            "axis.1.values.1",
        ),
        (
            base.replace("\"u_d3.linf\"", "\"u_d9.linf\""),
            "study.metrics.1",
        ),
        (
            base.replace("\"max.l1\", ", "\"max.l3\", "),
            "study.metrics.0",
        ),
        (
            base.replace("\"u_d3.linf\"", "\"u_d3.linf@2\""),
            "study.metrics.1",
        ),
        (
            base.replace("series = [\"drag.method\"]", "series = [\"sph.n\"]"),
            "study.series.0",
        ),
        (
            base.replace("\"idic\", \"explicit\"", "\"idic\", \"rk4\""),
            "axis.0.values.1",
        ),
        (
            base.replace("[0.02, 0.01, 0.005]", "[0.02, 0.01, 0.02]"),
            "axis.1.values.2",
        ),
        (
            base.replace("name = \"box\"", "name = \"../escaped\""),
            "study.name",
        ),
    ];
    for (i, (text, key)) in cases.iter().enumerate() {
        let dir = tmp.path().join(format!("c{i}"));
        std::fs::create_dir(&dir).unwrap();
        let file = write_study(&dir, text);
        let out = dir.join("out");
        let o = dustsph(&[
            "study",
            &file.display().to_string(),
            "--out",
            &out.display().to_string(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{key}: {err}");
        assert!(err.contains(key) && err.contains("s.toml"), "{key}: {err}");
        assert!(!out.exists(), "{key}: output written");
    }
}

#[test]
fn an_existing_output_is_refused_without_force_and_foreign_files_survive() {
    let tmp = tempfile::tempdir().unwrap();
    let text = study_text("").replace("[0.02, 0.01, 0.005]", "[0.02]");
    let file = write_study(tmp.path(), &text);
    let out = tmp.path().join("out");
    let args = |force: bool| {
        let mut a = vec![
            "study".to_string(),
            file.display().to_string(),
            "--out".into(),
            out.display().to_string(),
            "-q".into(),
        ];
        if force {
            a.push("--force".into());
        }
        a
    };
    let run = |force| dustsph(&args(force).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(run(false).status.success());
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let before = std::fs::read(out.join("results.csv")).unwrap();
    let o = run(false);
    assert!(!o.status.success());
    assert_eq!(std::fs::read(out.join("results.csv")).unwrap(), before);
    assert!(run(true).status.success());
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
}
