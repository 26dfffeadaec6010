//! The step: the physics resolved from the scene ([`Physics`]), the stages a scene runs
//! ([`Stages`]), the engine that runs them as kernel launches ([`engine`]) on one of its
//! launchers and precisions ([`backend`]), and the choice of each step's size
//! ([`timestep`]).
//!
//! A scene switches stages on or off (no dust → no IDIC pass; isothermal → no energy
//! equation; no viscosity unless asked); the run's summary lists the stages that ran, from
//! their timers.
pub mod backend;
pub mod check;
pub mod engine;
pub mod timers;
pub mod timestep;

pub use check::{check_state, Forces, Momentum, StepError, SUPPORT};

use crate::grid::Domain;
use crate::scene::{
    Coupling, DensityMethod, DragMethod, GradientMethod, Integrator, PositionUpdate, Precision,
    Scene,
};
use dustsph_device::drag::StoppingLaw;
use dustsph_device::eos::Eos;
use dustsph_device::sph::{DiscViscosity, Viscosity};

/// Everything the step needs to know about the physics, resolved from the scene.
#[derive(Debug, Clone)]
pub struct Physics {
    pub dim: u32,
    /// Global, fixed smoothing length (support 2h).
    pub h: f64,
    pub eos: Eos<f64>,
    pub av: Option<Viscosity<f64>>,
    /// One stopping-time law per dust fraction.
    pub laws: Vec<StoppingLaw<f64>>,
    pub heating: bool,
    /// IDIC, or the explicit baseline (same cells, forward Euler, τ ≤ 0.9 t_s).
    pub drag: DragMethod,
    /// Where the implicit drag takes its local means (grid cells or the gas particles).
    pub coupling: Coupling,
    /// GPU, kernel coupling: deposits summed by atomic scatter instead of the gather.
    pub deposit_scatter: bool,
    /// Kernel coupling: the dust's unresolved velocity deviation damped (`idic.dispersion`).
    pub damp_dispersion: bool,
    /// Kernel coupling: the deposits read at their gas particle through the gas's fitted
    /// velocity gradient (`idic.sampling = "linear"`).
    pub linear_sampling: bool,
    /// Constant external accelerations of the gas and of every dust particle.
    pub ext_gas: [f64; 3],
    pub ext_dust: [f64; 3],
    /// A central point mass (`[gravity]`; `gm` = 0: none), in A^n and B^n.
    pub gravity: dustsph_device::gravity::PointMass,
    /// Particles closer to the point mass than this are accreted after a step (0: none).
    pub accretion_radius: f64,
    /// Locally isothermal gas: c_s(x) (`on` = 0: the EOS's own).
    pub local_cs: dustsph_device::eos::LocalSoundSpeed,
    /// Nominal IDIC cell size Δc (periodic axes round it so cells tile the period).
    pub cell_size: f64,
    pub domain: Domain,
    pub position_update: PositionUpdate,
    /// Gas density by summation, or by the continuity equation.
    pub density: DensityMethod,
    /// Variable-h gas (Phantom's): `Some(hfact)`; `h` is then the initial/reference h (IDIC
    /// cells, CFL, dust densities).
    pub variable_h: Option<f64>,
    /// Standard kernel gradient or IAD in the gas pair terms.
    pub gradient: GradientMethod,
    pub integrator: Integrator,
    /// The float type of the step's kernels.
    pub precision: Precision,
    /// Neighbour lists for the gas's passes (`numerics.neighbour_list`).
    pub neighbour_list: crate::scene::ListChoice,
    /// How the kernel coupling's deposit rows are transposed (`numerics.deposit_rows`).
    pub deposit_rows: crate::scene::DepositRows,
}

