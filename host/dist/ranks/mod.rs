//! Stepping a scene over MPI ranks (docs/scaling.md). The particles are cut along the Morton
//! curve and migrated, and every rank steps an engine on its owned particles plus a halo, in
//! one of two forms:
//! - thin (a run's): ghosts within one reach (kernel support or IDIC cell, plus a margin for
//!   the particles' motion), refreshed from their owners between the step's neighbour passes
//!   ([`RankGhosts`](super::halo::RankGhosts), the engine's `GhostSync` hooks); the engine
//!   ([`Resident`](resident::Resident)) is kept across steps until the motion uses up the
//!   margin, a step that outran it is retaken;
//! - deep (`mpi-check --depth K`, and a step where a rank holds no gas): a halo K supports deep
//!   whose chain of passes is recomputed here, and a shell one support beyond held fixed at the
//!   owners' values, on an engine built for that step.
//!
//! The step size comes from the maxima over all ranks; each rank keeps its owned particles'
//! results.
mod balance;
mod deep;
mod devices;
mod layer;
mod output;
mod resident;

pub use self::balance::REBALANCE_AT;
use self::devices::{rank_device, RankDevice};
use self::resident::Resident;
use super::comm::{Comm, World};
use super::records::{records_where, state_of};
use crate::particles::State;
use crate::step::backend::{Backend, DeviceChoice};
use crate::step::timestep::{Plan, PlanError, StepPlanner};
use crate::step::{Forces, Physics};

/// Halo depth in kernel supports that a run over ranks needs for its step's chain of
/// neighbour passes to be exact on the owned particles (docs/scaling.md): the first-order step
/// 1 + max(1, c), the leapfrog 3 + max(1, c), where c is an IDIC cell's diagonal in supports
/// (a particle's drag reads its cell-mates' forces); with the kernel coupling (dust → gas
/// deposits, the solve on the gas, the return to the dust) 4 and 6. Measured on 3 ranks, as
/// the least depth exact to 1e-12 over 20 steps: the 1D wave (cells 0.5 h) 2; with cells of 4 h
/// 3; the Phantom slab (leapfrog, variable h, IAD) 4; with the kernel coupling the wave 3, the
/// settling column (IAD) 4, the Phantom slab 5.
pub fn depth_for(phys: &Physics) -> f64 {
    let kdk = phys.integrator == crate::scene::Integrator::Kdk;
    let chain = if kdk { 3.0 } else { 1.0 };
    if phys.coupling == crate::scene::Coupling::Kernel && !phys.laws.is_empty() {
        return chain + 3.0;
    }
    let cell = phys.cell_diagonal() / phys.support();
    chain + cell.max(1.0)
}

/// How a try at a step ended.
enum Tried {
    Done((Plan, f64, f64)),
    /// A rank holds no gas: this step takes the deep halo (the thin one's refresh needs an
    /// engine, hence gas, on every rank).
    NoGasOnARank,
    /// Particles moved (or h grew) beyond the thin halo's margin: again from the step's start,
    /// on a halo rebuilt with `margin` beyond the reach.
    Moved {
        margin: f64,
    },
}

/// The stages of a run over ranks beside the engine's (summary.json `stage_seconds`).
const STAGE_BUILD: &str = "ranks: halo built (cut, migration, halo, engine on the rank's share)";
const STAGE_MOTION: &str =
    "ranks: the motion since the halo reduced, the engine's particles copied to the host";
const STAGE_OUTPUT: &str =
    "ranks: an output's dust densities and stopping times, gathered on rank 0";
const STAGE_OWN_OUTPUT: &str =
    "ranks: an output's dust densities and stopping times, on each rank's own particles";

