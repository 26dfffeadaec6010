//! The driver: scene → set-up → step loop → snapshots and summary.
use crate::analysis::{self, ExactErrors};
use crate::io::{self, PhaseView, SnapshotView};
use crate::particles::State;
use crate::scene::LoadedScene;
use crate::setup;
use crate::step::backend::{Backend, DeviceChoice, StartError};
use crate::step::timestep::StepPlanner;
use crate::step::Physics;
use crate::step::StepError;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A run over MPI ranks: this rank's share and its stepper (`dist::ranks`); without the
/// `mpi` feature there is none.
#[cfg(feature = "mpi")]
pub type Ranks = crate::dist::ranks::RankStepper;
#[cfg(not(feature = "mpi"))]
pub enum Ranks {}

#[cfg(not(feature = "mpi"))]
impl Ranks {
    fn is_root(&self) -> bool {
        match *self {}
    }
    fn any(&self, _: bool) -> bool {
        match *self {}
    }
    fn describe(&self) -> String {
        match *self {}
    }
    fn gather(&self, _: f64, _: u64) -> Result<Option<State>, String> {
        match *self {}
    }
    fn step(
        &mut self,
        _: &StepPlanner,
        _: f64,
        _: u64,
        _: f64,
    ) -> Result<(crate::step::timestep::Plan, f64, f64), String> {
        match *self {}
    }
}

/// How a run over ranks splits its state: this rank's share, stepped with the run's halo depth.
#[cfg(feature = "mpi")]
fn over_ranks(
    world: crate::dist::comm::World,
    device: DeviceChoice,
    verbose: bool,
) -> impl FnOnce(&Physics, &State, Result<(), RunError>) -> Result<Option<Ranks>, RunError> {
    move |phys, state, verdict| {
        // Rank 0 alone builds the engine on the whole scene and checks the first step: its
        // verdict reaches every rank before any of them goes on (none waits on another).
        if world.any(verdict.is_err()) {
            // Rank 0 says why before any rank leaves: mpirun stops the job at the first rank
            // that exits non-zero, which could otherwise cut rank 0 off before it speaks (the
            // flake of tests/mpi.rs `a_first_step_refused_on_rank_0…`: rank 1's exit killed
            // rank 0 before its message was written).
            if let Err(e) = &verdict {
                eprintln!("error: {e}");
            }
            world.any(false);
            return Err(RunError::InputReported);
        }
        crate::dist::ranks::RankStepper::new(
            world,
            phys.clone(),
            state,
            crate::dist::ranks::depth_for(phys),
            device,
            verbose,
        )
        .map(Some)
        .map_err(RunError::Input)
    }
}

/// This process's rank in a run over MPI ranks.
#[cfg(feature = "mpi")]
fn this_rank() -> Option<u32> {
    Some(crate::dist::launched().map_or(0, |(r, _)| r))
}

#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out: PathBuf,
    pub force: bool,
    /// Print a line per snapshot.
    pub verbose: bool,
    /// Where to step (`--device`).
    pub device: DeviceChoice,
}

#[derive(Debug, Clone)]
pub enum RunError {
    /// Bad input (scene key at fault); nothing was written.
    Input(String),
    /// Bad input already reported (over MPI ranks rank 0 says it, once, before any rank
    /// leaves); exit 2 without a further message.
    InputReported,
    Io(String),
    Step(String),
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunError::Input(s) | RunError::Io(s) | RunError::Step(s) => f.write_str(s),
            RunError::InputReported => f.write_str("bad input (reported above)"),
        }
    }
}
impl std::error::Error for RunError {}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
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
    /// The scene as run: the file with the overrides applied, as TOML (what the snapshots'
    /// `Scene` attribute holds).
    pub scene_effective: String,
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
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ball: Option<BallReport>,
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
    eng: &mut Backend,
    state: &mut State,
) -> Result<(), RunError> {
    let step_err = |e: crate::step::StepError| RunError::Step(e.to_string());
    eng.refresh_dust_density(state).map_err(step_err)?;
    let t_stop = eng.dust_stopping_times(state).map_err(step_err)?;
    let phys = eng.phys();
    let h = phys.h;
    let g = &state.gas;
    // Variable h: the gas's own h; the dust's from its density (h = hfact (m/ρ)^(1/d), the
    // relation its solve satisfies); the box margin is the largest support.
    let dim = loaded.scene.dim();
    let dust_h: Vec<Option<Vec<f64>>> = state
        .dust
        .iter()
        .map(|d| {
            phys.variable_h.map(|hf| {
                d.m.iter()
                    .zip(&d.rho)
                    .map(|(&m, &r)| dustsph_device::kernel::h_of_density(m, r, hf, dim, h))
                    .collect()
            })
        })
        .collect();
    let gas_h = g.h.as_deref().filter(|_| phys.variable_h.is_some());
    let h_max = gas_h
        .iter()
        .flat_map(|v| v.iter())
        .chain(dust_h.iter().flatten().flatten())
        .fold(h, |a, &b| if b.is_finite() { a.max(b) } else { a });
    // The snapshot contract has InternalEnergy for every gas; isothermal gas solves no energy
    // equation, so it gets p/ρ (= c_s²), made here for output only.
    let e_iso: Option<Vec<f64>> =
        g.e.is_none()
            .then(|| g.p.iter().zip(&g.ph.rho).map(|(p, r)| p / r).collect());
    let scene_file = loaded.path.display().to_string();
    let view = SnapshotView {
        time: state.t,
        dim,
        periodic: phys.domain.periodic,
        pad: dustsph_device::kernel::SUPPORT * h_max,
        scene_text: &loaded.effective,
        source: io::SceneSource {
            file: &scene_file,
            text: &loaded.text,
            overrides: &loaded.overrides,
        },
        gas: Some(PhaseView {
            x: &g.ph.x,
            v: &g.ph.v,
            m: &g.ph.m,
            rho: &g.ph.rho,
            h,
            h_each: gas_h,
            id: &g.ph.id,
            e: g.e.as_deref().or(e_iso.as_deref()),
            p: Some(&g.p),
            t_stop: None,
        }),
        dust: state
            .dust
            .iter()
            .zip(&t_stop)
            .zip(&dust_h)
            .map(|((d, ts), dh)| PhaseView {
                x: &d.x,
                v: &d.v,
                m: &d.m,
                rho: &d.rho,
                h,
                h_each: dh.as_deref(),
                id: &d.id,
                e: None,
                p: None,
                t_stop: Some(ts),
            })
            .collect(),
    };
    io::write_snapshot(path, &view).map_err(|e| RunError::Io(e.to_string()))?;
    // ParaView sidecar: gas and dust as two point sets.
    io::write_xdmf_view(path, &view).map_err(|e| RunError::Io(e.to_string()))
}