impl Physics {
    pub fn from_scene(scene: &Scene, h: f64, domain: Domain) -> Physics {
        Physics {
            dim: scene.dim(),
            h,
            eos: scene.gas.eos.eos(),
            av: scene.sph.viscosity.map(|v| Viscosity {
                alpha: v.alpha,
                beta: v.beta,
                nu2_factor: 0.01,
                // ν = α c_s h/κ on every pair, so α_AV = κ α_SS H/h gives ν = α_SS c_s H.
                disc: v.alpha_ss.zip(scene.gravity).map(|(a, g)| DiscViscosity {
                    kappa_alpha_ss: DiscViscosity::kappa(scene.dim()) * a,
                    gm: g.central_mass,
                    centre: g.position,
                }),
            }),
            laws: scene.fractions().iter().map(|f| f.law).collect(),
            heating: scene.dust.as_ref().is_some_and(|d| d.heating),
            drag: scene.drag.method,
            coupling: scene.idic.coupling,
            deposit_scatter: scene.idic.deposit == crate::scene::DepositForm::Scatter,
            damp_dispersion: scene.idic.dispersion == crate::scene::Dispersion::Damped,
            linear_sampling: scene.idic.sampling == crate::scene::Sampling::Linear,
            ext_gas: scene.external.gas,
            ext_dust: scene.external.dust,
            local_cs: scene
                .gas
                .eos
                .local_sound_speed(scene.gravity.map(|g| g.position)),
            gravity: scene
                .gravity
                .map_or_else(Default::default, |g| g.point_mass()),
            accretion_radius: scene.gravity.map_or(0.0, |g| g.accretion_radius),
            cell_size: scene.idic.cell * h,
            domain,
            position_update: scene.time.position_update,
            density: scene.sph.density,
            variable_h: scene.sph.smoothing.variable_hfact(),
            gradient: scene.sph.gradient,
            integrator: scene.time.integrator,
            precision: scene.numerics.precision,
            neighbour_list: scene.numerics.neighbour_list,
            deposit_rows: scene.numerics.deposit_rows,
        }
    }

    /// A one-dimensional open domain at a fixed h, with everything else as a scene's defaults
    /// (no viscosity or heating, nearest-cell IDIC in cells of 0.5 h, summation density, the
    /// standard gradient, the first-order step, f64): the physics of a hand-made state (the
    /// stiffness matrix's slab, tests).
    pub fn open_1d(h: f64, eos: Eos<f64>, laws: Vec<StoppingLaw<f64>>) -> Physics {
        Physics {
            dim: 1,
            h,
            eos,
            av: None,
            laws,
            heating: false,
            drag: DragMethod::Idic,
            coupling: Coupling::Cell,
            deposit_scatter: false,
            damp_dispersion: false,
            linear_sampling: false,
            ext_gas: [0.0; 3],
            ext_dust: [0.0; 3],
            gravity: Default::default(),
            accretion_radius: 0.0,
            local_cs: Default::default(),
            cell_size: 0.5 * h,
            domain: Domain {
                dim: 1,
                periodic: [None; 3],
            },
            position_update: PositionUpdate::New,
            density: DensityMethod::Summation,
            variable_h: None,
            gradient: GradientMethod::Standard,
            integrator: Integrator::FirstOrder,
            precision: Precision::F64,
            neighbour_list: crate::scene::ListChoice::Auto,
            deposit_rows: crate::scene::DepositRows::Auto,
        }
    }

    pub fn support(&self) -> f64 {
        dustsph_device::kernel::SUPPORT * self.h
    }

    /// An IDIC cell's diagonal: the furthest two cell-mates can be apart (method.md §3.3).
    pub fn cell_diagonal(&self) -> f64 {
        self.cell_size * (self.dim as f64).sqrt()
    }
}