/// One rank's share of a scene stepped over the ranks.
pub struct RankStepper {
    pub world: World,
    phys: Physics,
    template: State,
    /// The rank's own particles (at the last build, output or retake; after a step on the
    /// resident engine they are its `local` state's, [`RankStepper::owned_stale`]).
    own: State,
    /// `own` is behind the resident engine's `local` state: read the own particles there
    /// (the host copy less its ghosts becomes `own` again at a build or a retake).
    owned_stale: bool,
    depth: f64,
    /// Where this rank steps: its own GPU (rank r on device r mod count), or the CPU.
    dev: RankDevice,
    /// Every rank's device, for the summary (gathered at the start).
    devices: Vec<String>,
    /// Whether the owned particles' densities are those of their layer (after a step here);
    /// the first step computes them, as one process does at its start or resume.
    layer_given: bool,
    /// The thin halo (one reach deep, refreshed between the step's passes) or the deep one.
    thin: bool,
    /// The thin halo's margin beyond the reach, for the step's motion (adapted each step).
    margin: f64,
    /// Steps taken again because the particles outran the margin.
    pub retakes: u64,
    /// Steps the thin halo handed to the deep one (a rank held no gas).
    deep_steps: u64,
    /// The largest halo over any rank and step, as a multiple of the rank's own particles.
    halo_ratio: f64,
    /// The thin halo's engine, kept across steps.
    resident: Option<Resident>,
    /// The stages' times of the engines dropped so far.
    timers: crate::step::timers::Timers,
    /// Thin halos built (each a migration and an engine built on the rank's particles), and
    /// steps taken.
    builds: u64,
    steps: u64,
    /// `DUSTSPH_FAIL_IN_STEP`: refreshes of this step before one fails (negative: none).
    fail: std::sync::Arc<std::sync::atomic::AtomicI64>,
    /// `DUSTSPH_HALO_TRACE` is set: rank 0 prints each step's halo test to stderr.
    trace: bool,
    /// The kernel coupling's normalisers of the layer the last step ended on, by particle key,
    /// from the engine dropped for a rebuilt halo: the next engine, on the same layer, takes
    /// them instead of computing them again (a disc rebuilds its halo about every step).
    carried_norms: Option<std::collections::HashMap<(u64, u64), f64>>,
    /// This rank's seconds of work in the steps since the ranks' balance was last judged (its
    /// steps' time less its time in MPI, where it waits for the others), and those steps.
    busy: f64,
    busy_steps: u64,
    /// This rank's measured cost per particle over the ranks' mean, which the cuts share out
    /// once the ranks' work differed by more than `rebalance_at` (`None`: equal counts).
    cost: Option<f64>,
    rebalance_at: f64,
    /// Thin halos built on a cut by the measured cost.
    rebalances: u64,
}

impl Drop for RankStepper {
    /// The resident engine's ghost refresh holds a duplicate of the communicator: freed before
    /// the world finalises MPI (fields drop in declaration order, the world first).
    fn drop(&mut self) {
        self.resident = None;
    }
}