/// Share of dust particles without gas in their IDIC cell above which a run with the
/// nearest-cell coupling warns (their drag is off).
const UNCOUPLED_WARNING: f64 = 0.05;
/// The driver's progress: everything besides the particles that a resumed run must know.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct Progress {
    next_output: usize,
    snapshots: Vec<String>,
    errors: Vec<ExactErrors>,
    /// +∞ before the first step (a checkpoint on an interrupt at step 0): JSON has no ∞.
    #[serde(with = "infinite_as_null")]
    dt_min: f64,
    dt_max: f64,
    cfl_max: f64,
    pscale: f64,
    mass0: (f64, Vec<f64>),
    p0: [f64; 3],
    e0: f64,
    /// Wall seconds of earlier sessions of this run.
    wall_before: f64,
    counts: ParticleCounts,
    /// Ball only: (t, I, 2Σm|v|² + 2dΣm p/ρ) after every step, and the core checks per output.
    lagrange_jacobi: Vec<(f64, f64, f64)>,
    core: Vec<analysis::ball::CoreCheck>,
    /// Time of each snapshot (for the XDMF time series).
    snapshot_times: Vec<f64>,
    /// Steps whose size the explicit drag's limit set.
    #[serde(default)]
    drag_limited_steps: u64,
}

/// An f64 that may be +∞ in JSON: written as null, read back as +∞ (serde_json writes every
/// non-finite number as null, which it cannot read as an f64).
mod infinite_as_null {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_none()
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
    }

    #[cfg(test)]
    mod tests {
        #[derive(serde::Serialize, serde::Deserialize)]
        struct T {
            #[serde(with = "super")]
            v: f64,
        }

        #[test]
        fn infinity_round_trips_through_json() {
            for v in [f64::INFINITY, 0.25, 1e-300] {
                let text = serde_json::to_string(&T { v }).unwrap();
                let back: T = serde_json::from_str(&text).unwrap();
                assert_eq!(back.v, v, "{text}");
            }
        }

        /// A checkpoint's progress written before the first step (dt_min = +∞) reads back.
        #[test]
        fn progress_before_the_first_step_reads_back() {
            let p = super::super::Progress {
                dt_min: f64::INFINITY,
                ..Default::default()
            };
            let text = serde_json::to_string(&p).unwrap();
            let back: super::super::Progress = serde_json::from_str(&text).unwrap();
            assert_eq!(back.dt_min, f64::INFINITY);
        }
    }
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

/// Why a run loop returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    Finished,
    /// Interrupted (Ctrl-C): a checkpoint was written; `dustsph resume DIR` continues.
    Interrupted,
}

/// A run in progress: scene, engine, state and the driver's bookkeeping.
pub struct Runner {
    loaded: LoadedScene,
    out: PathBuf,
    eng: Backend,
    pub state: State,
    times: Vec<f64>,
    prog: Progress,
    wall0: Instant,
    verbose: bool,
    /// Over MPI ranks (rank 0 writes; its `state` is the gathered whole after a sync).
    ranks: Option<Ranks>,
    /// Rank 0 over ranks: `eng` no longer matches the gathered `state` (rebuilt before output).
    eng_stale: bool,
}

impl Runner {
    /// Validate, set up, and write the t = 0 snapshot.
    pub fn start(loaded: &LoadedScene, opts: &RunOptions) -> Result<Runner, RunError> {
        Self::start_on(loaded, opts, None, |_, _, v| v.map(|_| None))
    }

