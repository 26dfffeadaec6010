//! A run: a scene's simulation with its outputs — snapshots at the scene's output times,
//! checkpoints, the progress bar — stepped to t_end, then the summary; the library API that
//! `dustsph run` / `resume` and the tests call. One process, or MPI ranks (rank 0 writes every
//! output).
use crate::dist::Comm;
use crate::io;
use crate::particles::State;
use crate::scene::LoadedScene;
use crate::sim::checkpoint::{self, Progress, RunCheckpoints};
use crate::sim::output::{BallChecks, BallRecord, OutputRecord, Outputs};
use crate::sim::progress::{CheckpointEvery, Interrupt, ProgressBar};
use crate::sim::start;
use crate::sim::summary;
use crate::sim::{Observer, Simulation, Stepper};
use crate::step::backend::DeviceChoice;
use crate::step::Physics;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

pub use crate::sim::summary::Summary;
pub use crate::sim::{RunError, Stop};

#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out: PathBuf,
    pub force: bool,
    /// Print a line per snapshot.
    pub verbose: bool,
    /// Where to step (`--device`).
    pub device: DeviceChoice,
    /// Write each snapshot before stepping on (`--inline-outputs`), not on the writer thread
    /// from a copy of the state.
    pub inline_outputs: bool,
}

impl RunOptions {
    /// Into `out` (which must be new or empty), quiet, on the CPU: a run a test or a script
    /// makes.
    pub fn quiet_on_cpu(out: impl Into<PathBuf>) -> RunOptions {
        RunOptions {
            out: out.into(),
            force: false,
            verbose: false,
            device: DeviceChoice::Cpu,
            inline_outputs: false,
        }
    }
}

/// A run in progress: its simulation and what it writes.
pub struct Run {
    pub sim: Simulation,
    loaded: LoadedScene,
    outputs: Outputs,
    ball: Option<BallChecks>,
    checkpoints: RunCheckpoints,
    verbose: bool,
    /// Seconds between progress lines where stderr is not a terminal.
    pub progress_every: f64,
}

impl Run {
    /// Validate, set up, and write the t = 0 snapshot.
    pub fn start(loaded: &LoadedScene, opts: &RunOptions) -> Result<Run, RunError> {
        let (phys, mut state, source) = start::prepare(loaded, None, true)?;
        let mut eng = start::engine(loaded, phys.clone(), &mut state, opts.device, opts.verbose)?;
        start::check_first_step(loaded, &mut eng, &state)?;
        Self::begin(loaded, opts, phys, state, source, Stepper::Local(eng))
    }

    /// [`Run::start`] as one of several MPI ranks: every rank sets up the scene, keeps its
    /// share and builds its engine on it; the first step is checked over every rank (its
    /// verdict the same on each) before anything is written; the ranks write each output
    /// together (rank 0 the file, each rank its particles' chunks).
    pub fn start_over_ranks(
        loaded: &LoadedScene,
        opts: &RunOptions,
        world: crate::dist::comm::World,
    ) -> Result<Run, RunError> {
        let root = world.rank() == 0;
        // Every rank gets the same set-up error (bad input): rank 0 says it before any rank
        // leaves (mpirun stops the job at the first rank that exits non-zero).
        let (phys, mut state, source, share) = match start::prepare_on(loaded, None, root, &world) {
            Err(e) => {
                if root {
                    eprintln!("error: {e}");
                }
                world.any(true);
                return Err(RunError::InputReported);
            }
            Ok(r) => r,
        };
        let start = Start {
            device: opts.device,
            verbose: opts.verbose,
            check_first: true,
            share,
        };
        let stepper = over_ranks(world, loaded, &phys, &mut state, start)?;
        Self::begin(loaded, opts, phys, state, source, stepper)
    }

