//! Shared helpers: run a scene from `configs/` with overrides into a temporary directory.
#![allow(dead_code)]
pub mod ics;
use dustsph::analysis::norms::Norms;
use dustsph::particles::State;
use dustsph::sim::run::{run, RunOptions, Summary};
use std::path::PathBuf;

pub fn config(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("configs")
        .join(format!("{name}.toml"))
}

/// Run `configs/<name>.toml` with `--set` overrides; returns the summary and final state.
pub fn run_scene(name: &str, sets: &[&str]) -> (Summary, State) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let loaded = dustsph::scene::load(&config(name), &sets).unwrap_or_else(|e| panic!("{e}"));
    let dir = tempfile::tempdir().unwrap();
    let opts = RunOptions::quiet_on_cpu(dir.path().join("out"));
    run(&loaded, &opts).unwrap_or_else(|e| panic!("{name} {sets:?}: {e}"))
}

/// Final-time error norms of `field` against the first reference of the summary
/// (`which` = 0: the exact solution; 1: the discrete oracle where there is one).
pub fn final_error(s: &Summary, which: usize, field: &str) -> Norms {
    let at_end: Vec<_> = s.errors.iter().filter(|e| e.t == s.t_final).collect();
    *at_end[which]
        .get(field)
        .unwrap_or_else(|| panic!("no field {field}"))
}

/// Measured order of convergence from errors at resolutions differing by `ratio`.
pub fn order(e_coarse: f64, e_fine: f64, ratio: f64) -> f64 {
    (e_coarse / e_fine).ln() / ratio.ln()
}

/// The tests' one seeded generator (fastrand's wyrand): the same draws on every run.
pub struct Rng(fastrand::Rng);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(fastrand::Rng::with_seed(seed))
    }
    /// Uniform in [0, 1).
    pub fn next(&mut self) -> f64 {
        self.0.f64()
    }
    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
    /// Log-uniform in [lo, hi).
    pub fn log(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.next()).exp()
    }
}

/// [`run_scene`], then `check` on the output folder before it is removed.
pub fn run_scene_in(
    name: &str,
    sets: &[&str],
    check: impl FnOnce(&std::path::Path),
) -> (Summary, State) {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let loaded = dustsph::scene::load(&config(name), &sets).unwrap_or_else(|e| panic!("{e}"));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let opts = RunOptions::quiet_on_cpu(out.clone());
    let r = run(&loaded, &opts).unwrap_or_else(|e| panic!("{name} {sets:?}: {e}"));
    check(&out);
    r
}

/// Resume the run in `dir` from its checkpoint on the CPU and take it to its end.
pub fn resume_to_the_end(dir: &std::path::Path) -> (Summary, State) {
    let mut run =
        dustsph::sim::run::Run::resume(dir, false, dustsph::step::backend::DeviceChoice::Cpu)
            .unwrap_or_else(|e| panic!("resume {}: {e}", dir.display()));
    run.advance(None, None, None).unwrap();
    run.finish().unwrap()
}
