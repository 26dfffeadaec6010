//! Stepping a scene over MPI ranks (docs/scaling.md). The particles are cut along the Morton
//! curve and migrated, and every rank steps an engine on its owned particles plus a halo, in
//! one of two forms:
//! - thin (a run's): ghosts within one reach (kernel support or IDIC cell, plus a margin for
//!   the particles' motion), refreshed from their owners between the step's neighbour passes
//!   ([`RankGhosts`], the engine's `GhostSync` hooks); the engine ([`Resident`]) is kept across
//!   steps until the motion uses up the margin, a step that outran it is retaken;
//! - deep (`mpi-check --depth K`, and a step where a rank holds no gas): a halo K supports deep
//!   whose chain of passes is recomputed here, and a shell one support beyond held fixed at the
//!   owners' values, on an engine built for that step.
//!
//! The step size comes from the maxima over all ranks; each rank keeps its owned particles'
//! results.
use super::comm::{Comm, World};
use super::halo::{cut, fail_requested, halo_sends, shell, RankGhosts};
use super::motion::MotionCells;
use super::records::{
    append_records, record_at, records_where, state_from, state_of, ParticleRecord,
};
use crate::particles::{KeySet, State};
use crate::step::backend::{Backend, DeviceChoice};
use crate::step::engine::InitialLayer;
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

/// A rank's halo for one step ([`RankStepper::local_layer`]), beside its own particles (the
/// stepper's, migrated by the step's cut).
struct LocalLayer {
    /// Per rank, the keys of the own particles sent to it as halo candidates.
    to: Vec<Vec<(u64, u64)>>,
    /// Per rank, which of the candidates it sent here are kept ([`shell`]).
    replies: Vec<Vec<u8>>,
    /// The halo's particles.
    halo: Vec<ParticleRecord>,
    ghost_keys: KeySet,
    support: f64,
    /// The reach of one neighbour pass: the support or an IDIC cell's diagonal.
    near: f64,
    /// How far the halo reaches.
    reach: f64,
    /// The cut's cells.
    cbox: crate::decomp::CellBox,
}

/// The thin halo's least margin beyond the support, in supports.
const MIN_MARGIN: f64 = 0.1;

/// The largest margin of a thin halo, in supports.
const MAX_MARGIN: f64 = 4.0;

/// How many times a run's first layer is computed again on a wider halo before the run stops
/// ([`RankStepper::build_resident`]).
const MAX_LAYER_TRIES: usize = 8;

/// A ghost's cost per step relative to an owned particle's, for the choice of the margin
/// ([`RankStepper::margin_for`]): it takes no h, density or force pass, only the cell sums,
/// the kick, the drift, the sort and its refreshes. (0.2 built fewer, larger halos: the ball
/// 5 in 40 steps instead of 7, the box's halo 0.93–0.99 of a rank's own instead of 0.44–0.83,
/// 50 MB more per rank, and no faster within the runs' spread, docs/scaling.md.)
const GHOST_COST: f64 = 0.5;

/// The ranks' work per step may exceed its mean by this much before the next cut shares out
/// their measured cost per particle instead ([`RankStepper::judge_balance`]);
/// `DUSTSPH_REBALANCE_AT` sets another (0: at every judgement; `inf`: never).
const REBALANCE_AT: f64 = 0.05;

/// Steps of work measured before the ranks' balance is judged (the cuts between keep the last
/// cost): fewer are dominated by this machine's noise.
const REBALANCE_STEPS: u64 = 4;

/// The stages of a run over ranks beside the engine's (summary.json `stage_seconds`).
const STAGE_BUILD: &str = "ranks: halo built (cut, migration, halo, engine on the rank's share)";
const STAGE_MOTION: &str =
    "ranks: the motion since the halo reduced, the engine's particles copied to the host";
const STAGE_OUTPUT: &str =
    "ranks: an output's dust densities and stopping times, gathered on rank 0";
const STAGE_OWN_OUTPUT: &str =
    "ranks: an output's dust densities and stopping times, on each rank's own particles";

/// A rank's engine kept across steps on its owned particles and thin halo, until the motion
/// since the halo was built uses up its margin (docs/scaling.md, "A resident engine").
struct Resident {
    eng: Backend,
    /// The engine's host copy, synced after each step that holds (a retaken step leaves it
    /// at the step's start), and its ghost flags then: where the rank's own particles are read
    /// from until the next output or build ([`RankStepper::owned_stale`]).
    local: State,
    flags: Vec<bool>,
    support: f64,
    near: f64,
    reach: f64,
    /// The largest displacement of any rank's owned particle from its anchor (after the last
    /// step), and the steps taken on this halo.
    moved: f64,
    steps: u64,
    /// The largest halo over the ranks as a multiple of a rank's own particles, the build's
    /// time, and a step's (the slowest rank's; the mean over the halo's steps).
    ratio: f64,
    build_seconds: f64,
    step_seconds: f64,
    /// The cells the motion test compares pair by pair.
    cells: MotionCells,
}

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

/// The launcher a rank steps on, kept across its steps (a GPU's kernels are loaded once).
enum RankDevice {
    Cpu,
    Cuda(crate::launch::Cuda),
}

impl RankDevice {
    /// The engine on this device for the rank's local state of one step.
    fn engine(
        &self,
        phys: Physics,
        state: &mut State,
        layer: InitialLayer,
    ) -> Result<Backend, crate::step::StepError> {
        match self {
            RankDevice::Cpu => Backend::on_cpu_at(phys, state, layer),
            RankDevice::Cuda(d) => Backend::on_cuda_at(d.clone(), phys, state, layer),
        }
    }
}