    /// All input is valid: the output directory (rank 0's), the simulation, the first
    /// snapshot.
    fn begin(
        loaded: &LoadedScene,
        opts: &RunOptions,
        phys: Physics,
        mut state: State,
        source: Option<crate::setup::file::IcSource>,
        mut stepper: Stepper,
    ) -> Result<Run, RunError> {
        let out = if stepper.is_root() {
            io::prepare_output_dir(&opts.out, opts.force)
                .map_err(|e| match e {
                    // A directory the user must empty or name differently is input, not a failure.
                    io::IoError::DirNotEmpty { .. } | io::IoError::Invalid { .. } => {
                        RunError::Input(e.to_string())
                    }
                    e => RunError::Io(e.to_string()),
                })
                .map(|_| ())
        } else {
            Ok(())
        };
        if stepper.any(out.is_err()) {
            out.clone()?;
            return Err(RunError::Io(
                "rank 0 could not prepare the output directory".into(),
            ));
        }
        // The stages of the run's summary are the steps' (not the set-up's or the check's).
        if let Some(eng) = stepper.local() {
            eng.timers_mut().clear();
        }
        let record = OutputRecord {
            start_time: state.t,
            initial_conditions: source,
            ..Default::default()
        };
        // Over ranks the whole state comes together on rank 0 here, its output fields computed
        // by the ranks' engines (one process syncs what it already holds), unless the outputs
        // are written by share.
        if !stepper.writes_by_share() {
            stepper
                .sync(&mut state)
                .map_err(|e| RunError::Step(e.to_string()))?;
        }
        let sim = Simulation::new(phys, &loaded.scene.time, state, stepper)
            .map_err(|e| RunError::Step(e.to_string()))?;
        let mut r = Run::with(
            loaded,
            opts.out.clone(),
            sim,
            record,
            None,
            0.0,
            opts.verbose,
        );
        if let Some(b) = &mut r.ball {
            b.record_now(&mut r.sim)?;
        }
        r.outputs.inline = opts.inline_outputs;
        r.outputs.write_next(&mut r.sim)?;
        r.shed_whole_state();
        Ok(r)
    }

    fn with(
        loaded: &LoadedScene,
        dir: PathBuf,
        sim: Simulation,
        outputs: OutputRecord,
        ball: Option<BallRecord>,
        wall_before: f64,
        verbose: bool,
    ) -> Run {
        let verbose = verbose && sim.is_root();
        Run {
            outputs: Outputs::new(loaded, &dir, outputs, verbose),
            ball: BallChecks::of(loaded, ball.unwrap_or_default()),
            checkpoints: RunCheckpoints {
                loaded: loaded.clone(),
                dir,
                wall_before,
                started: Instant::now(),
                last_step: None,
            },
            loaded: loaded.clone(),
            sim,
            verbose,
            progress_every: crate::sim::progress::LOG_EVERY_SECONDS,
        }
    }

    /// Over ranks, no rank keeps the whole state: each steps its share and writes it into each
    /// output and checkpoint (rank 0 gathers the whole for an output only on the settling
    /// column and the deep halo).
    fn shed_whole_state(&mut self) {
        self.sim.shed_gathered();
    }

    /// Continue a run from `DIR/checkpoint.h5`.
    pub fn resume(dir: &Path, verbose: bool, device: DeviceChoice) -> Result<Run, RunError> {
        let (state, loaded, progress) = checkpoint::read(dir)?;
        let layout = progress.layout;
        let (phys, mut state) = start::prepare_resumed(&loaded, state, layout.as_ref(), true)?;
        let eng = start::engine(&loaded, phys.clone(), &mut state, device, verbose)?;
        Ok(Self::resumed(
            &loaded,
            dir,
            phys,
            state,
            Stepper::Local(eng),
            progress,
            verbose,
        ))
    }

    /// [`Run::resume`] as one of several MPI ranks: each rank reads its share of the
    /// checkpoint's rows (one written by any number of ranks, or by one process; rank 0 checks
    /// its digest block by block) and steps from there: no rank reads every particle.
    pub fn resume_over_ranks(
        dir: &Path,
        verbose: bool,
        device: DeviceChoice,
        world: crate::dist::comm::World,
    ) -> Result<Run, RunError> {
        let (state, loaded, progress) = checkpoint::read_on(dir, &world)?;
        let layout = progress.layout;
        // No warnings: a rank's share says nothing of the whole (one process's resume from a
        // checkpoint with its layout warns of nothing either).
        let (phys, mut state) = start::prepare_resumed(&loaded, state, layout.as_ref(), false)?;
        let start = Start {
            device,
            verbose,
            check_first: false,
            share: true,
        };
        let stepper = over_ranks(world, &loaded, &phys, &mut state, start)?;
        let mut r = Self::resumed(&loaded, dir, phys, state, stepper, progress, verbose);
        r.shed_whole_state();
        Ok(r)
    }