    /// [`Runner::start`] as one of several MPI ranks: every rank sets up the whole scene, keeps
    /// its share and steps it ([`crate::dist::ranks`]); rank 0 writes every output.
    #[cfg(feature = "mpi")]
    pub fn start_over_ranks(
        loaded: &LoadedScene,
        opts: &RunOptions,
        world: crate::dist::comm::World,
    ) -> Result<Runner, RunError> {
        // The set-up (and rank 0's outputs) on the CPU; the steps on each rank's device.
        let setup = RunOptions {
            device: DeviceChoice::Cpu,
            ..opts.clone()
        };
        Self::start_on(
            loaded,
            &setup,
            this_rank(),
            over_ranks(world, opts.device, opts.verbose),
        )
    }

    /// `rank`: this process's rank over MPI ranks (`None`: one process). Only one process or
    /// rank 0 builds an engine on the whole scene (its first step is checked there, and its
    /// first snapshot written from it); the other ranks set up the scene and keep their share.
    fn start_on(
        loaded: &LoadedScene,
        opts: &RunOptions,
        rank: Option<u32>,
        ranks: impl FnOnce(&Physics, &State, Result<(), RunError>) -> Result<Option<Ranks>, RunError>,
    ) -> Result<Runner, RunError> {
        let whole = rank.is_none_or(|r| r == 0);
        let (phys, mut state) = Self::prepare(loaded, None, whole)?;
        let mut built = None;
        let verdict = if whole {
            Self::start_engine(loaded, phys.clone(), &mut state, opts.device, opts.verbose)
                .and_then(|mut eng| {
                    let checked = Self::check_first_step(loaded, &mut eng, &state);
                    built = Some(eng);
                    checked
                })
        } else {
            Ok(())
        };
        if rank.is_none() {
            verdict.clone()?;
        }
        let ranks = ranks(&phys, &state, verdict)?;
        let mut eng = match built {
            Some(e) => e,
            None => Self::idle_engine(phys, &state)?,
        };
        let root = ranks.as_ref().is_none_or(|r| r.is_root());
        // All input is valid: only now touch the output directory (rank 0's).
        let out = if root {
            io::prepare_output_dir(&opts.out, opts.force).map_err(|e| match e {
                // A directory the user must empty or name differently is input, not a failure.
                io::IoError::DirNotEmpty { .. } | io::IoError::Invalid { .. } => {
                    RunError::Input(e.to_string())
                }
                e => RunError::Io(e.to_string()),
            })
        } else {
            Ok(opts.out.clone())
        };
        if let Some(r) = &ranks {
            if r.any(out.is_err()) {
                return Err(out.err().unwrap_or_else(|| {
                    RunError::Io("rank 0 could not prepare the output directory".into())
                }));
            }
        }
        let out = out?;
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
        let prog = Progress {
            next_output: 0,
            snapshots: Vec::new(),
            errors: Vec::new(),
            dt_min: f64::INFINITY,
            dt_max: 0.0,
            cfl_max: 0.0,
            pscale: state.momentum_scale(),
            mass0: (
                state.gas.ph.total_mass(),
                state.dust.iter().map(|d| d.total_mass()).collect(),
            ),
            p0: state.total_momentum(),
            e0: state.total_energy(),
            wall_before: 0.0,
            counts,
            lagrange_jacobi: Vec::new(),
            core: Vec::new(),
            snapshot_times: Vec::new(),
            drag_limited_steps: 0,
        };
        let mut r = Runner {
            times: output_times(loaded),
            loaded: loaded.clone(),
            out,
            prog,
            wall0: Instant::now(),
            verbose: opts.verbose && root,
            ranks,
            eng_stale: false,
            eng: {
                *eng.timers_mut() = Default::default();
                eng
            },
            state: {
                state.t = 0.0;
                state
            },
        };
        r.record_ball_step();
        r.write_output()?;
        r.shed_whole_state();
        Ok(r)
    }

    /// Over ranks, only rank 0 keeps the whole state (for its outputs); every other rank steps
    /// its share alone (its engine is idle) and drops the set-up's whole state, which it would
    /// otherwise hold, unused, for the whole run.
    fn shed_whole_state(&mut self) {
        if self.ranks.is_some() && !self.is_root() {
            self.state = self.state.shape();
        }
    }

    /// Continue a run from `DIR/checkpoint.h5`.
    pub fn resume(dir: &Path, verbose: bool, device: DeviceChoice) -> Result<Runner, RunError> {
        Self::resume_on(dir, verbose, device, None, |_, _, v| v.map(|_| None))
    }

    /// [`Runner::resume`] as one of several MPI ranks: every rank reads the checkpoint (one
    /// written by any number of ranks, or by one process) and steps its share from there.
    #[cfg(feature = "mpi")]
    pub fn resume_over_ranks(
        dir: &Path,
        verbose: bool,
        device: DeviceChoice,
        world: crate::dist::comm::World,
    ) -> Result<Runner, RunError> {
        let steps_on = over_ranks(world, device, verbose);
        Self::resume_on(dir, verbose, DeviceChoice::Cpu, this_rank(), steps_on)
    }

