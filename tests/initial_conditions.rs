//! Initial conditions from an HDF5 file (`scene.problem = "file"`, host/io/ics.rs and
//! host/setup/file.rs): a file of a built-in set-up's particles runs as that set-up, bit for
//! bit; a snapshot continues its run; every class of bad file is refused with the file, the
//! dataset and the first offending row named, and nothing written.
mod common;
use common::ics::*;
use common::*;
use dustsph::particles::State;
use dustsph::scene::LoadedScene;
use std::path::PathBuf;

/// A scene's set-up (the built-in problem's initial state and h).
fn built_in(name: &str, sets: &[&str]) -> (LoadedScene, dustsph::setup::Setup) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let l = dustsph::scene::load(&config(name), &sets).unwrap_or_else(|e| panic!("{e}"));
    let su = dustsph::setup::build(&l.scene).unwrap_or_else(|e| panic!("{e}"));
    (l, su)
}

/// A particle's id, x, v, m and ρ.
type Row = (u64, [f64; 3], [f64; 3], f64, f64);

/// Every particle's row, ordered by id.
fn by_id(s: &State) -> Vec<Row> {
    let mut out: Vec<_> = std::iter::once(&s.gas.ph)
        .chain(&s.dust)
        .flat_map(|p| (0..p.len()).map(move |i| (p.id[i], p.x[i], p.v[i], p.m[i], p.rho[i])))
        .collect();
    out.sort_by_key(|r| r.0);
    out
}

const BOX_SETS: [&str; 5] = [
    "scene.dim=3",
    "sph.n=8",
    "sph.hfact=1.2",
    "time.t_end=0.05",
    "time.dt=0.01",
];

/// configs/dustybox.toml's laws (the ratios come from the file's masses).
const BOX_REST: &str = "[gas]\neos = \"isothermal\"\ncs = 1.0\n\n[dust]\nlaw = \"constant_t\"\n\
    [[dust.fractions]]\nt_stop = 0.1\n[[dust.fractions]]\nt_stop = 0.215443\n\
    [[dust.fractions]]\nt_stop = 0.464159\n[[dust.fractions]]\nt_stop = 1.0\n\n\
    [sph]\n\n[idic]\ncell = 0.5\n\n[time]\nt_end = 0.05\ndt = 0.01\n";

#[test]
fn an_ic_file_of_the_3d_box_lattice_runs_bit_for_bit_as_the_built_in_box() {
    let dir = tempfile::tempdir().unwrap();
    let (_, su) = built_in("dustybox", &BOX_SETS);
    IcFile::of_state(&su.state, su.h, 3, Some([1.0; 3])).write(&dir.path().join("box.h5"));
    let loaded = file_scene(dir.path(), 3, "box.h5", "[true, true, true]", BOX_REST);
    // The set-up says where its h comes from (here the file's own).
    let notes = dustsph::setup::build(&loaded.scene).unwrap().notes;
    assert!(
        notes[0].contains("(the file's SmoothingLength)"),
        "{notes:?}"
    );
    let (s_file, from_file) = run_in(dir.path(), &loaded, "file");
    let (_, built) = run_scene("dustybox", &BOX_SETS);
    assert_eq!(from_file.step, built.step);
    assert!(by_id(&from_file) == by_id(&built), "not bit for bit");
    // The run names its source and the SHA-256 of its bytes (against coreutils' sha256sum).
    let ics = s_file
        .initial_conditions
        .expect("initial_conditions in the summary");
    let sum = std::process::Command::new("sha256sum")
        .arg(dir.path().join("box.h5"))
        .output()
        .unwrap();
    let want = String::from_utf8(sum.stdout).unwrap();
    assert_eq!(ics.sha256, want.split_whitespace().next().unwrap());
    assert!(ics.path.ends_with("box.h5"), "{}", ics.path);
    let snap = dir.path().join("file/snapshot_0000.h5");
    let h = hdf5::File::open(&snap).unwrap().group("Header").unwrap();
    let d: hdf5::types::VarLenUnicode = h
        .attr("InitialConditionsSHA256")
        .unwrap()
        .read_scalar()
        .unwrap();
    assert_eq!(d.as_str(), ics.sha256);
}

