//! Launcher parity: a scene stepped by the one pipeline on the rayon launcher with a single
//! thread (the reference order) and on `device` (a CUDA GPU, or the rayon launcher on every
//! core), every array of every phase compared after every step. On a GPU this is CUDA against
//! the CPU; without one it checks that no result depends on how threads are scheduled.
use crate::particles::{Phase, State};
use crate::scene::LoadedScene;
use crate::scene::Precision;
use crate::setup;
use crate::sim::Simulation;
use crate::step::backend::{self, DeviceChoice};
use crate::step::Physics;

/// The largest difference found in one field over all steps.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldDiff {
    pub field: String,
    /// max |a − b| / max |a| over the array (0 when bit-identical).
    pub max_relative: f64,
    /// Whether every value matched bit for bit at every step.
    pub bitwise: bool,
}

#[derive(Debug, Clone)]
pub struct Parity {
    pub device: String,
    pub steps: u64,
    pub fields: Vec<FieldDiff>,
}

impl Parity {
    pub fn bitwise(&self) -> bool {
        self.fields.iter().all(|f| f.bitwise)
    }
    pub fn max_relative(&self) -> f64 {
        self.fields
            .iter()
            .map(|f| f.max_relative)
            .fold(0.0, f64::max)
    }
}

struct Comparison(Vec<FieldDiff>);

/// The permutation putting `b`'s particles in `a`'s id order (new index → old), or `None`
/// when the orders already agree (or the sets differ, which the comparison then reports).
fn id_order(a: &Phase, b: &Phase) -> Option<Vec<u32>> {
    if a.id == b.id || a.id.len() != b.id.len() {
        return None;
    }
    let at: std::collections::HashMap<u64, u32> =
        b.id.iter()
            .enumerate()
            .map(|(i, &id)| (id, i as u32))
            .collect();
    a.id.iter().map(|id| at.get(id).copied()).collect()
}

impl Comparison {
    fn add(&mut self, field: String, a: &[f64], b: &[f64]) {
        let scale = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        self.add_scaled(field, a, b, scale);
    }

    /// As `add`, relative to `scale` (a vector's components share their vector's scale: a
    /// component that is zero up to round-off is not its own yardstick).
    fn add_scaled(&mut self, field: String, a: &[f64], b: &[f64], scale: f64) {
        let mut bitwise = a.len() == b.len();
        let mut d = if bitwise { 0.0f64 } else { f64::INFINITY };
        for (x, y) in a.iter().zip(b) {
            if x.to_bits() != y.to_bits() {
                bitwise = false;
                let r = (x - y).abs() / if scale > 0.0 { scale } else { 1.0 };
                d = d.max(if r.is_nan() { f64::INFINITY } else { r });
            }
        }
        match self.0.iter_mut().find(|f| f.field == field) {
            Some(f) => {
                f.max_relative = f.max_relative.max(d);
                f.bitwise &= bitwise;
            }
            None => self.0.push(FieldDiff {
                field,
                max_relative: d,
                bitwise,
            }),
        }
    }

    fn v3(&mut self, field: &str, a: &[[f64; 3]], b: &[[f64; 3]]) {
        let scale = a.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
        for k in 0..3 {
            let pick = |v: &[[f64; 3]]| v.iter().map(|x| x[k]).collect::<Vec<_>>();
            self.add_scaled(format!("{field}[{k}]"), &pick(a), &pick(b), scale);
        }
    }

    fn order(&mut self, name: &str, a: &Phase, b: &Phase) {
        let ids = |p: &Phase| p.id.iter().map(|&i| i as f64).collect::<Vec<_>>();
        self.add(format!("{name} id (order)"), &ids(a), &ids(b));
    }

    fn phase(&mut self, name: &str, a: &Phase, b: &Phase, rho: bool) {
        self.v3(&format!("{name} x"), &a.x, &b.x);
        self.v3(&format!("{name} v"), &a.v, &b.v);
        if rho {
            self.add(format!("{name} rho"), &a.rho, &b.rho);
        }
    }