    fn resume_on(
        dir: &Path,
        verbose: bool,
        device: DeviceChoice,
        rank: Option<u32>,
        ranks: impl FnOnce(&Physics, &State, Result<(), RunError>) -> Result<Option<Ranks>, RunError>,
    ) -> Result<Runner, RunError> {
        let ck = dir.join(io::checkpoint::CHECKPOINT_NAME);
        // Everything resume checks is input: on a mismatch it exits 2 and changes nothing.
        let (state, meta) =
            io::checkpoint::read_checkpoint(&ck).map_err(|e| RunError::Input(e.to_string()))?;
        let bad = |e: String| RunError::Input(format!("{}: {e}", ck.display()));
        let overrides: Vec<String> =
            serde_json::from_str(&meta.overrides_json).map_err(|e| bad(e.to_string()))?;
        let file = PathBuf::from(&meta.scene_file);
        let loaded = LoadedScene::from_text(&meta.scene_text, &file, &overrides)
            .map_err(|e| bad(e.to_string()))?;
        let prog: Progress =
            serde_json::from_str(&meta.progress_json).map_err(|e| bad(e.to_string()))?;
        verify_resume(dir, &state, &loaded, &prog).map_err(bad)?;
        let whole = rank.is_none_or(|r| r == 0);
        let (phys, mut state) = Self::prepare(&loaded, Some(state), whole)?;
        let built = if whole {
            Self::start_engine(&loaded, phys.clone(), &mut state, device, verbose).map(Some)
        } else {
            Ok(None)
        };
        let verdict = built.as_ref().map(|_| ()).map_err(Clone::clone);
        if rank.is_none() {
            verdict.clone()?;
        }
        let ranks = ranks(&phys, &state, verdict)?;
        let eng = match built? {
            Some(e) => e,
            None => Self::idle_engine(phys, &state)?,
        };
        let root = ranks.as_ref().is_none_or(|r| r.is_root());
        let mut r = Runner {
            times: output_times(&loaded),
            loaded,
            out: dir.to_path_buf(),
            eng,
            state,
            prog,
            wall0: Instant::now(),
            verbose: verbose && root,
            ranks,
            eng_stale: false,
        };
        r.shed_whole_state();
        Ok(r)
    }

    /// The first step's size, before anything is written (with --force the old run's files
    /// would already be gone): a CFL step that has collapsed at t = 0, or a t_end beyond the
    /// step count allowed, is bad input, not a run to start. The forces are computed again by
    /// the first step (the same ones: the engine's forces are a pure function of its state).
    /// Warnings on the start are printed here.
    fn check_first_step(
        loaded: &LoadedScene,
        eng: &mut Backend,
        state: &State,
    ) -> Result<(), RunError> {
        if let Some(&t1) = output_times(loaded).get(1) {
            let drv = StepPlanner::new(&loaded.scene.time, eng.phys().h);
            let forces = eng.forces(state);
            let first = match &forces {
                Ok(f) => drv.plan(eng, state, f, t1).map(|_| f),
                Err(e) => Err(StepError::Blowup(e.to_string())),
            };
            match first {
                Err(e) => {
                    return Err(RunError::Input(format!(
                        "{}: the first step cannot be taken: {e}",
                        loaded.path.display()
                    )))
                }
                Ok(f) => {
                    for w in start_warnings(loaded, eng.phys(), state, f) {
                        eprintln!("dustsph: warning: {w}");
                    }
                }
            }
        }
        Ok(())
    }

    /// The scene's physics and its initial state (or a given, checkpointed one); `warn`: say
    /// what the set-up found worth a warning (one process, or rank 0 only).
    fn prepare(
        loaded: &LoadedScene,
        state: Option<State>,
        warn: bool,
    ) -> Result<(Physics, State), RunError> {
        let file = loaded.path.display().to_string();
        let su =
            setup::build(&loaded.scene).map_err(|e| RunError::Input(format!("{file}: {e}")))?;
        let state = state.unwrap_or(su.state);
        let phys = Physics::from_scene(&loaded.scene, su.h, su.domain);
        if warn && phys.coupling == crate::scene::Coupling::Cell {
            if let Some(f) = crate::step::dust_without_gas_in_cell(&phys, &state) {
                if f > UNCOUPLED_WARNING {
                    eprintln!(
                        "dustsph: warning: {:.0}% of the dust particles share no IDIC cell with a gas \
                         particle, so the nearest-cell coupling (idic.coupling = \"cell\") leaves \
                         their drag off; idic.coupling = \"kernel\" couples them wherever they sit \
                         (docs/method.md §K)",
                        100.0 * f
                    );
                }
            }
        }
        Ok((phys, state))
    }

    /// The engine on a scene's state (sorted in place). Sorting an already sorted state is the
    /// identity and densities are recomputed by the same code in the same order, so a resumed
    /// run continues bit for bit.
    fn start_engine(
        loaded: &LoadedScene,
        phys: Physics,
        state: &mut State,
        device: DeviceChoice,
        verbose: bool,
    ) -> Result<Backend, RunError> {
        let file = loaded.path.display().to_string();
        // The initial grid and densities come from the scene alone: a failure here is bad input.
        let (eng, note) = Backend::start(device, phys, state).map_err(|e| match e {
            StartError::Device(m) => RunError::Input(m),
            StartError::Step(StepError::Unsupported(m)) => RunError::Input(format!("{file}: {m}")),
            StartError::Step(e) => RunError::Input(format!(
                "{file}: the initial state cannot be set up (check idic.cell, sph.h/hfact, sph.n): {e}"
            )),
        })?;
        if let (Some(n), true) = (note, verbose) {
            eprintln!("dustsph: {n}");
        }
        Ok(eng)
    }

