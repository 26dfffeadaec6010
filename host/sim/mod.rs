//! A simulation: the physics, the state, what steps it ([`Stepper`]: one process or MPI
//! ranks) and its diagnostics, and the one step loop. Every command that steps a scene (run,
//! resume, study, stiffness, bench, parity, mpi-check) steps through [`Simulation::step`], so
//! they choose the same τ for the same state and report the same diagnostics; what a command
//! does around the steps (snapshots, checkpoints, the progress bar, its checks) are
//! [`Observer`]s of [`Simulation::run`].
pub mod accretion;
pub mod checkpoint;
pub mod diagnostics;
pub mod evolution;
pub mod output;
pub mod progress;
pub mod run;
pub mod start;
pub mod stepper;
pub mod summary;

use crate::particles::State;
use crate::scene::Time;
use crate::step::backend::{Backend, DeviceChoice, StartError};
use crate::step::timers::Timers;
use crate::step::timestep::{Plan, StepPlanner, Taken};
use crate::step::{Physics, StepError};
pub use diagnostics::{Diagnostics, ParticleCounts};
use std::time::Instant;
pub use stepper::Stepper;

/// Why a command stopped short, or could not start.
#[derive(Debug, Clone)]
pub enum RunError {
    /// Bad input (scene key at fault); nothing was written.
    Input(String),
    /// Bad input already reported (over MPI ranks rank 0 says it, once, before any rank
    /// leaves); exit 2 without a further message.
    InputReported,
    Io(String),
    Step(String),
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunError::Input(s) | RunError::Io(s) | RunError::Step(s) => f.write_str(s),
            RunError::InputReported => f.write_str("bad input (reported above)"),
        }
    }
}
impl std::error::Error for RunError {}

impl RunError {
    /// The exit code the command line gives it (README, "Exit codes").
    pub fn exit_code(&self) -> u8 {
        match self {
            RunError::Input(_) | RunError::InputReported => 2,
            _ => 1,
        }
    }
}

fn step_err(e: StepError) -> RunError {
    RunError::Step(e.to_string())
}

/// What an observer asks of the loop after it has seen a step (or before the next one).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    Continue,
    /// Write a checkpoint, then go on.
    Checkpoint,
    /// Stop here (Ctrl-C, a step budget), with a checkpoint first if asked.
    Stop {
        checkpoint: bool,
    },
}

/// Why [`Simulation::run`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    Finished,
    /// Stopped by an observer; `checkpointed`: a checkpoint was written to resume from.
    Interrupted {
        checkpointed: bool,
    },
}

/// Something a command does around the steps: write outputs, checkpoints, show progress,
/// record a check. Observers see the simulation after every step; the host state is up to
/// date then when any observer asks for it every step, and at every time an observer must
/// land on (its `next_time`).
pub trait Observer {
    /// What it does, for the summary's `output_seconds`.
    fn name(&self) -> &'static str {
        "other observers"
    }
    /// The next time after `t` the run must land on exactly (an output), if any.
    fn next_time(&self, _t: f64) -> Option<f64> {
        None
    }
    fn before_step(&mut self, _sim: &mut Simulation) -> Result<Flow, RunError> {
        Ok(Flow::Continue)
    }
    fn after_step(&mut self, _sim: &mut Simulation, _taken: &Taken) -> Result<Flow, RunError> {
        Ok(Flow::Continue)
    }
    /// Finish what it left running beside the steps (a snapshot being written), before a
    /// checkpoint keeps its record or the run ends.
    fn settle(&mut self) -> Result<(), RunError> {
        Ok(())
    }
    /// What a checkpoint keeps of this observer, as (name, JSON), to be restored on resume.
    fn save(&self) -> Option<(&'static str, serde_json::Value)> {
        None
    }
}

/// Writes a checkpoint of the simulation and its observers' saved parts.
pub trait Checkpointer {
    fn write(
        &mut self,
        sim: &mut Simulation,
        parts: Vec<(&'static str, serde_json::Value)>,
    ) -> Result<(), RunError>;
}

pub struct Simulation {
    pub phys: Physics,
    pub planner: StepPlanner,
    /// The host copy of the state: up to date after [`Simulation::sync`] (over ranks, the
    /// whole state on rank 0 only).
    pub state: State,
    pub stepper: Stepper,
    pub diagnostics: Diagnostics,
    /// Wall seconds of [`Simulation::run`] outside the steps: the state brought back at output
    /// times, each observer (snapshots, diagnostics, progress), checkpoints.
    pub output_timers: Timers,
}

impl Simulation {
    /// A simulation of `state` stepped by `stepper` (the engine built on it, which left the
    /// state up to date), its diagnostics starting here.
    pub fn new(
        phys: Physics,
        time: &Time,
        state: State,
        mut stepper: Stepper,
    ) -> Result<Simulation, StepError> {
        let m = stepper.momentum()?;
        let totals = stepper.totals(&state);
        Ok(Simulation {
            planner: StepPlanner::new(time, phys.h),
            diagnostics: Diagnostics::start(&totals, m),
            phys,
            state,
            stepper,
            output_timers: Timers::default(),
        })
    }

