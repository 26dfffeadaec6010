//! The thin halo: the resident engine built on a rank's own particles and ghosts, a step on
//! it, and the motion bound that keeps the halo, retakes a step or rebuilds the halo.
use super::balance::REBALANCE_STEPS;
use super::layer::{phase_counts, positions, LocalLayer};
use super::{
    abort_job, failure, max_over, take_planned, Comm, RankStepper, Tried, World, STAGE_BUILD,
    STAGE_MOTION,
};
use crate::dist::halo::{fail_requested, RankGhosts};
use crate::dist::motion::MotionCells;
use crate::dist::records::{append_records, ParticleRecord};
use crate::particles::State;
use crate::step::backend::Backend;
use crate::step::engine::InitialLayer;
use crate::step::timestep::{Plan, StepPlanner};
use crate::step::{Forces, Physics};

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

/// A rank's engine kept across steps on its owned particles and thin halo, until the motion
/// since the halo was built uses up its margin (docs/scaling.md, "A resident engine").
pub(super) struct Resident {
    pub(super) eng: Backend,
    /// The engine's host copy, synced after each step that holds (a retaken step leaves it
    /// at the step's start), and its ghost flags then: where the rank's own particles are read
    /// from until the next output or build ([`RankStepper::owned_stale`]).
    pub(super) local: State,
    pub(super) flags: Vec<bool>,
    pub(super) support: f64,
    pub(super) near: f64,
    pub(super) reach: f64,
    /// The largest displacement of any rank's owned particle from its anchor (after the last
    /// step), and the steps taken on this halo.
    pub(super) moved: f64,
    pub(super) steps: u64,
    /// The largest halo over the ranks as a multiple of a rank's own particles, the build's
    /// time, and a step's (the slowest rank's; the mean over the halo's steps).
    pub(super) ratio: f64,
    pub(super) build_seconds: f64,
    pub(super) step_seconds: f64,
    /// The cells the motion test compares pair by pair.
    pub(super) cells: MotionCells,
}

impl RankStepper {
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
    pub(super) fn build_resident(&mut self, step: u64) -> Result<Option<Resident>, String> {
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
            let h_max = max_over(&self.world, m.h_max);
            let need = crate::step::SUPPORT * h_max;
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
        let per_reach = crate::dist::motion::cells_per_reach(self.phys.dim);
        let shape = (self.phys.dim, per_reach);
        let cells = MotionCells::new(world, &cbox, reach, shape, positions(&self.own));
        let arriving: Vec<(u64, u64)> = halo.iter().map(ParticleRecord::key).collect();
        let owned = self.own.len();
        let ratio = max_over(world, halo.len() as f64 / owned.max(1) as f64);
        self.halo_ratio = self.halo_ratio.max(ratio);
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
        let build_seconds = max_over(world, t0.elapsed().as_secs_f64());
        Ok(Some(Resident {
            eng,
            local,
            flags,
            support,
            near,
            reach,
            moved: 0.0,
            steps: 0,
            ratio,
            build_seconds,
            step_seconds: 0.0,
            cells,
        }))
    }