    /// A rank other than 0: an engine on no particles (it steps its share through its
    /// `RankStepper`; this one only answers for the physics).
    fn idle_engine(phys: Physics, state: &State) -> Result<Backend, RunError> {
        Backend::new(DeviceChoice::Cpu, phys, &mut state.shape())
            .map_err(|e| RunError::Step(e.to_string()))
    }

    pub fn out_dir(&self) -> &Path {
        &self.out
    }

    fn write_output(&mut self) -> Result<(), RunError> {
        let name = io::snapshot_name(self.prog.snapshots.len());
        let written = self.write_files(&name);
        if let Some(r) = &self.ranks {
            // Every rank goes on, or none (no rank may wait on one that stopped).
            if r.any(written.is_err()) {
                written.clone()?;
                return Err(RunError::Io("rank 0 could not write the output".into()));
            }
        }
        written?;
        self.prog.snapshots.push(name);
        self.prog.snapshot_times.push(self.state.t);
        self.prog.next_output += 1;
        Ok(())
    }

    /// The snapshot, its errors against the exact solution and the XDMF series (rank 0 only
    /// over ranks).
    fn write_files(&mut self, name: &str) -> Result<(), RunError> {
        if !self.is_root() {
            return Ok(());
        }
        self.fresh_engine()?;
        write_snapshot(
            &self.out.join(name),
            &self.loaded,
            &mut self.eng,
            &mut self.state,
        )?;
        let fixed_dt = self.loaded.scene.time.dt;
        self.prog.errors.extend(analysis::exact_errors(
            &self.loaded.scene,
            &self.state,
            fixed_dt,
        ));
        if let Some(c) = self.ball_core() {
            self.prog.core.push(c);
        }
        if self.verbose {
            eprintln!(
                "  t = {:.6}  step {:>7}  → {}",
                self.state.t, self.state.step, name
            );
        }
        let series: Vec<(f64, String)> = self
            .prog
            .snapshot_times
            .iter()
            .copied()
            .chain([self.state.t])
            .zip(
                self.prog
                    .snapshots
                    .iter()
                    .cloned()
                    .chain([name.to_string()]),
            )
            .collect();
        io::write_xdmf_series(&self.out, &series).map_err(|e| RunError::Io(e.to_string()))
    }

    /// This process writes the output (always, unless it is a rank other than 0).
    pub fn is_root(&self) -> bool {
        self.ranks.as_ref().is_none_or(|r| r.is_root())
    }

    /// Rank 0 over ranks: an engine on the gathered state, for what an output computes from
    /// it (dust densities and stopping times).
    fn fresh_engine(&mut self) -> Result<(), RunError> {
        if self.eng_stale {
            let phys = self.eng.phys().clone();
            self.eng = Backend::new(DeviceChoice::Cpu, phys, &mut self.state)
                .map_err(|e| RunError::Step(e.to_string()))?;
            // The ranks leave the dust densities as a step does (one process refreshes them
            // for its outputs): a variable-h engine would otherwise keep the gathered ones.
            self.eng.dust_density_as_after_step();
            self.eng_stale = false;
        }
        Ok(())
    }

    /// Ball only: the Lagrange–Jacobi terms after a step.
    fn record_ball_step(&mut self) {
        if self.loaded.scene.scene.problem == crate::scene::Problem::Dustyball {
            let (i, rhs) =
                analysis::ball::lagrange_jacobi_terms(&self.state, self.loaded.scene.dim());
            self.prog.lagrange_jacobi.push((self.state.t, i, rhs));
        }
    }

    fn ball_core(&self) -> Option<analysis::ball::CoreCheck> {
        let sc = &self.loaded.scene;
        let b = sc.ball()?;
        let rho = sc.gas.rho?;
        let p = match sc.gas.eos {
            crate::scene::EosKind::Adiabatic => sc.gas.p?,
            crate::scene::EosKind::Isothermal => sc.gas.cs? * sc.gas.cs? * rho,
        };
        let cs = self.eng.phys().eos.sound_speed(rho, p);
        let eps: f64 = sc
            .dust
            .as_ref()
            .map_or(0.0, |d| d.fractions.iter().map(|f| f.eps).sum());
        analysis::ball::core_check(
            &self.state,
            b.radius,
            rho,
            eps * rho,
            p,
            cs,
            self.eng.phys().h,
        )
    }

    fn is_ball(&self) -> bool {
        self.loaded.scene.scene.problem == crate::scene::Problem::Dustyball
    }

    /// The state as it stands (brought up to date from the engine).
    pub fn current_state(&mut self) -> Result<&State, RunError> {
        self.sync()?;
        Ok(&self.state)
    }

    /// Host state up to date with the backend.
    fn sync(&mut self) -> Result<(), RunError> {
        if let Some(r) = &self.ranks {
            // Over ranks: every rank's particles gathered on rank 0 (collective).
            let (t, step) = (self.state.t, self.state.step);
            if let Some(st) = r.gather(t, step).map_err(RunError::Step)? {
                self.state = st;
                self.eng_stale = true;
            }
            return Ok(());
        }
        self.eng
            .sync(&mut self.state)
            .map_err(|e| RunError::Step(e.to_string()))
    }

