//! `dustsph run` and `dustsph resume`: a scene's simulation with its outputs — snapshots at the
//! scene's output times, checkpoints, the progress bar — stepped to t_end, then the summary.
//! One process, or MPI ranks (rank 0 writes every output).
use crate::dist::Comm;
use crate::io;
use crate::particles::State;
use crate::scene::{LoadedScene, Precision};
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
use std::sync::atomic::Ordering;
use std::sync::Arc;
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
}

/// A run in progress: its simulation and what it writes.
pub struct Run {
    pub sim: Simulation,
    loaded: LoadedScene,
    outputs: Outputs,
    ball: Option<BallChecks>,
    checkpoints: RunCheckpoints,
    verbose: bool,
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

    /// Write `DIR/checkpoint.h5` (atomically).
    pub fn checkpoint(&mut self) -> Result<(), RunError> {
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
        let mut bar = ProgressBar::new(self.verbose, t_end);
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
        self.sim
            .run(until, &mut observers, Some(&mut self.checkpoints))
            .map_err(|e| match e {
                RunError::Step(m) => {
                    RunError::Step(format!("{m}; the snapshots written so far are kept"))
                }
                e => e,
            })
    }

    /// The summary (also written to `DIR/summary.json`) and the final state.
    pub fn finish(mut self) -> Result<(Summary, State), RunError> {
        let wall = self.checkpoints.wall_before + self.checkpoints.started.elapsed().as_secs_f64();
        let ball = self.ball.take().map(|b| b.record);
        summary::finish(
            self.sim,
            &self.loaded,
            &self.outputs.dir,
            std::mem::take(&mut self.outputs.record),
            ball,
            wall,
        )
    }
}

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

// ---------------------------------------------------------------------------------------------
// The command line.

#[derive(clap::Args)]
pub struct RunArgs {
    /// Scene file (TOML), e.g. configs/dustywave.toml
    scene: PathBuf,
    /// Override a scene key, e.g. --set dust.fractions.0.t_stop=1e-6 (repeatable)
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Output directory (default: output/<scene name>)
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write into a non-empty output directory (replaces only dustsph's own files)
    #[arg(long)]
    force: bool,
    /// Write DIR/checkpoint.h5 every N steps (Ctrl-C always writes one)
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    checkpoint_every: Option<u64>,
    /// Stop as if interrupted after N steps (with --checkpoint-every N: a checkpoint to resume
    /// from; for tests)
    #[arg(long, value_name = "N", hide = true)]
    stop_after: Option<u64>,
    /// No progress output
    #[arg(long, short)]
    quiet: bool,
    /// Where to step: a CUDA GPU if usable, else the CPU (auto); the CPU's cores (cpu); a
    /// CUDA GPU (cuda). The same step and kernels on either.
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// The float type of the step: f64 (the reference) or f32 (docs/accuracy.md); the
    /// same as --set numerics.precision=…
    #[arg(long, value_enum)]
    precision: Option<Precision>,
}

#[derive(clap::Args)]
pub struct ResumeArgs {
    dir: PathBuf,
    /// Write DIR/checkpoint.h5 every N steps (Ctrl-C always writes one)
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    checkpoint_every: Option<u64>,
    #[arg(long, short)]
    quiet: bool,
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
}

/// MPI for a run started as one of several ranks (`None` otherwise). A rank that panics must
/// not finalise MPI while the others wait in a collective (that hangs the job): it prints and
/// leaves at once, and mpirun stops the others.
fn ranks_world() -> Option<Result<crate::dist::comm::World, RunError>> {
    // A build without MPI runs every command on one process (main refuses several ranks).
    if !cfg!(feature = "mpi") || crate::dist::launched().is_none_or(|(_, n)| n <= 1) {
        return None;
    }
    let world = crate::dist::comm::World::init().map_err(|e| RunError::Input(format!("MPI: {e}")));
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        hook(info);
        std::process::exit(70);
    }));
    Some(world)
}

