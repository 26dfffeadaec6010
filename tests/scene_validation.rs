//! Bad input is rejected before any output, with a message naming the file and the key.
mod common;
use common::config;
use dustsph::scene::{load, SceneError};

fn err(scene: &str, sets: &[&str]) -> SceneError {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    match load(&config(scene), &sets) {
        Ok(_) => panic!("{scene} {sets:?} was accepted"),
        Err(e) => e,
    }
}

#[test]
fn every_scene_in_configs_is_valid() {
    let dir = config("dustybox").parent().unwrap().to_path_buf();
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            load(&p, &[]).unwrap_or_else(|e| panic!("{e}"));
            n += 1;
        }
    }
    assert!(n >= 10, "{n} scenes in {}", dir.display());
}

#[test]
fn impossible_values_name_their_key_and_file() {
    let cases: &[(&str, &str, &str)] = &[
        ("dustybox", "sph.hfact=-1", "sph.hfact"),
        ("dustybox", "sph.hfact=0", "sph.hfact"),
        ("dustyshock", "sph.hfact=", "sph.hfact"),
        ("dustybox", "gas.rho=-1", "gas.rho"),
        (
            "dustybox",
            "dust.fractions.0.t_stop=-1e-3",
            "dust.fractions.0.t_stop",
        ),
        (
            "dustybox",
            "dust.fractions.2.eps=-0.1",
            "dust.fractions.2.eps",
        ),
        ("dustybox", "dust.fractions=[]", "dust.fractions"),
        ("dustybox", "time.dt=0", "time.dt"),
        ("dustybox", "time.dt=-0.1", "time.dt"),
        ("dustybox", "time.cfl=0.3", "time.dt"),
        ("dustywave", "time.cfl=2", "time.cfl"),
        ("dustybox", "time.t_end=0", "time.t_end"),
        ("dustybox", "scene.dim=4", "scene.dim"),
        ("dustyshock", "scene.dim=3", "scene.dim"),
        // Given but unused: no viscosity, or a lattice key on a 1D line.
        ("dustywave", "sph.beta=3", "sph.beta"),
        ("dustywave", "dustywave.layers=6", "dustywave.layers"),
        ("dustybox", "dustybox.lattice=\"cubic\"", "dustybox.lattice"),
        (
            "dustywave_phantom",
            "dustywave.layers=8",
            "dustywave.layers",
        ),
        (
            "dustywave_phantom",
            "sph.density=\"continuity\"",
            "sph.variable_h",
        ),
        ("dustybox", "dustybox.u_dust=[1.0]", "dustybox.u_dust"),
        ("dustybox", "dust.fractions.0.k=1.0", "dust.fractions.0.k"),
        ("dustybox", "dust.heating=true", "dust.heating"),
        ("dustyshock", "dustyshock.left.p=", "dustyshock.left.p"),
        (
            "dustyshock",
            "dustyshock.right.rho=0",
            "dustyshock.right.rho",
        ),
        ("dustywave", "gas.cs=", "gas.cs"),
        (
            "dustywave",
            "dustywave.amplitude=0.5",
            "dustywave.amplitude",
        ),
    ];
    let more: &[(&str, &str, &str)] = &[
        ("dustyshock", "idic.cell=1e-300", "idic.cell"),
        ("dustyshock", "idic.cell=10", "idic.cell"),
        ("dustybox", "time.output_dt=1e-14", "time.output_dt"),
        ("dustywave", "sph.n=1", "sph.n"),
        (
            "dustywave_phantom",
            "time.position_update=\"old\"",
            "time.position_update",
        ),
        // The kernel coupling, external accelerations and the settling column.
        (
            "dustybox",
            "drag.method=\"explicit\"\u{0}idic.coupling=\"kernel\"",
            "idic.coupling",
        ),
        ("dustybox", "external.gas=[0.0, 1.0, 0.0]", "external.gas"),
        ("dustybox", "dustybox.dust_shift=nan", "dustybox.dust_shift"),
        ("dustybox", "dustybox.jitter=-0.1", "dustybox.jitter"),
        ("dustybox", "dustybox.jitter=1.5", "dustybox.jitter"),
        ("dustywave", "dustywave.jitter=nan", "dustywave.jitter"),
        ("dustybox", "dustybox.seed=-3", "dustybox.seed"),
        (
            "dustywave",
            "dustywave.lattice=\"glass\"",
            "dustywave.lattice",
        ),
        (
            "dustysettle",
            "external.gas=[1.0, 0.0, 0.0]",
            "external.gas",
        ),
        (
            "dustysettle",
            "external.dust=[0.0, 0.0, 0.0]",
            "external.dust",
        ),
        (
            "dustysettle",
            "dustysettle.dust_shift=1.5",
            "dustysettle.dust_shift",
        ),
        ("dustysettle", "dustysettle.height=-1", "dustysettle.height"),
        ("dustysettle", "scene.dim=3", "scene.dim"),
        (
            "dustydisc",
            "gravity.accretion_radius=-0.1",
            "gravity.accretion_radius",
        ),
        (
            "dustydisc",
            "gravity.damp_inner=[1.0, 0.8]",
            "gravity.damp_inner",
        ),
        (
            "dustydisc",
            "gravity.damp_outer=[-1.0, 2.0]",
            "gravity.damp_outer",
        ),
        (
            "dustydisc",
            "gravity.damp_inner=[0.5, 1.8]\u{0}gravity.damp_outer=[1.5, 2.0]",
            "gravity.damp_inner",
        ),
        (
            "dustydisc",
            "gravity.damp_inner=\u{0}gravity.damp_outer=\u{0}gravity.damp_time=0.1",
            "gravity.damp_time",
        ),
        (
            "dustydisc",
            "gravity.damp_outer=[1.8, 2.0]\u{0}gravity.damp_time=0",
            "gravity.damp_time",
        ),
        ("dustydisc", "time.dt_max=0", "time.dt_max"),
        ("dustybox", "time.dt_max=0.1", "time.dt_max"),
        ("dustydisc", "scene.dim=1", "scene.dim"),
        (
            "dusty_ball",
            "idic.dispersion=\"damped\"",
            "idic.dispersion",
        ),
        ("dusty_ball", "idic.sampling=\"linear\"", "idic.sampling"),
        ("dustybox", "sph.alpha_ss=0.01", "sph.alpha_ss"),
        (
            "dustydisc",
            "sph.alpha_ss=0.01\u{0}sph.alpha=0.1",
            "sph.alpha",
        ),
        ("dustydisc", "sph.alpha_ss=-1", "sph.alpha_ss"),
        ("dustydisc", "dustydisc.r_c=0", "dustydisc.r_c"),
        (
            "dustydisc",
            "dustydisc.disc_mass=0.01",
            "dustydisc.disc_mass",
        ),
        (
            "dustydisc",
            "dustydisc.sigma_ref=\u{0}dustydisc.disc_mass=-1",
            "dustydisc.disc_mass",
        ),
        (
            "dustydisc",
            "dustydisc.particles=5000",
            "dustydisc.particles",
        ),
        (
            "dustydisc",
            "sph.n=\u{0}dustydisc.particles=50",
            "dustydisc.particles",
        ),
        (
            "dustydisc",
            "gravity.accretion_radius=0.6",
            "gravity.accretion_radius",
        ),
        ("dustydisc", "dustydisc.r_out=0.4", "dustydisc.r_out"),
        (
            "dustydisc",
            "dust.sizes={min=1e-4, max=1.0, count=4, dust_to_gas=0.01}",
            "dust.sizes",
        ),
        (
            "dustydisc",
            "dust.fractions=\u{0}dust.sizes={min=1e-4, max=1.0, count=4, dust_to_gas=0.01}",
            "dust.sizes",
        ),
        (
            "dustydisc",
            "idic.deposit=\"scatter\"\u{0}idic.sampling=\"linear\"",
            "idic.sampling",
        ),
        (
            "dustydisc",
            "dustydisc.dust_velocity=\"still\"",
            "dustydisc.dust_velocity",
        ),
    ];
    for (scene, set, key) in cases.iter().chain(more) {
        // A NUL separates several overrides of one case.
        let sets: Vec<&str> = set.split('\u{0}').collect();
        let e = err(scene, &sets);
        assert_eq!(e.key.as_deref(), Some(*key), "{scene} --set {set}: {e}");
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("{scene}.toml")),
            "message must name the file: {msg}"
        );
        assert!(msg.contains(key), "message must name the key: {msg}");
    }
}

