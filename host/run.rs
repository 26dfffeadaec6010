//! The driver: scene → set-up → step loop → snapshots and summary.
use crate::analysis::{self, ExactErrors};
use crate::engine::cpu::CpuEngine;
use crate::engine::Physics;
use crate::io::{self, PhaseView, SnapshotView};
use crate::particles::State;
use crate::scene::LoadedScene;
use crate::setup;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out: PathBuf,
    pub force: bool,
    /// Print a line per snapshot.
    pub verbose: bool,
}

#[derive(Debug)]
pub enum RunError {
    /// Bad input (scene key at fault); nothing was written.
    Input(String),
    Io(String),
    Step(String),
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunError::Input(s) | RunError::Io(s) | RunError::Step(s) => f.write_str(s),
        }
    }
}
impl std::error::Error for RunError {}

#[derive(Debug, Clone, Serialize)]
pub struct ParticleCounts {
    pub gas: usize,
    pub gas_fixed: usize,
    pub dust: Vec<usize>,
    pub dust_fixed: Vec<usize>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Drift {
    pub initial: f64,
    pub r#final: f64,
    /// (final − initial)/|initial|.
    pub relative: f64,
}

impl Drift {
    fn new(a: f64, b: f64) -> Drift {
        Drift {
            initial: a,
            r#final: b,
            relative: if a != 0.0 { (b - a) / a.abs() } else { b - a },
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct Conservation {
    pub mass_gas: Drift,
    pub mass_dust: Vec<Drift>,
    pub momentum_initial: [f64; 3],
    pub momentum_final: [f64; 3],
    /// |P(t) − P(0)| / Σ m|v| (the largest Σ m|v| seen in the run).
    pub momentum_drift_relative: f64,
    /// Kinetic (+ thermal for adiabatic gas). Drag without heating dissipates it.
    pub energy: Drift,
}

#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub code: &'static str,
    pub version: &'static str,
    pub git: &'static str,
    pub scene: String,
    pub problem: &'static str,
    pub scene_file: String,
    pub overrides: Vec<String>,
    pub dimension: u32,
    pub backend: String,
    pub precision: &'static str,
    pub particles: ParticleCounts,
    pub h: f64,
    pub idic_cell: f64,
    pub position_update: String,
    pub pipeline: Vec<&'static str>,
    pub steps: u64,
    pub t_final: f64,
    pub dt_min: f64,
    pub dt_max: f64,
    /// Largest τ·v_sig/h of the run.
    pub cfl_max: f64,
    pub wall_seconds: f64,
    pub particle_steps_per_second: f64,
    pub conservation: Conservation,
    /// Error norms at every snapshot time (scenes with an exact solution).
    pub errors: Vec<ExactErrors>,
    pub snapshots: Vec<String>,
    pub stage_seconds: Vec<(&'static str, f64)>,
}

fn output_times(loaded: &LoadedScene) -> Vec<f64> {
    let t = &loaded.scene.time;
    let mut v = vec![0.0];
    if let Some(dt) = t.output_dt {
        let n = (t.t_end / dt + 1e-9).floor() as usize;
        v.extend((1..=n).map(|i| i as f64 * dt));
    }
    if let Some(ts) = &t.output_times {
        v.extend(ts.iter().copied());
    }
    v.push(t.t_end);
    v.sort_by(|a, b| a.total_cmp(b));
    v.dedup_by(|a, b| (*a - *b).abs() <= 1e-12 * t.t_end);
    v
}

fn write_snapshot(
    path: &Path,
    loaded: &LoadedScene,
    eng: &mut CpuEngine,
    state: &mut State,
    box_size: f64,
) -> Result<(), RunError> {
    eng.refresh_dust_density(state);
    let t_stop = eng.dust_stopping_times(state);
    let h = eng.phys.h;
    let g = &state.gas;
    // The snapshot contract has InternalEnergy for every gas; isothermal gas solves no energy
    // equation, so it gets p/ρ (= c_s²), made here for output only.
    let e_iso: Option<Vec<f64>> =
        g.e.is_none()
            .then(|| g.p.iter().zip(&g.ph.rho).map(|(p, r)| p / r).collect());
    let view = SnapshotView {
        time: state.t,
        dim: loaded.scene.dim(),
        box_size,
        scene_text: &loaded.text,
        gas: Some(PhaseView {
            x: &g.ph.x,
            v: &g.ph.v,
            m: &g.ph.m,
            rho: &g.ph.rho,
            h,
            id: &g.ph.id,
            e: g.e.as_deref().or(e_iso.as_deref()),
            p: Some(&g.p),
            t_stop: None,
        }),
        dust: state
            .dust
            .iter()
            .zip(&t_stop)
            .map(|(d, ts)| PhaseView {
                x: &d.x,
                v: &d.v,
                m: &d.m,
                rho: &d.rho,
                h,
                id: &d.id,
                e: None,
                p: None,
                t_stop: Some(ts),
            })
            .collect(),
    };
    io::write_snapshot(path, &view).map_err(|e| RunError::Io(e.to_string()))
}

/// Run a scene to its end time; returns the summary and the final state.
pub fn run(loaded: &LoadedScene, opts: &RunOptions) -> Result<(Summary, State), RunError> {
    let scene = &loaded.scene;
    let file = loaded.path.display().to_string();
    let su = setup::build(scene).map_err(|e| RunError::Input(format!("{file}: {e}")))?;
    // All input is valid: only now touch the output directory.
    let out =
        io::prepare_output_dir(&opts.out, opts.force).map_err(|e| RunError::Io(e.to_string()))?;
    let wall0 = Instant::now();
    let mut state = su.state;
    let phys = Physics::from_scene(scene, su.h, su.domain);
    let idic_cell = phys.cell_size;
    let mut eng = CpuEngine::new(phys, &mut state).map_err(|e| RunError::Step(e.to_string()))?;
    let counts = ParticleCounts {
        gas: state.gas.ph.len(),
        gas_fixed: (0..state.gas.ph.len())
            .filter(|&i| state.gas.ph.is_fixed(i))
            .count(),
        dust: state.dust.iter().map(|d| d.len()).collect(),
        dust_fixed: state
            .dust
            .iter()
            .map(|d| (0..d.len()).filter(|&i| d.is_fixed(i)).count())
            .collect(),
    };
    let mass0 = (
        state.gas.ph.total_mass(),
        state
            .dust
            .iter()
            .map(|d| d.total_mass())
            .collect::<Vec<_>>(),
    );
    let p0 = state.total_momentum();
    let e0 = state.total_energy();
    let mut pscale = state.momentum_scale();
    let fixed_dt = scene.time.dt;
    let mut errors = Vec::new();
    let mut snaps = Vec::new();
    let times = output_times(loaded);
    let mut next = 0usize;
    let (mut dt_min, mut dt_max, mut cfl_max) = (f64::INFINITY, 0.0f64, 0.0f64);
    let write = |eng: &mut CpuEngine,
                 state: &mut State,
                 errors: &mut Vec<ExactErrors>,
                 snaps: &mut Vec<String>|
     -> Result<(), RunError> {
        let name = io::snapshot_name(snaps.len());
        write_snapshot(&out.join(&name), loaded, eng, state, su.box_size)?;
        errors.extend(analysis::exact_errors(scene, state, fixed_dt));
        if opts.verbose {
            eprintln!("  t = {:.6}  step {:>7}  → {}", state.t, state.step, name);
        }
        snaps.push(name);
        Ok(())
    };
    write(&mut eng, &mut state, &mut errors, &mut snaps)?;
    next += 1;
    let t_end = scene.time.t_end;
    let h = eng.phys.h;
    while next < times.len() {
        let forces = {
            let mut timers = std::mem::take(&mut eng.timers);
            let f = timers.time("gas forces", || eng.forces(&state));
            eng.timers = timers;
            f
        };
        let (dt_cfl, dt_force) = eng.dt_limits(&forces);
        let mut dt = match (fixed_dt, scene.time.cfl) {
            (Some(dt), _) => dt,
            (None, Some(c)) => c * dt_cfl.min(dt_force),
            _ => unreachable!("validated"),
        };
        if !(dt.is_finite() && dt > 0.0) {
            return Err(RunError::Step(format!(
                "step {}: time step is {dt} (no signal speed or force to set it); give time.dt",
                state.step
            )));
        }
        let t_out = times[next];
        let landing = state.t + dt >= t_out - 1e-9 * dt;
        if landing {
            dt = t_out - state.t;
        }
        dt_min = dt_min.min(dt);
        dt_max = dt_max.max(dt);
        cfl_max = cfl_max.max(dt * forces.vsig_max / h);
        eng.advance(&mut state, &forces, dt)
            .map_err(|e| RunError::Step(e.to_string()))?;
        pscale = pscale.max(state.momentum_scale());
        if landing {
            state.t = t_out;
            write(&mut eng, &mut state, &mut errors, &mut snaps)?;
            next += 1;
        }
    }
    debug_assert!((state.t - t_end).abs() <= 1e-9 * t_end);
    let wall = wall0.elapsed().as_secs_f64();
    let p1 = state.total_momentum();
    let dp = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2) + (p1[2] - p0[2]).powi(2)).sqrt();
    let n_part = state.gas.ph.len() + state.dust.iter().map(|d| d.len()).sum::<usize>();
    let summary = Summary {
        code: "dustsph",
        version: env!("CARGO_PKG_VERSION"),
        git: env!("DUSTSPH_GIT"),
        scene: scene.scene.name.clone(),
        problem: scene.scene.problem.name(),
        scene_file: file,
        overrides: loaded.overrides.clone(),
        dimension: scene.dim(),
        backend: format!("cpu (rayon, {} threads)", rayon::current_num_threads()),
        precision: "f64",
        particles: counts,
        h,
        idic_cell,
        position_update: format!("{:?}", eng.phys.position_update).to_lowercase(),
        pipeline: eng.pipe.stages(),
        steps: state.step,
        t_final: state.t,
        dt_min,
        dt_max,
        cfl_max,
        wall_seconds: wall,
        particle_steps_per_second: n_part as f64 * state.step as f64 / wall.max(1e-12),
        conservation: Conservation {
            mass_gas: Drift::new(mass0.0, state.gas.ph.total_mass()),
            mass_dust: state
                .dust
                .iter()
                .zip(&mass0.1)
                .map(|(d, &m)| Drift::new(m, d.total_mass()))
                .collect(),
            momentum_initial: p0,
            momentum_final: p1,
            momentum_drift_relative: if pscale > 0.0 { dp / pscale } else { dp },
            energy: Drift::new(e0, state.total_energy()),
        },
        errors,
        snapshots: snaps,
        stage_seconds: eng.timers.entries().to_vec(),
    };
    io::write_json_atomic(&out.join("summary.json"), &summary)
        .map_err(|e| RunError::Io(e.to_string()))?;
    Ok((summary, state))
}
