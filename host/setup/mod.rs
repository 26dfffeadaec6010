//! Scene → initial particles. One file per problem; each builds the [`Setup`] the engine starts from.
mod disorder;
mod dustyball;
mod dustybox;
mod dustydisc;
pub mod dustysettle;
mod dustyshock;
pub mod dustywave;
pub mod file;
pub mod glass;

use crate::grid::Domain;
use crate::particles::{Gas, Phase, State};
use crate::scene::{GasState, ProblemCfg, Scene};

/// Initial state plus the resolved resolution-dependent quantities.
#[derive(Debug, Clone)]
pub struct Setup {
    pub state: State,
    pub h: f64,
    pub domain: Domain,
    /// Reference gas particle spacing (h = hfact · spacing).
    pub spacing: f64,
    /// Length of the domain along x (written as BoxSize).
    pub box_size: f64,
    /// What the set-up made that a user should hear of (a glass's density noise).
    pub notes: Vec<String>,
    /// Initial conditions from a file: which, and its digest (every output records them).
    pub source: Option<file::IcSource>,
    /// The state holds only this process's share of the particles (a file read over MPI
    /// ranks, [`build_on`]); otherwise every particle.
    pub share: bool,
}

impl Setup {
    /// A set-up at t = 0 from its phases.
    pub(crate) fn at_start(
        gas: Gas,
        dust: Vec<Phase>,
        h: f64,
        domain: Domain,
        spacing: f64,
        box_size: f64,
    ) -> Setup {
        Setup {
            state: State {
                t: 0.0,
                step: 0,
                gas,
                dust,
            },
            h,
            domain,
            spacing,
            box_size,
            notes: Vec::new(),
            source: None,
            share: false,
        }
    }
}

/// The points of one phase (`phase`: 0 gas, k + 1 fraction k) in the periodic box [0, len):
/// the lattice `x0` itself, or a glass relaxed from it by the scene's SPH (`Lattice::Glass`, a
/// note with its density noise), then displaced by `jitter` spacings at random.
#[allow(clippy::too_many_arguments)]
pub(crate) fn arrange(
    x0: Vec<[f64; 3]>,
    dim: u32,
    len: &[f64; 3],
    spacing: f64,
    h: f64,
    order: (crate::scene::Lattice, f64, u64),
    phase: u64,
    scene: &Scene,
    notes: &mut Vec<String>,
) -> Result<Vec<[f64; 3]>, SetupError> {
    let (lattice, jitter, seed) = order;
    let mut x = if lattice == crate::scene::Lattice::Glass && dim > 1 {
        let sph = glass::GlassSph {
            variable_hfact: scene.sph.smoothing.variable_hfact(),
            iad: scene.sph.gradient == crate::scene::GradientMethod::Iad,
        };
        let spec = glass::GlassSpec {
            dim,
            len: *len,
            spacing,
            h,
            seed,
            phase,
            sph,
        };
        let g = glass::glass(&x0, &spec)?;
        let who = if phase == 0 {
            "gas".to_string()
        } else {
            format!("dust fraction {}", phase - 1)
        };
        notes.push(format!(
            "glass ({who}): SPH density noise {:.2} % rms (its random start: {:.2} %, {} relaxation steps)",
            100.0 * g.noise,
            100.0 * g.start_noise,
            g.iterations
        ));
        g.x
    } else {
        x0
    };
    disorder::jitter(&mut x, dim, len, spacing, jitter, seed, phase);
    Ok(x)
}

/// Memory a particle costs a run (gas or dust: the step's buffers, the host state, output
/// copies). Measured: 3D box, 5 × 64 000 particles, 116 MB peak (≈ 360 B each); 600 B leaves a
/// margin for the union-cell arrays of many fractions and for the kernel coupling. The CPU's
/// neighbour lists come on top, only while they fit in a quarter of the free memory.
pub const BYTES_PER_PARTICLE: f64 = 600.0;