    /// A step on the thin halo: on the resident engine (built first where there is none), its
    /// ghosts refreshed between the passes. Afterwards the motion since the halo was built is
    /// reduced over the ranks: where two particles could have closed in from beyond the halo
    /// to within a reach, the step is taken again on a rebuilt halo; where the next step could,
    /// the halo is rebuilt before it.
    pub(super) fn step_resident(
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
        let taken = Self::take_resident(world, &self.phys, res, drv, (t, step, t_target));
        let (plan, global, stepped, busy) = taken?;
        let t0 = std::time::Instant::now();
        let t_new = res.local.t;
        let trace = me == 0 && self.trace;
        let bound = Self::motion_bound(world, &self.phys, res, stepped, step, trace);
        let Bound {
            moved,
            need,
            d,
            margin,
        } = bound;
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

    /// The step on the resident engine (its host copy `local` keeps the step's start until it
    /// is synced), of the size the forces' maxima over the ranks give: the plan, those
    /// maxima, and this rank's seconds in the step and, less its time in MPI, at work.
    fn take_resident(
        world: &World,
        phys: &Physics,
        res: &mut Resident,
        drv: &StepPlanner,
        (t, step, t_target): (f64, u64, f64),
    ) -> Result<(Plan, Forces, f64, f64), String> {
        res.local.t = t;
        res.local.step = step;
        let blocked = crate::dist::comm::traffic().blocked_seconds();
        let t_step = std::time::Instant::now();
        let (_, global, drag) = Self::global_limits(world, phys, Some(&mut res.eng), true, step)?;
        let (e, local) = (&mut res.eng, &mut res.local);
        let r = take_planned(e, local, drv, (&global, drag), (t, step, t_target));
        let plan = r.unwrap_or_else(|x| abort_job(world, step, &x));
        let stepped = t_step.elapsed().as_secs_f64();
        let busy = stepped - (crate::dist::comm::traffic().blocked_seconds() - blocked);
        Ok((plan, global, stepped, busy))
    }

    /// The motion since the halo was built, and the largest h, over every rank (collective;
    /// `stepped`: this rank's seconds in the step, averaged into the halo's step time): the
    /// bound on the motion that matters ([`Bound`]); `trace` prints it.
    fn motion_bound(
        world: &World,
        phys: &Physics,
        res: &mut Resident,
        stepped: f64,
        step: u64,
        trace: bool,
    ) -> Bound {
        // Each own particle's displacement binned by its cell at the build, in the same pass
        // (on a GPU rank the positions cross to the host once).
        let cells = &mut res.cells;
        cells.clear();
        let m = (res.eng.owned_motion(&mut |k, x, d| cells.add(k, x, d)))
            .unwrap_or_else(|x| abort_job(world, step, &x))
            .expect("a resident engine has its ghosts");
        let mine = Worst {
            largest: m.largest,
            h_max: m.h_max,
            stepped,
            hi: m.hi,
            neg_lo: [-m.lo[0], -m.lo[1], -m.lo[2]],
        };
        let worst = max_over(world, mine);
        let lo = [-worst.neg_lo[0], -worst.neg_lo[1], -worst.neg_lo[2]];
        let spread = relative_motion(worst.largest, lo, worst.hi);
        let near = (crate::step::SUPPORT * worst.h_max).max(res.near);
        // Where the global bound, growing as it has, would hold the halo another step, it
        // serves; otherwise the pairs of cells of two ranks close enough to meet give twice
        // the motion that matters, and the phases' own reach where they meet
        // ([`MotionCells::bound`]).
        let next = 2.0 * spread * (res.steps + 2) as f64 / (res.steps + 1) as f64;
        let moved = if near + next <= res.reach {
            spread
        } else {
            let cross = match phys.coupling {
                crate::scene::Coupling::Kernel => near,
                crate::scene::Coupling::Cell => phys.cell_diagonal().min(near),
            };
            0.5 * res.cells.bound(world, res.reach, near, cross, 2.0 * spread)
        };
        let need = near + 2.0 * moved;
        if trace {
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
        res.step_seconds += (worst.stepped - res.step_seconds) / (res.steps + 1) as f64;
        let margin = Self::margin_for(d, res) + (need - 2.0 * moved - res.near);
        Bound {
            moved,
            need,
            d,
            margin,
        }
    }
}

/// The maxima over the ranks of their owned particles' motion since the halo was built
/// ([`RankStepper::motion_bound`]): the largest displacement, the largest h, the step's
/// seconds, and the displacements' box (its lower corner negated, for the maximum).
#[repr(C)]
#[derive(Clone, Copy)]
struct Worst {
    largest: f64,
    h_max: f64,
    stepped: f64,
    hi: [f64; 3],
    neg_lo: [f64; 3],
}

// SAFETY: `repr(C)` of f64 fields only (no padding), and every bit pattern is a valid f64.
unsafe impl bytemuck::Zeroable for Worst {}
unsafe impl bytemuck::Pod for Worst {}

/// What the motion since the halo was built allows ([`RankStepper::motion_bound`]).
struct Bound {
    /// Half the largest change of any two particles' separation that matters to the halo.
    moved: f64,
    /// The reach the halo needs now: a neighbour pass's, and twice `moved`.
    need: f64,
    /// This step's motion (estimated).
    d: f64,
    /// The margin beyond the reach for a rebuilt halo.
    margin: f64,
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
pub(super) fn ghost_flags(eng: &Backend) -> Vec<bool> {
    eng.ghost_flags().expect("a resident engine has its ghosts")
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