/// A file whose dust does not sit on the gas (the 3D box, its dust lattice shifted by half a
/// spacing: no dust particle shares a 0.5h cell with a gas particle) runs with the defaults on
/// the kernel coupling, as the built-in offset box, bit for bit; and that box follows the
/// discrete drag ODE to round-off (1e-10), every dust particle coupled.
#[test]
fn an_ic_file_with_offset_dust_relaxes_on_the_drag_ode_with_the_defaults() {
    let dir = tempfile::tempdir().unwrap();
    let sets: Vec<&str> = BOX_SETS
        .iter()
        .copied()
        .chain(["dustybox.dust_shift=0.5"])
        .collect();
    let (_, su) = built_in("dustybox", &sets);
    IcFile::of_state(&su.state, su.h, 3, Some([1.0; 3])).write(&dir.path().join("box.h5"));
    let loaded = file_scene(dir.path(), 3, "box.h5", "[true, true, true]", BOX_REST);
    assert_eq!(loaded.scene.idic.coupling, dustsph::scene::Coupling::Kernel);
    let (_, from_file) = run_in(dir.path(), &loaded, "file");
    let (s_built, built) = run_scene("dustybox", &sets);
    assert!(by_id(&from_file) == by_id(&built), "not bit for bit");
    for k in 0..4 {
        let e = final_error(&s_built, 1, &format!("u_d{k}"));
        assert!(e.linf < 1e-10, "fraction {k}: {e:?} off the drag ODE");
    }
}

/// The source report's ball, stopped half-way: its snapshot as initial conditions (with the
/// ball's own coupling, the nearest cell) continues to the uninterrupted run's final state. Not to the bit: a snapshot stores positions in
/// GADGET's frame, Coordinates = x − CoordinateOffset in [0, BoxSize), and (x − o) + o
/// rounds x by up to an ulp of |o|; the run carries that round-off (measured ≤ 2e-14).
#[test]
fn a_ball_snapshot_as_initial_conditions_continues_its_run_to_round_off() {
    let dir = tempfile::tempdir().unwrap();
    let sets = [
        "sph.n=12",
        "sph.h=0.17",
        "time.t_end=0.1",
        "time.output_dt=0.05",
    ];
    let sets_s: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let l = dustsph::scene::load(&config("dusty_ball"), &sets_s).unwrap();
    let (_, whole) = run_in(dir.path(), &l, "whole");
    let rest = "[gas]\neos = \"adiabatic\"\ngamma = 1.4\n\n[dust]\nlaw = \"epstein\"\n\
        [[dust.fractions]]\ns_rho = 1e-3\n\n[sph]\nh = 0.17\n\n[idic]\ncoupling = \"cell\"\n\
        cell = 0.5\n\n[time]\nt_end = 0.1\ndt = 0.005\noutput_dt = 0.05\n";
    let loaded = file_scene(
        dir.path(),
        3,
        "whole/snapshot_0001.h5",
        "[false, false, false]",
        rest,
    );
    let (s, cont) = run_in(dir.path(), &loaded, "continued");
    assert_eq!(s.t_start, 0.05);
    assert_eq!(cont.t, whole.t);
    let (a, b) = (by_id(&whole), by_id(&cont));
    assert_eq!(a.len(), b.len());
    let mut worst: f64 = 0.0;
    for (p, q) in a.iter().zip(&b) {
        assert_eq!(p.0, q.0);
        assert_eq!(p.3, q.3, "masses are copied exactly");
        for k in 0..3 {
            worst = worst
                .max((p.1[k] - q.1[k]).abs())
                .max((p.2[k] - q.2[k]).abs());
        }
        worst = worst.max((p.4 - q.4).abs() / p.4);
    }
    assert!(worst < 1e-13, "continued run differs by {worst:e}");
}

/// A glass made by the code, written out and read back, runs as the built-in glass set-up.
#[test]
fn a_glass_written_out_and_read_back_gives_the_built_in_glass_run() {
    let dir = tempfile::tempdir().unwrap();
    let sets = [
        "scene.dim=2",
        "sph.n=12",
        "sph.hfact=1.2",
        "dustybox.lattice=\"glass\"",
        "idic.coupling=\"kernel\"",
        "time.t_end=0.05",
        "time.dt=0.01",
    ];
    let (_, su) = built_in("dustybox", &sets);
    IcFile::of_state(&su.state, su.h, 2, Some([1.0, 1.0, 0.0])).write(&dir.path().join("g.h5"));
    let rest = BOX_REST.replace("[idic]\n", "[idic]\ncoupling = \"kernel\"\n");
    let loaded = file_scene(dir.path(), 2, "g.h5", "[true, true, false]", &rest);
    let (_, from_file) = run_in(dir.path(), &loaded, "file");
    let (_, built) = run_scene("dustybox", &sets);
    assert!(by_id(&from_file) == by_id(&built), "not bit for bit");
}

