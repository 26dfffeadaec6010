//! Observers of a run's course: the progress bar, the checkpoint cadence, and the stops (Ctrl-C,
//! a step budget).
use super::{Flow, Observer, RunError, Simulation};
use crate::step::timestep::Taken;
use std::sync::atomic::{AtomicBool, Ordering};

/// A progress bar in units of 1e-4 of t_end (hidden unless asked for and stderr is a
/// terminal: indicatif checks the latter).
pub struct ProgressBar {
    bar: indicatif::ProgressBar,
    t_end: f64,
}

impl ProgressBar {
    pub fn new(visible: bool, t_end: f64) -> ProgressBar {
        let bar = if visible {
            indicatif::ProgressBar::new(10_000)
        } else {
            indicatif::ProgressBar::hidden()
        };
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bar:30} {percent:>3}% {msg}  ETA {eta}")
                .expect("a valid template"),
        );
        ProgressBar { bar, t_end }
    }

    /// Run `f` with the bar out of the way (a line printed while it shows).
    pub fn suspend<T>(&self, f: impl FnOnce() -> T) -> T {
        self.bar.suspend(f)
    }
}

impl Drop for ProgressBar {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}

impl Observer for ProgressBar {
    fn after_step(&mut self, sim: &mut Simulation, taken: &Taken) -> Result<Flow, RunError> {
        self.bar
            .set_position((sim.state.t / self.t_end * 1e4) as u64);
        self.bar.set_message(format!(
            "step {} t = {:.5} dt = {:.3e}",
            sim.state.step, sim.state.t, taken.plan.dt
        ));
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
