//! The command and output contract: `dustsph run SCENE [--set]... [--out DIR] [--force]`,
//! GADGET-style snapshots at every output time (t = 0 included) and summary.json.
use std::path::Path;
use std::process::Command;

fn dustsph(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dustsph"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap()
}

fn out_dir(dir: &Path) -> String {
    dir.join("run").display().to_string()
}

#[test]
fn run_writes_snapshots_at_output_times_and_a_summary() {
    let tmp = tempfile::tempdir().unwrap();
    let out = out_dir(tmp.path());
    let o = dustsph(&["run", "configs/dustybox.toml", "--out", &out, "-q"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scene_text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/dustybox.toml"),
    )
    .unwrap();
    let times = [0.0, 0.25, 0.5, 0.75, 1.0];
    for (i, t) in times.iter().enumerate() {
        let p = Path::new(&out).join(format!("snapshot_{i:04}.h5"));
        let s = dustsph::io::read_snapshot(&p).unwrap();
        assert!(
            (s.time - t).abs() < 1e-12,
            "{} at t = {}",
            p.display(),
            s.time
        );
        assert_eq!(s.dim, 1);
        // Without overrides the effective scene is the file's table.
        let effective = dustsph::scene::effective_text(&scene_text, Path::new("f"), &[]).unwrap();
        assert_eq!(s.scene_text, effective);
        let h = dustsph::io::snapshot::read_header(&p).unwrap();
        assert_eq!(h.source_text.as_deref(), Some(scene_text.as_str()));
        assert_eq!(h.overrides, Some(vec![]));
        assert_eq!(s.num_part, [64, 0, 0, 4 * 64, 0, 0]);
        let d = s.dust.as_ref().unwrap();
        for k in 0..4u32 {
            assert_eq!(
                d.fraction
                    .as_ref()
                    .unwrap()
                    .iter()
                    .filter(|&&f| f == k)
                    .count(),
                64
            );
        }
        assert!(
            s.gas.as_ref().unwrap().e.is_some(),
            "InternalEnergy is part of the contract"
        );
    }
    assert!(!Path::new(&out).join("snapshot_0005.h5").exists());
    // Header attribute types as external readers expect them.
    let f = hdf5::File::open(Path::new(&out).join("snapshot_0004.h5")).unwrap();
    let h = f.group("Header").unwrap();
    assert_eq!(
        h.attr("NumPart_Total").unwrap().read_raw::<u64>().unwrap(),
        vec![64, 0, 0, 256, 0, 0]
    );
    assert_eq!(
        h.attr("MassTable").unwrap().read_raw::<f64>().unwrap(),
        vec![0.0; 6]
    );
    assert_eq!(
        h.attr("Dimension").unwrap().read_scalar::<i32>().unwrap(),
        1
    );
    assert_eq!(
        h.attr("NumFilesPerSnapshot")
            .unwrap()
            .read_scalar::<i32>()
            .unwrap(),
        1
    );
    // The periodic 1D wave: the box is the period along x, the unused axes 2 supports wide,
    // and every stored coordinate inside it (GADGET's [0, BoxSize)).
    let bs: Vec<f64> = h.attr("BoxSizePerAxis").unwrap().read_raw().unwrap();
    let one: f64 = h.attr("BoxSize").unwrap().read_scalar().unwrap();
    assert_eq!(one, bs[0].max(bs[1]));
    let off: Vec<f64> = h.attr("CoordinateOffset").unwrap().read_raw().unwrap();
    assert_eq!((bs[0], off[0]), (1.0, 0.0));
    assert!(
        bs[1] > 0.0 && bs[1] == bs[2] && off[1] == -bs[1] / 2.0,
        "{bs:?} {off:?}"
    );
    let c: Vec<f64> = f
        .dataset("PartType0/Coordinates")
        .unwrap()
        .read_raw()
        .unwrap();
    assert!(c
        .iter()
        .enumerate()
        .all(|(i, &x)| x >= 0.0 && x < bs[i % 3]));
    for ds in [
        "Coordinates",
        "Velocities",
        "Masses",
        "Density",
        "InternalEnergy",
        "Pressure",
        "SmoothingLength",
        "ParticleIDs",
    ] {
        assert!(
            f.dataset(&format!("PartType0/{ds}")).is_ok(),
            "PartType0/{ds}"
        );
    }
    for ds in [
        "Coordinates",
        "Velocities",
        "Masses",
        "Density",
        "SmoothingLength",
        "ParticleIDs",
        "FractionIndex",
        "StoppingTime",
    ] {
        assert!(
            f.dataset(&format!("PartType3/{ds}")).is_ok(),
            "PartType3/{ds}"
        );
    }
    // The summary.
    let s: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(Path::new(&out).join("summary.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(s["scene"], "dustybox");
    assert_eq!(s["dimension"], 1);
    assert_eq!(s["steps"], 100);
    assert_eq!(s["t_final"], 1.0);
    assert_eq!(s["particles"]["dust"].as_array().unwrap().len(), 4);
    let wall = s["wall_seconds"].as_f64().unwrap();
    assert!(wall > 0.0);
    // Where the wall time went: the steps' stages and the outputs, apart, together within it.
    let sum = |k: &str| -> f64 {
        s[k].as_array()
            .unwrap()
            .iter()
            .map(|e| e[1].as_f64().unwrap())
            .sum()
    };
    let named = |k: &str, name: &str| {
        s[k].as_array()
            .unwrap()
            .iter()
            .any(|e| e[0].as_str().unwrap().starts_with(name) && e[1].as_f64().unwrap() > 0.0)
    };
    assert!(
        named("stage_seconds", "gas forces"),
        "{}",
        s["stage_seconds"]
    );
    assert!(
        named("output_seconds", "snapshots"),
        "{}",
        s["output_seconds"]
    );
    assert!(
        sum("stage_seconds") + sum("output_seconds") <= wall,
        "stages {} + outputs {} > wall {wall}",
        sum("stage_seconds"),
        sum("output_seconds")
    );
    for k in ["mass_gas", "mass_dust", "momentum_drift_relative", "energy"] {
        assert!(!s["conservation"][k].is_null(), "conservation.{k}");
    }
    let last = s["errors"].as_array().unwrap().last().unwrap();
    assert_eq!(last["t"], 1.0);
    let fields: Vec<&str> = last["fields"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["field"].as_str().unwrap())
        .collect();
    for f in ["rho_g", "v_g", "rho_d0", "u_d0", "rho_d3", "u_d3"] {
        assert!(fields.contains(&f), "{f} in {fields:?}");
    }
    assert!(
        last["fields"][0]["l1"].is_number()
            && last["fields"][0]["l2"].is_number()
            && last["fields"][0]["linf"].is_number()
    );
}

#[test]
fn an_existing_non_empty_output_is_never_overwritten_without_force() {
    let tmp = tempfile::tempdir().unwrap();
    let out = out_dir(tmp.path());
    let short = [
        "run",
        "configs/dustybox.toml",
        "--set",
        "time.t_end=0.05",
        "--set",
        "time.output_dt=",
        "--out",
        &out,
        "-q",
    ];
    assert!(dustsph(&short).status.success());
    let summary = Path::new(&out).join("summary.json");
    let before = std::fs::read(&summary).unwrap();
    std::fs::write(Path::new(&out).join("notes.txt"), "mine").unwrap();
    let o = dustsph(&short);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains(&out),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(
        std::fs::read(&summary).unwrap(),
        before,
        "refused run must not touch the summary"
    );
    let mut forced = short.to_vec();
    forced.push("--force");
    assert!(dustsph(&forced).status.success());
    assert_eq!(
        std::fs::read_to_string(Path::new(&out).join("notes.txt")).unwrap(),
        "mine"
    );
}

#[test]
fn bad_input_exits_non_zero_naming_key_and_file_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let out = out_dir(tmp.path());
    let o = dustsph(&[
        "run",
        "configs/dustywave.toml",
        "--set",
        "sph.hfact=-2",
        "--out",
        &out,
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("sph.hfact") && err.contains("dustywave.toml"),
        "{err}"
    );
    assert!(!Path::new(&out).exists());
    let o = dustsph(&["run", "configs/missing.toml", "--out", &out]);
    assert_ne!(o.status.code(), Some(0));
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing.toml"));
    assert!(!Path::new(&out).exists());
}

#[test]
fn a_blow_up_stops_naming_step_particle_and_field_and_keeps_good_snapshots() {
    // τ = 0.05 is ten times the CFL step of this tube: the run must fail loudly, not write junk.
    let tmp = tempfile::tempdir().unwrap();
    let out = out_dir(tmp.path());
    let o = dustsph(&[
        "run",
        "configs/dustyshock.toml",
        "--set",
        "time.cfl=",
        "--set",
        "time.dt=0.05",
        "--set",
        "time.t_end=2",
        "--out",
        &out,
        "-q",
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("step ") && err.contains("particle id") && err.contains("has a bad"),
        "{err}"
    );
    assert!(
        Path::new(&out).join("snapshot_0000.h5").exists(),
        "earlier snapshots are kept"
    );
    // The summary of the state reached says the run failed, and where.
    let s: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(Path::new(&out).join("summary.json")).unwrap(),
    )
    .unwrap();
    let ending = s["ending"].as_str().unwrap();
    assert!(
        ending.starts_with("failed: step ") && ending.contains("has a bad"),
        "{ending}"
    );
    assert_ne!(
        s["t_final"], 2.0,
        "a failed run's summary is not a finished one's"
    );
    // Every snapshot left behind is complete and readable.
    for e in std::fs::read_dir(&out).unwrap() {
        let p = e.unwrap().path();
        assert!(
            !p.to_string_lossy().ends_with(".tmp"),
            "temporary left: {}",
            p.display()
        );
        if p.extension().is_some_and(|x| x == "h5") {
            dustsph::io::read_snapshot(&p).unwrap();
        }
    }
}

#[test]
fn ball_run_writes_xdmf_profiles_and_figures_and_profile_command_works() {
    let tmp = tempfile::tempdir().unwrap();
    let out = out_dir(tmp.path());
    let o = dustsph(&[
        "run",
        "configs/dusty_ball.toml",
        "--set",
        "sph.n=8",
        "--set",
        "sph.h=0.25",
        "--set",
        "time.output_dt=0.1",
        "--out",
        &out,
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let d = Path::new(&out);
    for f in [
        "snapshot_0000.xmf",
        "snapshot_0002.xmf",
        "snapshots.xmf",
        "snapshot_0002_profile.csv",
    ] {
        assert!(d.join(f).exists(), "{f}");
    }
    for f in [
        "snapshot_0002_profiles.png",
        "snapshot_0002_speed_tstop.png",
        "snapshot_0002_xy.png",
    ] {
        let bytes = std::fs::read(d.join(f)).unwrap();
        assert!(
            bytes.starts_with(b"\x89PNG\r\n\x1a\n") && bytes.len() > 10_000,
            "{f}"
        );
    }
    let csv = std::fs::read_to_string(d.join("snapshot_0002_profile.csv")).unwrap();
    assert!(
        csv.starts_with("r,rho_g,rho_d,p,e,v_g,u_d,t_stop,n_gas,n_dust"),
        "{csv}"
    );
    let series = std::fs::read_to_string(d.join("snapshots.xmf")).unwrap();
    assert_eq!(series.matches("<Time ").count(), 3, "{series}");
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("summary.json")).unwrap()).unwrap();
    assert!(s["ball"]["symmetry"]["rho_g_relative_l1"].as_f64().unwrap() < 0.05);
    // The profile command on an earlier snapshot prints the reference errors.
    let o = dustsph(&["profile", &d.join("snapshot_0001.h5").display().to_string()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("whole ball") && text.contains("symmetry"),
        "{text}"
    );
    assert!(d.join("snapshot_0001_profiles.png").exists());
    // --force replaces all of these, and keeps a user's own file.
    std::fs::write(d.join("my_plot.png"), "mine").unwrap();
    let o = dustsph(&[
        "run",
        "configs/dusty_ball.toml",
        "--set",
        "sph.n=8",
        "--set",
        "sph.h=0.25",
        "--set",
        "time.t_end=0.05",
        "--set",
        "time.output_dt=",
        "--out",
        &out,
        "--force",
        "-q",
    ]);
    assert!(o.status.success());
    // (This run ends at snapshot 1, so nothing of snapshot 2 may survive.)
    for f in [
        "snapshot_0002.h5",
        "snapshot_0002.xmf",
        "snapshot_0002_profiles.png",
        "snapshot_0002_profile.csv",
    ] {
        assert!(!d.join(f).exists(), "{f} survived --force");
    }
    assert!(d.join("my_plot.png").exists());
}

/// The README's exit-code table, held: 0 success, 1 a run-time stop (with the snapshots kept),
/// 2 bad input (nothing written); 130 (interrupted, checkpoint written) is held by
/// tests/resume.rs.
#[test]
fn exit_codes_hold_the_readme_table() {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    for row in ["| 0 |", "| 1 |", "| 2 |", "| 130 |"] {
        assert!(readme.contains(row), "README lacks the exit-code row {row}");
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = |d: &str| tmp.path().join(d).display().to_string();
    let ok = dustsph(&["run", "configs/dustybox.toml", "--out", &out("ok"), "-q"]);
    assert_eq!(ok.status.code(), Some(0));
    let bad = dustsph(&[
        "run",
        "configs/dustybox.toml",
        "--set",
        "sph.hfact=-1",
        "--out",
        &out("bad"),
        "-q",
    ]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(!Path::new(&out("bad")).exists());
    // A CFL step that collapses at t = 0 (c_s = 1e12: 2e14 steps) is refused before anything
    // is written, naming the step, the limit and the particles that set it; with --force the
    // earlier run in that directory stays whole.
    let stop = dustsph(&[
        "run",
        "configs/dustywave.toml",
        "--set",
        "gas.cs=1e12",
        "--out",
        &out("stop"),
        "-q",
    ]);
    assert_eq!(stop.status.code(), Some(2));
    let err = String::from_utf8_lossy(&stop.stderr);
    assert!(
        err.contains("step 0") && err.contains("collapsed") && err.contains("gas particle id"),
        "{err}"
    );
    assert!(!Path::new(&out("stop")).exists());
    let before = std::fs::read(Path::new(&out("ok")).join("summary.json")).unwrap();
    let over = dustsph(&[
        "run",
        "configs/dustywave.toml",
        "--set",
        "gas.cs=1e12",
        "--out",
        &out("ok"),
        "--force",
        "-q",
    ]);
    assert_eq!(over.status.code(), Some(2));
    let after = std::fs::read(Path::new(&out("ok")).join("summary.json")).unwrap();
    assert_eq!(
        before, after,
        "a refused --force run touched the earlier run"
    );
    assert!(Path::new(&out("ok")).join("snapshot_0001.h5").exists());
}

/// `dustsph scaling` (docs/scaling.md): a small cloud gives one table row per rank count with
/// no halo on one rank and a halo on two; bad arguments exit 2 naming them.
#[test]
fn scaling_model_prints_its_table_and_refuses_bad_arguments() {
    let out = dustsph(&["scaling", "--particles", "2e4", "--ranks", "1,2,8"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    for kind in ["ball:", "slab:"] {
        assert!(text.contains(kind), "{text}");
    }
    let rows: Vec<Vec<&str>> = text
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| ranks"))
        .map(|l| l.split('|').map(str::trim).collect())
        .collect();
    assert_eq!(rows.len(), 6, "{text}");
    for r in &rows {
        let halo: f64 = r[4].parse().unwrap();
        match r[1] {
            "1" => assert_eq!(halo, 0.0),
            _ => assert!(halo > 0.0, "{r:?}"),
        }
    }
    // A halo three supports deep (one exchange per step for a chain of three passes) is
    // larger than the one-support halo of an exchange before each pass.
    let deep = dustsph(&[
        "scaling",
        "--particles",
        "2e4",
        "--ranks",
        "8",
        "--depth",
        "3",
    ]);
    let halo_of = |o: &std::process::Output| -> Vec<f64> {
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .filter(|l| l.starts_with("| 8 |"))
            .map(|l| l.split('|').map(str::trim).nth(4).unwrap().parse().unwrap())
            .collect()
    };
    let thin: Vec<f64> = rows
        .iter()
        .filter(|r| r[1] == "8")
        .map(|r| r[4].parse().unwrap())
        .collect();
    let thick = halo_of(&deep);
    assert_eq!(thick.len(), 2);
    assert!(
        thick[0] > thin[0] && thick[1] > thin[1],
        "{thin:?} {thick:?}"
    );
    for bad in [
        &["scaling", "--ranks", "0"][..],
        &["scaling", "--particles", "1e20"],
        &["scaling", "--depth", "0.5"],
    ] {
        let out = dustsph(bad);
        assert_eq!(out.status.code(), Some(2), "{bad:?}");
        assert!(String::from_utf8_lossy(&out.stderr).contains("--"));
    }
}

/// A single-process command started as one of several MPI ranks (the launcher's environment
/// says so) refuses with exit 2 and writes nothing: every rank would otherwise run the whole
/// command into the same output directory. (`run` itself splits over ranks in a build with the
/// mpi feature, tests/mpi.rs; without it, it refuses too.)
#[test]
fn a_run_launched_as_one_of_several_mpi_ranks_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = out_dir(tmp.path());
    let mut commands = vec![vec![
        "study",
        "configs/studies/ball_small.toml",
        "--out",
        &dir,
    ]];
    if !cfg!(feature = "mpi") {
        commands.push(vec!["run", "configs/dustybox.toml", "--out", &dir, "-q"]);
    }
    for args in &commands {
        for (size_var, rank_var) in [
            ("OMPI_COMM_WORLD_SIZE", "OMPI_COMM_WORLD_RANK"),
            ("PMI_SIZE", "PMI_RANK"),
        ] {
            let o = Command::new(env!("CARGO_BIN_EXE_dustsph"))
                .args(args)
                .current_dir(env!("CARGO_MANIFEST_DIR"))
                .env(size_var, "3")
                .env(rank_var, "1")
                .output()
                .unwrap();
            assert_eq!(o.status.code(), Some(2), "{args:?} {size_var}");
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(err.contains("rank 1 of 3"), "{err}");
            assert!(!Path::new(&dir).exists(), "output written");
        }
    }
    // One rank is an ordinary run.
    let o = Command::new(env!("CARGO_BIN_EXE_dustsph"))
        .args(["run", "configs/dustybox.toml", "--out", &dir, "-q"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("OMPI_COMM_WORLD_SIZE", "1")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0));
}

/// Runs that will likely be unstable or noise are warned about at the start (they still run:
/// a user may mean it): a fixed step above the initial state's CFL/force limit, and kernels
/// holding almost no neighbours. The shipped scenes get no warning. A malformed `--set` value
/// and another problem's section are refused, naming the key.
#[test]
fn dubious_runs_are_warned_about_and_malformed_overrides_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let out = |d: &str| tmp.path().join(d).display().to_string();
    let run = |sets: &[&str], dir: &str| {
        let mut a = vec!["run", "configs/dustyshock.toml", "-q", "--out"];
        let o = out(dir);
        a.push(&o);
        for s in sets {
            a.extend(["--set", s]);
        }
        let r = dustsph(&a);
        (
            r.status.code(),
            String::from_utf8_lossy(&r.stderr).to_string(),
        )
    };
    let short = "time.t_end=0.002";
    let (code, err) = run(&[short], "plain");
    assert_eq!(code, Some(0), "{err}");
    assert!(!err.contains("warning"), "{err}");
    let (code, err) = run(&[short, "time.cfl=", "time.dt=0.05"], "big_dt");
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("warning: time.dt = 0.05 is"), "{err}");
    let (code, err) = run(&[short, "sph.hfact=0.1"], "few");
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("neighbours each within 2h"), "{err}");
    for (set, key) in [("sph.n=[32", "sph.n"), ("dustybox.length=1", "dustybox")] {
        let (code, err) = run(&[set], "bad");
        assert_eq!(code, Some(2), "{set}: {err}");
        assert!(err.contains(&format!("key `{key}`")), "{set}: {err}");
        assert!(!tmp.path().join("bad").exists());
    }
}

/// `profile` given a directory or a missing file, and `parity` asked for a device that is not
/// there, are bad input: exit 2 with a plain message.
#[test]
fn profile_and_parity_refuse_what_is_not_there_with_exit_2() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().display().to_string();
    let o = dustsph(&["profile", &dir]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("is a directory"));
    let missing = tmp.path().join("snapshot_0001.h5").display().to_string();
    let o = dustsph(&["profile", &missing]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no such file"));
    let gpu = dustsph(&["gpu"]);
    if String::from_utf8_lossy(&gpu.stdout).contains("device: none") {
        let o = dustsph(&["parity", "--device", "cuda"]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert_eq!(err.matches("error:").count(), 1, "{err}");
    }
}

/// A run logged to a file (stderr not a terminal) prints plain progress lines: the step, the
/// simulated time, dt and what limits it, the step rate and the time left.
#[test]
fn a_logged_run_prints_progress_lines_with_its_rate_and_what_limits_its_step() {
    let tmp = tempfile::tempdir().unwrap();
    let run = |dir: &str, quiet: bool| {
        let out = tmp.path().join(dir).display().to_string();
        let mut a = vec!["run", "configs/dustywave.toml", "--set", "time.t_end=0.05"];
        a.extend(["--progress-every", "0", "--out", &out]);
        if quiet {
            a.push("-q");
        }
        let o = dustsph(&a);
        assert_eq!(o.status.code(), Some(0));
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    let err = run("logged", false);
    let lines: Vec<&str> = err.lines().filter(|l| l.contains("steps/s")).collect();
    assert!(lines.len() >= 3, "{err}");
    for l in &lines {
        assert!(
            l.contains("particle-steps/s") && l.contains("dt = ") && l.contains("left"),
            "{l}"
        );
    }
    // The wave's steps are set by the CFL limit, its last one by landing on t_end.
    assert!(lines[0].contains("(CFL)"), "{}", lines[0]);
    assert!(
        lines
            .last()
            .unwrap()
            .contains("(landing on an output time)"),
        "{err}"
    );
    // Quiet: none.
    assert!(!run("quiet", true).contains("steps/s"));
}

/// A reader that stops early (`dustsph run … | head`, here one that never reads) ends the run's
/// printing quietly, as for any Unix tool: no panic (exit 101 says "a bug"), and the summary
/// is written before anything is printed.
#[test]
#[cfg(unix)]
fn a_closed_stdout_ends_quietly_after_the_summary_is_written() {
    use std::os::unix::process::ExitStatusExt;
    let tmp = tempfile::tempdir().unwrap();
    let out = out_dir(tmp.path());
    let mut child = Command::new(env!("CARGO_BIN_EXE_dustsph"))
        .args(["run", "configs/dustybox.toml", "-q", "--out", &out])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_ne!(o.status.code(), Some(101), "{err}");
    assert_eq!(
        o.status.signal(),
        Some(13),
        "killed by SIGPIPE: {:?}",
        o.status
    );
    assert!(Path::new(&out).join("summary.json").exists());
}
