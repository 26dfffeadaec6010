//! CPU speed: particle-steps/s and neighbour interactions/s of the step, without output.
use crate::engine::cpu::CpuEngine;
use crate::engine::{step_size, Physics};
use crate::scene::Scene;
use crate::setup;
use std::time::Instant;

#[derive(Debug, Clone)]
pub struct BenchResult {
    pub case: String,
    pub threads: usize,
    pub gas: usize,
    pub dust: usize,
    pub mean_neighbours: f64,
    pub steps: u64,
    pub seconds: f64,
}

impl BenchResult {
    /// All particles (gas + dust) advanced per second.
    pub fn particle_steps_per_s(&self) -> f64 {
        (self.gas + self.dust) as f64 * self.steps as f64 / self.seconds
    }
    /// Gas pair interactions per second: two neighbour passes (density, forces) per step.
    pub fn interactions_per_s(&self) -> f64 {
        2.0 * self.gas as f64 * self.mean_neighbours * self.steps as f64 / self.seconds
    }
}

/// Time `steps` steps of `scene` on `threads` threads (set-up and the first grid excluded).
pub fn bench(case: &str, scene: &Scene, steps: u64, threads: usize) -> Result<BenchResult, String> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| e.to_string())?;
    pool.install(|| {
        let su = setup::build(scene).map_err(|e| e.to_string())?;
        let mut state = su.state;
        let phys = Physics::from_scene(scene, su.h, su.domain);
        let mut eng = CpuEngine::new(phys, &mut state).map_err(|e| e.to_string())?;
        let nb = eng.mean_gas_neighbours(&state);
        let t0 = Instant::now();
        for _ in 0..steps {
            let f = eng.forces(&state);
            let (dt_cfl, dt_force) = eng.dt_limits(&f);
            let (dt, _) = step_size(&scene.time, dt_cfl, dt_force, eng.drag_dt_limit(&state));
            eng.advance(&mut state, &f, dt).map_err(|e| e.to_string())?;
        }
        Ok(BenchResult {
            case: case.to_string(),
            threads,
            gas: state.gas.ph.len(),
            dust: state.dust.iter().map(|d| d.len()).sum(),
            mean_neighbours: nb,
            steps,
            seconds: t0.elapsed().as_secs_f64(),
        })
    })
}