    fn resumed(
        loaded: &LoadedScene,
        dir: &Path,
        phys: Physics,
        state: State,
        stepper: Stepper,
        p: Progress,
        verbose: bool,
    ) -> Run {
        let time = &loaded.scene.time;
        let sim = Simulation::resumed(phys, time, state, stepper, p.diagnostics);
        let ball = Some(p.ball);
        Run::with(
            loaded,
            dir.to_path_buf(),
            sim,
            p.outputs,
            ball,
            p.wall_before,
            verbose,
        )
    }

    pub fn out_dir(&self) -> &Path {
        &self.outputs.dir
    }

    /// This process writes the output (always, unless it is a rank other than 0).
    pub fn is_root(&self) -> bool {
        self.sim.is_root()
    }

    /// The state as it stands (brought up to date from the engine).
    pub fn current_state(&mut self) -> Result<&State, RunError> {
        self.sim.sync().map_err(|e| RunError::Step(e.to_string()))?;
        Ok(&self.sim.state)
    }

    /// Write each snapshot from here on before stepping on (`true`), or on the writer thread
    /// beside the steps (the default).
    pub fn set_inline_outputs(&mut self, inline: bool) {
        self.outputs.inline = inline;
    }

    /// Write `DIR/checkpoint.h5` (atomically), once the snapshot being written is whole.
    pub fn checkpoint(&mut self) -> Result<(), RunError> {
        self.outputs.settle()?;
        let mut parts = vec![self.outputs.save()];
        parts.extend(self.ball.as_ref().map(|b| b.save()));
        let parts = parts.into_iter().flatten().collect();
        crate::sim::Checkpointer::write(&mut self.checkpoints, &mut self.sim, parts)
    }

    /// Whether the last checkpoint holds the state as it stands.
    pub fn checkpointed_now(&self) -> bool {
        self.checkpoints.last_step == Some(self.sim.state.step)
    }

    /// Step until t_end (or `max_steps` more steps, or `stop` is raised); a checkpoint every
    /// `checkpoint_every` steps and on interruption.
    pub fn advance(
        &mut self,
        max_steps: Option<u64>,
        checkpoint_every: Option<u64>,
        stop: Option<&AtomicBool>,
    ) -> Result<Stop, RunError> {
        let t_end = self.loaded.scene.time.t_end;
        // The last output is at t_end: once it is written the run is over.
        let until = if self.outputs.done() {
            self.sim.state.t
        } else {
            t_end
        };
        let time_s = self.loaded.scene.units.map(|u| u.time_s());
        let start = (self.sim.state.t, self.sim.state.step);
        let mut bar = ProgressBar::new(self.verbose, t_end, time_s, start);
        bar.every = self.progress_every;
        let mut every = checkpoint_every.map(CheckpointEvery);
        let mut interrupt = Interrupt {
            flag: stop,
            max_steps,
            taken: 0,
        };
        // The ball's terms before the outputs: an output's engine reorders the state.
        let mut observers: Vec<&mut dyn Observer> = Vec::new();
        if let Some(b) = &mut self.ball {
            observers.push(b);
        }
        observers.push(&mut self.outputs);
        observers.push(&mut bar);
        if let Some(e) = &mut every {
            observers.push(e);
        }
        observers.push(&mut interrupt);
        let ran = self
            .sim
            .run(until, &mut observers, Some(&mut self.checkpoints));
        // The snapshot being written is whole before the run reports (and one that could not
        // be written fails it, unless the step failed first).
        let settled = self.outputs.settle();
        let stop = ran.map_err(|e| match e {
            RunError::Step(m) => {
                RunError::Step(format!("{m}; the snapshots written so far are kept"))
            }
            e => e,
        })?;
        settled?;
        Ok(stop)
    }

    /// The summary (also written to `DIR/summary.json`) and the final state.
    pub fn finish(self) -> Result<(Summary, State), RunError> {
        self.finish_as(FINISHED.to_string())
    }

