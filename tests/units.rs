//! Physical units (`[units]`, docs/scenes.md): the code units follow from G = 1, grains given
//! in cm and g cm⁻³ become the Epstein law's s ρ_s in code units (the source report's form or
//! Phantom's), grains beyond 9λ/4 drag in the Stokes regime, and snapshots and the summary
//! carry the units where readers look for them.
mod common;
use common::config;
use dustsph::scene::{load, Scene};
use dustsph_device::drag::StoppingLaw;

fn scene(sets: &[&str]) -> Scene {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    load(&config("dusty_ball"), &sets)
        .unwrap_or_else(|e| panic!("{e}"))
        .scene
}

/// The ball in au and solar masses, its grain 1 mm of 3 g cm⁻³.
const AU_MSUN: [&str; 6] = [
    "units.length=\"au\"",
    "units.mass=\"msun\"",
    "dust.fractions.0.s_rho=",
    "dust.fractions.0.size=0.1",
    "dust.grain_density=3",
    "time.t_end=0.01",
];

fn epstein(s: &Scene) -> (f64, f64) {
    match s.fractions()[0].law {
        StoppingLaw::Epstein { s_rho, stokes } => (s_rho, stokes),
        l => panic!("not Epstein: {l:?}"),
    }
}

#[test]
fn au_and_solar_masses_give_the_year_over_two_pi_and_grains_in_code_units() {
    let s = scene(&AU_MSUN);
    let u = s.units.expect("units");
    // G = 1 in au and M_sun: one orbit at 1 au takes 2π code times, one (Julian) year within
    // the 1e-4 the year differs from a Keplerian orbit of the nominal Sun by.
    let year = 365.25 * 86400.0;
    assert!(
        (2.0 * std::f64::consts::PI * u.time_s() / year - 1.0).abs() < 1e-4,
        "{}",
        u.time_s()
    );
    assert!((u.velocity_cm_s() / 2.978e6 - 1.0).abs() < 1e-3);
    // s ρ_s = 0.1 cm × 3 g cm⁻³ in M_sun au⁻².
    let (s_rho, _) = epstein(&s);
    let want = 0.3 * u.length_cm * u.length_cm / u.mass_g;
    assert!((s_rho / want - 1.0).abs() < 1e-15, "{s_rho} vs {want}");
    // Phantom's form: the thermal speed √(8/(πγ)) c_s in place of c_s (γ = 1.4 here).
    let p = scene(&[&AU_MSUN[..], &["dust.epstein=\"phantom\""]].concat());
    let ratio = epstein(&s).0 / epstein(&p).0;
    assert!((ratio - (8.0 / (std::f64::consts::PI * 1.4)).sqrt()).abs() < 1e-14);
}

/// The law at gas densities below and above the Stokes transition s = 9λ/4: Epstein below,
/// 4s/(9λ) times Epstein above, continuous at the transition, and the transition where
/// λ = μ m_H/(ρ_g σ) puts it.
#[test]
fn grains_beyond_nine_quarter_mean_free_paths_drag_in_the_stokes_regime() {
    // 1 cm grains; σ = 2e-15 cm², μ = 2.353: s = 9λ/4 at ρ_g = 9 μ m_H/(4 s σ).
    let s = scene(
        &[
            &AU_MSUN[..],
            &["dust.fractions.0.size=1", "dust.cross_section=2e-15"],
        ]
        .concat(),
    );
    let u = s.units.unwrap();
    let (s_rho, stokes) = epstein(&s);
    let rho_t_cgs = 9.0 * 2.353 * 1.673_557_5e-24 / (4.0 * 1.0 * 2e-15);
    let rho_t = rho_t_cgs / (u.mass_g / u.length_cm.powi(3));
    assert!((stokes * rho_t - 1.0).abs() < 1e-12, "{}", stokes * rho_t);
    let law = s.fractions()[0].law;
    let cs = 0.05;
    for f in [1e-3, 0.5, 1.0, 2.0, 1e3] {
        let rho = f * rho_t;
        let t = law.stopping_time(rho, 0.0, cs);
        let ep = s_rho / (rho * cs);
        let want = if f > 1.0 { ep * f } else { ep };
        assert!((t / want - 1.0).abs() < 1e-12, "ρ/ρ_t = {f}: {t} vs {want}");
    }
    // Without a size (s_rho in code units) the law stays Epstein.
    assert_eq!(epstein(&scene(&["time.t_end=0.01"])).1, 0.0);
}

