//! `summary.json`: what a run did, how it was made, and its diagnostics (docs/outputs.md).
use super::output::{BallRecord, OutputRecord};
use super::{Diagnostics, ParticleCounts, RunError, Simulation};
use crate::analysis::{self, ExactErrors};
use crate::io;
use crate::scene::LoadedScene;
use serde::Serialize;
use std::path::Path;

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
    /// The largest |P(t) − P(0)| after any step, relative to the largest Σ m|v| of the run
    /// (M·c_s for a system at rest): `Diagnostics::momentum_drift`.
    pub momentum_drift_relative: f64,
    /// Kinetic (+ thermal for adiabatic gas). Drag without heating dissipates it.
    pub energy: Drift,
    /// Scenes with a point mass: the angular momentum about it, particles plus what the star
    /// accreted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angular_momentum: Option<AngularMomentum>,
    /// With an accretion radius: what the star took in (the masses above include it).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub star: Option<super::accretion::Accreted>,
}

#[derive(Debug, Clone, Serialize)]
pub struct AngularMomentum {
    /// The point about which it is taken (the star's position).
    pub about: [f64; 3],
    pub initial: [f64; 3],
    /// The particles' at the end plus what was accreted.
    pub r#final: [f64; 3],
    /// max over the steps of |L(t) + L_accreted − L(0)| / |L(0)|.
    pub drift_relative: f64,
}

/// Exact checks of the ball into vacuum (method.md §6.1).
#[derive(Debug, Clone, Serialize)]
pub struct BallReport {
    /// Undisturbed core at each output time: largest relative deviations from the initial state.
    pub core: Vec<analysis::ball::CoreCheck>,
    /// Largest |d²I/dt² − (2Σm|v|² + 6Σ_gas m p/ρ)| / rhs over the run (central differences).
    pub lagrange_jacobi_max_relative: Option<f64>,
    /// R_est = sqrt(5 Σm r² / (3 Σm)) of gas and of all dust at the end (the radius of a
    /// uniform ball with that moment of inertia).
    pub radius_estimate_gas: f64,
    pub radius_estimate_dust: f64,
    /// Axis vs diagonal profiles at the end.
    pub symmetry: Option<crate::commands::profile::Symmetry>,
    /// Profiles CSV and figures of the last snapshot.
    pub figures: Vec<String>,
}