/// Rank `me`'s device for `asked` (`--device`): with a GPU, device `me` mod the count this
/// process sees, tried on the rank's share before anything is written; `auto` falls back to
/// the CPU (with a note) where that fails, `cuda` stops. `Err` is the rank's message.
fn rank_device(
    asked: DeviceChoice,
    me: u32,
    phys: &Physics,
    share: &State,
) -> Result<(RankDevice, Option<String>), String> {
    use crate::launch::Cuda;
    let (device, note) = crate::step::backend::select(asked)?;
    if device != DeviceChoice::Cuda {
        return Ok((RankDevice::Cpu, note));
    }
    let tried = crate::launch::cuda::device_count()
        .and_then(|n| {
            let ordinal = me as usize % n.max(1);
            Cuda::new(ordinal, crate::launch::PTX)
                .map_err(|e| format!("CUDA device {ordinal}: {e}"))
        })
        .and_then(|d| {
            if share.gas.ph.x.is_empty() && share.dust.iter().all(|p| p.x.is_empty()) {
                return Ok(d);
            }
            // Tried on a copy: the share stays as set up (an engine sorts and lays out its
            // state).
            Backend::on_cuda(d.clone(), phys.clone(), &mut share.clone())
                .map(|_| d)
                .map_err(|e| e.to_string())
        });
    match (tried, asked) {
        (Ok(d), _) => Ok((RankDevice::Cuda(d), None)),
        (Err(e), DeviceChoice::Auto) => Ok((
            RankDevice::Cpu,
            Some(format!("rank {me}: no GPU used ({e}); stepping on the CPU")),
        )),
        (Err(e), _) => Err(format!("--device cuda on rank {me}: {e}")),
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
        let rebalance_at = match crate::env::var("DUSTSPH_REBALANCE_AT") {
            None => REBALANCE_AT,
            Some(v) => match v.trim().parse::<f64>() {
                Ok(x) if x >= 0.0 => x,
                _ => {
                    return Err(format!(
                        "DUSTSPH_REBALANCE_AT = {v:?}: expected a number ≥ 0 (or inf)"
                    ))
                }
            },
        };
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
            rebalance_at,
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
        let mut s = [i, rhs];
        self.world.sum_f64(&mut s);
        (s[0], s[1])
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

    /// The thin halo's margin beyond the reach for the next build, from what this one cost
    /// (docs/scaling.md, "A resident engine"): a wider margin holds a halo for more steps
    /// (m / 2d steps at motion d per step) but makes it larger (in proportion to its reach).
    /// Per step, a halo costs [`GHOST_COST`] × its ratio to the owned particles, and a build
    /// B steps' time spread over the steps it holds: G r(m) + 2dB/m is least at
    /// m = √(2dB (near + m₀) / (G r₀)), r₀ and m₀ this halo's ratio and margin. At least three
    /// steps' motion and [`MIN_MARGIN`], at most [`MAX_MARGIN`] supports.
    fn margin_for(d: f64, res: &Resident) -> f64 {
        let s = res.support;
        let least = (3.0 * d).max(MIN_MARGIN * s);
        let b = res.build_seconds / res.step_seconds.max(1e-12);
        let m0 = res.reach - res.near;
        let best = if res.ratio > 0.0 {
            (2.0 * d * b * (res.near + m0) / (GHOST_COST * res.ratio)).sqrt()
        } else {
            MAX_MARGIN * s
        };
        best.min(MAX_MARGIN * s).max(least)
    }

    /// This rank's resident engine on its owned particles and a thin halo, `margin` beyond the
    /// reach (collective; `None` when a rank holds no gas). Where its engine computes the first
    /// layer (a run's start, a resume), the layer holds only if every own particle's support
    /// at the h it solved lies within the halo: the halo's reach comes from the h the particles
    /// carry (the reference h at a start), and a disc's tapered edge solves h several times
    /// that, short of the neighbours beyond the halo. Where it does not, the layer is computed
    /// again, from the particles as they were given, on a halo that reaches the solved h.
    fn build_resident(&mut self, step: u64) -> Result<Option<Resident>, String> {
        if self.layer_given {
            return self.build_resident_once(step);
        }
        let given = self.own.clone();
        let motion = self.margin;
        for _ in 0..MAX_LAYER_TRIES {
            let Some(res) = self.build_resident_once(step)? else {
                return Ok(None);
            };
            let m = (res.eng.owned_motion(&mut |_, _, _| {}))
                .unwrap_or_else(|x| abort_job(&self.world, step, &x))
                .expect("a resident engine has its ghosts");
            let mut h_max = [m.h_max];
            self.world.max_f64(&mut h_max);
            let need = crate::step::SUPPORT * h_max[0];
            if need <= res.reach {
                // Exact: a retake of the first step starts from this layer, as one process's
                // first step does.
                self.layer_given = true;
                return Ok(Some(res));
            }
            // A reach that covers the solved h, and beyond it the margin kept for the motion.
            self.margin = need - res.near + motion;
            drop(res);
            self.own = given.clone();
            self.owned_stale = false;
        }
        Err(format!(
            "step {step}: the first layer's h grew beyond the halo {MAX_LAYER_TRIES} times \
             over; its particles' h keeps outgrowing their neighbourhood"
        ))
    }

    /// [`RankStepper::build_resident`] on the halo of the current margin: the cut, the
    /// migration, the halo, the engine and its ghosts' refresh.
    fn build_resident_once(&mut self, step: u64) -> Result<Option<Resident>, String> {
        let t0 = std::time::Instant::now();
        let Some(lay) = self.local_layer(true)? else {
            return Ok(None);
        };
        let world = &self.world;
        let me = world.rank();
        let (support, near, reach) = (lay.support, lay.near, lay.reach);
        let LocalLayer {
            to: keys,
            replies,
            halo,
            ghost_keys,
            cbox,
            ..
        } = lay;
        let per_reach = super::motion::cells_per_reach(self.phys.dim);
        let shape = (self.phys.dim, per_reach);
        let cells = MotionCells::new(world, &cbox, reach, shape, positions(&self.own));
        let arriving: Vec<(u64, u64)> = halo.iter().map(ParticleRecord::key).collect();
        let owned = self.own.len();
        let mut ratio = [halo.len() as f64 / owned.max(1) as f64];
        world.max_f64(&mut ratio);
        self.halo_ratio = self.halo_ratio.max(ratio[0]);
        // The rank's own particles and the halo after them, then the engine's host copy
        // (below): the own particles are read there until a build, an output or a retake.
        let mut local = std::mem::take(&mut self.own);
        let counts = phase_counts(&halo, 1 + local.dust.len());
        append_records(&mut local, halo.into_iter(), &counts);
        let layer = if self.layer_given {
            InitialLayer::FromState
        } else {
            InitialLayer::Compute
        };
        let built = self.dev.engine(self.phys.clone(), &mut local, layer);
        let err = built.as_ref().err().map(|x| x.to_string());
        if world.any(err.is_some()) {
            return Err(failure(world, step, me, &err.unwrap_or_default()));
        }
        let mut eng = built.map_err(|x| x.to_string())?;
        let sync = RankGhosts::new(
            world.duplicate(),
            keys,
            replies,
            arriving,
            self.fail.clone(),
        )?;
        // Built from the records (no layer computed), its ghosts hold their owners' values.
        let fresh = matches!(layer, InitialLayer::FromState);
        if let Err(x) = eng.set_ghosts(Box::new(sync), ghost_keys, fresh) {
            abort_job(world, step, &x);
        }
        // The engine's host copy, in its order beside its ghost flags.
        if let Err(x) = eng.sync(&mut local) {
            abort_job(world, step, &x);
        }
        // The layer's normalisers from the engine this one replaces (the same positions).
        if let Some(norms) = self.carried_norms.take() {
            let mut given = [Vec::new(), Vec::new()];
            let phases = std::iter::once(&local.gas.ph).chain(&local.dust);
            for (k, ph) in phases.enumerate() {
                let at = |i: usize| norms.get(&(k as u64, ph.id[i])).copied();
                given[(k > 0) as usize].extend((0..ph.len()).map(|i| at(i).unwrap_or(f64::NAN)));
            }
            if let Err(x) = eng.keep_norms(given).and_then(|()| eng.norms_now()) {
                abort_job(world, step, &x);
            }
        }
        let flags = ghost_flags(&eng);
        self.owned_stale = true;
        self.builds += 1;
        let mut seconds = [t0.elapsed().as_secs_f64()];
        world.max_f64(&mut seconds);
        Ok(Some(Resident {
            eng,
            local,
            flags,
            support,
            near,
            reach,
            moved: 0.0,
            steps: 0,
            ratio: ratio[0],
            build_seconds: seconds[0],
            step_seconds: 0.0,
            cells,
        }))
    }

    /// A step on the thin halo: on the resident engine (built first where there is none), its
    /// ghosts refreshed between the passes. Afterwards the motion since the halo was built is
    /// reduced over the ranks: where two particles could have closed in from beyond the halo
    /// to within a reach, the step is taken again on a rebuilt halo; where the next step could,
    /// the halo is rebuilt before it.
    fn step_resident(
        &mut self,
        drv: &StepPlanner,
        t: f64,
        step: u64,
        t_target: f64,
    ) -> Result<Tried, String> {
        use std::sync::atomic::Ordering;
        self.fail.store(-1, Ordering::Relaxed);
        if self.resident.is_none() {
            let t0 = std::time::Instant::now();
            let built = self.build_resident(step)?;
            self.timers.add(STAGE_BUILD, t0.elapsed().as_secs_f64());
            match built {
                Some(r) => self.resident = Some(r),
                None => return Ok(Tried::NoGasOnARank),
            }
        }
        let world = &self.world;
        let me = world.rank();
        if fail_requested(me, step) {
            self.fail.store(0, Ordering::Relaxed);
        }
        let res = self.resident.as_mut().expect("built above");
        res.local.t = t;
        res.local.step = step;
        let blocked = super::comm::traffic().blocked_seconds();
        let t_step = std::time::Instant::now();
        let (_, global, drag) =
            Self::global_limits(world, &self.phys, Some(&mut res.eng), true, step)?;
        let (e, local) = (&mut res.eng, &mut res.local);
        let r = take_planned(e, local, drv, (&global, drag), (t, step, t_target));
        let plan = r.unwrap_or_else(|x| abort_job(world, step, &x));
        let stepped = t_step.elapsed().as_secs_f64();
        let busy = stepped - (super::comm::traffic().blocked_seconds() - blocked);
        let t0 = std::time::Instant::now();
        let t_new = local.t;
        // The motion since the halo was built, and the largest h, over every rank; each own
        // particle's displacement binned by its cell at the build, in the same pass (on a GPU
        // rank the positions cross to the host once).
        let cells = &mut res.cells;
        cells.clear();
        let m = (e.owned_motion(&mut |k, x, d| cells.add(k, x, d)))
            .unwrap_or_else(|x| abort_job(world, step, &x))
            .expect("a resident engine has its ghosts");
        let (lo, hi) = (m.lo, m.hi);
        let mut worst = [
            m.largest, m.h_max, stepped, hi[0], hi[1], hi[2], -lo[0], -lo[1], -lo[2],
        ];
        world.max_f64(&mut worst);
        let lo = [-worst[6], -worst[7], -worst[8]];
        let spread = relative_motion(worst[0], lo, [worst[3], worst[4], worst[5]]);
        let near = (crate::step::SUPPORT * worst[1]).max(res.near);
        // Where the global bound, growing as it has, would hold the halo another step, it
        // serves; otherwise the pairs of cells of two ranks close enough to meet give twice
        // the motion that matters, and the phases' own reach where they meet
        // ([`MotionCells::bound`]).
        let next = 2.0 * spread * (res.steps + 2) as f64 / (res.steps + 1) as f64;
        let moved = if near + next <= res.reach {
            spread
        } else {
            let cross = match self.phys.coupling {
                crate::scene::Coupling::Kernel => near,
                crate::scene::Coupling::Cell => self.phys.cell_diagonal().min(near),
            };
            0.5 * res.cells.bound(world, res.reach, near, cross, 2.0 * spread)
        };
        let need = near + 2.0 * moved;
        if me == 0 && self.trace {
            eprintln!(
                "halo: step {step}: reach {:.4e}, near {near:.4e}, global bound {:.4e}, \
                 used {:.4e}",
                res.reach,
                2.0 * spread,
                2.0 * moved
            );
        }
        // This step's motion (a cumulative largest displacement does not add up exactly; this
        // estimate only sets when the halo is rebuilt, the test above keeps it exact).
        let d = (moved - res.moved).max(moved / (res.steps + 1) as f64);
        res.step_seconds += (worst[2] - res.step_seconds) / (res.steps + 1) as f64;
        let margin = Self::margin_for(d, res) + (need - 2.0 * moved - res.near);
        if need > res.reach {
            // Taken again from its start: `local` still holds it (synced after the last step).
            self.drop_resident();
            return Ok(Tried::Moved { margin });
        }
        (res.eng.sync(&mut res.local)).unwrap_or_else(|x| abort_job(world, step, &x));
        res.flags = ghost_flags(&res.eng);
        self.owned_stale = true;
        res.moved = moved;
        res.steps += 1;
        self.timers.add(STAGE_MOTION, t0.elapsed().as_secs_f64());
        // Rebuild before the next step where its motion could use up the margin, or where the
        // ranks' work has grown uneven enough to pay for a new cut.
        let outrun = need + 2.0 * d > res.reach;
        let horizon = res.steps.max(REBALANCE_STEPS) as f64;
        let build_seconds = res.build_seconds;
        self.busy += busy;
        self.busy_steps += 1;
        let rebalance = self.busy_steps >= REBALANCE_STEPS
            && self.judge_balance(horizon, build_seconds)
            && !outrun;
        if outrun || rebalance {
            let world = &self.world;
            let res = self.resident.as_mut().expect("stepped on it");
            let norms = (res.eng.layer_norms()).unwrap_or_else(|x| abort_job(world, step, &x));
            self.carried_norms = norms.map(|n| by_key(&res.local, &n));
            self.drop_resident();
            self.margin = margin;
        }
        self.layer_given = true;
        Ok(Tried::Done((plan, t_new, global.vsig_max)))
    }

    /// A step on the deep halo: an engine built on the rank's particles and a halo deep enough
    /// for the step's chain of passes (no refresh), dropped after the step.
    fn step_deep(
        &mut self,
        drv: &StepPlanner,
        t: f64,
        step: u64,
        t_target: f64,
    ) -> Result<Tried, String> {
        self.drop_resident();
        self.carried_norms = None;
        let Some(lay) = self.local_layer(false)? else {
            unreachable!("the deep halo serves a rank without gas");
        };
        let world = &self.world;
        let me = world.rank();
        // The rank's own particles, and the halo after them.
        let mine: KeySet = keys_of(&self.own).collect();
        let mut local = std::mem::take(&mut self.own);
        let counts = phase_counts(&lay.halo, 1 + local.dust.len());
        append_records(&mut local, lay.halo.into_iter(), &counts);
        local.t = t;
        local.step = step;
        // Forces on every rank, the step size from the maxima over all ranks, the advance.
        let mut err = String::new();
        let mut eng = None;
        if !local.is_empty() {
            let layer = if self.layer_given {
                InitialLayer::FromState
            } else {
                InitialLayer::Compute
            };
            match self.dev.engine(self.phys.clone(), &mut local, layer) {
                Ok(e) => eng = Some(e),
                Err(x) => err = x.to_string(),
            }
        }
        if world.any(!err.is_empty()) {
            return Err(failure(world, step, me, &err));
        }
        let (forces, global, drag) =
            Self::global_limits(world, &self.phys, eng.as_mut(), false, step)?;
        let mut plan = None;
        if let (Some(e), Some(_)) = (&mut eng, forces) {
            let r = take_planned(e, &mut local, drv, (&global, drag), (t, step, t_target));
            match r.and_then(|p| e.sync(&mut local).map(|_| p)) {
                Ok(p) => plan = Some(p),
                Err(x) => err = x.to_string(),
            }
        }
        drop(eng);
        // The own particles stepped, in place (the halo's, and its shell's flags, dropped).
        let keep: Vec<bool> = keys_of(&local).map(|k| mine.contains(&k)).collect();
        local.retain_rows(&keep);
        drop_unused_fixed(&mut local, &self.template);
        if world.any(!err.is_empty()) {
            return Err(failure(world, step, me, &err));
        }
        // Every rank took the same step (a rank without particles learns it from the others).
        let mut tt = [if plan.is_some() {
            local.t
        } else {
            f64::NEG_INFINITY
        }];
        world.max_f64(&mut tt);
        // A rank without particles rebuilds the step from the new time (the others' plan).
        let plan = plan.unwrap_or(Plan {
            dt: tt[0] - t,
            dt_free: tt[0] - t,
            by_drag: false,
            landing: tt[0] == t_target,
            t_target,
        });
        self.own = local;
        self.layer_given = true;
        Ok(Tried::Done((plan, tt[0], global.vsig_max)))
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
        let mut most = [
            forces.as_ref().map_or(0.0, |f| f.vsig_max),
            forces.as_ref().map_or(0.0, |f| f.acc_max),
            forces.as_ref().map_or(0.0, |f| f.damp_rate_max),
        ];
        world.max_f64(&mut most);
        let global = Forces {
            vsig_max: most[0],
            acc_max: most[1],
            damp_rate_max: most[2],
        };
        let explicit = phys.drag == crate::scene::DragMethod::Explicit;
        if explicit && !thin {
            return Err(format!(
                "step {step}: the explicit drag baseline (drag.method = \"explicit\") steps \
                 over ranks with the thin halo only, and a rank holds no gas"
            ));
        }
        let mut drag = [f64::INFINITY];
        if let (true, Some(e)) = (explicit, eng.as_mut()) {
            match e.timed_drag_limit() {
                Ok(d) => drag[0] = d,
                Err(x) => err = x.to_string(),
            }
        }
        if world.any(!err.is_empty()) {
            return Err(failure(world, step, me, &err));
        }
        world.min_f64(&mut drag);
        Ok((forces, global, drag[0]))
    }

    /// How many particles this rank owns (its host copy less its ghosts after a step).
    fn own_len(&self) -> usize {
        match (&self.resident, self.owned_stale) {
            (Some(r), true) => r.flags.iter().filter(|&&g| !g).count(),
            _ => self.own.len(),
        }
    }

    /// Whether the ranks' work per step since the last judgement (their steps' time less their
    /// time in MPI, where they wait for each other; [`REBALANCE_STEPS`] or more) is uneven
    /// enough to rebuild the halo on a cut by cost now (collective): where the busiest rank's
    /// exceeds the mean by more than `rebalance_at`, the next cut shares out each rank's work
    /// per owned particle over the ranks' mean (kept until the next imbalance: it holds the
    /// cut where it balanced the ranks), and the halo is rebuilt at once where the wait it
    /// saves over `horizon` steps exceeds a build's `build_seconds` (docs/scaling.md, "Cut").
    fn judge_balance(&mut self, horizon: f64, build_seconds: f64) -> bool {
        let world = &self.world;
        let n = self.own_len() as f64;
        let per_step = self.busy / self.busy_steps as f64;
        (self.busy, self.busy_steps) = (0.0, 0);
        let mut sums = [per_step, n];
        world.sum_f64(&mut sums);
        let mut most = [per_step, build_seconds];
        world.max_f64(&mut most);
        let mean = sums[0] / world.size() as f64;
        let uneven = mean > 0.0 && most[0] > (1.0 + self.rebalance_at) * mean;
        let worth = (most[0] - mean) * horizon > most[1];
        if self.trace && world.rank() == 0 {
            eprintln!(
                "halo: the busiest rank's work {:.4e} s a step against the mean {mean:.4e} s{}",
                most[0],
                match (uneven, worth) {
                    (true, true) => ": cut by the measured cost now",
                    (true, false) => ": cut by the measured cost at the next build",
                    _ => "",
                }
            );
        }
        if !uneven {
            return false;
        }
        // An empty rank has no cost per particle of its own: the mean's.
        let mean_per_particle = sums[0] / sums[1].max(1.0);
        self.cost = Some(match n > 0.0 {
            true => (per_step / n) / mean_per_particle,
            false => 1.0,
        });
        worth
    }

    /// This rank's particles for a step: its own migrated by this step's cut, in place (only
    /// those that leave travel, as records), and the halo (thin: every neighbour and IDIC
    /// cell-mate of an owned particle, now and after the step's drift, the margin; deep: the
    /// step's chain of passes, and a fixed shell). `None` when the thin halo cannot serve (a
    /// rank holds no gas: the ghosts' refresh is collective inside the step, and every rank
    /// must step an engine). Collective.
    fn local_layer(&mut self, thin: bool) -> Result<Option<LocalLayer>, String> {
        let world = &self.world;
        let domain = self.phys.domain;
        // The support: of the largest h over all ranks where h varies (the reference h at
        // least), so that the halo holds every neighbour of its stepped particles.
        let solved = self.own.gas.h.iter().flatten();
        let mut h_max = [solved.fold(self.phys.h, |a, &h| a.max(h))];
        world.max_f64(&mut h_max);
        let support = crate::step::SUPPORT * h_max[0];
        let cell = self.phys.cell_diagonal();
        let near = support.max(cell);
        let (inner, reach) = if thin {
            (near + self.margin, near + self.margin)
        } else {
            (self.depth * support, (self.depth + 1.0) * support)
        };
        let xs: Vec<[f64; 3]> = positions(&self.own).collect();
        let part = cut(world, &xs, &domain, reach, self.cost);
        self.rebalances += (thin && self.cost.is_some()) as u64;
        drop(xs);
        migrate_own(world, &part, &mut self.own)?;
        let own = &self.own;
        let xs: Vec<[f64; 3]> = positions(own).collect();
        let to = halo_sends(world.size(), &part, &xs, |x| *x);
        drop(xs);
        // Rank by rank in one buffer: one copy of each record sent, received straight into
        // records.
        let at = row_of(own);
        let sends: Vec<ParticleRecord> = (to.iter().flatten())
            .map(|&n| {
                let (k, i) = at(n);
                record_at(own, k, i)
            })
            .collect();
        let counts: Vec<usize> = to.iter().map(Vec::len).collect();
        let (halo, from) = world.exchange_flat_from(&sends, &counts)?;
        // Only the owned particles sent as halo can lie within `reach` of one received: an
        // owned particle within reach of a particle of rank q has a cell of q within its ring.
        let (kept, flags) = shell(&sends, &halo, inner, reach, &domain);
        // Which of each rank's candidates are kept, for its refreshes.
        let mut flag = flags.iter().map(|&f| f as u8);
        let replies = (from.iter())
            .map(|&c| flag.by_ref().take(c).collect())
            .collect();
        let mut sent = sends.iter().map(ParticleRecord::key);
        let to = (counts.iter())
            .map(|&c| sent.by_ref().take(c).collect())
            .collect();
        drop((sends, halo));
        let ghost_keys: KeySet = kept.iter().map(|r| r.key()).collect();
        let gas_here = !own.gas.ph.is_empty() || kept.iter().any(|r| r.phase == 0);
        if thin && world.any(!gas_here) {
            return Ok(None);
        }
        Ok(Some(LocalLayer {
            to,
            replies,
            halo: kept,
            ghost_keys,
            support,
            near,
            reach,
            cbox: part.cbox,
        }))
    }

    /// The momentum and its scale Σ m|v| of every rank's own particles, summed over the ranks
    /// (collective).
    pub fn momentum(&self) -> crate::step::Momentum {
        // Accretion is refused over ranks, so no particle is counted inside a radius here.
        let c = self.phys.gravity.pos;
        let mut s = [0.0f64; 7];
        let mut add = |m: f64, x: [f64; 3], v: [f64; 3]| {
            let x = dustsph_device::sub(x, c);
            for (sk, vk) in s.iter_mut().zip(v) {
                *sk += m * vk;
            }
            s[3] += m * dustsph_device::dot(v, v).sqrt();
            for (sk, lk) in s[4..].iter_mut().zip(dustsph_device::cross(x, v)) {
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
        self.world.sum_f64(&mut s);
        crate::step::Momentum {
            p: [s[0], s[1], s[2]],
            scale: s[3],
            l: [s[4], s[5], s[6]],
            inside: 0,
        }
    }

    /// An output's dust densities and stopping times per fraction, on the resident engine
    /// (built first where there is none: timed as a build, not as the output), for every
    /// particle of its host copy at time `t`, step `step`, which is synced whole beside its
    /// ghost flags; the refresh's buffers freed until the next step (collective). `None` where
    /// no rank steps on a thin halo.
    fn output_fields_here(
        &mut self,
        t: f64,
        step: u64,
        t0: &mut std::time::Instant,
    ) -> Result<Option<Vec<Vec<f64>>>, String> {
        if self.thin && self.resident.is_none() {
            self.resident = self.build_resident(step)?;
            self.timers.add(STAGE_BUILD, t0.elapsed().as_secs_f64());
            *t0 = std::time::Instant::now();
        }
        let Some(res) = self.resident.as_mut() else {
            return Ok(None);
        };
        res.local.t = t;
        res.local.step = step;
        let ts = (res.eng.dust_stopping_times(&mut res.local))
            .unwrap_or_else(|x| abort_job(&self.world, step, &x));
        res.flags = ghost_flags(&res.eng);
        res.eng.free_refresh_buffers();
        Ok(Some(ts))
    }

    /// `f` of this rank's own particles as they stand, at time `t`, step `step`, read where they
    /// lie (the resident engine's host copy drops its ghost rows until the next sync: a retake
    /// of the next step starts from them, none flagged), and the ranks.
    pub fn with_own<R>(&mut self, t: f64, step: u64, f: impl FnOnce(&State, &World) -> R) -> R {
        let own = match (self.resident.as_mut(), self.owned_stale) {
            (Some(res), true) => {
                res.local
                    .retain_rows(&res.flags.iter().map(|&g| !g).collect::<Vec<_>>());
                res.flags = vec![false; res.local.len()];
                &mut res.local
            }
            _ => &mut self.own,
        };
        own.t = t;
        own.step = step;
        f(own, &self.world)
    }

    /// An output written by share: `write` gets this rank's own particles at time `t`, step
    /// `step`, with the dust densities and stopping times per fraction its engine computed for
    /// them (the ghosts refreshed between), and the ranks (collective); `None` on every rank
    /// where no rank steps on a thin halo (the deep halo, a rank without gas: the output is
    /// gathered instead).
    pub fn own_output<R>(
        &mut self,
        t: f64,
        step: u64,
        write: impl FnOnce(&State, &[Vec<f64>], &World) -> R,
    ) -> Result<Option<R>, String> {
        let mut t0 = std::time::Instant::now();
        let Some(ts) = self.output_fields_here(t, step, &mut t0)? else {
            return Ok(None);
        };
        let res = self.resident.as_ref().expect("fields computed");
        // The stopping times of the own rows (`with_own` drops the ghosts' rows).
        let mut at = res.local.gas.ph.len();
        let ts: Vec<Vec<f64>> = (ts.into_iter().zip(&res.local.dust))
            .map(|(v, ph)| {
                let g = &res.flags[at..at + ph.len()];
                at += ph.len();
                v.into_iter()
                    .zip(g)
                    .filter(|p| !*p.1)
                    .map(|p| p.0)
                    .collect()
            })
            .collect();
        let done = self.with_own(t, step, |own, world| write(own, &ts, world));
        self.timers
            .add(STAGE_OWN_OUTPUT, t0.elapsed().as_secs_f64());
        Ok(Some(done))
    }

    /// Every rank's particles as one state on rank 0 for an output (`None` on the other
    /// ranks), with the dust densities and stopping times each rank's engine computed for its
    /// own particles, the ghosts refreshed between (collective). Where no rank steps on a thin
    /// halo (the deep halo, a rank without gas) the stopping times are `None`: rank 0 computes
    /// them on the gathered state.
    #[allow(clippy::type_complexity)]
    pub fn gather_output(
        &mut self,
        t: f64,
        step: u64,
    ) -> Result<Option<(State, Option<Vec<Vec<f64>>>)>, String> {
        let mut t0 = std::time::Instant::now();
        let Some(ts) = self.output_fields_here(t, step, &mut t0)? else {
            return Ok(self.gather(t, step)?.map(|st| (st, None)));
        };
        let (res, world) = (
            self.resident.as_mut().expect("fields computed"),
            &self.world,
        );
        // The own particles in key order (phase, index), read where they lie: the engine's
        // host copy keeps them (the output's dust densities too, which the next steps start
        // from, as one process's engine does), and their records only pass through the
        // stream to rank 0, a message at a time.
        let (ghost, local) = (&res.flags, &res.local);
        let mut own: Vec<((u64, u64), u32, u32)> = Vec::with_capacity(ghost.len());
        let phases = std::iter::once(&local.gas.ph).chain(local.dust.iter());
        let mut n = 0;
        for (k, ph) in phases.enumerate() {
            for i in 0..ph.len() {
                if !ghost[n] {
                    own.push(((k as u64, ph.id[i]), k as u32, i as u32));
                }
                n += 1;
            }
        }
        own.sort_unstable_by_key(|o| o.0);
        let at = |j: usize| {
            let (k, i) = (own[j].1 as usize, own[j].2 as usize);
            (record_at(local, k, i), (k > 0).then(|| ts[k - 1][i]))
        };
        let mut counts = vec![0u64; 1 + local.dust.len()];
        for o in &own {
            counts[o.1 as usize] += 1;
        }
        let gathered = gather_sorted(world, &self.template, &counts, at, true, (t, step));
        self.timers.add(STAGE_OUTPUT, t0.elapsed().as_secs_f64());
        Ok(gathered)
    }

    /// Every rank's particles as one state on rank 0 (phases in order, each by particle id),
    /// at time `t`, step `step`; `None` on the other ranks. Collective.
    fn gather(&mut self, t: f64, step: u64) -> Result<Option<State>, String> {
        let own = &self.own;
        let row = row_of(own);
        let mut order: Vec<((u64, u64), u32, u32)> = (keys_of(own).enumerate())
            .map(|(n, key)| {
                let (k, i) = row(n);
                (key, k as u32, i as u32)
            })
            .collect();
        order.sort_unstable_by_key(|o| o.0);
        let at = |j: usize| {
            (
                record_at(own, order[j].1 as usize, order[j].2 as usize),
                None,
            )
        };
        let counts: Vec<u64> = (std::iter::once(&own.gas.ph).chain(&own.dust))
            .map(|ph| ph.len() as u64)
            .collect();
        let st = gather_sorted(&self.world, &self.template, &counts, at, false, (t, step));
        Ok(st.map(|(st, _)| st))
    }
}

/// Records per message of a rank's stream to rank 0 at an output (5.8 MB): no rank holds its
/// whole share as records for the gather, nor rank 0 every rank's.
const STREAM_RECORDS: usize = 32 * 1024;

/// [`STREAM_RECORDS`], or `DUSTSPH_STREAM_RECORDS` where set (tests/mpi.rs streams a small
/// run in many short messages).
fn stream_records() -> usize {
    crate::env::count("DUSTSPH_STREAM_RECORDS", STREAM_RECORDS)
}

/// Every rank's particles as one state on rank 0 (phases in order, each by particle id), at
/// time `t`, step `step`; `None` on the other ranks. Collective. This rank has `n`, `at(j)` the
/// j-th in key order: its record and, with `values`, a value per dust record (gathered per
/// fraction in the state's order). Each rank streams its records in key order to rank 0 a
/// message at a time ([`stream_records`]: records, then the values of the dust among them),
/// and rank 0 merges the streams with its own, reading each record once, in order.
#[allow(clippy::type_complexity)]
fn gather_sorted(
    world: &World,
    template: &State,
    phase_counts: &[u64],
    at: impl Fn(usize) -> (ParticleRecord, Option<f64>),
    values: bool,
    (t, step): (f64, u64),
) -> Option<(State, Option<Vec<Vec<f64>>>)> {
    const REC: usize = std::mem::size_of::<ParticleRecord>();
    let per_msg = stream_records();
    let n = phase_counts.iter().sum::<u64>() as usize;
    let Some(counts) = world.gather_bytes(bytemuck::cast_slice(phase_counts)) else {
        let mut msg = Vec::with_capacity(per_msg.min(n) * (REC + 8));
        let mut vals = Vec::new();
        for lo in (0..n).step_by(per_msg) {
            msg.clear();
            vals.clear();
            for j in lo..(lo + per_msg).min(n) {
                let (rec, v) = at(j);
                msg.extend_from_slice(bytemuck::bytes_of(&rec));
                vals.extend(v);
            }
            msg.extend_from_slice(bytemuck::cast_slice(&vals));
            world.send_to_root(&msg);
        }
        return None;
    };
    let runs = counts.len();
    // Each rank's count per phase: the whole state's columns are allocated at their size.
    let per_phase = |b: &Vec<u8>| -> Vec<usize> {
        (b.chunks_exact(8))
            .map(|c| u64::from_le_bytes(c.try_into().expect("a count")) as usize)
            .collect()
    };
    let mut totals = vec![0usize; phase_counts.len()];
    let mut left: Vec<usize> = Vec::with_capacity(runs);
    for b in &counts {
        let c = per_phase(b);
        for (t, x) in totals.iter_mut().zip(&c) {
            *t += x;
        }
        left.push(c.iter().sum());
    }
    left[0] = 0;
    let mut own_at = 0;
    let mut pending: Vec<std::vec::IntoIter<(ParticleRecord, Option<f64>)>> =
        (0..runs).map(|_| Vec::new().into_iter()).collect();
    // A run's next record: rank 0's own read where it lies, the others' from their streams
    // (a malformed message stops the job: the other ranks have gone on to the next step).
    let mut pull = |r: usize| -> Option<(ParticleRecord, Option<f64>)> {
        if r == 0 {
            own_at += 1;
            return (own_at <= n).then(|| at(own_at - 1));
        }
        if let Some(x) = pending[r].next() {
            return Some(x);
        }
        if left[r] == 0 {
            return None;
        }
        let k = left[r].min(per_msg);
        left[r] -= k;
        let msg = world.receive_from(r as u32);
        let malformed = |want: usize| -> ! {
            let why = format!(
                "rank {r}'s output stream sent {} bytes where {k} records need {want}",
                msg.len()
            );
            abort_job(world, step, &why)
        };
        if msg.len() < k * REC {
            malformed(k * REC);
        }
        let recs: Vec<ParticleRecord> = (0..k)
            .map(|i| bytemuck::pod_read_unaligned(&msg[i * REC..][..REC]))
            .collect();
        let dust = recs.iter().filter(|x| x.phase > 0).count();
        let want = k * REC + if values { 8 * dust } else { 0 };
        if msg.len() != want {
            malformed(want);
        }
        let mut v = (msg[k * REC..].chunks_exact(8)).map(bytemuck::pod_read_unaligned);
        let items: Vec<_> = (recs.into_iter())
            .map(|x| (x, (values && x.phase > 0).then(|| v.next()).flatten()))
            .collect();
        pending[r] = items.into_iter();
        pending[r].next()
    };
    let mut head = Vec::with_capacity(runs);
    for r in 0..runs {
        head.push(pull(r));
    }
    let mut per_fraction: Vec<Vec<f64>> = (1..totals.len())
        .map(|k| Vec::with_capacity(if values { totals[k] } else { 0 }))
        .collect();
    let merged = std::iter::from_fn(|| {
        let r = (0..runs)
            .filter(|&r| head[r].is_some())
            .min_by_key(|&r| head[r].map(|h| h.0.key()))?;
        let (rec, v) = head[r].take().expect("a run's head");
        head[r] = pull(r);
        if let Some(v) = v {
            per_fraction[rec.phase as usize - 1].push(v);
        }
        Some(rec)
    });
    let mut st = state_from(merged, template, &totals);
    st.t = t;
    st.step = step;
    Some((st, values.then_some(per_fraction)))
}

/// Per-particle values of an engine (gas, then every dust fraction together, in its order:
/// its host copy `st`'s) by particle key.
fn by_key(st: &State, values: &[Vec<f64>; 2]) -> std::collections::HashMap<(u64, u64), f64> {
    let mut out = std::collections::HashMap::with_capacity(st.len());
    let mut dust_at = 0;
    for (k, ph) in std::iter::once(&st.gas.ph).chain(&st.dust).enumerate() {
        for i in 0..ph.len() {
            let v = if k == 0 {
                values[0].get(i)
            } else {
                values[1].get(dust_at + i)
            };
            if let Some(&v) = v {
                out.insert((k as u64, ph.id[i]), v);
            }
        }
        if k > 0 {
            dust_at += ph.len();
        }
    }
    out
}

/// Every particle's position in a state, gas first, then each dust fraction (the order of
/// [`State::retain_rows`]).
fn positions(st: &State) -> impl Iterator<Item = [f64; 3]> + '_ {
    std::iter::once(&st.gas.ph)
        .chain(&st.dust)
        .flat_map(|ph| ph.x.iter().copied())
}

/// Every particle's key (phase, id), in the order of [`positions`].
fn keys_of(st: &State) -> impl Iterator<Item = (u64, u64)> + '_ {
    (std::iter::once(&st.gas.ph).chain(&st.dust))
        .enumerate()
        .flat_map(|(k, ph)| ph.id.iter().map(move |&id| (k as u64, id)))
}

/// The phase and index of a state's n-th particle (the order of [`positions`]).
fn row_of(st: &State) -> impl Fn(usize) -> (usize, usize) {
    let mut starts = vec![0usize];
    for ph in std::iter::once(&st.gas.ph).chain(&st.dust) {
        starts.push(starts.last().copied().unwrap_or(0) + ph.len());
    }
    move |n| {
        let k = starts.partition_point(|&s| s <= n) - 1;
        (k, n - starts[k])
    }
}

/// Records per phase (phase 0 the gas, then each of `nph - 1` dust fractions).
fn phase_counts(recs: &[ParticleRecord], nph: usize) -> Vec<usize> {
    let mut c = vec![0; nph];
    for r in recs {
        c[r.phase as usize] += 1;
    }
    c
}

/// A rank's own particles to the ranks owning their cells under `part` (collective): those
/// that leave go as records and are dropped here, those that arrive are appended; the rest
/// stay where they lie.
fn migrate_own(
    world: &World,
    part: &crate::decomp::Partition,
    own: &mut State,
) -> Result<(), String> {
    let me = world.rank();
    let mut sends: Vec<Vec<ParticleRecord>> = vec![Vec::new(); world.size() as usize];
    let at = row_of(own);
    let stays: Vec<bool> = (positions(own).enumerate())
        .map(|(n, x)| {
            let q = part.owner_at(x);
            if q != me {
                let (k, i) = at(n);
                sends[q as usize].push(record_at(own, k, i));
            }
            q == me
        })
        .collect();
    own.retain_rows(&stays);
    drop(stays);
    let arrived = world.exchange(&sends)?;
    drop(sends);
    let counts = phase_counts(&arrived, 1 + own.dust.len());
    append_records(own, arrived.into_iter(), &counts);
    Ok(())
}

/// A phase's fixed flags where the scene has none and no particle is fixed (the deep halo's
/// shell was, and has gone).
fn drop_unused_fixed(st: &mut State, template: &State) {
    let phases = std::iter::once((&mut st.gas.ph, &template.gas.ph))
        .chain(st.dust.iter_mut().zip(&template.dust));
    for (ph, t) in phases {
        if t.fixed.is_none() && ph.fixed.as_ref().is_some_and(|f| !f.iter().any(|&f| f)) {
            ph.fixed = None;
        }
    }
}

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

/// The largest displacement that two particles' relative position can have taken, from every
/// rank's own particles' motion: |dᵢ − dⱼ| ≤ 2 min(max |d|, max |d − u|) for any u, and with u
/// the centre of the displacements' box |d − u| is at most its half-diagonal. Under a common
/// drift (the dusty box's gas and dust each moving as one) this is half the relative motion,
/// where the largest displacement alone counts the drift too.
fn relative_motion(largest: f64, lo: [f64; 3], hi: [f64; 3]) -> f64 {
    let half_diagonal = (0..3)
        .map(|a| (0.5 * (hi[a] - lo[a])).powi(2))
        .sum::<f64>()
        .sqrt();
    largest.min(half_diagonal)
}

/// A resident engine's ghost flags (its ghosts are set when it is built).
fn ghost_flags(eng: &Backend) -> Vec<bool> {
    eng.ghost_flags().expect("a resident engine has its ghosts")
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

#[cfg(test)]
mod tests {
    use super::relative_motion;

    /// The bound the halo's rebuild rests on: for displacements d of every particle,
    /// |dᵢ − dⱼ| ≤ 2 · relative_motion for every pair, and under a common drift the bound is
    /// the spread of the displacements, not the drift.
    #[test]
    fn relative_motion_bounds_every_pair_and_ignores_a_common_drift() {
        // A deterministic scatter of displacement sets: a spread around a drift.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for set in 0..200 {
            let drift = [3.0 * next(), 3.0 * next(), 3.0 * next()];
            let spread = if set % 2 == 0 { 0.01 } else { 1.0 };
            let d: Vec<[f64; 3]> = (0..50)
                .map(|_| [0, 1, 2].map(|k| drift[k] + spread * next()))
                .collect();
            let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let largest = d.iter().map(|&v| norm(v)).fold(0.0, f64::max);
            let lo = [0, 1, 2].map(|k| d.iter().map(|v| v[k]).fold(f64::INFINITY, f64::min));
            let hi = [0, 1, 2].map(|k| d.iter().map(|v| v[k]).fold(f64::NEG_INFINITY, f64::max));
            let bound = relative_motion(largest, lo, hi);
            for a in &d {
                for b in &d {
                    let gap = norm([a[0] - b[0], a[1] - b[1], a[2] - b[2]]);
                    assert!(
                        gap <= 2.0 * bound * (1.0 + 1e-12),
                        "set {set}: {gap} > 2 × {bound}"
                    );
                }
            }
            assert!(bound <= largest);
            if spread < 0.1 {
                // The drift is up to 2.6 long, the spread 0.01 a side: the bound is the spread.
                assert!(
                    bound <= 0.01 * 3f64.sqrt() / 2.0 * (1.0 + 1e-12),
                    "set {set}: {bound}"
                );
            }
        }
    }
}