#[test]
fn output_times_after_the_end_are_refused() {
    let e = err(
        "dustybox",
        &["time.output_dt=", "time.output_times=[0.5, 2.0]"],
    );
    assert_eq!(e.key.as_deref(), Some("time.output_times.1"), "{e}");
}

#[test]
fn unknown_keys_and_wrong_types_name_their_key() {
    let e = err("dustybox", &["gas.gammma=1.4"]);
    assert!(e.to_string().contains("gammma"), "{e}");
    let e = err("dustybox", &["sph.hfact=\"four\""]);
    assert_eq!(e.key.as_deref(), Some("sph.hfact"), "{e}");
    let e = err("dustybox", &["dust.law=\"stokes\""]);
    assert_eq!(e.key.as_deref(), Some("dust.law"), "{e}");
    let e = err("dustybox", &["dust.fractions.9.eps=1"]);
    assert_eq!(e.key.as_deref(), Some("dust.fractions.9.eps"), "{e}");
    let e = err("dustybox", &["time.integrator=\"rk4\""]);
    assert_eq!(e.key.as_deref(), Some("time.integrator"), "{e}");
    let e = err("dustybox", &["sph.gradient=\"corrected\""]);
    assert_eq!(e.key.as_deref(), Some("sph.gradient"), "{e}");
    let e = err("dustybox", &["no_equals_sign"]);
    assert!(e.to_string().contains("key=value"), "{e}");
}