impl RankStepper {
    /// This rank's share of `full`, until the first step's cut moves the particles to their
    /// owners: `full` itself where it is already this rank's share (`shared`: a file read by
    /// share), else, of the scene's whole state built alike on every rank, the particles of
    /// id + phase ≡ rank (mod R). `full` is left without particles.
    /// Each rank steps on the device `device` resolves to for it ([`rank_device`]); a rank
    /// that cannot stops every rank (collective), before anything is written.
    pub fn new(
        world: World,
        phys: Physics,
        full: &mut State,
        shared: bool,
        depth: f64,
        device: DeviceChoice,
        verbose: bool,
    ) -> Result<RankStepper, String> {
        let me = world.rank();
        // The shape of the state (phases, energy, fixed particles), without its particles.
        let template = full.shape();
        // `full` is left without particles: a share read from a file is this rank's as it
        // is; of a whole scene each rank keeps the particles of its keys (by key, not
        // position: the set-up's order is the same on every rank).
        let share = if shared {
            std::mem::replace(full, template.clone())
        } else {
            let keep = crate::setup::Keep::of(&world);
            let mine = records_where(full, |_, (phase, id)| keep.mine(phase, id));
            *full = template.clone();
            state_of(&mine, &template)
        };
        let chosen = rank_device(device, me, &phys, &share);
        if world.any(chosen.is_err()) {
            return Err(chosen.err().unwrap_or_else(|| {
                "another rank cannot use the device asked for (its message above)".into()
            }));
        }
        let (dev, note) = chosen?;
        // The same note on every rank (no GPU here at all) is said once, by rank 0.
        if let (Some(n), true) = (note, verbose) {
            if me == 0 || n.starts_with("rank ") {
                eprintln!("dustsph: {n}");
            }
        }
        let mine = match &dev {
            RankDevice::Cpu => format!(
                "cpu ({})",
                crate::launch::threads(rayon::current_num_threads())
            ),
            RankDevice::Cuda(d) => format!("cuda: {}", crate::launch::Launcher::describe(d)),
        };
        let devices = world
            .all_gather_bytes(mine.as_bytes())
            .into_iter()
            .map(|b| String::from_utf8_lossy(&b).into_owned())
            .collect();
        // The thin halo, unless a step finds a rank without gas (`Tried::NoGasOnARank`) or
        // `use_deep_halo` asks for the deep one.
        let (thin, margin) = (true, 0.5 * phys.support());
        Ok(RankStepper {
            world,
            phys,
            template,
            own: share,
            owned_stale: false,
            depth,
            dev,
            devices,
            layer_given: false,
            thin,
            margin,
            retakes: 0,
            deep_steps: 0,
            halo_ratio: 0.0,
            resident: None,
            timers: Default::default(),
            builds: 0,
            steps: 0,
            fail: std::sync::Arc::new(std::sync::atomic::AtomicI64::new(-1)),
            trace: crate::env::check("DUSTSPH_HALO_TRACE"),
            carried_norms: None,
            busy: 0.0,
            busy_steps: 0,
            cost: None,
            rebalance_at: REBALANCE_AT,
            rebalances: 0,
        })
    }

    /// Build the resident engine now (a run's set-up, before its clock starts, as one process
    /// builds its engine): collective. A rank without gas leaves it to the first step.
    pub fn prepare(&mut self, step: u64) -> Result<(), String> {
        if self.thin && self.resident.is_none() {
            self.resident = self.build_resident(step)?;
        }
        Ok(())
    }

    /// The first step's forces and size toward `t_target` over every rank, nothing advanced
    /// (a run's start; the first step computes the same forces again): the forces' maxima over
    /// the ranks, or why the step cannot be taken (the same on every rank: collective). Rank 0's
    /// own particles and halo come with it, for the start's warnings.
    pub fn plan_first(
        &mut self,
        drv: &StepPlanner,
        t: f64,
        step: u64,
        t_target: f64,
    ) -> Result<(Option<Forces>, Option<&State>), String> {
        self.prepare(step)?;
        let Some(res) = self.resident.as_mut() else {
            // A rank holds no gas: its first step takes the deep halo and plans there.
            return Ok((None, None));
        };
        let (_, global, drag) =
            Self::global_limits(&self.world, &self.phys, Some(&mut res.eng), true, step)?;
        match drv.plan(&global, drag, t, step, t_target) {
            Ok(_) => Ok((Some(global), Some(&res.local))),
            Err(PlanError::NoLimit(m)) => Err(m),
            // Every rank names its own culprits (where the step collapsed, they are one rank's).
            Err(PlanError::Collapsed(m)) => Err(match res.eng.dt_culprits() {
                Ok(c) => format!("{m}; on rank {}: {c}", self.world.rank()),
                Err(_) => m,
            }),
        }
    }

    /// Cut by the ranks' measured cost once their work per step differs from the mean by more
    /// than `at` (`numerics.rebalance_at`; [`REBALANCE_AT`] until set).
    pub fn rebalance_at(&mut self, at: f64) {
        self.rebalance_at = at;
    }

    /// Step with the deep halo (`depth` supports) even where the thin one would do.
    pub fn use_deep_halo(&mut self) {
        self.thin = false;
        self.drop_resident();
    }