    /// Write `DIR/checkpoint.h5` (atomically).
    pub fn checkpoint(&mut self) -> Result<(), RunError> {
        self.sync()?;
        let mut prog = self.prog.clone();
        prog.wall_before += self.wall0.elapsed().as_secs_f64();
        let meta = io::checkpoint::CheckpointMeta {
            scene_text: self.loaded.text.clone(),
            scene_file: self.loaded.path.display().to_string(),
            overrides_json: serde_json::to_string(&self.loaded.overrides)
                .expect("strings serialise"),
            progress_json: serde_json::to_string(&prog).map_err(|e| RunError::Io(e.to_string()))?,
        };
        let written = if self.is_root() {
            io::checkpoint::write_checkpoint(
                &self.out.join(io::checkpoint::CHECKPOINT_NAME),
                &self.state,
                &meta,
            )
            .map_err(|e| RunError::Io(e.to_string()))
        } else {
            Ok(())
        };
        if let Some(r) = &self.ranks {
            if r.any(written.is_err()) {
                written.clone()?;
                return Err(RunError::Io("rank 0 could not write the checkpoint".into()));
            }
        }
        written
    }

    /// Step until t_end (or `max_steps` more steps, or `stop` is raised); a checkpoint every
    /// `checkpoint_every` steps and on interruption.
    pub fn advance(
        &mut self,
        max_steps: Option<u64>,
        checkpoint_every: Option<u64>,
        stop: Option<&std::sync::atomic::AtomicBool>,
    ) -> Result<Stop, RunError> {
        let h = self.eng.phys().h;
        let t_end = self.loaded.scene.time.t_end;
        let bar = progress_bar(self.verbose);
        let mut taken = 0u64;
        while self.prog.next_output < self.times.len() {
            let asked = stop.is_some_and(|s| s.load(std::sync::atomic::Ordering::Relaxed));
            // Over ranks, one rank's Ctrl-C stops all at the same step.
            let asked = match &self.ranks {
                Some(r) => r.any(asked),
                None => asked,
            };
            if asked {
                bar.finish_and_clear();
                self.checkpoint()?;
                return Ok(Stop::Interrupted);
            }
            if max_steps.is_some_and(|m| taken >= m) {
                bar.finish_and_clear();
                return Ok(Stop::Interrupted);
            }
            let t_out = self.times[self.prog.next_output];
            let driver = StepPlanner::new(&self.loaded.scene.time, h);
            let kept =
                |e: String| RunError::Step(format!("{e}; the snapshots written so far are kept"));
            let step = match &mut self.ranks {
                Some(r) => {
                    let (t, n) = (self.state.t, self.state.step);
                    let (plan, t_new, vsig_max) = r.step(&driver, t, n, t_out).map_err(kept)?;
                    self.state.t = t_new;
                    self.state.step += 1;
                    crate::step::timestep::Taken {
                        plan,
                        forces: crate::step::Forces {
                            acc: Vec::new(),
                            dedt: None,
                            vsig_max,
                            acc_max: 0.0,
                        },
                    }
                }
                None => driver
                    .step(&mut self.eng, &mut self.state, t_out)
                    .map_err(|e| kept(e.to_string()))?,
            };
            let (dt, landing) = (step.plan.dt, step.plan.landing);
            self.prog.drag_limited_steps += u64::from(step.plan.by_drag);
            self.prog.dt_min = self.prog.dt_min.min(dt);
            self.prog.dt_max = self.prog.dt_max.max(dt);
            self.prog.cfl_max = self.prog.cfl_max.max(dt * step.forces.vsig_max / h);
            taken += 1;
            if self.is_ball() {
                // The Lagrange–Jacobi check needs every step's state on the host.
                self.sync()?;
            }
            self.record_ball_step();
            if landing {
                self.sync()?;
                self.prog.pscale = self.prog.pscale.max(self.state.momentum_scale());
                bar.suspend(|| self.write_output())?;
            }
            bar.set_position((self.state.t / t_end * 1e4) as u64);
            bar.set_message(format!(
                "step {} t = {:.5} dt = {:.3e}",
                self.state.step, self.state.t, dt
            ));
            if checkpoint_every.is_some_and(|k| k > 0 && self.state.step % k == 0) {
                self.checkpoint()?;
            }
        }
        bar.finish_and_clear();
        Ok(Stop::Finished)
    }