#[test]
fn a_missing_or_broken_file_is_named() {
    let e = load(std::path::Path::new("configs/no_such_scene.toml"), &[]).unwrap_err();
    assert!(e.to_string().contains("no_such_scene.toml"), "{e}");
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("broken.toml");
    std::fs::write(&p, "[scene\nname = 1").unwrap();
    let e = load(&p, &[]).unwrap_err();
    assert!(
        e.to_string().contains("broken.toml") && e.to_string().contains("TOML"),
        "{e}"
    );
}

/// Run a scene that must fail as bad input: the message, after checking that no output
/// directory was made.
fn input_error_writes_nothing(scene: &str, sets: &[String]) -> String {
    let loaded = load(&config(scene), sets).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never");
    let opts = dustsph::sim::run::RunOptions::quiet_on_cpu(out.clone());
    let e = dustsph::sim::run::run(&loaded, &opts).unwrap_err();
    assert!(matches!(e, dustsph::sim::run::RunError::Input(_)), "{e}");
    assert!(!out.exists());
    e.to_string()
}

#[test]
fn set_up_errors_name_the_key_and_write_nothing() {
    // Kernel support too large for the periodic box: caught before the output directory exists.
    let e = input_error_writes_nothing("dustybox", &["sph.hfact=40".to_string()]);
    assert!(e.contains("dustybox.length"), "{e}");
    // A disc whose kernel is wider than its scale height over most of its mass.
    let sets = ["dustydisc.particles=300".to_string()];
    let e = input_error_writes_nothing("dustydisc3d", &sets);
    assert!(
        e.contains("dustydisc.particles") && e.contains("h/H > 1"),
        "{e}"
    );
}

#[test]
fn an_unknown_coupling_is_refused_naming_the_key() {
    let e = err("dustybox", &["idic.coupling=\"pic\""]);
    assert!(e.to_string().contains("idic"), "{e}");
    let e = err("dustybox", &["external.wind=[1.0, 0.0, 0.0]"]);
    assert!(e.to_string().contains("wind"), "{e}");
}

/// Issue 13: a section given as an array is not read by position; a scene's name cannot lead
/// the output outside output/; a fixed step that would never reach t_end is refused; so are
/// magnitudes beyond 1e±100.
#[test]
fn arrays_for_tables_path_names_and_endless_steps_are_refused() {
    let cases: &[(&str, &[&str], &str)] = &[
        ("dustywave", &["idic=[0.5]"], "idic"),
        ("dustywave", &["sph=[64, 1.2]"], "sph"),
        (
            "dustywave",
            &["dust.fractions=[[1.0, 2.0]]"],
            "dust.fractions.0",
        ),
        ("dustywave", &["scene.name=\"../x\""], "scene.name"),
        ("dustywave", &["scene.name=\"/tmp/x\""], "scene.name"),
        ("dustywave", &["scene.name=\"a\\\\b\""], "scene.name"),
        ("dustywave", &["time.cfl=", "time.dt=1e-300"], "time.dt"),
        ("dustybox", &["time.dt=1e-12"], "time.dt"),
        // Magnitudes whose products overflow (a summary would hold NaN, written as null).
        ("dustybox", &["gas.rho=1e300"], "gas.rho"),
        ("dustybox", &["gas.rho=1e-300"], "gas.rho"),
    ];
    for (scene, sets, key) in cases {
        let e = err(scene, sets);
        assert_eq!(e.key.as_deref(), Some(*key), "{scene} {sets:?}: {e}");
        assert!(e.file.ends_with(format!("{scene}.toml")), "{e}");
    }
    // The limits are limits, not bans: a plain name and a long but finite run are fine.
    load(&config("dustywave"), &["scene.name=\"wave-2.b_1\"".into()]).unwrap();
    load(&config("dustybox"), &["time.dt=1e-8".into()]).unwrap();
}

