//! Per-stage wall-clock timers (reported in the run summary).
use std::sync::Arc;
use std::time::Instant;

/// Waits until the device has finished the work issued so far (a GPU's launches return at
/// once; without the wait a stage's time would be its launch cost, and the next wait would
/// carry its work).
pub type SyncHook = Arc<dyn Fn() + Send + Sync>;

#[derive(Clone, Default)]
pub struct Timers {
    entries: Vec<(&'static str, f64)>,
    sync: Option<SyncHook>,
}

impl std::fmt::Debug for Timers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Timers")
            .field("entries", &self.entries)
            .field("synchronised", &self.sync.is_some())
            .finish()
    }
}

impl Timers {
    /// Timers that wait for the device at the end of each stage.
    pub fn synchronised(sync: Option<SyncHook>) -> Timers {
        Timers {
            entries: Vec::new(),
            sync,
        }
    }

    /// Empty timers waiting for the same device as these.
    pub fn empty_like(&self) -> Timers {
        Timers::synchronised(self.sync.clone())
    }

    /// No stage timed yet (the device wait kept).
    pub fn clear(&mut self) {
        self.entries.clear();
    }

    /// Run `f`, adding its wall time to the stage `name` (on a GPU, until its work is done).
    pub fn time<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let t0 = Instant::now();
        let r = f();
        if let Some(sync) = &self.sync {
            sync();
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stage_ends_when_the_device_wait_returns_also_after_clear() {
        let wait = std::time::Duration::from_millis(30);
        let mut t = Timers::synchronised(Some(Arc::new(move || std::thread::sleep(wait))));
        t.time("stage", || ());
        assert!(t.entries()[0].1 >= 0.03, "{:?}", t.entries());
        t.clear();
        assert!(t.entries().is_empty());
        t.time("stage", || ());
        let mut e = t.empty_like();
        e.time("other", || ());
        assert!(t.entries()[0].1 >= 0.03 && e.entries()[0].1 >= 0.03);
        // Without a wait a stage is its own time only.
        let mut plain = Timers::default();
        plain.time("stage", || ());
        assert!(plain.entries()[0].1 < 0.03);
    }
}
