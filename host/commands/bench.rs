//! Speed: particle-steps/s and neighbour interactions/s of the step, without output, on the
//! CPU or on a device.
use crate::scene::Scene;
use crate::setup;
use crate::sim::Simulation;
use crate::step::backend::{self, DeviceChoice};
use crate::step::Physics;
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
    /// Where it ran.
    pub device: String,
    /// Device memory the engine allocated, per particle (GPU only).
    pub bytes_per_particle: Option<f64>,
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

/// Time `steps` steps of `scene` on `threads` CPU threads, or on `device` (set-up and the
/// first grid excluded; the GPU synchronises every step when it reads back the time-step
/// limits, so the wall time covers all device work).
pub fn bench(
    case: &str,
    scene: &Scene,
    steps: u64,
    threads: usize,
    device: DeviceChoice,
) -> Result<BenchResult, String> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| e.to_string())?;
    pool.install(|| {
        let su = setup::build(scene).map_err(|e| e.to_string())?;
        let phys = Physics::from_scene(scene, su.h, su.domain);
        let nb = mean_gas_neighbours(&phys, &su.state).map_err(|e| e.to_string())?;
        let (resolved, _) = backend::select(device)?;
        let used0 = backend::device_memory_used(resolved);
        let (mut sim, note) =
            Simulation::local(phys, &scene.time, su.state, device).map_err(|e| match e {
                backend::StartError::Device(m) => m,
                backend::StartError::Step(e) => e.to_string(),
            })?;
        if let Some(n) = note {
            eprintln!("dustsph: {n}");
        }
        let used1 = backend::device_memory_used(resolved);
        let state = &sim.state;
        let (gas, dust) = (
            state.gas.ph.len(),
            state.dust.iter().map(|d| d.len()).sum::<usize>(),
        );
        let n = gas + dust;
        let t0 = Instant::now();
        for _ in 0..steps {
            // No output times: the bench never lands.
            sim.step(f64::INFINITY).map_err(|e| e.to_string())?;
        }
        let seconds = t0.elapsed().as_secs_f64();
        Ok(BenchResult {
            case: case.to_string(),
            threads,
            gas,
            dust,
            mean_neighbours: nb,
            steps,
            seconds,
            device: sim.stepper.describe(),
            bytes_per_particle: match (used0, used1) {
                (Some(a), Some(b)) => Some(b.saturating_sub(a) as f64 / n.max(1) as f64),
                _ => None,
            },
        })
    })
}

/// Mean number of gas neighbours within the support 2h (self excluded) of a set-up, for the
/// table: the grid walk of the step, on the host.
pub fn mean_gas_neighbours(
    phys: &Physics,
    state: &crate::particles::State,
) -> Result<f64, crate::grid::GridError> {
    use crate::grid::{CellIndex, Grid};
    use rayon::prelude::*;
    let x = &state.gas.ph.x;
    let grid = Grid::build(&phys.domain, phys.cell_size, phys.support(), &[x])?;
    let (perm, idx) = CellIndex::sort(&grid, x);
    let xs: Vec<[f64; 3]> = perm.iter().map(|&p| x[p as usize]).collect();
    let total: usize = (0..xs.len())
        .into_par_iter()
        .map(|i| {
            let mut n = 0usize;
            dustsph_device::grid::for_neighbours(
                &grid.geom,
                &idx.lookup(),
                &xs,
                xs[i],
                |j, _, _| n += (j != i) as usize,
            );
            n
        })
        .sum();
    Ok(total as f64 / xs.len().max(1) as f64)
}
