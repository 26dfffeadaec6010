//! The deep halo: a step on an engine built for it on a rank's particles and a halo deep
//! enough for the step's chain of passes (a rank without gas, `mpi-check --depth`).
use super::layer::{keys_of, phase_counts};
use super::{failure, max_over, take_planned, Comm, RankStepper, Tried};
use crate::dist::records::append_records;
use crate::particles::{KeySet, State};
use crate::step::engine::InitialLayer;
use crate::step::timestep::{Plan, StepPlanner};

impl RankStepper {
    /// A step on the deep halo: an engine built on the rank's particles and a halo deep enough
    /// for the step's chain of passes (no refresh), dropped after the step.
    pub(super) fn step_deep(
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
        let t_here = if plan.is_some() {
            local.t
        } else {
            f64::NEG_INFINITY
        };
        let t_new = max_over(world, t_here);
        // A rank without particles rebuilds the step from the new time (the others' plan).
        let plan = plan.unwrap_or(Plan {
            dt: t_new - t,
            dt_free: t_new - t,
            by_drag: false,
            landing: t_new == t_target,
            t_target,
        });
        self.own = local;
        self.layer_given = true;
        Ok(Tried::Done((plan, t_new, global.vsig_max)))
    }
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
