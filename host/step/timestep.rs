//! The size of each step: the fixed `time.dt`, or `time.cfl` × min(CFL limit, force limit),
//! never above the explicit drag's limit (finite only for the explicit baseline; IDIC never
//! limits the step), shortened to land exactly on a target time (an output, t_end). One rule
//! for every way of stepping: one process, MPI ranks (with the maxima over the ranks), parity.
use super::Forces;
use crate::scene::{StepRule, Time, MAX_FIXED_STEPS};
use dustsph_device::timestep::{cfl_limit, force_limit};

/// What the planner chose for one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plan {
    /// The step size taken.
    pub dt: f64,
    /// The step size before shortening it to land on the target time.
    pub dt_free: f64,
    /// The explicit drag's limit set it.
    pub by_drag: bool,
    /// The step ends exactly on the target time.
    pub landing: bool,
    /// The time the step was planned toward.
    pub t_target: f64,
}

/// A planned step and the forces' maxima it was planned from.
#[derive(Debug, Clone, Copy)]
pub struct Taken {
    pub plan: Plan,
    pub forces: Forces,
}

/// Why no step can be planned.
#[derive(Debug, Clone, PartialEq)]
pub enum PlanError {
    /// Nothing sets the step (no signal speed, no force, no fixed `time.dt`).
    NoLimit(String),
    /// The CFL step has collapsed: t_end is more steps away than allowed. The message lacks the
    /// particles that set the step; the engine adds them (`Backend::dt_culprits`).
    Collapsed(String),
}

/// Chooses steps for one scene's time settings.
#[derive(Debug, Clone)]
pub struct StepPlanner {
    pub time: Time,
    /// Reference smoothing length (the CFL length).
    pub h: f64,
}

/// Time-step limits from the forces: (CFL with factor 1, force limit with factor 1).
pub fn dt_limits(h: f64, f: &Forces) -> (f64, f64) {
    (cfl_limit(h, f.vsig_max), force_limit(h, f.acc_max))
}

/// The edge zones' limit 1/rate (+∞ outside them).
pub fn damp_limit(rate: f64) -> f64 {
    if rate > 0.0 {
        1.0 / rate
    } else {
        f64::INFINITY
    }
}

/// One particle's own step under a CFL rule: [`step_size`] with its own smoothing length, signal
/// speed, |acceleration| and damping rate (`None` for a fixed `time.dt`, the same for all).
pub fn own_step(time: &Time, h: f64, vsig: f64, acc: f64, damp_rate: f64) -> Option<f64> {
    time.fixed_dt().is_none().then(|| {
        let limits = (cfl_limit(h, vsig), force_limit(h, acc));
        step_size(
            time,
            limits.0,
            limits.1,
            damp_limit(damp_rate),
            f64::INFINITY,
        )
        .0
    })
}

/// The step size τ: the fixed `time.dt`, or `time.cfl` × min(CFL limit, force limit) capped by
/// the edge zones' 1/rate (`dt_damp`: their explicit decay stays monotone) and `time.dt_max`,
/// and in
/// either case no more than the drag limit `dt_drag`. Returns (τ, whether the drag limit set
/// it).
pub fn step_size(
    time: &Time,
    dt_cfl: f64,
    dt_force: f64,
    dt_damp: f64,
    dt_drag: f64,
) -> (f64, bool) {
    let base = match time.step {
        StepRule::Fixed { dt } => dt,
        StepRule::Cfl { cfl, dt_max } => (cfl * dt_cfl.min(dt_force))
            .min(dt_damp)
            .min(dt_max.unwrap_or(f64::INFINITY)),
    };
    if dt_drag < base {
        (dt_drag, true)
    } else {
        (base, false)
    }
}

impl StepPlanner {
    /// What set a planned step, for a person watching the run: `time.dt`, landing on an
    /// output, the explicit drag, the CFL or force limit, the edge zones, `time.dt_max`; `None`
    /// where the maxima at hand match none (over ranks only the signal speed is reported).
    pub fn what_limits(&self, forces: &Forces, plan: &Plan) -> Option<&'static str> {
        if plan.landing && plan.dt < plan.dt_free {
            return Some("landing on an output time");
        }
        if plan.by_drag {
            return Some("explicit drag");
        }
        let StepRule::Cfl { cfl, dt_max } = self.time.step else {
            return Some("time.dt");
        };
        let (dt_cfl, dt_force) = dt_limits(self.h, forces);
        let same = |x: f64| (x - plan.dt_free).abs() <= 1e-12 * plan.dt_free;
        [
            (cfl * dt_cfl, "CFL"),
            (cfl * dt_force, "force"),
            (damp_limit(forces.damp_rate_max), "edge zones"),
            (dt_max.unwrap_or(f64::INFINITY), "time.dt_max"),
        ]
        .into_iter()
        .find(|(x, _)| same(*x))
        .map(|(_, name)| name)
    }

    pub fn new(time: &Time, h: f64) -> StepPlanner {
        StepPlanner {
            time: time.clone(),
            h,
        }
    }

    /// The step from time `t` (step count `step`) toward `t_target` (never past it), given the
    /// forces' maxima at the current layer and the explicit drag's limit (+∞ for IDIC).
    pub fn plan(
        &self,
        forces: &Forces,
        dt_drag: f64,
        t: f64,
        step: u64,
        t_target: f64,
    ) -> Result<Plan, PlanError> {
        let (dt_cfl, dt_force) = dt_limits(self.h, forces);
        let dt_damp = damp_limit(forces.damp_rate_max);
        let (dt_free, by_drag) = step_size(&self.time, dt_cfl, dt_force, dt_damp, dt_drag);
        if !(dt_free.is_finite() && dt_free > 0.0) {
            return Err(PlanError::NoLimit(format!(
                "step {step}, t = {t:e}: time step is {dt_free} (no signal speed or force to set \
                 it); give time.dt"
            )));
        }
        // A CFL step that has collapsed would never reach the end: stop with a diagnosis (the
        // fixed time.dt has the same bound at validation).
        let left = self.time.t_end - t;
        if self.time.fixed_dt().is_none() && left > 0.0 && left / dt_free > MAX_FIXED_STEPS {
            let (limit, value) = if dt_cfl <= dt_force {
                ("CFL (h / max signal speed)", forces.vsig_max)
            } else {
                ("force (sqrt(h / max |A|))", forces.acc_max)
            };
            return Err(PlanError::Collapsed(format!(
                "step {step}, t = {t:e}: at the time step {dt_free:e} ({limit}; max = {value:e}), \
                 t_end = {} is {:.1e} steps away, more than the {MAX_FIXED_STEPS:.0e} allowed: \
                 the step has collapsed or time.t_end is too far",
                self.time.t_end,
                left / dt_free,
            )));
        }
        let landing = t + dt_free >= t_target - 1e-9 * dt_free;
        let dt = if landing { t_target - t } else { dt_free };
        Ok(Plan {
            dt,
            dt_free,
            by_drag,
            landing,
            t_target,
        })
    }
}