    fn state(&mut self, a: &State, b: &State, dust_rho: bool) {
        // The order is compared as it is; every other field particle by particle, matched by
        // id (b put in a's order first when they differ, e.g. f32 against f64).
        self.order("gas", &a.gas.ph, &b.gas.ph);
        for (k, (da, db)) in a.dust.iter().zip(&b.dust).enumerate() {
            self.order(&format!("dust{k}"), da, db);
        }
        let gas_perm = id_order(&a.gas.ph, &b.gas.ph);
        let dust_perm: Vec<_> = a
            .dust
            .iter()
            .zip(&b.dust)
            .map(|(p, q)| id_order(p, q))
            .collect();
        let owned;
        let b = if gas_perm.is_some() || dust_perm.iter().any(Option::is_some) {
            let mut o = b.clone();
            if let Some(p) = &gas_perm {
                o.gas.permute(p);
            }
            for (d, p) in o.dust.iter_mut().zip(&dust_perm) {
                if let Some(p) = p {
                    d.permute(p);
                }
            }
            owned = o;
            &owned
        } else {
            b
        };
        self.phase("gas", &a.gas.ph, &b.gas.ph, true);
        if let (Some(ha), Some(hb)) = (&a.gas.h, &b.gas.h) {
            self.add("gas h".into(), ha, hb);
        }
        if let (Some(oa), Some(ob)) = (&a.gas.omega, &b.gas.omega) {
            self.add("gas omega".into(), oa, ob);
        }
        self.add("gas p".into(), &a.gas.p, &b.gas.p);
        if let (Some(ea), Some(eb)) = (&a.gas.e, &b.gas.e) {
            self.add("gas e".into(), ea, eb);
        }
        for (k, (da, db)) in a.dust.iter().zip(&b.dust).enumerate() {
            self.phase(&format!("dust{k}"), da, db, dust_rho);
        }
    }
}

/// Step `steps` steps of a scene on the one-thread CPU reference and on `device` (the
/// reference's time step for both) and compare all arrays after set-up, after every step, and
/// the dust stopping times at the end.
pub fn compare(loaded: &LoadedScene, steps: u64, device: DeviceChoice) -> Result<Parity, String> {
    compare_tables(loaded, steps, device, false)
}

/// [`compare`], with the device on sparse cell tables when `sparse` (the reference keeps the
/// dense ones): both forms of the tables must give the same step.
pub fn compare_tables(
    loaded: &LoadedScene,
    steps: u64,
    device: DeviceChoice,
    sparse: bool,
) -> Result<Parity, String> {
    compare_scenes(loaded, loaded, steps, device, sparse)
}

