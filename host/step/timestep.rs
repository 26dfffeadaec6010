//! The one step loop's step: forces, the step size (fixed `time.dt` or CFL, the explicit
//! drag's limit), landing exactly on a target time, and the advance. `run`, `resume`, `study`,
//! `stiffness`, `parity` and `bench` all step through [`StepPlanner`], so they choose the same τ
//! for the same state.
use super::backend::Backend;
use super::{dt_limits, step_size};
use super::{Forces, StepError};
use crate::particles::State;
use crate::scene::{TimeCfg, MAX_FIXED_STEPS};

/// What the driver chose for one step.
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

/// One step taken: the plan and the forces it started from.
#[derive(Debug, Clone)]
pub struct Taken {
    pub plan: Plan,
    pub forces: Forces,
}

/// Chooses and takes steps for one scene's time settings.
#[derive(Debug, Clone)]
pub struct StepPlanner {
    pub time: TimeCfg,
    /// Reference smoothing length (the CFL length).
    pub h: f64,
}

impl StepPlanner {
    pub fn new(time: &TimeCfg, h: f64) -> StepPlanner {
        StepPlanner {
            time: time.clone(),
            h,
        }
    }

    /// The step from `state` toward `t_target` (never past it) given the forces at `state`.
    pub fn plan(
        &self,
        eng: &mut Backend,
        state: &State,
        forces: &Forces,
        t_target: f64,
    ) -> Result<Plan, StepError> {
        self.plan_with(eng, state, forces, t_target, None)
    }

    /// As [`StepPlanner::plan`], with the explicit drag's step limit given (over MPI ranks: the
    /// least of every rank's) instead of computed here.
    pub fn plan_with(
        &self,
        eng: &mut Backend,
        state: &State,
        forces: &Forces,
        t_target: f64,
        drag_limit: Option<f64>,
    ) -> Result<Plan, StepError> {
        let (dt_cfl, dt_force) = dt_limits(self.h, forces);
        let dt_drag = if let Some(d) = drag_limit {
            d
        } else if eng.stages().explicit_drag {
            let t0 = std::time::Instant::now();
            let d = eng.drag_dt_limit(state)?;
            eng.timers_mut().add(
                "explicit drag time-step limit (τ ≤ 0.9/Λ)",
                t0.elapsed().as_secs_f64(),
            );
            d
        } else {
            f64::INFINITY
        };
        let (dt_free, by_drag) = step_size(&self.time, dt_cfl, dt_force, dt_drag);
        if !(dt_free.is_finite() && dt_free > 0.0) {
            return Err(StepError::Blowup(format!(
                "step {}, t = {:e}: time step is {dt_free} (no signal speed or force to set it); \
                 give time.dt",
                state.step, state.t
            )));
        }
        // A CFL step that has collapsed would never reach the end: stop with a diagnosis (the
        // fixed time.dt has the same bound at validation).
        let left = self.time.t_end - state.t;
        if self.time.dt.is_none() && left > 0.0 && left / dt_free > MAX_FIXED_STEPS {
            let (limit, value) = if dt_cfl <= dt_force {
                ("CFL (h / max signal speed)", forces.vsig_max)
            } else {
                ("force (sqrt(h / max |A|))", forces.acc_max)
            };
            return Err(StepError::Blowup(format!(
                "step {}, t = {:e}: at the time step {dt_free:e} ({limit}; max = {value:e}), \
                 t_end = {} is {:.1e} steps away, more than the {MAX_FIXED_STEPS:.0e} allowed: the \
                 step has collapsed or time.t_end is too far; {}",
                state.step,
                state.t,
                self.time.t_end,
                left / dt_free,
                eng.dt_culprits()?
            )));
        }
        let landing = state.t + dt_free >= t_target - 1e-9 * dt_free;
        let dt = if landing { t_target - state.t } else { dt_free };
        Ok(Plan {
            dt,
            dt_free,
            by_drag,
            landing,
            t_target,
        })
    }

    /// The forces at `state` and the step toward `t_target` (nothing is advanced yet).
    pub fn prepare(
        &self,
        eng: &mut Backend,
        state: &State,
        t_target: f64,
    ) -> Result<Taken, StepError> {
        let forces = eng.forces(state)?;
        let plan = self.plan(eng, state, &forces, t_target)?;
        Ok(Taken { plan, forces })
    }

    /// Advance by a prepared step; on landing the time is set to the target exactly.
    pub fn take(&self, eng: &mut Backend, state: &mut State, s: &Taken) -> Result<(), StepError> {
        eng.advance(state, &s.forces, s.plan.dt)?;
        if s.plan.landing {
            state.t = s.plan.t_target;
        }
        Ok(())
    }

    /// Take one step toward `t_target`.
    pub fn step(
        &self,
        eng: &mut Backend,
        state: &mut State,
        t_target: f64,
    ) -> Result<Taken, StepError> {
        let s = self.prepare(eng, state, t_target)?;
        self.take(eng, state, &s)?;
        Ok(s)
    }
}