/// The memory this machine can give a run (Linux: MemAvailable), if known.
pub(crate) fn available_memory() -> Option<f64> {
    let m = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = m.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

/// Before any allocation: refuse a lattice of `per_phase` particles in each of `phases` phases
/// that the particle indices (u32) or this machine's memory cannot hold, naming `key` (and the
/// other keys `also` that set the count) and the estimate (an absurd `sph.n` must not abort the
/// process).
pub(crate) fn check_size(
    per_phase: f64,
    phases: usize,
    key: &str,
    also: &[&str],
) -> Result<(), SetupError> {
    let or = if also.is_empty() {
        String::new()
    } else {
        format!(" (or {})", also.join(", "))
    };
    let total = per_phase * phases as f64;
    let need = total * BYTES_PER_PARTICLE;
    let fail = |why: String| {
        Err(SetupError {
            key: key.into(),
            msg: format!(
                "about {total:.3e} particles ({per_phase:.3e} per phase × {phases}) {why}; lower {key}{or}"
            ),
        })
    };
    if !total.is_finite() || per_phase >= u32::MAX as f64 {
        return fail(format!("exceed the {} a phase can index", u32::MAX));
    }
    match available_memory() {
        Some(avail) if need > avail => fail(format!(
            "need about {:.1} GB, more than the {:.1} GB available",
            need / 1e9,
            avail / 1e9
        )),
        _ => Ok(()),
    }
}

/// Which particles a process sets up of a scene shared over the processes of a collective:
/// over several, those whose id + phase (0 gas, k + 1 fraction k) ≡ its rank (mod their
/// number), the share each rank starts from until the first cut moves the particles to their
/// owners; alone, every one.
#[derive(Debug, Clone, Copy)]
pub struct Keep {
    rank: u64,
    size: u64,
}

impl Keep {
    pub fn of(c: &dyn crate::dist::Comm) -> Keep {
        Keep {
            rank: c.rank() as u64,
            size: c.size().max(1) as u64,
        }
    }

    /// Whether particle `id` of phase `phase` is this process's.
    pub fn mine(&self, phase: u64, id: u64) -> bool {
        id.wrapping_add(phase) % self.size == self.rank
    }

    /// Whether this process sets up less than every particle.
    pub fn shared(&self) -> bool {
        self.size > 1
    }
}

/// A set-up error names the scene key at fault.
#[derive(Debug, Clone, PartialEq)]
pub struct SetupError {
    pub key: String,
    pub msg: String,
}

impl std::fmt::Display for SetupError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "key `{}`: {}", self.key, self.msg)
    }
}
impl std::error::Error for SetupError {}

pub fn build(scene: &Scene) -> Result<Setup, SetupError> {
    build_on(scene, &crate::dist::Alone)
}

/// [`build`] as one of the processes in `c`: initial conditions from a file are read by
/// share (each process its own rows, [`Setup::share`]), the ball, the box and the wave set up
/// by share (each process its [`Keep`]); other scenes are set up whole on each (collective;
/// every process gets the same error).
pub fn build_on(scene: &Scene, c: &dyn crate::dist::Comm) -> Result<Setup, SetupError> {
    let su = build_problem(scene, c)?;
    // A point mass's pull has no periodic image: it needs open axes.
    if scene.gravity.is_some() && su.domain.periodic.iter().any(Option::is_some) {
        return Err(SetupError {
            key: "gravity".into(),
            msg: format!(
                "a central point mass needs open axes; problem `{}` is periodic",
                scene.kind().name()
            ),
        });
    }
    Ok(su)
}

fn build_problem(scene: &Scene, c: &dyn crate::dist::Comm) -> Result<Setup, SetupError> {
    match &scene.problem {
        ProblemCfg::Dustybox(b) => dustybox::build(scene, b, Keep::of(c)),
        ProblemCfg::Dustywave(w) => dustywave::build(scene, w, Keep::of(c)),
        ProblemCfg::Dustyshock(s) => dustyshock::build(scene, s),
        ProblemCfg::Dustyball(b) => dustyball::build(scene, b, Keep::of(c)),
        ProblemCfg::Dustysettle(c) => dustysettle::build(scene, c),
        ProblemCfg::File(f) => file::build(scene, f, c),
        ProblemCfg::Dustydisc(d) => dustydisc::build(scene, d),
    }
}