    /// Drop the resident engine (its halo is rebuilt before the next step), keeping its
    /// stages' times and its own particles (as records).
    fn drop_resident(&mut self) {
        if let Some(r) = self.resident.take() {
            for &(name, s) in r.eng.timers().entries() {
                self.timers.add(name, s);
            }
            // The host copy less its ghosts, in place, is the rank's own particles.
            drop(r.eng);
            if self.owned_stale {
                let mut own = r.local;
                let keep: Vec<bool> = r.flags.iter().map(|&g| !g).collect();
                own.retain_rows(&keep);
                self.own = own;
                self.owned_stale = false;
            }
        }
    }

    /// The run's physics.
    pub fn phys(&self) -> &Physics {
        &self.phys
    }

    /// The stages' times of this rank's engines so far.
    pub fn timers(&self) -> crate::step::timers::Timers {
        let mut t = self.timers.clone();
        if let Some(r) = &self.resident {
            for &(name, s) in r.eng.timers().entries() {
                t.add(name, s);
            }
        }
        t
    }

    /// The ball's Lagrange–Jacobi terms of every rank's own particles, summed (collective).
    pub fn lagrange_jacobi_terms(&self, dim: u32) -> (f64, f64) {
        use crate::analysis::ball::lagrange_jacobi_terms_where as terms;
        let (i, rhs) = match (&self.resident, self.owned_stale) {
            (Some(r), true) => terms(&r.local, dim, |n| !r.flags[n]),
            _ => terms(&self.own, dim, |_| true),
        };
        let s = sum_over(&self.world, LagrangeJacobi { i, rhs });
        (s.i, s.rhs)
    }

    /// Rank 0 writes the output.
    pub fn is_root(&self) -> bool {
        self.world.rank() == 0
    }

    /// Whether any rank says so (collective).
    pub fn any(&self, flag: bool) -> bool {
        self.world.any(flag)
    }

    /// "R MPI ranks", for the summary.
    pub fn describe(&self) -> String {
        let on = if self.devices.iter().all(|d| *d == self.devices[0]) {
            format!("each stepping on {}", self.devices[0])
        } else {
            let each: Vec<String> = (self.devices.iter().enumerate())
                .map(|(r, d)| format!("rank {r} on {d}"))
                .collect();
            format!("stepping {}", each.join("; "))
        };
        let depth = format!("{:.2}", self.depth);
        let halo = if self.thin {
            format!(
                "a thin halo refreshed between the step's passes, at most {:.2} × a rank's own \
                 particles, built {} times in {} steps{}",
                self.halo_ratio,
                self.builds,
                self.steps,
                match self.rebalances {
                    0 => String::new(),
                    n => format!(", {n} of them on a cut by the ranks' measured cost"),
                }
            )
        } else {
            format!(
                "a halo {} supports deep",
                depth.trim_end_matches('0').trim_end_matches('.')
            )
        };
        let mut retaken = match self.retakes {
            0 => String::new(),
            n => format!(", {n} steps retaken with a wider margin"),
        };
        if self.thin && self.deep_steps > 0 {
            retaken += &format!(
                ", {} steps on a halo {} supports deep (a rank held no gas)",
                self.deep_steps,
                depth.trim_end_matches('0').trim_end_matches('.')
            );
        }
        format!("{} MPI ranks ({halo}{retaken}), {on}", self.world.size())
    }

    /// One step from time `t` (step count `step`) toward `t_target` on every rank: the plan
    /// taken (the same on every rank: the one process's) and the new time. With the thin halo
    /// a step whose particles moved (or whose h grew) further than the halo's margin allows is
    /// taken again, from its start, on a halo rebuilt with a wider margin.
    pub fn step(
        &mut self,
        drv: &StepPlanner,
        t: f64,
        step: u64,
        t_target: f64,
    ) -> Result<(Plan, f64, f64), String> {
        let mut thin = self.thin;
        loop {
            let tried = if thin {
                self.step_resident(drv, t, step, t_target)?
            } else {
                self.step_deep(drv, t, step, t_target)?
            };
            match tried {
                Tried::Done(r) => {
                    self.steps += 1;
                    return Ok(r);
                }
                Tried::NoGasOnARank => {
                    thin = false;
                    self.deep_steps += 1;
                }
                Tried::Moved { margin } => {
                    self.margin = margin;
                    self.retakes += 1;
                }
            }
        }
    }

