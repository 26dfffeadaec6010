//! What steps a simulation: the engine on one process, or the scene's particles split over MPI
//! ranks ([`crate::dist::ranks`]). Either takes a step with the planner's one rule, reports the
//! momentum after it, and brings the host state up to date for an output.
use crate::dist::Comm;
use crate::particles::State;
use crate::step::backend::Backend;
use crate::step::backend::DeviceChoice;
use crate::step::timestep::{StepPlanner, Taken};
use crate::step::Forces;
use crate::step::{Momentum, StepError};

pub use crate::dist::ranks::RankStepper;

/// Where a simulation steps.
pub enum Stepper {
    /// One process: the engine on its launcher; the host state is the whole state.
    Local(Backend),
    /// MPI ranks: this rank's share. Rank 0's state is the gathered whole after a sync, with
    /// the dust densities and stopping times the ranks' engines computed for it.
    Ranks {
        ranks: Box<RankStepper>,
        /// The dust stopping times of the gathered state (rank 0), per fraction.
        t_stop: Option<Vec<Vec<f64>>>,
        /// Rank 0's engine on the gathered state, for an output the ranks' engines did not
        /// compute (a step on the deep halo has none): built when needed.
        output: Option<Backend>,
        /// `output` no longer matches the gathered state (rebuilt before its next use).
        stale: bool,
        /// The outputs are written by share, each rank its own particles, and no rank gathers
        /// the whole state (the scene's outputs need no analysis of every particle at once,
        /// [`crate::analysis::outputs_read_whole_state`]).
        by_share: bool,
    },
}

impl Stepper {
    /// One step toward `t_target`; `state`'s time and step count follow it.
    pub fn step(
        &mut self,
        planner: &StepPlanner,
        state: &mut State,
        t_target: f64,
    ) -> Result<Taken, StepError> {
        match self {
            Stepper::Local(eng) => eng.step(planner, state, t_target),
            Stepper::Ranks { ranks, .. } => {
                let (plan, t_new, vsig_max) = ranks
                    .step(planner, state.t, state.step, t_target)
                    .map_err(StepError::Blowup)?;
                state.t = t_new;
                state.step += 1;
                Ok(Taken {
                    plan,
                    forces: Forces {
                        vsig_max,
                        acc_max: 0.0,
                        damp_rate_max: 0.0,
                    },
                })
            }
        }
    }

    /// Over MPI ranks, a communicator of the output's own (collective): the other ranks
    /// deflate rank 0's snapshot chunks over it (`dist::farm`). `None` on one process.
    pub fn output_world(&self) -> Option<crate::dist::comm::World> {
        match self {
            Stepper::Ranks { ranks, .. } => Some(ranks.world.duplicate()),
            Stepper::Local(_) => None,
        }
    }

    /// Whether the outputs are written by share over ranks (the whole state never gathered).
    pub fn writes_by_share(&self) -> bool {
        match self {
            Stepper::Local(_) => false,
            Stepper::Ranks { by_share, .. } => *by_share,
        }
    }

    /// The sums over every particle (collective over ranks): of the (synced) state, or where
    /// the outputs are written by share, of every rank's own particles.
    pub fn totals(&mut self, state: &State) -> crate::sim::diagnostics::Totals {
        use crate::sim::diagnostics::Totals;
        if let Some(t) = self.with_own(state, |own, w| Totals::of(own).reduce(w)) {
            return t;
        }
        Totals::of(state)
    }

    /// Where the outputs are written by share: `f` of this rank's own particles as they stand
    /// (at `state`'s time and step) and the ranks (collective where `f` is); `None` elsewhere.
    pub fn with_own<R>(
        &mut self,
        state: &State,
        f: impl FnOnce(&State, &crate::dist::comm::World) -> R,
    ) -> Option<R> {
        match self {
            Stepper::Ranks {
                ranks,
                by_share: true,
                ..
            } => Some(ranks.with_own(state.t, state.step, f)),
            _ => None,
        }
    }

    /// Where the outputs are written by share: `write` gets this rank's own particles at
    /// `state`'s time and step, the dust stopping times its engine computed for them, and the
    /// ranks (collective); `None` elsewhere, and where the ranks step on the deep halo (the
    /// output is then gathered: [`Stepper::sync`]).
    pub fn own_output<R>(
        &mut self,
        state: &State,
        write: impl FnOnce(&State, &[Vec<f64>], &crate::dist::comm::World) -> R,
    ) -> Result<Option<R>, StepError> {
        match self {
            Stepper::Ranks {
                ranks,
                by_share: true,
                ..
            } => (ranks.own_output(state.t, state.step, write)).map_err(StepError::Blowup),
            _ => Ok(None),
        }
    }

    /// The momentum of every particle after the last step (collective over ranks).
    pub fn momentum(&mut self) -> Result<Momentum, StepError> {
        match self {
            Stepper::Local(eng) => eng.momentum(),
            Stepper::Ranks { ranks, .. } => Ok(ranks.momentum()),
        }
    }

    /// Bring the host state up to date for an output: from the engine, or over ranks every
    /// rank's particles gathered on rank 0 with the dust densities and stopping times each
    /// rank's engine computed for its own (collective; the other ranks' states keep only their
    /// time and step).
    pub fn sync(&mut self, state: &mut State) -> Result<(), StepError> {
        match self {
            Stepper::Local(eng) => eng.sync(state),
            Stepper::Ranks {
                ranks,
                t_stop,
                stale,
                ..
            } => {
                let gathered = ranks
                    .gather_output(state.t, state.step)
                    .map_err(StepError::Blowup)?;
                if let Some((st, ts)) = gathered {
                    *state = st;
                    *t_stop = ts;
                    *stale = true;
                }
                Ok(())
            }
        }
    }