    /// The summary (also written to `DIR/summary.json`).
    pub fn finish(mut self) -> Result<(Summary, State), RunError> {
        self.sync()?;
        let Runner {
            loaded,
            out,
            eng,
            state,
            prog,
            wall0,
            ranks,
            ..
        } = self;
        let scene = &loaded.scene;
        let wall = prog.wall_before + wall0.elapsed().as_secs_f64();
        let p1 = state.total_momentum();
        let p0 = prog.p0;
        let dp =
            ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2) + (p1[2] - p0[2]).powi(2)).sqrt();
        let n_part = state.gas.ph.len() + state.dust.iter().map(|d| d.len()).sum::<usize>();
        let r_est = |phs: &[&crate::particles::Phase]| -> f64 {
            let (mut mr2, mut m) = (0.0, 0.0);
            for ph in phs {
                for (mi, x) in ph.m.iter().zip(&ph.x) {
                    mr2 += mi * (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
                    m += mi;
                }
            }
            if m > 0.0 {
                (5.0 * mr2 / (3.0 * m)).sqrt()
            } else {
                0.0
            }
        };
        let root = ranks.as_ref().is_none_or(|r| r.is_root());
        let post = match (scene.ball(), prog.snapshots.last()) {
            (Some(_), Some(last)) if root => Some(
                crate::commands::profile::post_process(&out.join(last), 100)
                    .map_err(|e| RunError::Io(e.to_string()))?,
            ),
            _ => None,
        };
        let ball = scene.ball().map(|_| BallReport {
            symmetry: post.as_ref().and_then(|p| p.symmetry.clone()),
            figures: post.as_ref().map_or(Vec::new(), |p| {
                p.files
                    .iter()
                    .filter_map(|f| f.file_name().map(|n| n.to_string_lossy().into_owned()))
                    .collect()
            }),
            core: prog.core.clone(),
            lagrange_jacobi_max_relative: analysis::ball::lagrange_jacobi_deviation(
                &prog.lagrange_jacobi,
            ),
            radius_estimate_gas: r_est(&[&state.gas.ph]),
            radius_estimate_dust: r_est(&state.dust.iter().collect::<Vec<_>>()),
        });
        let summary = Summary {
            code: "dustsph",
            version: env!("CARGO_PKG_VERSION"),
            git: env!("DUSTSPH_GIT"),
            scene: scene.scene.name.clone(),
            problem: scene.scene.problem.name(),
            scene_file: loaded.path.display().to_string(),
            overrides: loaded.overrides.clone(),
            scene_effective: loaded.effective.clone(),
            dimension: scene.dim(),
            backend: match &ranks {
                Some(r) => format!("{}; set-up and outputs: {}", r.describe(), eng.describe()),
                None => eng.describe(),
            },
            precision: eng.phys().precision.name(),
            particles: prog.counts.clone(),
            h: eng.phys().h,
            idic_cell: eng.phys().cell_size,
            position_update: format!("{:?}", eng.phys().position_update).to_lowercase(),
            integrator: match eng.phys().integrator {
                crate::scene::Integrator::FirstOrder => "first_order",
                crate::scene::Integrator::Kdk => "kdk",
            },
            gradient: match eng.phys().gradient {
                crate::scene::GradientMethod::Standard => "standard",
                crate::scene::GradientMethod::Iad => "iad",
            },
            // The stages that ran, in the order they first ran (from the timers).
            pipeline: eng.timers().entries().iter().map(|e| e.0).collect(),
            drag_method: eng.phys().drag.name(),
            drag_limited_steps: prog.drag_limited_steps,
            steps: state.step,
            t_final: state.t,
            dt_min: prog.dt_min,
            dt_max: prog.dt_max,
            cfl_max: prog.cfl_max,
            wall_seconds: wall,
            particle_steps_per_second: n_part as f64 * state.step as f64 / wall.max(1e-12),
            conservation: Conservation {
                mass_gas: Drift::new(prog.mass0.0, state.gas.ph.total_mass()),
                mass_dust: state
                    .dust
                    .iter()
                    .zip(&prog.mass0.1)
                    .map(|(d, &m)| Drift::new(m, d.total_mass()))
                    .collect(),
                momentum_initial: p0,
                momentum_final: p1,
                momentum_drift_relative: if prog.pscale > 0.0 {
                    dp / prog.pscale
                } else {
                    dp
                },
                energy: Drift::new(prog.e0, state.total_energy()),
            },
            errors: prog.errors,
            snapshots: prog.snapshots,
            stage_seconds: eng.timers().entries().to_vec(),
            ball,
        };
        if root {
            io::write_json_atomic(&out.join("summary.json"), &summary)
                .map_err(|e| RunError::Io(e.to_string()))?;
        }
        Ok((summary, state))
    }
}