/// [`compare_tables`] with the device stepping `device_scene`, a variant of the reference
/// scene in how it computes (e.g. the kernel coupling's scatter deposits against the gather):
/// the same particles, the same plan, arrays compared after every step.
pub fn compare_scenes(
    loaded: &LoadedScene,
    device_scene: &LoadedScene,
    steps: u64,
    device: DeviceChoice,
    sparse: bool,
) -> Result<Parity, String> {
    let scene = &loaded.scene;
    let su = setup::build(scene).map_err(|e| e.to_string())?;
    let phys = Physics::from_scene(scene, su.h, su.domain);
    let phys_dev = Physics::from_scene(&device_scene.scene, su.h, su.domain);
    let (device, _) = backend::select(device)?;
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| e.to_string())?;
    let err = |e: crate::step::StepError| e.to_string();
    let start = |e: backend::StartError| match e {
        backend::StartError::Device(m) => m,
        backend::StartError::Step(e) => e.to_string(),
    };
    let time = &scene.time;
    let (mut cpu, _) = one
        .install(|| Simulation::local(phys, time, su.state.clone(), DeviceChoice::Cpu))
        .map_err(start)?;
    let (mut dev, _) = Simulation::local(phys_dev, time, su.state, device).map_err(start)?;
    if sparse {
        let Simulation { stepper, state, .. } = &mut dev;
        (stepper
            .local()
            .expect("one process")
            .force_sparse_tables(state))
        .map_err(err)?;
    }
    let dust_rho = cpu
        .local_engine()
        .map_err(err)?
        .stages()
        .dust_density_each_step;
    let mut acc = Comparison(Vec::new());
    acc.state(&cpu.state, &dev.state, dust_rho);
    // Both step with the reference's plan (never landing), so a difference in the forces
    // cannot change the step size and hide itself.
    for step in 1..=steps {
        if cpu.local_engine().map_err(err)?.stages().explicit_drag {
            let a = one
                .install(|| cpu.local_engine()?.drag_dt_limit())
                .map_err(err)?;
            let b = dev
                .local_engine()
                .map_err(err)?
                .drag_dt_limit()
                .map_err(err)?;
            acc.add("explicit drag step limit".into(), &[a], &[b]);
        }
        let tc = one
            .install(|| {
                let t = cpu.step(f64::INFINITY)?;
                cpu.sync()?;
                Ok::<_, crate::step::StepError>(t)
            })
            .map_err(|e| format!("cpu step {step}: {e}"))?;
        let td = dev
            .step_with(&tc.plan)
            .map_err(|e| format!("device step {step}: {e}"))?;
        dev.sync().map_err(err)?;
        let (fc, fd) = (tc.forces, td.forces);
        acc.add("max signal speed".into(), &[fc.vsig_max], &[fd.vsig_max]);
        acc.add("max |A|".into(), &[fc.acc_max], &[fd.acc_max]);
        acc.state(&cpu.state, &dev.state, dust_rho);
    }
    let tc = one.install(|| cpu.dust_stopping_times()).map_err(err)?;
    let td = dev.dust_stopping_times().map_err(err)?;
    for (k, (a, b)) in tc.iter().zip(&td).enumerate() {
        // Matched by particle id (see `Comparison::state`).
        let perm = id_order(&cpu.state.dust[k], &dev.state.dust[k]);
        let in_order = |v: &[f64]| match &perm {
            Some(p) => p.iter().map(|&i| v[i as usize]).collect(),
            None => v.to_vec(),
        };
        // +∞ (uncoupled) compares by bits; finite values by size.
        acc.add(format!("dust{k} t_stop"), a, &in_order(b));
        acc.add(
            format!("dust{k} rho (output)"),
            &cpu.state.dust[k].rho,
            &in_order(&dev.state.dust[k].rho),
        );
    }
    Ok(Parity {
        device: dev.stepper.describe(),
        steps,
        fields: acc.0,
    })
}

