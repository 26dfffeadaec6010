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
        let dt = t0.elapsed().as_secs_f64();
        match self.entries.iter_mut().find(|(n, _)| *n == name) {
            Some(e) => e.1 += dt,
            None => self.entries.push((name, dt)),
        }
        r
    }

    pub fn entries(&self) -> &[(&'static str, f64)] {
        &self.entries
    }
}
