//! `dustsph run` and `dustsph resume`: their options, the start over MPI ranks where launched
//! so, the run driven to its end with its report (the run itself: [`crate::sim::run`]).
use crate::scene::Precision;
use crate::sim::run::{Run, RunError, RunOptions, Stop, Summary};
use crate::step::backend::DeviceChoice;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

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
    /// Seconds between progress lines where stderr is not a terminal (a log, a batch job)
    #[arg(long, value_name = "SECONDS", default_value_t = crate::sim::progress::LOG_EVERY_SECONDS)]
    progress_every: f64,
    /// Where to step: a CUDA GPU if usable, else the CPU (auto); the CPU's cores (cpu); a
    /// CUDA GPU (cuda). The same step and kernels on either.
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// The float type of the step: f64 (the reference) or f32 (docs/accuracy.md); the
    /// same as --set numerics.precision=…
    #[arg(long, value_enum)]
    precision: Option<Precision>,
    /// Write each snapshot before stepping on, not from a copy of the state on a thread of its
    /// own while the run steps on (no copy: less memory; slower where snapshots are large)
    #[arg(long)]
    inline_outputs: bool,
}

#[derive(clap::Args)]
pub struct ResumeArgs {
    dir: PathBuf,
    /// Write DIR/checkpoint.h5 every N steps (Ctrl-C always writes one)
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    checkpoint_every: Option<u64>,
    #[arg(long, short)]
    quiet: bool,
    /// Seconds between progress lines where stderr is not a terminal (a log, a batch job)
    #[arg(long, value_name = "SECONDS", default_value_t = crate::sim::progress::LOG_EVERY_SECONDS)]
    progress_every: f64,
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// Write each snapshot before stepping on, not from a copy of the state on a thread of its
    /// own while the run steps on (no copy: less memory; slower where snapshots are large)
    #[arg(long)]
    inline_outputs: bool,
}

/// When a run writes checkpoints and progress lines, and when it stops early.
struct Cadence {
    checkpoint_every: Option<u64>,
    stop_after: Option<u64>,
    progress_every: f64,
    /// `--inline-outputs`.
    inline_outputs: bool,
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
fn drive(start: impl FnOnce() -> Result<Run, RunError>, cadence: Cadence) -> u8 {
    let Cadence {
        checkpoint_every,
        stop_after,
        progress_every,
        inline_outputs,
    } = cadence;
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
    r.progress_every = progress_every;
    r.set_inline_outputs(inline_outputs);
    let out = r.out_dir().to_path_buf();
    let root = r.is_root();
    match r.advance(stop_after, checkpoint_every, Some(&stop)) {
        Ok(Stop::Finished) => {}
        Ok(Stop::Interrupted { .. }) => {
            let (step, t) = (r.sim.state.step, r.sim.state.t);
            let how = if r.checkpointed_now() {
                format!(
                    "interrupted at step {step}, t = {t}: checkpoint written; continue with \
                     `dustsph resume {}`",
                    out.display()
                )
            } else {
                format!("stopped at step {step}, t = {t}, without a checkpoint of this state")
            };
            // The summary of the state reached (collective over ranks); the stop is said
            // whether or not it could be written.
            let written = r.finish_as(how.clone());
            if root {
                eprintln!("{how}");
                match written {
                    Ok(_) => eprintln!("summary: {}", out.join("summary.json").display()),
                    Err(e) => eprintln!("warning: no summary of the state reached: {e}"),
                }
            }
            return 130;
        }
        Err(e) => {
            // One process: the summary of the last state the engine holds, saying the failure
            // (over ranks a failed rank may not take part in the summary's reductions).
            if r.sim.stepper.local().is_some() {
                let how = format!("failed: {e}");
                if let Err(w) = r.finish_as(how) {
                    eprintln!("warning: no summary of the state reached: {w}");
                }
            }
            return fail(e);
        }
    }
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
        progress_every,
        device,
        precision,
        inline_outputs,
    } = a;
    let cadence = Cadence {
        checkpoint_every,
        stop_after,
        progress_every,
        inline_outputs,
    };
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
        inline_outputs,
    };
    // Started as one of several MPI ranks: the run is split over them (docs/scaling.md).
    if let Some(world) = ranks_world() {
        let start = || world.and_then(|w| Run::start_over_ranks(&loaded, &opts, w));
        return drive(start, cadence);
    }
    drive(|| Run::start(&loaded, &opts), cadence)
}

pub fn execute_resume(a: ResumeArgs) -> u8 {
    let ResumeArgs {
        dir,
        checkpoint_every,
        quiet,
        progress_every,
        device,
        inline_outputs,
    } = a;
    let cadence = Cadence {
        checkpoint_every,
        stop_after: None,
        progress_every,
        inline_outputs,
    };
    let quiet = quiet || crate::dist::launched().is_some_and(|(r, _)| r != 0);
    if !quiet {
        eprintln!("dustsph: resuming {}", dir.display());
    }
    // Started as one of several MPI ranks: the rest of the run is split over them.
    if let Some(world) = ranks_world() {
        let start = || world.and_then(|w| Run::resume_over_ranks(&dir, !quiet, device, w));
        return drive(start, cadence);
    }
    drive(|| Run::resume(&dir, !quiet, device), cadence)
}
