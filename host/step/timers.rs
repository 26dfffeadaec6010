//! Per-stage wall-clock timers (reported in the run summary).
use std::time::Instant;

#[derive(Debug, Clone, Default)]
pub struct Timers {
    entries: Vec<(&'static str, f64)>,
}

impl Timers {
    /// Run `f`, adding its wall time to the stage `name`.
    pub fn time<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let t0 = Instant::now();
        let r = f();
        self.add(name, t0.elapsed().as_secs_f64());
        r
    }

    /// Add `seconds` to the stage `name`.
    pub fn add(&mut self, name: &'static str, seconds: f64) {
        match self.entries.iter_mut().find(|(n, _)| *n == name) {
            Some(e) => e.1 += seconds,
            None => self.entries.push((name, seconds)),
        }
    }

    pub fn entries(&self) -> &[(&'static str, f64)] {
        &self.entries
    }
}