    /// The dust densities (in `state`) and stopping times per fraction of the synced state,
    /// for an output: computed by the stepping engine, or over ranks by the ranks' engines at
    /// the sync (rank 0 only; nothing here is collective).
    pub fn output_fields(&mut self, state: &mut State) -> Result<Vec<Vec<f64>>, StepError> {
        if let Stepper::Ranks {
            t_stop: Some(ts), ..
        } = self
        {
            return Ok(ts.clone());
        }
        // It refreshes the dust densities into the state first.
        self.engine(state)?.dust_stopping_times(state)
    }

    /// Each gas particle's |A| and signal speed for the synced state, which is brought into
    /// the engine's order (rank 0 only over ranks; after the output's fields, whose stopping
    /// times follow the gathered order).
    pub fn particle_limits(
        &mut self,
        state: &mut State,
    ) -> Result<(Vec<[f64; 3]>, Vec<f64>), StepError> {
        let eng = self.engine(state)?;
        let limits = eng.particle_limits()?;
        eng.sync(state)?;
        Ok(limits)
    }

    /// The dust densities of the synced state (over ranks, the sync computed them).
    pub fn refresh_dust_density(&mut self, state: &mut State) -> Result<(), StepError> {
        if let Stepper::Ranks {
            t_stop: Some(_), ..
        } = self
        {
            return Ok(());
        }
        self.engine(state)?.refresh_dust_density(state)
    }

    /// An engine on the whole (synced) state: the stepping engine itself, or over ranks, where
    /// the ranks' engines did not compute an output's fields, rank 0's engine rebuilt on the
    /// gathered state.
    // The state is rank 0's gathered one over ranks; one process's engine is already on it.
    fn engine(&mut self, state: &mut State) -> Result<&mut Backend, StepError> {
        match self {
            Stepper::Local(eng) => Ok(eng),
            Stepper::Ranks {
                ranks,
                output,
                stale,
                ..
            } => {
                if *stale || output.is_none() {
                    let phys = ranks.phys().clone();
                    let mut eng = Backend::new(DeviceChoice::Cpu, phys, state)?;
                    // The ranks leave the dust densities as a step does (one process refreshes
                    // them for its outputs): a variable-h engine would otherwise keep the
                    // gathered ones.
                    eng.dust_density_as_after_step();
                    *output = Some(eng);
                    *stale = false;
                }
                Ok(output.as_mut().expect("built above"))
            }
        }
    }

    /// The run's physics.
    pub fn phys(&self) -> &crate::step::Physics {
        match self {
            Stepper::Local(eng) => eng.phys(),
            Stepper::Ranks { ranks, .. } => ranks.phys(),
        }
    }

    /// The stages' times of the steps: the engine's, or over ranks this rank's engines'.
    pub fn timers(&self) -> crate::step::timers::Timers {
        match self {
            Stepper::Local(eng) => eng.timers().clone(),
            Stepper::Ranks { ranks, .. } => ranks.timers(),
        }
    }

    /// The ball's Lagrange–Jacobi terms (I, 2Σm|v|² + 2dΣm p/ρ) of every particle after the
    /// last step (collective over ranks: each rank's own particles, summed).
    pub fn lagrange_jacobi_terms(&mut self, dim: u32) -> Result<(f64, f64), StepError> {
        match self {
            // A reduction on the engine's launcher: the particles stay on the device.
            Stepper::Local(eng) => eng.lagrange_jacobi(dim),
            Stepper::Ranks { ranks, .. } => Ok(ranks.lagrange_jacobi_terms(dim)),
        }
    }

    /// The stepping engine of one process (`None` over ranks).
    pub fn local(&mut self) -> Option<&mut Backend> {
        match self {
            Stepper::Local(eng) => Some(eng),
            Stepper::Ranks { .. } => None,
        }
    }

    /// This process writes the output: one process, or rank 0.
    pub fn is_root(&self) -> bool {
        match self {
            Stepper::Local(_) => true,
            Stepper::Ranks { ranks, .. } => ranks.is_root(),
        }
    }

    /// Whether any process says so (collective over ranks).
    pub fn any(&self, flag: bool) -> bool {
        match self {
            Stepper::Local(_) => flag,
            Stepper::Ranks { ranks, .. } => ranks.any(flag),
        }
    }

    /// Every rank's traffic so far, in rank order (collective over ranks; `None` on one
    /// process, which sends nothing).
    pub fn traffic(&self) -> Option<Vec<crate::dist::Traffic>> {
        match self {
            Stepper::Local(_) => None,
            Stepper::Ranks { ranks, .. } => {
                let mine = crate::dist::comm::traffic();
                let all = ranks.world.all_gather_bytes(bytemuck::bytes_of(&mine));
                Some(
                    all.iter()
                        .map(|b| bytemuck::pod_read_unaligned::<crate::dist::Traffic>(b))
                        .collect(),
                )
            }
        }
    }

    /// Where the run steps, for the summary.
    pub fn describe(&self) -> String {
        match self {
            Stepper::Local(eng) => eng.describe(),
            Stepper::Ranks { ranks, .. } => {
                format!("{}; set-up: cpu (rank 0)", ranks.describe())
            }
        }
    }
}