    /// The dust stopping times of the current (synced) state, per fraction (+∞ where a
    /// particle's drag is off).
    pub fn dust_stopping_times(&mut self) -> Result<Vec<Vec<f64>>, StepError> {
        let Simulation { stepper, state, .. } = self;
        stepper.output_fields(state)
    }

    /// A simulation continuing from a checkpoint's diagnostics.
    pub fn resumed(
        phys: Physics,
        time: &Time,
        state: State,
        stepper: Stepper,
        diagnostics: Diagnostics,
    ) -> Simulation {
        Simulation {
            planner: StepPlanner::new(time, phys.h),
            phys,
            state,
            stepper,
            diagnostics,
            output_timers: Timers::default(),
        }
    }

    /// One process on `device` (the state sorted in place by the engine): a note when `auto`
    /// did not use the GPU.
    pub fn local(
        phys: Physics,
        time: &Time,
        mut state: State,
        device: DeviceChoice,
    ) -> Result<(Simulation, Option<String>), StartError> {
        let (eng, note) = Backend::start(device, phys.clone(), &mut state)?;
        let sim =
            Simulation::new(phys, time, state, Stepper::Local(eng)).map_err(StartError::Step)?;
        Ok((sim, note))
    }

    /// A scene's simulation on one process: its set-up, its physics and the engine on
    /// `device` (a note when `auto` did not use the GPU). Errors are the set-up's or the
    /// engine's message.
    pub fn of_scene(
        scene: &crate::scene::Scene,
        device: DeviceChoice,
    ) -> Result<(Simulation, Option<String>), String> {
        let su = crate::setup::build(scene).map_err(|e| e.to_string())?;
        let phys = Physics::from_scene(scene, su.h, su.domain);
        Simulation::local(phys, &scene.time, su.state, device).map_err(|e| e.to_string())
    }

    /// One step toward `t_target` (never past it); the diagnostics follow it.
    pub fn step(&mut self, t_target: f64) -> Result<Taken, StepError> {
        let taken = self
            .stepper
            .step(&self.planner, &mut self.state, t_target)?;
        self.record(&taken)?;
        Ok(taken)
    }

    /// One process: a step of the size `plan` gives (another run's plan: parity compares two
    /// launchers on the same steps), from the forces of this engine.
    pub fn step_with(&mut self, plan: &Plan) -> Result<Taken, StepError> {
        let Simulation { stepper, state, .. } = self;
        let eng = stepper
            .local()
            .ok_or_else(|| StepError::Unsupported("this runs on one process only".into()))?;
        let forces = eng.forces()?;
        eng.take(state, plan)?;
        let taken = Taken {
            plan: *plan,
            forces,
        };
        self.record(&taken)?;
        Ok(taken)
    }

    fn record(&mut self, taken: &Taken) -> Result<(), StepError> {
        let mut m = self.stepper.momentum()?;
        if m.inside > 0 {
            self.accrete()?;
            m = self.stepper.momentum()?;
        }
        self.diagnostics.after_step(taken, m, self.phys.h);
        Ok(())
    }

    /// Remove the particles inside the accretion radius into the star's record and rebuild
    /// the engine on what is left (one process: the scene's check refuses accretion over
    /// ranks, whose momentum reduction counts none inside).
    fn accrete(&mut self) -> Result<(), StepError> {
        self.sync()?;
        let g = &self.phys.gravity;
        let removed =
            self.diagnostics
                .accreted
                .take(&mut self.state, g.pos, self.phys.accretion_radius);
        if removed > 0 {
            let Simulation { stepper, state, .. } = self;
            let eng = stepper.local().ok_or_else(|| {
                StepError::Unsupported("accretion runs on one process only".into())
            })?;
            *eng = eng.rebuilt(state)?;
        }
        Ok(())
    }

    /// One process: the forces and the step the planner would take toward `t_target` now
    /// (nothing is advanced; the next step computes the same forces again).
    pub fn plan_next(&mut self, t_target: f64) -> Result<Taken, StepError> {
        let planner = self.planner.clone();
        let state = &self.state;
        match &mut self.stepper {
            Stepper::Local(eng) => eng.plan(&planner, state, t_target),
            Stepper::Ranks { .. } => Err(StepError::Unsupported(
                "planning a step without taking it runs on one process".into(),
            )),
        }
    }

    /// The engine of one process (an error over ranks).
    pub fn local_engine(&mut self) -> Result<&mut Backend, StepError> {
        self.stepper
            .local()
            .ok_or_else(|| StepError::Unsupported("this runs on one process only".into()))
    }

    /// Bring the host state up to date (over ranks: gathered on rank 0; collective).
    pub fn sync(&mut self) -> Result<(), StepError> {
        self.stepper.sync(&mut self.state)
    }