/// Issue 13: an absurd resolution is refused before anything is allocated, naming `sph.n` and
/// the estimate (it used to abort on a 24 PB allocation, overflow, or grow until killed).
#[test]
fn absurd_sizes_are_refused_before_allocating() {
    for (scene, sets) in [
        ("dustybox", vec!["scene.dim=3", "sph.n=100000"]),
        ("dustybox", vec!["sph.n=9223372036854775807"]),
        ("dusty_ball", vec!["sph.n=2000"]),
        ("dusty_ball", vec!["sph.n=1000"]),
        ("dustyshock", vec!["sph.n=9000000000000"]),
        ("dustywave", vec!["sph.n=1000000000000"]),
        ("dustysettle", vec!["sph.n=1000000000000"]),
    ] {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let m = input_error_writes_nothing(scene, &sets);
        assert!(
            m.contains("sph.n") && m.contains("particles"),
            "{scene} {sets:?}: {m}"
        );
    }
}

/// Initial conditions from a file: what the file gives, the scene must not (ε, sph.n, the
/// background gas state), and what the file cannot give, it must.
#[test]
fn a_file_scene_refuses_what_the_file_gives_and_names_the_key() {
    let base =
        "[scene]\nname = \"f\"\nproblem = \"file\"\ndim = 2\n\n[file]\npath = \"ics.h5\"\n\n\
        [gas]\neos = \"isothermal\"\ncs = 1.0\n\n[dust]\nlaw = \"constant_t\"\n\
        [[dust.fractions]]\nt_stop = 0.1\n\n[sph]\n\n[time]\nt_end = 0.1\ndt = 0.01\n";
    let path = std::path::Path::new("scene.toml");
    let loaded = dustsph::scene::LoadedScene::from_text(base, path, &[]).unwrap();
    let dustsph::scene::ProblemCfg::File(f) = &loaded.scene.problem else {
        panic!("not a file scene")
    };
    assert_eq!(f.resolved, std::path::Path::new("ics.h5"));
    assert!(
        !loaded.scene.to_toml().contains("\neps ="),
        "ε is the file's"
    );
    let cases: &[(&str, &str)] = &[
        ("dust.fractions.0.eps=0.5", "dust.fractions.0.eps"),
        ("sph.n=16", "sph.n"),
        ("gas.rho=1", "gas.rho"),
        ("file.periodic=[true, true, true]", "file.periodic.2"),
        ("file.path=\"\"", "file.path"),
        ("sph.variable_h=true", "sph.variable_h"),
        ("dustybox.length=1", "dustybox"),
    ];
    for (set, key) in cases {
        let e =
            dustsph::scene::LoadedScene::from_text(base, path, &[set.to_string()]).expect_err(set);
        assert_eq!(e.key.as_deref(), Some(*key), "{set}: {e}");
    }
    let e = dustsph::scene::LoadedScene::from_text(
        &base.replace("[file]\npath = \"ics.h5\"\n", ""),
        path,
        &[],
    )
    .unwrap_err();
    assert_eq!(e.key.as_deref(), Some("file"), "{e}");
    // The built-in problems still need ε and sph.n.
    assert_eq!(
        err("dustybox", &["dust.fractions.1.eps="]).key.as_deref(),
        Some("dust.fractions.1.eps")
    );
    assert_eq!(err("dustybox", &["sph.n="]).key.as_deref(), Some("sph.n"));
}

/// The ball given by its gas particle count: the lattice's particles per unit length follow,
/// and about that many are placed (the integer lattice rounds: within 10 %), the same in each
/// dust fraction; the count and `sph.n` together are refused, naming the key.
#[test]
fn a_ball_given_by_its_particle_count_places_about_that_many() {
    for (asked, dim) in [(30_000u64, "3"), (5_000, "2")] {
        let sets: Vec<String> = [
            "sph.n=".to_string(),
            format!("dustyball.particles={asked}"),
            "sph.h=0.2".into(),
            format!("scene.dim={dim}"),
        ]
        .into();
        let l =
            dustsph::scene::load(&config("dusty_ball"), &sets).unwrap_or_else(|e| panic!("{e}"));
        let su = dustsph::setup::build(&l.scene).unwrap();
        let placed = su.state.gas.ph.len() as f64;
        assert!(
            (placed / asked as f64 - 1.0).abs() < 0.1,
            "{dim}D: {placed} placed for {asked}"
        );
        assert_eq!(su.state.dust[0].len(), su.state.gas.ph.len());
    }
    let e = err("dusty_ball", &["dustyball.particles=30000"]);
    assert_eq!(e.key.as_deref(), Some("dustyball.particles"));
    let e = err("dusty_ball", &["sph.n=", "dustyball.particles=10"]);
    assert_eq!(e.key.as_deref(), Some("dustyball.particles"));
}