/// A checkpoint may continue only the run it was written by, in its own directory: its
/// particles agree with its own scene (counts per phase, unused coordinates zero), every
/// snapshot its progress lists is there and was written by the same scene with the same
/// particle counts no later than the checkpoint, and no other snapshot would be overwritten.
fn verify_resume(
    dir: &Path,
    state: &State,
    loaded: &LoadedScene,
    prog: &Progress,
) -> Result<(), String> {
    let scene = &loaded.scene;
    let su = setup::build(scene).map_err(|e| format!("its scene cannot be set up: {e}"))?;
    let counts = |s: &State| -> (usize, Vec<usize>) {
        (s.gas.ph.len(), s.dust.iter().map(|d| d.len()).collect())
    };
    let (want, have) = (counts(&su.state), counts(state));
    if want != have {
        return Err(format!(
            "its particles (gas {}, dust {:?}) do not match its own scene (gas {}, dust {:?})",
            have.0, have.1, want.0, want.1
        ));
    }
    let dim = scene.dim() as usize;
    let phases = std::iter::once(&state.gas.ph).chain(&state.dust);
    if dim < 3
        && phases
            .flat_map(|p| &p.x)
            .any(|x| x[dim..].iter().any(|c| *c != 0.0))
    {
        return Err(format!(
            "its particles are not {dim}-dimensional as its scene (scene.dim = {dim}) says"
        ));
    }
    if let Some(&t_end) = output_times(loaded).last() {
        if state.t >= t_end {
            return Err(format!(
                "its run already reached t_end = {t_end} (t = {}): nothing to resume, and the \
                 output stays as it is (to run further, start a new run with a later \
                 time.t_end)",
                state.t
            ));
        }
    }
    let n_dust: usize = have.1.iter().sum();
    for (k, name) in prog.snapshots.iter().enumerate() {
        let p = dir.join(name);
        let h = io::snapshot::read_header(&p).map_err(|e| {
            format!("the snapshot {name} its run wrote is missing or unreadable ({e})")
        })?;
        let same_scene = same_run_scene(&h, loaded);
        let same_counts = h.num_part[io::snapshot::GAS_TYPE] as usize == have.0
            && h.num_part[io::snapshot::DUST_TYPE] as usize == n_dust;
        if !same_scene || !same_counts || h.dim as usize != dim {
            return Err(format!(
                "{name} in {} was written by another run (scene {}, particles {:?}): the \
                 checkpoint belongs elsewhere",
                dir.display(),
                if same_scene { "the same" } else { "different" },
                h.num_part
            ));
        }
        if h.time > state.t {
            return Err(format!(
                "{name} is at t = {} after the checkpoint's t = {}: the checkpoint is older \
                 than the run's output",
                h.time, state.t
            ));
        }
        // The run wrote this snapshot at a known time: another one copied over it is not it.
        if let Some(&t) = prog.snapshot_times.get(k) {
            if h.time != t {
                return Err(format!(
                    "{name} in {} is at t = {}, but the checkpoint's run wrote it at t = {t}: \
                     it was replaced; put the run's own file back",
                    dir.display(),
                    h.time
                ));
            }
        }
    }
    let listed: std::collections::HashSet<&str> =
        prog.snapshots.iter().map(|s| s.as_str()).collect();
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        if io::output_dir::is_snapshot_name(&name) && !listed.contains(name.as_str()) {
            // The same run, written after the checkpoint was: say so.
            if let Ok(h) = io::snapshot::read_header(&e.path()) {
                if same_run_scene(&h, loaded) && h.time > state.t {
                    return Err(format!(
                        "{name} in {} (t = {}) was written after the checkpoint (t = {}); \
                         resuming would overwrite it (move it and the later snapshots away \
                         to continue from the checkpoint)",
                        dir.display(),
                        h.time,
                        state.t
                    ));
                }
            }
            return Err(format!(
                "{name} in {} is not one the checkpoint's run wrote; resuming would overwrite \
                 it (move it away, or resume in the run's own directory)",
                dir.display()
            ));
        }
    }
    Ok(())
}

/// Whether a snapshot was written from the scene a run is made of: the same effective scene
/// (file and overrides). A snapshot from before the Header recorded the effective scene holds
/// the file's text alone, which is the run's only if it had no overrides.
fn same_run_scene(h: &io::snapshot::SnapshotHeader, loaded: &LoadedScene) -> bool {
    match h.source_text {
        Some(_) => h.scene_text == loaded.effective,
        None => loaded.overrides.is_empty() && h.scene_text == loaded.text,
    }
}

/// What a physicist should hear before a run that will likely be noise or unstable: a fixed
/// step above the CFL/force limit of the initial state, and kernels holding too few
/// neighbours to be SPH sums (method.md §2).
fn start_warnings(
    loaded: &LoadedScene,
    phys: &Physics,
    state: &State,
    f: &crate::step::Forces,
) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(dt) = loaded.scene.time.dt {
        let (dt_cfl, dt_force) = crate::step::dt_limits(phys.h, f);
        let limit = dt_cfl.min(dt_force);
        if dt > limit {
            out.push(format!(
                "time.dt = {dt} is {:.2}× the step limit min(h/v_sig, √(h/|A|)) = {limit:.3e} of \
                 the initial state: explicit SPH is stable only below ≈0.3–0.5 of it (lower \
                 time.dt, or use time.cfl)",
                dt / limit
            ));
        }
    }
    // Fewer neighbours than a kernel of half the usual width would hold (hfact ≈ 0.6).
    let least = [2.0, 5.0, 12.0][(phys.domain.dim as usize).clamp(1, 3) - 1];
    if let Ok(nb) = crate::bench::mean_gas_neighbours(phys, state) {
        if !state.gas.ph.x.is_empty() && nb < least {
            out.push(format!(
                "the gas particles have {nb:.1} neighbours each within 2h on average (fewer than \
                 {least} in {}D): the SPH sums are noise at this resolution; raise sph.hfact (or \
                 sph.h)",
                phys.domain.dim
            ));
        }
    }
    out
}

/// Progress in units of 1e-4 of t_end.
fn progress_bar(visible: bool) -> indicatif::ProgressBar {
    // Hidden unless asked for and stderr is a terminal (indicatif checks the latter).
    let bar = if visible {
        indicatif::ProgressBar::new(10_000)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:30} {percent:>3}% {msg}  ETA {eta}")
            .expect("valid template"),
    );
    bar
}

/// Run a scene to its end time; returns the summary and the final state.
pub fn run(loaded: &LoadedScene, opts: &RunOptions) -> Result<(Summary, State), RunError> {
    let mut r = Runner::start(loaded, opts)?;
    r.advance(None, None, None)?;
    r.finish()
}