    /// The dust densities of the current state (computed where the step does not keep them
    /// fresh), the host state brought up to date.
    pub fn refresh_dust_density(&mut self) -> Result<(), StepError> {
        self.sync()?;
        let Simulation { stepper, state, .. } = self;
        stepper.refresh_dust_density(state)
    }

    /// Over ranks, drop the whole state rank 0 gathered for an output (it is gathered again
    /// for the next): no rank holds the whole run between outputs.
    pub fn shed_gathered(&mut self) {
        if let Stepper::Ranks { t_stop, output, .. } = &mut self.stepper {
            self.state = self.state.shape();
            *t_stop = None;
            *output = None;
        }
    }

    /// This process writes the outputs (one process, or rank 0).
    pub fn is_root(&self) -> bool {
        self.stepper.is_root()
    }

    /// Whether any process says so (collective over ranks).
    pub fn any(&self, flag: bool) -> bool {
        self.stepper.any(flag)
    }

    /// Step until `t_end` (landing on every observer's times), or until an observer stops the
    /// run. Checkpoints that observers ask for are written by `checkpoints`.
    pub fn run(
        &mut self,
        t_end: f64,
        observers: &mut [&mut dyn Observer],
        checkpoints: Option<&mut dyn Checkpointer>,
    ) -> Result<Stop, RunError> {
        let mut checkpoints = checkpoints;
        while self.state.t < t_end {
            if let Some(stop) =
                self.consult(observers, &mut checkpoints, |o, s| o.before_step(s))?
            {
                return Ok(stop);
            }
            let target = observers
                .iter()
                .filter_map(|o| o.next_time(self.state.t))
                .fold(t_end, f64::min);
            let taken = self.step(target).map_err(step_err)?;
            // Where the outputs are written by share, no rank gathers the whole state.
            if taken.plan.landing && !self.stepper.writes_by_share() {
                let t0 = Instant::now();
                self.sync().map_err(step_err)?;
                self.output_timers
                    .add("the state brought back", t0.elapsed().as_secs_f64());
            }
            let after = |o: &mut dyn Observer, s: &mut Simulation| o.after_step(s, &taken);
            if let Some(stop) = self.consult(observers, &mut checkpoints, after)? {
                return Ok(stop);
            }
        }
        Ok(Stop::Finished)
    }

    /// Ask every observer (`ask`: before or after a step), each timed, then carry out what
    /// they asked.
    fn consult(
        &mut self,
        observers: &mut [&mut dyn Observer],
        checkpoints: &mut Option<&mut dyn Checkpointer>,
        mut ask: impl FnMut(&mut dyn Observer, &mut Simulation) -> Result<Flow, RunError>,
    ) -> Result<Option<Stop>, RunError> {
        let mut flow = Flow::Continue;
        for o in observers.iter_mut() {
            let t0 = Instant::now();
            flow = most(flow, ask(&mut **o, self)?);
            self.output_timers.add(o.name(), t0.elapsed().as_secs_f64());
        }
        let t0 = Instant::now();
        let stop = self.obey(flow, observers, checkpoints)?;
        self.output_timers
            .add("checkpoints", t0.elapsed().as_secs_f64());
        Ok(stop)
    }

    /// Carry out what the observers asked: a checkpoint, a stop.
    fn obey(
        &mut self,
        flow: Flow,
        observers: &mut [&mut dyn Observer],
        checkpoints: &mut Option<&mut dyn Checkpointer>,
    ) -> Result<Option<Stop>, RunError> {
        let checkpoint = matches!(flow, Flow::Checkpoint | Flow::Stop { checkpoint: true });
        let written = match (checkpoint, checkpoints.as_mut()) {
            (true, Some(c)) => {
                // A checkpoint lists only outputs whose files are whole.
                for o in observers.iter_mut() {
                    o.settle()?;
                }
                let parts = observers.iter().filter_map(|o| o.save()).collect();
                c.write(self, parts)?;
                true
            }
            _ => false,
        };
        Ok(match flow {
            Flow::Stop { .. } => Some(Stop::Interrupted {
                checkpointed: written,
            }),
            _ => None,
        })
    }
}

/// The stronger of two requests (stop over checkpoint over continue; a checkpoint asked by
/// either is kept).
fn most(a: Flow, b: Flow) -> Flow {
    match (a, b) {
        (Flow::Stop { checkpoint: x }, Flow::Stop { checkpoint: y }) => {
            Flow::Stop { checkpoint: x || y }
        }
        (Flow::Stop { checkpoint }, f) | (f, Flow::Stop { checkpoint }) => Flow::Stop {
            checkpoint: checkpoint || f == Flow::Checkpoint,
        },
        (Flow::Checkpoint, _) | (_, Flow::Checkpoint) => Flow::Checkpoint,
        _ => Flow::Continue,
    }
}
