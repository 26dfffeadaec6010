//! Observers of a run's course: the progress bar, the checkpoint cadence, and the stops (Ctrl-C,
//! a step budget).
use super::{Flow, Observer, RunError, Simulation};
use crate::step::timestep::Taken;
use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// How often a run whose stderr is not a terminal (a log, a batch job) prints a progress line
/// (`dustsph run --progress-every`).
pub const LOG_EVERY_SECONDS: f64 = 60.0;

/// The run's progress for a person watching it (shown unless quiet): on a terminal a live bar
/// (1e-4 of t_end per tick) with the step, the simulated time (and in years under
/// `[units]`), the step size and what limits it, steps/s and particle-steps/s and the time
/// left; elsewhere the same as a plain line every `every` seconds.
pub struct ProgressBar {
    bar: indicatif::ProgressBar,
    t_end: f64,
    /// Plain lines instead of the bar.
    lines: bool,
    /// Seconds per code time unit (`[units]`), for the time in years.
    time_s: Option<f64>,
    /// This session's start: wall clock, simulated time, steps.
    started: (Instant, f64, u64),
    last_line: Instant,
    /// Seconds between plain lines.
    pub every: f64,
}

impl ProgressBar {
    pub fn new(visible: bool, t_end: f64, time_s: Option<f64>, start: (f64, u64)) -> ProgressBar {
        let terminal = std::io::stderr().is_terminal();
        let bar = if visible && terminal {
            indicatif::ProgressBar::new(10_000)
        } else {
            indicatif::ProgressBar::hidden()
        };
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bar:30} {percent:>3}% {msg}  ETA {eta}")
                .expect("a valid template"),
        );
        let now = Instant::now();
        ProgressBar {
            bar,
            t_end,
            lines: visible && !terminal,
            time_s,
            started: (now, start.0, start.1),
            last_line: now,
            every: LOG_EVERY_SECONDS,
        }
    }

    /// Run `f` with the bar out of the way (a line printed while it shows).
    pub fn suspend<T>(&self, f: impl FnOnce() -> T) -> T {
        self.bar.suspend(f)
    }

    /// The progress after a step, in words.
    fn describe(&self, sim: &Simulation, taken: &Taken) -> String {
        let (t, step) = (sim.state.t, sim.state.step);
        let wall = self.started.0.elapsed().as_secs_f64().max(1e-9);
        let steps_per_s = (step - self.started.2) as f64 / wall;
        let particles = sim.diagnostics.counts.total() as f64;
        let years = self.time_s.map_or(String::new(), |s| {
            format!(" ({:.4e} yr)", t * s / (365.25 * 86400.0))
        });
        let why = (sim.planner.what_limits(&taken.forces, &taken.plan))
            .map_or(String::new(), |w| format!(" ({w})"));
        format!(
            "step {step}  t = {t:.6e}{years}  dt = {:.3e}{why}  {steps_per_s:.2} steps/s, \
             {:.3e} particle-steps/s",
            taken.plan.dt,
            steps_per_s * particles
        )
    }
}

impl Drop for ProgressBar {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}

impl Observer for ProgressBar {
    fn after_step(&mut self, sim: &mut Simulation, taken: &Taken) -> Result<Flow, RunError> {
        let now = Instant::now();
        if self.lines && now.duration_since(self.last_line).as_secs_f64() >= self.every {
            self.last_line = now;
            let (t, t0) = (sim.state.t, self.started.1);
            let wall = self.started.0.elapsed().as_secs_f64();
            let left = if t > t0 {
                format!(", about {:.0} s left", (self.t_end - t) * wall / (t - t0))
            } else {
                String::new()
            };
            eprintln!(
                "  {:5.1} %  {}{left}",
                100.0 * t / self.t_end,
                self.describe(sim, taken)
            );
        } else if !self.bar.is_hidden() {
            self.bar
                .set_position((sim.state.t / self.t_end * 1e4) as u64);
            self.bar.set_message(self.describe(sim, taken));
        }
        Ok(Flow::Continue)
    }
}

/// A checkpoint every `every` steps (by the run's step count).
pub struct CheckpointEvery(pub u64);

impl Observer for CheckpointEvery {
    fn after_step(&mut self, sim: &mut Simulation, _: &Taken) -> Result<Flow, RunError> {
        Ok(if self.0 > 0 && sim.state.step % self.0 == 0 {
            Flow::Checkpoint
        } else {
            Flow::Continue
        })
    }
}

/// Stops the run before its next step: on Ctrl-C (`flag`, with a checkpoint; over ranks one
/// rank's Ctrl-C stops all at the same step) or after `max_steps` steps of this session
/// (without one, unless the cadence writes one then).
pub struct Interrupt<'a> {
    pub flag: Option<&'a AtomicBool>,
    pub max_steps: Option<u64>,
    pub taken: u64,
}

impl Observer for Interrupt<'_> {
    fn before_step(&mut self, sim: &mut Simulation) -> Result<Flow, RunError> {
        let asked = self.flag.is_some_and(|s| s.load(Ordering::Relaxed));
        if sim.any(asked) {
            return Ok(Flow::Stop { checkpoint: true });
        }
        if self.max_steps.is_some_and(|m| self.taken >= m) {
            return Ok(Flow::Stop { checkpoint: false });
        }
        Ok(Flow::Continue)
    }

    fn after_step(&mut self, _: &mut Simulation, _: &Taken) -> Result<Flow, RunError> {
        self.taken += 1;
        Ok(Flow::Continue)
    }
}