/// The 2D box's file, for the bad-file cases.
fn good_file() -> (IcFile, dustsph::setup::Setup) {
    let (_, su) = built_in(
        "dustybox",
        &["scene.dim=2", "sph.n=6", "sph.hfact=1.2", "time.t_end=0.02"],
    );
    (
        IcFile::of_state(&su.state, su.h, 2, Some([1.0, 1.0, 0.0])),
        su,
    )
}

/// The set-up's error for a file broken by `spoil` (the message, which must name the file).
fn refusal(spoil: impl FnOnce(&mut IcFile)) -> String {
    let dir = tempfile::tempdir().unwrap();
    let (mut f, _) = good_file();
    spoil(&mut f);
    let path = dir.path().join("ics.h5");
    f.write(&path);
    let l = file_scene(dir.path(), 2, "ics.h5", "[true, true, false]", BOX_REST);
    let e = dustsph::setup::build(&l.scene).expect_err("a bad file is refused");
    let msg = e.to_string();
    assert!(msg.contains("ics.h5"), "names the file: {msg}");
    msg
}

fn set_i(f: &mut IcFile, group: &str, name: &str, row: usize, value: i64) {
    if let Column::I(v) = f.column(group, name) {
        v[row] = value;
    }
}

fn set_f(f: &mut IcFile, group: &str, name: &str, row: usize, value: f64) {
    if let Column::F(v, w) = f.column(group, name) {
        v[row * *w] = value;
    }
}

#[test]
fn the_good_file_of_the_bad_file_cases_is_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let (f, su) = good_file();
    f.write(&dir.path().join("ics.h5"));
    let l = file_scene(dir.path(), 2, "ics.h5", "[true, true, false]", BOX_REST);
    let got = dustsph::setup::build(&l.scene).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(got.state.gas.ph.x, su.state.gas.ph.x);
    assert_eq!(got.h, su.h);
}

#[test]
fn a_file_that_is_not_hdf5_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("ics.h5"), "x,y,z\n0,0,0\n").unwrap();
    let l = file_scene(dir.path(), 2, "ics.h5", "[true, true, false]", BOX_REST);
    let msg = dustsph::setup::build(&l.scene).unwrap_err().to_string();
    assert!(msg.contains("ics.h5") && msg.contains("HDF5"), "{msg}");
}

#[test]
fn a_missing_dataset_is_named() {
    let msg = refusal(|f| f.remove("PartType0", "Masses"));
    assert!(msg.contains("/PartType0/Masses is missing"), "{msg}");
}

#[test]
fn a_misshapen_dataset_is_named_with_its_shape() {
    let msg = refusal(|f| {
        if let Column::F(v, w) = f.column("PartType3", "Coordinates") {
            v.truncate(v.len() / 3 * 2);
            *w = 2;
        }
    });
    assert!(
        msg.contains("/PartType3/Coordinates has shape") && msg.contains("(N, 3)"),
        "{msg}"
    );
}

#[test]
fn columns_of_different_lengths_are_refused() {
    let msg = refusal(|f| {
        if let Column::F(v, _) = f.column("PartType0", "Velocities") {
            v.truncate(v.len() - 3);
        }
    });
    assert!(
        msg.contains("/PartType0/Velocities has 35 rows") && msg.contains("has 36"),
        "{msg}"
    );
}

#[test]
fn a_nan_or_inf_is_named_with_its_row() {
    let msg = refusal(|f| set_f(f, "PartType0", "Velocities", 7, f64::NAN));
    assert!(msg.contains("/PartType0/Velocities[7]"), "{msg}");
    let msg = refusal(|f| set_f(f, "PartType3", "Masses", 30, f64::INFINITY));
    assert!(msg.contains("/PartType3/Masses[30]"), "{msg}");
}

#[test]
fn non_positive_masses_and_densities_are_named_with_their_row() {
    let msg = refusal(|f| set_f(f, "PartType3", "Masses", 12, 0.0));
    assert!(msg.contains("/PartType3/Masses[12] is 0"), "{msg}");
    let msg = refusal(|f| set_f(f, "PartType0", "Density", 3, -1.0));
    assert!(msg.contains("/PartType0/Density[3] is -1"), "{msg}");
}

