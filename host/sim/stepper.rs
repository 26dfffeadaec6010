//! What steps a simulation: the engine on one process, or the scene's particles split over MPI
//! ranks ([`crate::dist::ranks`]). Either takes a step with the planner's one rule, reports the
//! momentum after it, and brings the host state up to date for an output.
use crate::particles::State;
use crate::step::backend::Backend;
#[cfg(feature = "mpi")]
use crate::step::backend::DeviceChoice;
use crate::step::timestep::{StepPlanner, Taken};
#[cfg(feature = "mpi")]
use crate::step::Forces;
use crate::step::{Momentum, StepError};

#[cfg(feature = "mpi")]
pub use crate::dist::ranks::RankStepper;

/// Where a simulation steps.
pub enum Stepper {
    /// One process: the engine on its launcher; the host state is the whole state.
    Local(Backend),
    /// MPI ranks: this rank's share. Rank 0's state is the gathered whole after a sync, and
    /// `output` an engine on it for what an output computes (dust densities, stopping times).
    #[cfg(feature = "mpi")]
    Ranks {
        ranks: Box<RankStepper>,
        output: Backend,
        /// `output` no longer matches the gathered state (rebuilt before its next use).
        stale: bool,
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
            #[cfg(feature = "mpi")]
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

    /// The momentum of every particle after the last step (collective over ranks).
    pub fn momentum(&mut self) -> Result<Momentum, StepError> {
        match self {
            Stepper::Local(eng) => eng.momentum(),
            #[cfg(feature = "mpi")]
            Stepper::Ranks { ranks, .. } => Ok(ranks.momentum()),
        }
    }

    /// Bring the host state up to date: from the engine, or every rank's particles gathered on
    /// rank 0 (collective; the other ranks' states keep only their time and step).
    pub fn sync(&mut self, state: &mut State) -> Result<(), StepError> {
        match self {
            Stepper::Local(eng) => eng.sync(state),
            #[cfg(feature = "mpi")]
            Stepper::Ranks { ranks, stale, .. } => {
                let gathered = ranks
                    .gather(state.t, state.step)
                    .map_err(StepError::Blowup)?;
                if let Some(st) = gathered {
                    *state = st;
                    *stale = true;
                }
                Ok(())
            }
        }
    }

    /// An engine on the whole (synced) state, for what an output computes from it: the
    /// stepping engine itself, or over ranks rank 0's engine rebuilt on the gathered state.
    // The state is rank 0's gathered one over ranks; one process's engine is already on it.
    #[cfg_attr(not(feature = "mpi"), allow(unused_variables))]
    pub fn engine(&mut self, state: &mut State) -> Result<&mut Backend, StepError> {
        match self {
            Stepper::Local(eng) => Ok(eng),
            #[cfg(feature = "mpi")]
            Stepper::Ranks { output, stale, .. } => {
                if *stale {
                    let phys = output.phys().clone();
                    *output = Backend::new(DeviceChoice::Cpu, phys, state)?;
                    // The ranks leave the dust densities as a step does (one process refreshes
                    // them for its outputs): a variable-h engine would otherwise keep the
                    // gathered ones.
                    output.dust_density_as_after_step();
                    *stale = false;
                }
                Ok(output)
            }
        }
    }

    /// The engine that steps (one process), or rank 0's output engine (over ranks): for its
    /// physics, timers and description.
    pub fn backend(&self) -> &Backend {
        match self {
            Stepper::Local(eng) => eng,
            #[cfg(feature = "mpi")]
            Stepper::Ranks { output, .. } => output,
        }
    }

    /// The stepping engine of one process (`None` over ranks).
    pub fn local(&mut self) -> Option<&mut Backend> {
        match self {
            Stepper::Local(eng) => Some(eng),
            #[cfg(feature = "mpi")]
            Stepper::Ranks { .. } => None,
        }
    }

    /// This process writes the output: one process, or rank 0.
    pub fn is_root(&self) -> bool {
        match self {
            Stepper::Local(_) => true,
            #[cfg(feature = "mpi")]
            Stepper::Ranks { ranks, .. } => ranks.is_root(),
        }
    }

    /// Whether any process says so (collective over ranks).
    pub fn any(&self, flag: bool) -> bool {
        match self {
            Stepper::Local(_) => flag,
            #[cfg(feature = "mpi")]
            Stepper::Ranks { ranks, .. } => ranks.any(flag),
        }
    }

    /// Every rank's traffic so far, in rank order (collective over ranks; `None` on one
    /// process, which sends nothing).
    pub fn traffic(&self) -> Option<Vec<crate::dist::Traffic>> {
        match self {
            Stepper::Local(_) => None,
            #[cfg(feature = "mpi")]
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
            #[cfg(feature = "mpi")]
            Stepper::Ranks { ranks, output, .. } => format!(
                "{}; set-up and outputs: {}",
                ranks.describe(),
                output.describe()
            ),
        }
    }
}
