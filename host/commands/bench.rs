//! Speed: particle-steps/s and neighbour interactions/s of the step, without output, on the
//! CPU or on a device.
use crate::scene::Scene;
use crate::scene::{ListChoice, Precision};
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
    /// Device memory per particle: on a GPU what the driver reports the engine took; on the
    /// CPU the most the engine's buffers held at once over the timed steps (the rayon launcher
    /// allocates the very buffers a GPU does).
    pub bytes_per_particle: Option<f64>,
    /// The timed steps' stages (wall seconds; on a GPU each ends when its work is done).
    pub stages: Vec<(&'static str, f64)>,
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
        let (resolved, _) = backend::select(device)?;
        let used0 = backend::device_memory_used(resolved);
        let (mut sim, note) = Simulation::of_scene(scene, device)?;
        let nb = mean_gas_neighbours(&sim.phys, &sim.state).map_err(|e| e.to_string())?;
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
        let before = sim.stepper.timers();
        let t0 = Instant::now();
        for _ in 0..steps {
            // No output times: the bench never lands.
            sim.step(f64::INFINITY).map_err(|e| e.to_string())?;
        }
        let seconds = t0.elapsed().as_secs_f64();
        let held = sim.local_engine().map(|e| e.device_bytes()).ok();
        let stages = sim
            .stepper
            .timers()
            .entries()
            .iter()
            .map(|&(name, t)| {
                let t0 = before
                    .entries()
                    .iter()
                    .find(|e| e.0 == name)
                    .map_or(0.0, |e| e.1);
                (name, t - t0)
            })
            .collect();
        Ok(BenchResult {
            case: case.to_string(),
            threads,
            gas,
            dust,
            mean_neighbours: nb,
            steps,
            seconds,
            device: sim.stepper.describe(),
            bytes_per_particle: match (used0, used1, held) {
                (Some(a), Some(b), _) => Some(b.saturating_sub(a) as f64 / n.max(1) as f64),
                (_, _, Some(b)) => Some(b as f64 / n.max(1) as f64),
                _ => None,
            },
            stages,
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
    // Variable h: each particle's own support 2h_a (the reference h says little where h
    // varies tenfold across a disc).
    if let (Some(_), Some(h)) = (phys.variable_h, &state.gas.h) {
        if h.len() == x.len() && !x.is_empty() {
            return Ok(mean_within_own_support(x, h));
        }
    }
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

/// The mean number of other particles within each particle's own support 2h_a (cells of the
/// median support).
fn mean_within_own_support(x: &[[f64; 3]], h: &[f64]) -> f64 {
    use rayon::prelude::*;
    let support = |a: usize| dustsph_device::kernel::SUPPORT * h[a];
    let mut s: Vec<f64> = (0..x.len()).map(support).collect();
    s.sort_by(f64::total_cmp);
    let grid = crate::analysis::support_grid::SupportGrid::new(x, s[s.len() / 2]);
    let total: usize = (0..x.len())
        .into_par_iter()
        .map(|a| {
            let r = support(a);
            let mut n = 0;
            grid.cells_within(x[a], r, |_, m, whole| {
                n += if whole {
                    m.len()
                } else {
                    (m.iter())
                        .filter(|&&b| {
                            let d = dustsph_device::sub(x[b], x[a]);
                            dustsph_device::dot(d, d) < r * r
                        })
                        .count()
                };
            });
            n - 1
        })
        .sum();
    total as f64 / x.len() as f64
}

// ---------------------------------------------------------------------------------------------
// The command line.

#[derive(clap::Args)]
pub struct BenchArgs {
    /// Steps to time per case
    #[arg(long, default_value_t = 10)]
    steps: u64,
    /// Thread counts to run, e.g. 1,2
    #[arg(long, value_delimiter = ',', default_values_t = vec![1usize, 2])]
    threads: Vec<usize>,
    /// Also the full seed ball (2 × 248 439 particles, ≈2000 neighbours; minutes per step count)
    #[arg(long)]
    full: bool,
    /// Particles per side of the uniform 3D box (per phase), e.g. 32,100,160,215 for
    /// 3.3e4 … 1e7
    #[arg(long, value_delimiter = ',', default_values_t = vec![32usize])]
    box_n: Vec<usize>,
    /// Where to run: cpu (default) or cuda
    #[arg(long, value_enum, default_value_t = DeviceChoice::Cpu)]
    device: DeviceChoice,
    /// The float type of the step (f64 or f32)
    #[arg(long, value_enum, default_value_t = Precision::F64)]
    precision: Precision,
    /// Per-particle neighbour lists (auto: on the CPU, off on CUDA; numerics.neighbour_list)
    #[arg(long, value_enum, default_value_t = ListChoice::Auto)]
    neighbour_list: ListChoice,
    /// Below each row, the step's stages and their share of the timed steps
    #[arg(long)]
    stages: bool,
}

pub fn execute(a: BenchArgs) -> u8 {
    let BenchArgs {
        steps,
        threads,
        full,
        box_n,
        device,
        precision,
        neighbour_list,
        stages,
    } = a;
    let bad = check_args(steps, &threads, &box_n);
    if let Some(m) = bad {
        eprintln!("error: {m}");
        return 2;
    }
    let cases = bench_cases(&box_n, full);
    println!(
        "{:<28} {:>7} {:>9} {:>9} {:>10} {:>6} {:>9} {:>14} {:>14} {:>9}",
        "case",
        "threads",
        "gas",
        "dust",
        "neighbours",
        "steps",
        "seconds",
        "particle-st/s",
        "interact./s",
        "B/part."
    );
    let mut where_ = String::new();
    for (name, file, sets) in cases {
        let name = name.as_str();
        let loaded = crate::scene::load_shipped(file, &sets)
            .and_then(|l| l.with_numerics(Some(precision), Some(neighbour_list)));
        let loaded = match loaded {
            Ok(l) => l,
            Err(e) => {
                eprintln!("error: {e}");
                return 2;
            }
        };
        for &t in &threads {
            match crate::commands::bench::bench(name, &loaded.scene, steps, t, device) {
                Ok(r) => {
                    print_row(&r, stages);
                    where_ = r.device;
                }
                Err(e) => {
                    eprintln!("error: {name}: {e}");
                    return 1;
                }
            }
        }
    }
    println!("device: {where_}");
    0
}

/// Why the arguments cannot be run, if they cannot: no steps, a thread count out of range, a
/// box under 2 particles per side.
fn check_args(steps: u64, threads: &[usize], box_n: &[usize]) -> Option<String> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if steps == 0 {
        Some("--steps must be at least 1".to_string())
    } else if let Some(t) = threads.iter().find(|&&t| t == 0 || t > 16 * cores) {
        Some(format!(
            "--threads {t}: each count must be between 1 and {} (16 × the {cores} cores here)",
            16 * cores
        ))
    } else {
        box_n
            .iter()
            .find(|&&n| n < 2)
            .map(|n| format!("--box-n {n}: at least 2 particles per side"))
    }
}

/// The benchmark's cases: (name, shipped scene, overrides) for each box size, the ball, and
/// with `full` the ball's seed.
fn bench_cases(box_n: &[usize], full: bool) -> Vec<(String, &'static str, Vec<String>)> {
    let mut cases: Vec<(String, &str, Vec<String>)> = box_n
        .iter()
        .map(|n| {
            (
                format!("box 3D n={n}, ~60 nb"),
                "configs/dustybox.toml",
                vec![
                    "scene.dim=3".to_string(),
                    format!("sph.n={n}"),
                    "sph.hfact=1.215".into(),
                    "dust.fractions=[{eps=0.5, t_stop=0.1}]".into(),
                    "dustybox.u_dust=[1.0]".into(),
                ],
            )
        })
        .collect();
    cases.push((
        "ball 3D, n=20, h=0.1".into(),
        "configs/dusty_ball.toml",
        vec!["sph.n=20".into()],
    ));
    if full {
        cases.push((
            "ball 3D seed (n=39, h=0.1)".into(),
            "configs/dusty_ball.toml",
            vec![],
        ));
    }
    cases
}

/// One result's row of the table (and below it, with `stages`, its stages' times).
fn print_row(r: &BenchResult, stages: bool) {
    println!(
        "{:<28} {:>7} {:>9} {:>9} {:>10.1} {:>6} {:>9.3} {:>14.3e} {:>14.3e} {:>9}",
        r.case,
        r.threads,
        r.gas,
        r.dust,
        r.mean_neighbours,
        r.steps,
        r.seconds,
        r.particle_steps_per_s(),
        r.interactions_per_s(),
        r.bytes_per_particle
            .map_or("-".into(), |b| format!("{b:.0}"))
    );
    if stages {
        for (stage, t) in &r.stages {
            println!("    {:>9.4} s {:>5.1} %  {stage}", t, 100.0 * t / r.seconds);
        }
    }
}