    /// The forces of this rank's engine, and the step's limits over all ranks: the forces'
    /// maxima, and the explicit drag's least limit (+∞ for IDIC) over each rank's cells that
    /// hold a particle of its own (a cell of ghosts only may lack members beyond the halo).
    /// Collective.
    fn global_limits(
        world: &World,
        phys: &Physics,
        eng: Option<&mut Backend>,
        thin: bool,
        step: u64,
    ) -> Result<(Option<Forces>, Forces, f64), String> {
        let me = world.rank();
        let mut err = String::new();
        let mut forces = None;
        let mut eng = eng;
        if let Some(e) = eng.as_mut() {
            match e.forces() {
                Ok(f) => forces = Some(f),
                Err(x) if thin => abort_job(world, step, &x),
                Err(x) => err = x.to_string(),
            }
        }
        if world.any(!err.is_empty()) {
            return Err(failure(world, step, me, &err));
        }
        let most = ForceMaxima {
            vsig_max: forces.as_ref().map_or(0.0, |f| f.vsig_max),
            acc_max: forces.as_ref().map_or(0.0, |f| f.acc_max),
            damp_rate_max: forces.as_ref().map_or(0.0, |f| f.damp_rate_max),
        };
        let most = max_over(world, most);
        let global = Forces {
            vsig_max: most.vsig_max,
            acc_max: most.acc_max,
            damp_rate_max: most.damp_rate_max,
        };
        let explicit = phys.drag == crate::scene::DragMethod::Explicit;
        if explicit && !thin {
            return Err(format!(
                "step {step}: the explicit drag baseline (drag.method = \"explicit\") steps \
                 over ranks with the thin halo only, and a rank holds no gas"
            ));
        }
        let mut drag = f64::INFINITY;
        if let (true, Some(e)) = (explicit, eng.as_mut()) {
            match e.timed_drag_limit() {
                Ok(d) => drag = d,
                Err(x) => err = x.to_string(),
            }
        }
        if world.any(!err.is_empty()) {
            return Err(failure(world, step, me, &err));
        }
        let drag = min_over(world, drag);
        Ok((forces, global, drag))
    }

    /// The momentum and its scale Σ m|v| of every rank's own particles, summed over the ranks
    /// (collective).
    pub fn momentum(&self) -> crate::step::Momentum {
        // Accretion is refused over ranks, so no particle is counted inside a radius here.
        let c = self.phys.gravity.pos;
        let mut s = MomentumSums {
            p: [0.0; 3],
            scale: 0.0,
            l: [0.0; 3],
        };
        let mut add = |m: f64, x: [f64; 3], v: [f64; 3]| {
            let x = dustsph_device::sub(x, c);
            for (sk, vk) in s.p.iter_mut().zip(v) {
                *sk += m * vk;
            }
            s.scale += m * dustsph_device::dot(v, v).sqrt();
            for (sk, lk) in s.l.iter_mut().zip(dustsph_device::cross(x, v)) {
                *sk += m * lk;
            }
        };
        let (st, flags) = match (&self.resident, self.owned_stale) {
            (Some(r), true) => (&r.local, Some(&r.flags)),
            _ => (&self.own, None),
        };
        let phases = std::iter::once(&st.gas.ph).chain(&st.dust);
        let each = phases.flat_map(|ph| (0..ph.len()).map(move |i| (ph, i)));
        for (n, (ph, i)) in each.enumerate() {
            if !flags.is_some_and(|f| f[n]) {
                add(ph.m[i], ph.x[i], ph.v[i]);
            }
        }
        let s = sum_over(&self.world, s);
        crate::step::Momentum {
            p: s.p,
            scale: s.scale,
            l: s.l,
            inside: 0,
        }
    }
}