/// One code unit of each quantity in cgs (G = 1).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct UnitsReport {
    pub length_cm: f64,
    pub mass_g: f64,
    pub time_s: f64,
    pub velocity_cm_per_s: f64,
    pub density_g_per_cm3: f64,
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
    /// The scene as run: the file with the overrides applied, as TOML (what the snapshots'
    /// `Scene` attribute holds).
    pub scene_effective: String,
    /// The resolved scene model as TOML ([`crate::scene::Scene::to_toml`]: every default
    /// applied, the same text as the snapshots' `Header/SceneModel`).
    pub scene_model: String,
    /// Initial conditions from a file: its path and SHA-256.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub initial_conditions: Option<crate::setup::file::IcSource>,
    /// `[units]`: cgs per code unit (absent: no unit system).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub units: Option<UnitsReport>,
    pub dimension: u32,
    pub backend: String,
    pub precision: &'static str,
    pub particles: ParticleCounts,
    pub h: f64,
    pub idic_cell: f64,
    pub position_update: String,
    /// `first_order` (the report's step) or `kdk` (leapfrog).
    pub integrator: &'static str,
    /// `standard` kernel gradient or `iad`.
    pub gradient: &'static str,
    /// `idic`, or `explicit` (the baseline: τ ≤ 0.9 t_s).
    pub drag_method: &'static str,
    /// Steps whose size the explicit drag's limit set (always 0 with IDIC).
    pub drag_limited_steps: u64,
    pub pipeline: Vec<&'static str>,
    pub steps: u64,
    /// The time the run started at (0, or the initial conditions' `Header/Time`).
    pub t_start: f64,
    pub t_final: f64,
    /// How the run ended: "finished" (at t_end), or why it stopped at t_final (interrupted,
    /// with or without a checkpoint; a failed step, with its message).
    pub ending: String,
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
    /// The step's stages, in wall seconds of this session (from the start, or the resume):
    /// on a GPU each stage ends when the device has finished its work.
    pub stage_seconds: Vec<(&'static str, f64)>,
    /// Wall seconds of this session outside the steps: the state brought back at output
    /// times, snapshots with their analysis, other observers, checkpoints.
    pub output_seconds: Vec<(&'static str, f64)>,
    /// Wall seconds of the snapshot writer over the whole run (each snapshot's files, error
    /// norms and the ball's core): on a thread of its own beside the steps (the default on
    /// one process), else within `output_seconds`.
    pub snapshot_writer_seconds: f64,
    /// Over MPI ranks: what each rank sent and how long it spent in the exchanges, in rank
    /// order, over the whole run (set-up, steps and outputs; docs/scaling.md).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rank_traffic: Option<Vec<crate::dist::Traffic>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ball: Option<BallReport>,
    /// At each snapshot after the first: the time bins individual steps would give its state,
    /// and the particle updates the global step took per update they would take
    /// (method.md §T; CFL steps only).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub time_bins: Vec<crate::analysis::bins::BinCensus>,
}

/// The conservation of a run from its diagnostics and the sums over its final state; masses count
/// what the star accreted, and the angular momentum (about `phys`'s point mass) is the
/// engine's reduction after the last step plus the star's record.
pub fn conservation(
    d: &Diagnostics,
    totals: &crate::sim::diagnostics::Totals,
    phys: &crate::step::Physics,
) -> Conservation {
    let a = &d.accreted;
    let taken = |k: usize| a.dust_mass.get(k).copied().unwrap_or(0.0);
    let l = dustsph_device::add(d.angular_momentum, a.angular_momentum);
    Conservation {
        mass_gas: Drift::new(d.mass0.0, totals.mass_gas + a.gas_mass),
        mass_dust: (totals.mass_dust.iter())
            .zip(&d.mass0.1)
            .enumerate()
            .map(|(k, (&p, &m))| Drift::new(m, p + taken(k)))
            .collect(),
        momentum_initial: d.momentum0,
        momentum_final: totals.momentum,
        momentum_drift_relative: d.momentum_drift(),
        energy: Drift::new(d.energy0, totals.energy),
        angular_momentum: phys.gravity.is_on().then(|| AngularMomentum {
            about: phys.gravity.pos,
            initial: d.angular_momentum0,
            r#final: l,
            drift_relative: d.angular_momentum_drift(),
        }),
        star: (phys.accretion_radius > 0.0).then(|| a.clone()),
    }
}

/// R_est = sqrt(5 Σm r² / (3 Σm)) of the phases.
fn radius_estimate((mr2, m): (f64, f64)) -> f64 {
    if m > 0.0 {
        (5.0 * mr2 / (3.0 * m)).sqrt()
    } else {
        0.0
    }
}

/// The run's summary from the simulation, its outputs and its ball checks, with the final
/// state (over ranks gathered on rank 0 where the outputs are, else this rank's time and step
/// alone; the sums are reduced over the ranks); for the ball the profiles and figures of the last
/// snapshot are made here, after the engines are dropped (the post-processing reads the whole
/// snapshot: with an engine alive beside it, the end of a run would be its peak of memory).
/// Written to `DIR/summary.json` by rank 0.
pub fn finish(
    mut sim: Simulation,
    loaded: &LoadedScene,
    dir: &Path,
    outputs: OutputRecord,
    ball: Option<BallRecord>,
    (wall, ending): (f64, String),
) -> Result<(Summary, crate::particles::State), RunError> {
    // Where the outputs are written by share, no rank gathers the whole state: the sums
    // are reduced over the ranks.
    if !sim.stepper.writes_by_share() {
        sim.sync().map_err(|e| RunError::Step(e.to_string()))?;
    }
    let totals = sim.stepper.totals(&sim.state);
    let scene = &loaded.scene;
    let root = sim.is_root();
    let phys = sim.stepper.phys().clone();
    let timers = sim.stepper.timers();
    let backend = sim.stepper.describe();
    let rank_traffic = sim.stepper.traffic();
    let Simulation {
        state,
        stepper,
        diagnostics: d,
        output_timers,
        ..
    } = sim;
    drop(stepper);
    let post = match (scene.ball(), outputs.snapshots.last()) {
        (Some(_), Some(last)) if root => Some(
            crate::commands::profile::post_process(&dir.join(last), 100)
                .map_err(|e| RunError::Io(e.to_string()))?,
        ),
        _ => None,
    };
    let ball = ball.map(|b| BallReport {
        symmetry: post.as_ref().and_then(|p| p.symmetry.clone()),
        figures: post.as_ref().map_or(Vec::new(), |p| {
            p.files
                .iter()
                .filter_map(|f| f.file_name().map(|n| n.to_string_lossy().into_owned()))
                .collect()
        }),
        lagrange_jacobi_max_relative: analysis::ball::lagrange_jacobi_deviation(&b.lagrange_jacobi),
        core: outputs.ball_core.clone(),
        radius_estimate_gas: radius_estimate(totals.moments[0]),
        radius_estimate_dust: radius_estimate(totals.moments[1]),
    });
    let summary = Summary {
        code: "dustsph",
        version: env!("CARGO_PKG_VERSION"),
        git: env!("DUSTSPH_GIT"),
        scene: scene.name.clone(),
        problem: scene.kind().name(),
        scene_file: loaded.path.display().to_string(),
        overrides: loaded.overrides.clone(),
        scene_effective: loaded.effective.clone(),
        scene_model: scene.to_toml(),
        initial_conditions: outputs.initial_conditions.clone(),
        units: scene.units.map(|u| UnitsReport {
            length_cm: u.length_cm,
            mass_g: u.mass_g,
            time_s: u.time_s(),
            velocity_cm_per_s: u.velocity_cm_s(),
            density_g_per_cm3: u.mass_g / u.length_cm.powi(3),
        }),
        dimension: scene.dim(),
        backend,
        precision: phys.precision.name(),
        particles: d.counts.clone(),
        h: phys.h,
        idic_cell: phys.cell_size,
        position_update: format!("{:?}", phys.position_update).to_lowercase(),
        integrator: match phys.integrator {
            crate::scene::Integrator::FirstOrder => "first_order",
            crate::scene::Integrator::Kdk => "kdk",
        },
        gradient: match phys.gradient {
            crate::scene::GradientMethod::Standard => "standard",
            crate::scene::GradientMethod::Iad => "iad",
        },
        // The stages that ran, in the order they first ran (from the timers).
        pipeline: timers.entries().iter().map(|e| e.0).collect(),
        drag_method: phys.drag.name(),
        drag_limited_steps: d.drag_limited_steps,
        steps: state.step,
        t_start: outputs.start_time,
        t_final: state.t,
        ending,
        dt_min: d.dt_min,
        dt_max: d.dt_max,
        cfl_max: d.cfl_max,
        wall_seconds: wall,
        particle_steps_per_second: d.counts.total() as f64 * state.step as f64 / wall.max(1e-12),
        conservation: conservation(&d, &totals, &phys),
        errors: outputs.errors,
        time_bins: outputs.time_bins,
        snapshots: outputs.snapshots,
        stage_seconds: timers.entries().to_vec(),
        output_seconds: output_timers.entries().to_vec(),
        snapshot_writer_seconds: outputs.writer_seconds,
        rank_traffic,
        ball,
    };
    if root {
        io::write_json_atomic(&dir.join("summary.json"), &summary)
            .map_err(|e| RunError::Io(e.to_string()))?;
    }
    Ok((summary, state))
}