#[test]
fn unit_and_grain_keys_name_their_key_when_wrong() {
    let cases: &[(&[&str], &str)] = &[
        (
            &["units.length=\"furlong\"", "units.mass=\"g\""],
            "units.length",
        ),
        (&["units.length=\"au\""], "units.mass"),
        (&["units.length=-1", "units.mass=\"g\""], "units.length"),
        (
            &[
                "dust.fractions.0.s_rho=",
                "dust.fractions.0.size=0.1",
                "dust.grain_density=3",
            ],
            "dust.fractions.0.size",
        ),
        (&AU_MSUN[..3], "dust.fractions.0.s_rho"),
        (
            &[
                "units.length=\"au\"",
                "units.mass=\"msun\"",
                "dust.fractions.0.size=0.1",
            ],
            "dust.fractions.0.size",
        ),
        (
            &[
                "units.length=\"au\"",
                "units.mass=\"msun\"",
                "dust.fractions.0.s_rho=",
                "dust.fractions.0.size=0.1",
            ],
            "dust.fractions.0.grain_density",
        ),
        (&["dust.cross_section=2e-15"], "dust.cross_section"),
    ];
    for (sets, key) in cases {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let e = load(&config("dusty_ball"), &sets).expect_err(&format!("{sets:?}"));
        assert_eq!(e.key.as_deref(), Some(*key), "{sets:?}: {e}");
    }
    let e = load(
        &config("dustybox"),
        &["dust.fractions.0.size=0.1".to_string()],
    )
    .unwrap_err();
    assert_eq!(e.key.as_deref(), Some("dust.fractions.0.size"), "{e}");
}

/// A run in units writes them where GADGET-4/AREPO readers (and yt's `unit_base`) and SWIFT
/// readers look, and into the summary; a run without has none.
#[test]
fn snapshots_and_the_summary_carry_the_units() {
    let sets = [&AU_MSUN[..], &["sph.n=8", "time.dt=0.005"]].concat();
    let (s, _) = common::run_scene_in("dusty_ball", &sets, |dir| {
        let f = hdf5::File::open(dir.join("snapshot_0000.h5")).unwrap();
        let h = f.group("Header").unwrap();
        let get =
            |g: &hdf5::Group, n: &str| -> f64 { g.attr(n).unwrap().read_raw::<f64>().unwrap()[0] };
        assert_eq!(get(&h, "UnitLength_in_cm"), 1.495_978_707e13);
        assert_eq!(get(&h, "UnitMass_in_g"), 1.988_409_870_698_051e33);
        let t = get(&h, "UnitTime_in_s");
        assert!((get(&h, "UnitVelocity_in_cm_per_s") * t / 1.495_978_707e13 - 1.0).abs() < 1e-15);
        let u = f.group("Units").unwrap();
        assert_eq!(get(&u, "Unit time in cgs (U_t)"), t);
        assert_eq!(get(&u, "Unit length in cgs (U_L)"), 1.495_978_707e13);
    });
    let u = s.units.expect("summary units");
    assert_eq!(u.length_cm, 1.495_978_707e13);
    let (s, _) = common::run_scene_in("dusty_ball", &["sph.n=8", "time.t_end=0.005"], |dir| {
        let f = hdf5::File::open(dir.join("snapshot_0000.h5")).unwrap();
        assert!(f.group("Header").unwrap().attr("UnitLength_in_cm").is_err());
        assert!(f.group("Units").is_err());
    });
    assert!(s.units.is_none());
}

/// `[dust.sizes]` (configs/dustydisc3d.toml: 1 µm to 1 cm in four bins, index 3.5, dust-to-gas
/// 0.01, 3 g cm⁻³): each fraction sits at its bin's log-centre (s ρ_s = size · 3 g cm⁻³ in code
/// units), the ε sum to the dust-to-gas ratio, and with dn/ds ∝ s^−3.5 the mass per bin
/// ∝ ∫ s^−½ ds, so successive ε grow by (10)^½ per decade-wide bin.
#[test]
fn grains_by_size_distribution_split_the_dust_by_mass_at_log_centres() {
    let scene: Scene = load(&config("dustydisc3d"), &[]).unwrap().scene;
    let fr = scene.fractions();
    assert_eq!(fr.len(), 4);
    let sigma_unit = scene.units.unwrap().surface_density_g_cm2();
    let eps_sum: f64 = fr.iter().map(|f| f.eps).sum();
    assert!((eps_sum - 0.01).abs() < 1e-15, "ε sum {eps_sum}");
    for (k, f) in fr.iter().enumerate() {
        let size = 10f64.powf(-3.5 + k as f64);
        let StoppingLaw::Epstein { s_rho, .. } = f.law else {
            panic!("fraction {k}: {:?}", f.law)
        };
        assert!(
            (s_rho * sigma_unit / (3.0 * size) - 1.0).abs() < 1e-12,
            "fraction {k} size"
        );
        if k > 0 {
            let ratio = f.eps / fr[k - 1].eps;
            assert!(
                (ratio - 10f64.sqrt()).abs() < 1e-12,
                "fraction {k}: ε ratio {ratio}"
            );
        }
    }
}