#[test]
fn duplicate_particle_ids_are_named() {
    let msg = refusal(|f| set_i(f, "PartType3", "ParticleIDs", 5, 2));
    assert!(
        msg.contains("/PartType0/ParticleIDs[2]") && msg.contains("/PartType3/ParticleIDs[5]"),
        "{msg}"
    );
}

#[test]
fn a_fraction_index_beyond_the_scenes_fractions_is_named() {
    let msg = refusal(|f| set_i(f, "PartType3", "FractionIndex", 40, 4));
    assert!(
        msg.contains("/PartType3/FractionIndex[40] is 4") && msg.contains("4 fraction"),
        "{msg}"
    );
}

#[test]
fn a_particle_outside_the_periodic_box_is_named() {
    let msg = refusal(|f| set_f(f, "PartType0", "Coordinates", 9, 1.25));
    assert!(
        msg.contains("/PartType0/Coordinates[9]") && msg.contains("outside the periodic box"),
        "{msg}"
    );
}

/// On the command line: exit 2, the message names file and dataset, nothing written.
#[test]
fn the_command_line_refuses_a_bad_file_with_exit_2_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (mut f, _) = good_file();
    set_f(&mut f, "PartType0", "Masses", 4, -2.0);
    f.write(&dir.path().join("ics.h5"));
    let l = file_scene(dir.path(), 2, "ics.h5", "[true, true, false]", BOX_REST);
    let out: PathBuf = dir.path().join("out");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_dustsph"))
        .args(["run", l.path.to_str().unwrap(), "--device", "cpu", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("ics.h5") && err.contains("/PartType0/Masses[4]"),
        "{err}"
    );
    assert!(!out.exists(), "nothing written");
}

/// The run starts at the file's Header/Time: a time.t_end not after it is refused, naming
/// the key, before anything is written.
#[test]
fn a_t_end_not_after_the_files_time_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (mut f, _) = good_file();
    f.header.retain(|h| h.0 != "Time");
    f.header.push(("Time", vec![0.5]));
    f.write(&dir.path().join("ics.h5"));
    let l = file_scene(dir.path(), 2, "ics.h5", "[true, true, false]", BOX_REST);
    let opts = dustsph::sim::run::RunOptions::quiet_on_cpu(dir.path().join("out"));
    let e = dustsph::sim::run::run(&l, &opts).expect_err("t_end 0.05 < t = 0.5");
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains("time.t_end"), "{e}");
    assert!(!dir.path().join("out").exists());
}

/// A run from a file, checkpointed and resumed (with the file moved away meanwhile), ends as
/// the uninterrupted one, bit for bit, and its record keeps where it started (the file's
/// time, its digest).
#[test]
fn a_run_from_a_file_resumes_bit_for_bit_and_keeps_its_source() {
    let dir = tempfile::tempdir().unwrap();
    let (mut f, _) = good_file();
    f.header.retain(|h| h.0 != "Time");
    f.header.push(("Time", vec![0.02]));
    f.write(&dir.path().join("ics.h5"));
    let rest = BOX_REST.replace("t_end = 0.05", "t_end = 0.1");
    let l = file_scene(dir.path(), 2, "ics.h5", "[true, true, false]", &rest);
    let opts = |d: &str| dustsph::sim::run::RunOptions::quiet_on_cpu(dir.path().join(d));
    let mut whole = dustsph::sim::run::Run::start(&l, &opts("whole")).unwrap();
    whole.advance(None, None, None).unwrap();
    let (sw, a) = whole.finish().unwrap();
    let mut first = dustsph::sim::run::Run::start(&l, &opts("split")).unwrap();
    first.advance(Some(3), None, None).unwrap();
    first.checkpoint().unwrap();
    drop(first);
    // The resume needs no initial-conditions file: its record holds what the set-up made.
    std::fs::rename(dir.path().join("ics.h5"), dir.path().join("moved.h5")).unwrap();
    let (s, b) = common::resume_to_the_end(&dir.path().join("split"));
    assert_eq!(a.step, 8, "0.02 → 0.1 in steps of 0.01");
    assert!(by_id(&a) == by_id(&b), "not bit for bit");
    assert_eq!(s.t_start, 0.02);
    assert_eq!(s.initial_conditions, sw.initial_conditions);
    assert!(s.initial_conditions.is_some());
    assert_eq!(s.snapshots, sw.snapshots);
}