/// `v` (a `#[repr(C)]` struct of f64 fields, or one f64) reduced over the ranks element-wise
/// as one buffer, in the order of its fields: the maximum of each (collective).
fn max_over<T: bytemuck::Pod>(world: &World, mut v: T) -> T {
    world.max_f64(bytemuck::cast_slice_mut(std::slice::from_mut(&mut v)));
    v
}

/// [`max_over`]'s minimum.
fn min_over<T: bytemuck::Pod>(world: &World, mut v: T) -> T {
    world.min_f64(bytemuck::cast_slice_mut(std::slice::from_mut(&mut v)));
    v
}

/// [`max_over`]'s sum.
fn sum_over<T: bytemuck::Pod>(world: &World, mut v: T) -> T {
    world.sum_f64(bytemuck::cast_slice_mut(std::slice::from_mut(&mut v)));
    v
}

/// The ball's Lagrange–Jacobi terms ([`RankStepper::lagrange_jacobi_terms`]), summed over the
/// ranks.
#[repr(C)]
#[derive(Clone, Copy)]
struct LagrangeJacobi {
    i: f64,
    rhs: f64,
}

/// The forces' maxima ([`RankStepper::global_limits`]), reduced over the ranks.
#[repr(C)]
#[derive(Clone, Copy)]
struct ForceMaxima {
    vsig_max: f64,
    acc_max: f64,
    damp_rate_max: f64,
}

/// The momentum, its scale Σ m|v| and the angular momentum ([`RankStepper::momentum`]),
/// summed over the ranks.
#[repr(C)]
#[derive(Clone, Copy)]
struct MomentumSums {
    p: [f64; 3],
    scale: f64,
    l: [f64; 3],
}

// SAFETY: `repr(C)` of f64 fields only (no padding), and every bit pattern is a valid f64.
unsafe impl bytemuck::Zeroable for LagrangeJacobi {}
unsafe impl bytemuck::Pod for LagrangeJacobi {}
unsafe impl bytemuck::Zeroable for ForceMaxima {}
unsafe impl bytemuck::Pod for ForceMaxima {}
unsafe impl bytemuck::Zeroable for MomentumSums {}
unsafe impl bytemuck::Pod for MomentumSums {}

/// The step the planner's rule gives from the maxima over all ranks (`limits`: the forces',
/// the explicit drag's), taken on this rank's engine (its host state `local` not synced: it
/// keeps the step's start until the caller syncs it).
fn take_planned(
    e: &mut Backend,
    local: &mut State,
    drv: &StepPlanner,
    limits: (&Forces, f64),
    (t, step, t_target): (f64, u64, f64),
) -> Result<Plan, crate::step::StepError> {
    let p = match drv.plan(limits.0, limits.1, t, step, t_target) {
        Ok(p) => p,
        Err(PlanError::NoLimit(m)) => return Err(crate::step::StepError::Blowup(m)),
        Err(PlanError::Collapsed(m)) => {
            let why = format!("{m}; {}", e.dt_culprits()?);
            return Err(crate::step::StepError::Blowup(why));
        }
    };
    e.take(local, &p)?;
    Ok(p)
}

/// Stop the whole job on a failure inside a step with a thin halo, its message first: the
/// other ranks wait in a refresh this rank will not reach.
fn abort_job(world: &World, step: u64, x: &dyn std::fmt::Display) -> ! {
    eprintln!(
        "error: {}",
        failure(world, step, world.rank(), &x.to_string())
    );
    world.abort(1)
}

/// A step's failure, with the rank that saw it (every rank reports its own; all stop).
fn failure(_world: &World, step: u64, me: u32, err: &str) -> String {
    if err.is_empty() {
        format!("step {step}: another rank failed (its message above)")
    } else {
        format!("step {step}: rank {me}: {err}")
    }
}