/// h from `sph.h` or `sph.hfact × spacing`.
pub(crate) fn smoothing_length(scene: &Scene, spacing: f64) -> f64 {
    scene.sph.smoothing.h(spacing)
}

/// Periodic boxes must hold the kernel support twice over, so minimum-image pairs are unique.
pub(crate) fn check_periodic_fits(length: f64, h: f64, len_key: &str) -> Result<(), SetupError> {
    let support = dustsph_device::kernel::SUPPORT * h;
    if length < 2.0 * support {
        return Err(SetupError {
            key: len_key.into(),
            msg: format!(
                "periodic length {length} must be at least twice the kernel support 2h = {support} \
                 (lower sph.hfact/sph.h or raise sph.n)"
            ),
        });
    }
    Ok(())
}

/// Specific internal energy for adiabatic gas in the state `st` (`None`: isothermal).
pub(crate) fn internal_energy(scene: &Scene, st: GasState) -> Option<f64> {
    scene.gas.eos.internal_energy(st)
}

/// Assemble a gas phase; `e` only for adiabatic gas.
pub(crate) fn gas_phase(ph: Phase, e: Option<Vec<f64>>) -> Gas {
    let n = ph.len();
    Gas {
        ph,
        p: vec![0.0; n],
        c: vec![0.0; n],
        e,
        h: None,
        omega: None,
        closing_forces: None,
    }
}

/// One dust phase per fraction at the gas particles' places: fraction k gets mass ε_k m and
/// density ε_k ρ of the gas particle it sits on, velocity `u(k)`, and ids after the gas and the
/// earlier fractions. No dust section: no dust phases.
pub(crate) fn co_located_dust(
    scene: &Scene,
    gas: &Phase,
    u: impl Fn(usize) -> [f64; 3],
) -> Vec<Phase> {
    let n = gas.len() as u64;
    scene
        .fractions()
        .iter()
        .enumerate()
        .map(|(k, f)| Phase {
            x: gas.x.clone(),
            v: vec![u(k); gas.len()],
            m: gas.m.iter().map(|m| f.eps * m).collect(),
            rho: gas.rho.iter().map(|r| f.eps * r).collect(),
            id: ((k as u64 + 1) * n..(k as u64 + 2) * n).collect(),
            fixed: gas.fixed.clone(),
        })
        .collect()
}

/// The particles of one phase (`phase`: 0 gas, k + 1 fraction k) whose particle i sits at
/// `x[i]` with id `first + i`, of those `keep` says are this process's: `at(i, x[i])` gives
/// each its velocity, mass and density.
pub(crate) fn phase_kept(
    x: Vec<[f64; 3]>,
    (phase, first): (u64, u64),
    keep: Keep,
    at: impl Fn(usize, [f64; 3]) -> ([f64; 3], f64, f64),
) -> Phase {
    let mut ph = Phase::default();
    for (i, q) in x.into_iter().enumerate() {
        let id = first + i as u64;
        if keep.mine(phase, id) {
            let (v, m, rho) = at(i, q);
            ph.x.push(q);
            ph.v.push(v);
            ph.m.push(m);
            ph.rho.push(rho);
            ph.id.push(id);
        }
    }
    ph.shrink_to_fit();
    ph
}