/// The scenes `dustsph parity` runs: (label, config, overrides, steps).
pub const CASES: &[(&str, &str, &[&str], u64)] = &[
    ("dustybox", "configs/dustybox.toml", &[], 20),
    ("dustywave N=4", "configs/dustywave.toml", &["sph.n=64"], 20),
    (
        "dustywave adiabatic, constant K, old update",
        "configs/dustywave.toml",
        &[
            "sph.n=64",
            "gas.eos=adiabatic",
            "gas.cs=",
            "gas.gamma=1.4",
            "gas.p=1.0",
            "dust.law=constant_k",
            "dust.fractions=[{eps=1.0, k=5.0}, {eps=0.5, k=50.0}]",
            "time.position_update=old",
        ],
        15,
    ),
    (
        "dustyshock (walls, AV, heating)",
        "configs/dustyshock.toml",
        &["sph.n=200"],
        20,
    ),
    (
        "small ball 3D (Epstein)",
        "configs/dusty_ball.toml",
        &["sph.n=6", "sph.h=0.3"],
        8,
    ),
    // The kernel coupling (docs/method.md §K) on every scene kind.
    (
        "kernel coupling: dustybox 3D, dust offset 0.5, external accelerations",
        "configs/dustybox.toml",
        &[
            "scene.dim=3",
            "sph.n=8",
            "sph.hfact=1.2",
            "dustybox.dust_shift=0.5",
            "idic.coupling=kernel",
            "external.gas=[1.0, 0.5, 0.0]",
            "external.dust=[0.0, 0.0, -2.0]",
        ],
        10,
    ),
    (
        "kernel coupling: dustywave N=4, dust offset 0.5",
        "configs/dustywave.toml",
        &[
            "sph.n=64",
            "idic.coupling=kernel",
            "dustywave.dust_shift=0.5",
        ],
        20,
    ),
    (
        "kernel coupling: dustywave adiabatic, constant K",
        "configs/dustywave.toml",
        &[
            "sph.n=64",
            "gas.eos=adiabatic",
            "gas.cs=",
            "gas.gamma=1.4",
            "gas.p=1.0",
            "dust.law=constant_k",
            "dust.fractions=[{eps=1.0, k=5.0}, {eps=0.5, k=50.0}]",
            "idic.coupling=kernel",
        ],
        15,
    ),
    (
        "kernel coupling: dustyshock (walls, AV)",
        "configs/dustyshock.toml",
        &["sph.n=200", "idic.coupling=kernel", "dust.heating=false"],
        20,
    ),
    (
        "kernel coupling: small ball 3D (Epstein)",
        "configs/dusty_ball.toml",
        &["sph.n=6", "sph.h=0.3", "idic.coupling=kernel"],
        8,
    ),
    (
        "kernel coupling: dustysettle (walls, gravity, Epstein)",
        "configs/dustysettle.toml",
        &["sph.n=100", "sph.gradient=standard"],
        10,
    ),
    // Variable h (every phase) and the IAD gradient on the GPU step.
    (
        "variable h + IAD: Phantom wave 3D, constant K (first-order step)",
        "configs/dustywave_phantom.toml",
        &[
            "sph.n=16",
            "dustywave.layers=6",
            "time.integrator=first_order",
        ],
        10,
    ),
    (
        "variable h: dustywave adiabatic, constant K, drag heating",
        "configs/dustywave.toml",
        &[
            "sph.n=64",
            "sph.variable_h=true",
            "gas.eos=adiabatic",
            "gas.cs=",
            "gas.gamma=1.4",
            "gas.p=1.0",
            "dust.law=constant_k",
            "dust.fractions=[{eps=1.0, k=5.0}, {eps=0.5, k=50.0}]",
            "dust.heating=true",
        ],
        15,
    ),
    (
        "IAD, fixed h: small ball 3D (Epstein)",
        "configs/dusty_ball.toml",
        &["sph.n=6", "sph.h=0.3", "sph.gradient=iad"],
        8,
    ),
    // The kick–drift–kick leapfrog.
    (
        "leapfrog + variable h + IAD: Phantom wave 3D as shipped",
        "configs/dustywave_phantom.toml",
        &["sph.n=16", "dustywave.layers=6"],
        10,
    ),
    (
        "leapfrog: dustyshock (walls, AV, heating)",
        "configs/dustyshock.toml",
        &["sph.n=200", "time.integrator=kdk"],
        20,
    ),
    (
        "leapfrog + kernel coupling: dustybox 3D, dust offset 0.5, external accelerations",
        "configs/dustybox.toml",
        &[
            "scene.dim=3",
            "sph.n=8",
            "sph.hfact=1.2",
            "dustybox.dust_shift=0.5",
            "idic.coupling=kernel",
            "external.gas=[1.0, 0.5, 0.0]",
            "external.dust=[0.0, 0.0, -2.0]",
            "time.integrator=kdk",
        ],
        10,
    ),
    // The explicit drag baseline and the continuity density.
    (
        "explicit drag: dustywave N=4",
        "configs/dustywave.toml",
        &["sph.n=64", "drag.method=explicit"],
        20,
    ),
    (
        "explicit drag + leapfrog: dustyshock (walls, AV, heating)",
        "configs/dustyshock.toml",
        &["sph.n=200", "drag.method=explicit", "time.integrator=kdk"],
        20,
    ),
    (
        "continuity density: dustywave adiabatic, constant K",
        "configs/dustywave.toml",
        &[
            "sph.n=64",
            "sph.density=continuity",
            "gas.eos=adiabatic",
            "gas.cs=",
            "gas.gamma=1.4",
            "gas.p=1.0",
            "dust.law=constant_k",
            "dust.fractions=[{eps=1.0, k=5.0}, {eps=0.5, k=50.0}]",
        ],
        15,
    ),
    // The kernel coupling with variable h, drag heating and the authors' position update.
    (
        "kernel coupling + variable h + IAD + leapfrog: Phantom wave 3D, dust offset 0.5",
        "configs/dustywave_phantom.toml",
        &[
            "sph.n=16",
            "dustywave.layers=6",
            "idic.coupling=kernel",
            "dustywave.dust_shift=0.5",
        ],
        10,
    ),
    (
        "kernel coupling + drag heating: dustyshock (walls, AV)",
        "configs/dustyshock.toml",
        &["sph.n=200", "idic.coupling=kernel"],
        20,
    ),
    (
        "kernel coupling + old position update: dustywave N=4",
        "configs/dustywave.toml",
        &[
            "sph.n=64",
            "idic.coupling=kernel",
            "time.position_update=old",
        ],
        20,
    ),
    (
        "kernel coupling, damped dispersion: the 2D dusty disc (point mass, locally isothermal, \
         edge damping zones)",
        "configs/dustydisc.toml",
        &["sph.n=16"],
        5,
    ),
    (
        "the disc viscosity (α_SS on every pair) and the linear sampling: the 2D dusty disc",
        "configs/dustydisc.toml",
        &["sph.n=16", "sph.alpha_ss=0.01", "sph.beta=0"],
        5,
    ),
    (
        "the 3D disc in physical units: four Epstein grain sizes, variable h in 3D, the leapfrog, \
         an accretion radius, α_SS, edge damping zones (unbalanced: dustydisc.relax = false)",
        "configs/dustydisc3d.toml",
        &["dustydisc.particles=10000", "dustydisc.relax=false"],
        3,
    ),
];