/// The nearest-cell coupling's blind spot (method.md §3.5): how many dust particles (all
/// fractions) have no gas particle in their IDIC cell, so that their drag is off, and how many
/// there are, over the particles of every process in `c` (collective; each process its own).
/// The cells are those of one grid over every process's particles; each cell's gas and dust
/// counts meet on the process that checks it ([`crate::dist::checker_of`]). (0, 0) without
/// dust, or when the grid cannot be built or the counts not exchanged (the run then stops
/// with its own error).
pub fn dust_without_gas_in_cell(
    phys: &Physics,
    state: &crate::particles::State,
    c: &dyn crate::dist::Comm,
) -> (usize, usize) {
    use crate::grid::{merge_bounds, Grid, EMPTY_BOUNDS};
    if state.dust.is_empty() {
        return (0, 0);
    }
    let phases = std::iter::once(&state.gas.ph.x).chain(state.dust.iter().map(|d| &d.x));
    let (lo, hi) = (phases.flatten()).fold(EMPTY_BOUNDS, |b, &x| merge_bounds(b, (x, x)));
    let mut ends = [hi[0], hi[1], hi[2], -lo[0], -lo[1], -lo[2]];
    c.max_f64(&mut ends);
    let bounds = ([-ends[3], -ends[4], -ends[5]], [ends[0], ends[1], ends[2]]);
    let Ok(grid) = Grid::from_bounds(&phys.domain, phys.cell_size, phys.support(), bounds) else {
        return (0, 0);
    };
    // (cell key, u64::MAX) for a cell holding gas, (cell key, n) for n dust particles in it.
    const GAS: u64 = u64::MAX;
    let mut to: Vec<Vec<[u64; 2]>> = vec![Vec::new(); c.size() as usize];
    let mut runs = |mut keys: Vec<u64>, gas: bool| {
        keys.sort_unstable();
        for run in keys.chunk_by(|a, b| a == b) {
            let n = if gas { GAS } else { run.len() as u64 };
            to[crate::dist::checker_of(run[0], c.size())].push([run[0], n]);
        }
    };
    runs(state.gas.ph.x.iter().map(|&x| grid.key(x)).collect(), true);
    let dust = state.dust.iter().flat_map(|d| d.x.iter());
    runs(dust.map(|&x| grid.key(x)).collect(), false);
    let Ok(got) = crate::dist::route(c, to) else {
        return (0, 0);
    };
    let gas: std::collections::HashSet<u64> =
        (got.iter()).filter(|p| p[1] == GAS).map(|p| p[0]).collect();
    let mut n = [0u64; 2];
    for p in got.iter().filter(|p| p[1] != GAS) {
        n[1] += p[1];
        if !gas.contains(&p[0]) {
            n[0] += p[1];
        }
    }
    c.sum_u64(&mut n);
    (n[0] as usize, n[1] as usize)
}

/// Which stages a step runs; derived from [`Physics`], never set by hand.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Stages {
    pub drag: bool,
    /// The drag is the explicit baseline (adds a drag time-step limit).
    pub explicit_drag: bool,
    pub energy: bool,
    pub viscosity: bool,
    pub heating: bool,
    /// Dust SPH density every step (constant-K drag needs it); otherwise only for output.
    pub dust_density_each_step: bool,
    /// Gas density from the continuity equation instead of summation.
    pub continuity_density: bool,
    /// Variable smoothing length (grad-h SPH) for the gas.
    pub variable_h: bool,
    /// IAD gradient: a pass for the matrices C_a before the forces.
    pub iad: bool,
    /// Kick–drift–kick leapfrog instead of the first-order step.
    pub kdk: bool,
    /// The drag solve on the gas particles with kernel weights (`idic.coupling = "kernel"`).
    pub kernel_coupling: bool,
    /// Constant external accelerations are added (`[external]`).
    pub external: bool,
}

impl Stages {
    pub fn from_physics(p: &Physics) -> Stages {
        Stages {
            drag: !p.laws.is_empty(),
            explicit_drag: !p.laws.is_empty() && p.drag == DragMethod::Explicit,
            energy: matches!(p.eos, Eos::Adiabatic { .. }),
            viscosity: p.av.is_some(),
            heating: p.heating,
            dust_density_each_step: p.laws.iter().any(|l| l.needs_dust_density()),
            continuity_density: p.density == DensityMethod::Continuity,
            variable_h: p.variable_h.is_some(),
            iad: p.gradient == GradientMethod::Iad,
            kdk: p.integrator == Integrator::Kdk,
            kernel_coupling: !p.laws.is_empty() && p.coupling == Coupling::Kernel,
            external: p.ext_gas.iter().chain(&p.ext_dust).any(|a| *a != 0.0),
        }
    }
}