/// Uniform lattice of `n_axis` points per axis in [0, length)^dim at cell centres.
pub(crate) fn lattice(dim: u32, n_axis: usize, length: f64) -> Vec<[f64; 3]> {
    let dx = length / n_axis as f64;
    let ny = if dim >= 2 { n_axis } else { 1 };
    let nz = if dim >= 3 { n_axis } else { 1 };
    let mut x = Vec::with_capacity(n_axis * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..n_axis {
                let c = |i: usize, used: bool| if used { (i as f64 + 0.5) * dx } else { 0.0 };
                x.push([c(i, true), c(j, dim >= 2), c(k, dim >= 3)]);
            }
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each particle as (phase, id, the bits of its position, x-velocity, mass, density).
    fn records(st: &State) -> Vec<(u64, u64, [u64; 6])> {
        let mut v = Vec::new();
        for (p, ph) in std::iter::once(&st.gas.ph).chain(&st.dust).enumerate() {
            for i in 0..ph.len() {
                let [a, b, c] = ph.x[i].map(f64::to_bits);
                let [d, e, f] = [ph.v[i][0], ph.m[i], ph.rho[i]].map(f64::to_bits);
                v.push((p as u64, ph.id[i], [a, b, c, d, e, f]));
            }
        }
        v
    }

    /// The scene `name` set up by share over 3 processes: each share holds its `Keep`'s
    /// particles and about a third of every phase, and the shares together are the scene set
    /// up alone, id by id, bit for bit.
    fn set_up_by_share_is_set_up_alone(name: &str, overrides: &[&str]) {
        let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        let loaded = crate::scene::load_shipped(name, &overrides).unwrap();
        let alone = build(&loaded.scene).unwrap();
        assert!(!alone.share);
        let mut joined = Vec::new();
        for c in crate::dist::threads::Threads::group(3) {
            let keep = Keep::of(&c);
            let su = build_on(&loaded.scene, &c).unwrap();
            assert!(su.share, "{name}");
            let mine = records(&su.state);
            assert!(mine.iter().all(|r| keep.mine(r.0, r.1)), "{name}");
            let shares = std::iter::once(&su.state.gas.ph).chain(&su.state.dust);
            let wholes = std::iter::once(&alone.state.gas.ph).chain(&alone.state.dust);
            for (p, (ph, whole)) in shares.zip(wholes).enumerate() {
                assert!(ph.len().abs_diff(whole.len() / 3) <= 1, "{name} phase {p}");
            }
            let e = su.state.gas.e.as_ref().map(Vec::len);
            assert_eq!(e.is_some(), alone.state.gas.e.is_some(), "{name}");
            assert!(e.is_none_or(|n| n == su.state.gas.ph.len()), "{name}");
            joined.extend(mine);
        }
        let mut whole = records(&alone.state);
        whole.sort();
        joined.sort();
        assert!(joined == whole, "{name}: the shares are not the whole");
    }

    #[test]
    fn the_ball_the_box_and_the_wave_set_up_by_share_are_each_set_up_alone_shared_out() {
        let two = "dust.fractions=[{s_rho=1e-3,eps=0.5},{s_rho=2e-3,eps=0.25}]";
        set_up_by_share_is_set_up_alone("configs/dusty_ball.toml", &["sph.n=10", two]);
        set_up_by_share_is_set_up_alone(
            "configs/dustybox.toml",
            &["scene.dim=3", "sph.n=12", "sph.hfact=1.2"],
        );
        // A glass for each phase, the dust shifted and jittered.
        set_up_by_share_is_set_up_alone(
            "configs/dustybox.toml",
            &[
                "scene.dim=2",
                "sph.n=12",
                "sph.hfact=1.2",
                "dustybox.lattice=\"glass\"",
                "dustybox.dust_shift=0.5",
                "dustybox.jitter=0.1",
            ],
        );
        // The Phantom slab (close-packed, adiabatic: each particle its energy) and a 2D wave
        // on glasses, the dust shifted.
        set_up_by_share_is_set_up_alone("configs/dustywave_phantom.toml", &["sph.n=16"]);
        set_up_by_share_is_set_up_alone(
            "configs/dustywave.toml",
            &[
                "scene.dim=2",
                "sph.n=16",
                "dustywave.lattice=\"glass\"",
                "dustywave.dust_shift=0.5",
                "dustywave.layers=16",
            ],
        );
    }
}