    /// The summary of the state a run stopped at (`ending` says why it stopped there), written
    /// as [`Run::finish`] writes it (collective over ranks).
    pub fn finish_as(mut self, ending: String) -> Result<(Summary, State), RunError> {
        self.outputs.settle()?;
        let wall = self.checkpoints.wall_before + self.checkpoints.started.elapsed().as_secs_f64();
        let ball = self.ball.take().map(|b| b.record);
        summary::finish(
            self.sim,
            &self.loaded,
            &self.outputs.dir,
            std::mem::take(&mut self.outputs.record),
            ball,
            (wall, ending),
        )
    }
}

/// A summary's `ending` for a run that reached t_end.
pub const FINISHED: &str = "finished";

/// How a run over ranks starts ([`over_ranks`]).
struct Start {
    device: DeviceChoice,
    verbose: bool,
    /// Check the first step over every rank (a run's start, not a resume).
    check_first: bool,
    /// Each rank's state is its own share (a file read by share), not every particle.
    share: bool,
}

/// The stepper of a run over ranks: each rank's share of the scene and its engine on it, and
/// (`check_first`, a run's start) the first step checked over every rank. Every rank drops the
/// whole `state` once its share is taken (before its engine is built), or takes it as its
/// share (`share`); the outputs are written by share where the scene's analyses allow
/// ([`crate::analysis::outputs_read_whole_state`]), else gathered on rank 0. A start refused is
/// said before any rank leaves (mpirun stops the job at the first rank that exits non-zero,
/// which could otherwise cut the others off before they speak).
fn over_ranks(
    world: crate::dist::comm::World,
    loaded: &LoadedScene,
    phys: &Physics,
    state: &mut State,
    start: Start,
) -> Result<Stepper, RunError> {
    let Start {
        device,
        verbose,
        check_first,
        share,
    } = start;
    let root = world.rank() == 0;
    if phys.accretion_radius > 0.0 {
        // Removing particles rebuilds one process's engine; a rank's share cannot yet.
        if root {
            eprintln!(
                "error: gravity.accretion_radius: accretion runs on one process only (not over \
                 MPI ranks); run without mpirun or set it to 0"
            );
        }
        world.any(true);
        return Err(RunError::InputReported);
    }
    let mut ranks = crate::dist::ranks::RankStepper::new(
        world,
        phys.clone(),
        state,
        share,
        crate::dist::ranks::depth_for(phys),
        device,
        verbose,
    )
    .map_err(RunError::Input)?;
    ranks.rebalance_at(loaded.scene.numerics.rebalance_at);
    let file = loaded.path.display().to_string();
    let checked = match crate::sim::output::output_times(loaded, state.t).get(1) {
        Some(&t1) if check_first => {
            let planner = crate::step::timestep::StepPlanner::new(&loaded.scene.time, phys.h);
            match ranks.plan_first(&planner, state.t, state.step, t1) {
                Ok((forces, local)) => {
                    if let (true, Some(f), Some(local)) = (root, forces, local) {
                        // The warnings' neighbour count: rank 0's particles and halo.
                        for w in start::start_warnings(loaded, phys, local, &f) {
                            eprintln!("dustsph: warning: {w}");
                        }
                    }
                    Ok(())
                }
                Err(e) => Err(format!("{file}: the first step cannot be taken: {e}")),
            }
        }
        _ => ranks.prepare(state.step).map_err(|e| {
            format!(
                "{file}: the initial state cannot be set up (check idic.cell, sph.h/hfact, \
                 sph.n): {e}"
            )
        }),
    };
    // Every rank's verdict is the same (the plan's from maxima over all ranks; a rank's own
    // failure reaches the others as "another rank failed"): rank 0 says it, then all stop.
    if let Err(e) = &checked {
        if root || !e.contains("another rank failed") {
            eprintln!("error: {e}");
        }
        ranks.any(true);
        return Err(RunError::InputReported);
    }
    Ok(Stepper::Ranks {
        ranks: Box::new(ranks),
        t_stop: None,
        output: None,
        stale: false,
        by_share: !crate::analysis::outputs_read_whole_state(&loaded.scene),
    })
}

/// Run a scene to its end time; returns the summary and the final state.
pub fn run(loaded: &LoadedScene, opts: &RunOptions) -> Result<(Summary, State), RunError> {
    let mut r = Run::start(loaded, opts)?;
    r.advance(None, None, None)?;
    r.finish()
}