/// Start the run (`start`: set-up and the first snapshot) and step it to the end. Ctrl-C is
/// caught from before the start: pressed during the set-up, the run stops at its first step
/// with a checkpoint (exit 130), as later.
fn drive(
    start: impl FnOnce() -> Result<Run, RunError>,
    checkpoint_every: Option<u64>,
    stop_after: Option<u64>,
) -> u8 {
    let fail = |e: RunError| {
        if !matches!(e, RunError::InputReported) {
            eprintln!("error: {e}");
        }
        match e {
            RunError::Input(_) | RunError::InputReported => 2,
            _ => 1,
        }
    };
    // Ctrl-C asks the loop to stop after the current step and write a checkpoint; a second one
    // stops at once (files are written to a temporary name and renamed, so none is left torn).
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    if let Err(e) = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::Relaxed) {
            eprintln!("dustsph: second interrupt: stopping now, without a checkpoint");
            std::process::exit(130);
        }
    }) {
        eprintln!("warning: Ctrl-C will not checkpoint ({e})");
    }
    let mut r = match start() {
        Ok(r) => r,
        Err(e) => return fail(e),
    };
    match r.advance(stop_after, checkpoint_every, Some(&stop)) {
        Ok(Stop::Finished) => {}
        Ok(Stop::Interrupted { .. }) if !r.is_root() => return 130,
        Ok(Stop::Interrupted { .. }) => {
            let (step, t) = (r.sim.state.step, r.sim.state.t);
            if r.checkpointed_now() {
                eprintln!(
                    "interrupted at step {step}, t = {t}: checkpoint written; continue with \
                     `dustsph resume {}`",
                    r.out_dir().display()
                );
            } else {
                eprintln!("stopped at step {step}, t = {t}, without a checkpoint of this state");
            }
            return 130;
        }
        Err(e) => return fail(e),
    }
    let out = r.out_dir().to_path_buf();
    let root = r.is_root();
    match r.finish() {
        Ok((s, _)) => {
            if root {
                report(&s, &out);
            }
            0
        }
        Err(e) => fail(e),
    }
}

fn report(s: &Summary, out: &std::path::Path) {
    println!(
        "{}: {} steps to t = {} in {:.2} s ({:.3e} particle-steps/s; outputs {:.2} s); summary: {}",
        s.scene,
        s.steps,
        s.t_final,
        s.wall_seconds,
        s.particle_steps_per_second,
        s.output_seconds.iter().map(|e| e.1).sum::<f64>(),
        out.join("summary.json").display()
    );
    if let Some(u) = &s.units {
        println!(
            "  units: length {:e} cm, mass {:e} g, time {:e} s (G = 1), velocity {:e} cm/s",
            u.length_cm, u.mass_g, u.time_s, u.velocity_cm_per_s
        );
    }
    for last in s.errors.iter().filter(|e| e.t == s.t_final) {
        super::profile::print_errors(last);
    }
    for (r, t) in s.rank_traffic.iter().flatten().enumerate() {
        let per_step = |x: f64| x / s.steps.max(1) as f64;
        println!(
            "  rank {r}: {} exchanges, {:.3e} B sent ({:.3e} B/step), {:.3} s in them ({:.3e} \
             s/step); {:.3e} B to rank 0's gathers in {:.3} s",
            t.exchanges,
            t.exchange_bytes as f64,
            per_step(t.exchange_bytes as f64),
            t.exchange_seconds,
            per_step(t.exchange_seconds),
            t.gather_bytes as f64,
            t.gather_seconds
        );
    }
}

pub fn execute(a: RunArgs) -> u8 {
    let RunArgs {
        scene,
        set,
        out,
        force,
        checkpoint_every,
        stop_after,
        quiet,
        device,
        precision,
    } = a;
    let loaded = crate::scene::load(&scene, &set).and_then(|l| l.with_numerics(precision, None));
    let loaded = match loaded {
        Ok(l) => l,
        Err(e) => {
            eprintln!("error: {e}");
            return 2;
        }
    };
    let out = out.unwrap_or_else(|| PathBuf::from("output").join(&loaded.scene.name));
    // Over MPI ranks only rank 0 speaks (and writes).
    let quiet = quiet || crate::dist::launched().is_some_and(|(r, _)| r != 0);
    if !quiet {
        eprintln!("dustsph: {} → {}", scene.display(), out.display());
    }
    let opts = RunOptions {
        out,
        force,
        verbose: !quiet,
        device,
    };
    // Started as one of several MPI ranks: the run is split over them (docs/scaling.md).
    if let Some(world) = ranks_world() {
        let start = || world.and_then(|w| Run::start_over_ranks(&loaded, &opts, w));
        return drive(start, checkpoint_every, stop_after);
    }
    drive(|| Run::start(&loaded, &opts), checkpoint_every, stop_after)
}

pub fn execute_resume(a: ResumeArgs) -> u8 {
    let ResumeArgs {
        dir,
        checkpoint_every,
        quiet,
        device,
    } = a;
    let quiet = quiet || crate::dist::launched().is_some_and(|(r, _)| r != 0);
    if !quiet {
        eprintln!("dustsph: resuming {}", dir.display());
    }
    // Started as one of several MPI ranks: the rest of the run is split over them.
    if let Some(world) = ranks_world() {
        let start = || world.and_then(|w| Run::resume_over_ranks(&dir, !quiet, device, w));
        return drive(start, checkpoint_every, None);
    }
    drive(|| Run::resume(&dir, !quiet, device), checkpoint_every, None)
}