// ---------------------------------------------------------------------------------------------
// The command line.

#[derive(clap::Args)]
pub struct ParityArgs {
    /// The device to check against the one-thread CPU reference (cuda; or cpu: every core)
    #[arg(long, value_enum, default_value_t = DeviceChoice::Cuda)]
    device: DeviceChoice,
    /// Check the f32 kernels instead of the f64 ones
    #[arg(long, value_enum, default_value_t = Precision::F64)]
    precision: Precision,
}

pub fn execute(a: ParityArgs) -> u8 {
    let ParityArgs { device, precision } = a;
    // A device that is not there is bad input (exit 2), said once, before any case runs.
    if let Err(e) = crate::step::backend::select(device) {
        eprintln!("error: {e}");
        return 2;
    }
    let mut all_ok = true;
    for (label, file, sets, steps) in crate::commands::parity::CASES {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let loaded = crate::scene::load_shipped(file, &sets)
            .and_then(|l| l.with_numerics(Some(precision), None));
        let loaded = match loaded {
            Ok(l) => l,
            Err(e) => {
                eprintln!("error: {e}");
                return 2;
            }
        };
        match crate::commands::parity::compare(&loaded, *steps, device) {
            Ok(p) => {
                let worst = p.fields.iter().filter(|f| !f.bitwise).count();
                println!(
                    "{label:<44} {steps:>3} steps on {}: {} of {} fields bit-identical, max relative difference {:.3e}",
                    p.device,
                    p.fields.len() - worst,
                    p.fields.len(),
                    p.max_relative()
                );
                for f in p.fields.iter().filter(|f| !f.bitwise) {
                    println!("    {:<28} {:.3e}", f.field, f.max_relative);
                }
                all_ok &= p.max_relative() <= 1e-10;
            }
            Err(e) => {
                eprintln!("error: {label}: {e}");
                return 1;
            }
        }
    }
    if all_ok {
        0
    } else {
        eprintln!("parity: some array differs by more than 1e-10 (relative)");
        1
    }
}
