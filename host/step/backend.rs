//! The backend a run steps on: the engine (host/step/engine) on a launcher — the CPU's rayon
//! pool, or a CUDA device — in f64 or f32. Chosen by `--device auto|cpu|cuda`.
use super::engine::{self, Engine, GhostSync, InitialLayer};
use super::timers::Timers;
use super::timestep::{Plan, PlanError, StepPlanner, Taken};
use super::Momentum;
use super::{Forces, Physics, Stages, StepError};
use crate::launch::{self, Cuda, Launcher, Rayon};
use crate::particles::State;
use crate::scene::Precision;

/// What the user asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum DeviceChoice {
    /// A CUDA GPU when one is usable, else the CPU (with a one-line note).
    #[default]
    Auto,
    /// The step's kernels on this machine's cores (rayon).
    Cpu,
    Cuda,
}

/// The one step on one of its two launchers, in one of its two precisions.
pub enum Backend {
    Cpu(Box<Engine<Rayon, f64>>),
    Cuda(Box<Engine<Cuda, f64>>),
    CpuF32(Box<Engine<Rayon, f32>>),
    CudaF32(Box<Engine<Cuda, f32>>),
}

/// The same call on any launcher and precision.
macro_rules! each {
    ($self:expr, $e:ident => $body:expr) => {
        match $self {
            Backend::Cpu($e) => $body,
            Backend::Cuda($e) => $body,
            Backend::CpuF32($e) => $body,
            Backend::CudaF32($e) => $body,
        }
    };
}

/// Either the backend, or a message for the user (bad choice for this machine).
pub fn select(choice: DeviceChoice) -> Result<(DeviceChoice, Option<String>), String> {
    let why_not = || -> Option<String> {
        if launch::PTX.is_empty() {
            return Some(format!("the GPU kernels were {}", launch::PTX_NOTE));
        }
        launch::probe().err()
    };
    match choice {
        DeviceChoice::Auto => Ok(match why_not() {
            None => (DeviceChoice::Cuda, None),
            Some(w) => (
                DeviceChoice::Cpu,
                Some(format!(
                    "no GPU used ({w}); running on the CPU with {}",
                    launch::threads(rayon::current_num_threads())
                )),
            ),
        }),
        DeviceChoice::Cuda => match why_not() {
            None => Ok((DeviceChoice::Cuda, None)),
            Some(w) => Err(format!("--device cuda: {w}")),
        },
        c => Ok((c, None)),
    }
}

/// [`Backend::start`] after `select`, with the CUDA engine's constructor given (tests pass one
/// that fails).
fn start_resolved(
    asked: DeviceChoice,
    device: DeviceChoice,
    note: Option<String>,
    phys: Physics,
    state: &mut State,
    gpu: impl FnOnce(Physics, &mut State) -> Result<Backend, StepError>,
) -> Result<(Backend, Option<String>), StartError> {
    if asked != DeviceChoice::Auto || device != DeviceChoice::Cuda {
        let eng = Backend::new(device, phys, state).map_err(StartError::Step)?;
        return Ok((eng, note));
    }
    let saved = state.clone();
    match gpu(phys.clone(), state) {
        Ok(eng) => Ok((eng, None)),
        Err(e) => {
            *state = saved;
            let why = match &e {
                StepError::Unsupported(m) => m.clone(),
                e => format!("the GPU failed at start ({e})"),
            };
            let eng = Backend::new(DeviceChoice::Cpu, phys, state).map_err(StartError::Step)?;
            let note = format!(
                "{why}: running on the CPU with {}",
                launch::threads(rayon::current_num_threads())
            );
            Ok((eng, Some(note)))
        }
    }
}

/// Refuse, before any device allocation, a run whose particles would not fit in the GPU's free
/// memory ([`engine::device_bytes_estimate`], measured); `auto` then runs on the CPU.
fn check_device_memory(
    dev: &Cuda,
    phys: &Physics,
    state: &State,
    f32: bool,
) -> Result<(), StepError> {
    let n = state.gas.ph.x.len() + state.dust.iter().map(|d| d.x.len()).sum::<usize>();
    let per = engine::DEVICE_BYTES_PER_PARTICLE[f32 as usize];
    let pairs = engine::coupling_pairs_estimate(phys, state);
    let need = engine::device_bytes_estimate(phys, state, f32);
    let free = dev.memory_free()? as f64;
    if need > free {
        let coupling = if pairs > 0.0 {
            format!(
                " and about {pairs:.2e} kernel-coupling pairs at {} B each",
                engine::COUPLING_BYTES_PER_PAIR[f32 as usize]
            )
        } else {
            String::new()
        };
        return Err(StepError::Unsupported(format!(
            "{n} particles need about {:.1} GB of GPU memory ({per} B each{coupling}, {}), more \
             than the {:.1} GB free on {}; lower sph.n, use numerics.precision = \"f32\", or run \
             on the CPU",
            need / 1e9,
            if f32 { "f32" } else { "f64" },
            free / 1e9,
            dev.describe()
        )));
    }
    Ok(())
}

/// Device memory in use on CUDA device 0 (None for other backends or without a driver).
pub fn device_memory_used(choice: DeviceChoice) -> Option<usize> {
    if choice != DeviceChoice::Cuda {
        return None;
    }
    Cuda::new(0, launch::PTX).ok()?.memory_used().ok()
}

/// Why no engine was started.
#[derive(Debug)]
pub enum StartError {
    /// The device asked for is not usable here (`--device cuda` without a GPU).
    Device(String),
    /// The engine could not set up the initial state.
    Step(StepError),
}

impl std::fmt::Display for StartError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StartError::Device(m) => f.write_str(m),
            StartError::Step(e) => write!(f, "{e}"),
        }
    }
}

impl Backend {
    /// The engine for what the user asked, and a one-line note when `auto` did not use the
    /// GPU. `auto` falls back to the CPU when no GPU is usable, when the CUDA engine refuses the
    /// scene, or when CUDA fails to initialise or to run the set-up launches (sort, densities);
    /// all of that happens before any output is written. The state is restored before the CPU
    /// starts, so a failed GPU attempt leaves no trace.
    pub fn start(
        asked: DeviceChoice,
        phys: Physics,
        state: &mut State,
    ) -> Result<(Backend, Option<String>), StartError> {
        let (device, note) = select(asked).map_err(StartError::Device)?;
        start_resolved(asked, device, note, phys, state, |p, s| {
            Backend::new(DeviceChoice::Cuda, p, s)
        })
    }

    /// Build the engine for a resolved choice (`select` first); sorts `state` in place. CUDA
    /// means device 0.
    pub fn new(
        choice: DeviceChoice,
        phys: Physics,
        state: &mut State,
    ) -> Result<Backend, StepError> {
        Ok(match choice {
            DeviceChoice::Cuda => {
                Self::refuse_on_cuda(&phys)?;
                Self::on_cuda(Cuda::new(0, launch::PTX)?, phys, state)?
            }
            _ => Self::on_cpu_at(phys, state, InitialLayer::Compute)?,
        })
    }

    /// The engine on an opened CUDA device (a rank's own GPU keeps one across its steps).
    pub fn on_cuda(dev: Cuda, phys: Physics, state: &mut State) -> Result<Backend, StepError> {
        Self::on_cuda_at(dev, phys, state, InitialLayer::Compute)
    }

    /// As [`Backend::on_cuda`], taking the state's layer as given ([`InitialLayer`]).
    pub fn on_cuda_at(
        dev: Cuda,
        phys: Physics,
        state: &mut State,
        layer: InitialLayer,
    ) -> Result<Backend, StepError> {
        Self::refuse_on_cuda(&phys)?;
        let f32 = phys.precision == Precision::F32;
        check_device_memory(&dev, &phys, state, f32)?;
        Ok(if f32 {
            Backend::CudaF32(Box::new(Engine::with_layer(phys, state, dev, layer)?))
        } else {
            Backend::Cuda(Box::new(Engine::with_layer(phys, state, dev, layer)?))
        })
    }

    /// The engine on the CPU's cores (rayon) taking the state's layer as given or not ([`InitialLayer`]).
    pub fn on_cpu_at(
        phys: Physics,
        state: &mut State,
        layer: InitialLayer,
    ) -> Result<Backend, StepError> {
        Ok(if phys.precision == Precision::F32 {
            Backend::CpuF32(Box::new(Engine::with_layer(phys, state, Rayon, layer)?))
        } else {
            Backend::Cpu(Box::new(Engine::with_layer(phys, state, Rayon, layer)?))
        })
    }

    /// What the CUDA build of the step cannot do, refused before any device work.
    fn refuse_on_cuda(phys: &Physics) -> Result<(), StepError> {
        if phys.neighbour_list == crate::scene::ListChoice::On {
            return Err(StepError::Unsupported(
                "numerics.neighbour_list = \"on\": the GPU kernels are built without \
                 neighbour lists (they would cost the forces kernel registers; \
                 docs/performance.md); use \"auto\" or \"off\""
                    .into(),
            ));
        }
        Ok(())
    }

    /// A new engine of the same launcher and precision on `state` (its layer computed from
    /// the positions, as at a resume), keeping the stage timers: after particles left the
    /// state (accretion).
    pub fn rebuilt(&self, state: &mut State) -> Result<Backend, StepError> {
        let phys = self.phys().clone();
        let mut new = match self {
            Backend::Cpu(_) | Backend::CpuF32(_) => {
                Self::on_cpu_at(phys, state, InitialLayer::Compute)?
            }
            Backend::Cuda(_) | Backend::CudaF32(_) => {
                Backend::new(DeviceChoice::Cuda, phys, state)?
            }
        };
        let rebuild = new.timers().entries().to_vec();
        *new.timers_mut() = self.timers().clone();
        for (name, s) in rebuild {
            new.timers_mut().add(name, s);
        }
        Ok(new)
    }

    pub fn phys(&self) -> &Physics {
        each!(self, e => &e.phys)
    }

    pub fn stages(&self) -> &Stages {
        each!(self, e => &e.stages)
    }

    pub fn timers(&self) -> &Timers {
        each!(self, e => &e.timers)
    }

    pub fn timers_mut(&mut self) -> &mut Timers {
        each!(self, e => &mut e.timers)
    }

    /// Whether the step runs on the CPU's cores (either precision).
    pub fn is_cpu(&self) -> bool {
        matches!(self, Backend::Cpu(_) | Backend::CpuF32(_))
    }

    /// Device memory the engine has allocated (exact on the rayon launcher, which allocates
    /// what a GPU would).
    pub fn device_bytes(&self) -> usize {
        each!(self, e => e.device_bytes())
    }

    /// Where the run steps, for the summary.
    pub fn describe(&self) -> String {
        match self {
            Backend::Cpu(e) => format!("cpu ({})", e.describe()),
            Backend::Cuda(e) => format!("cuda: {}", e.describe()),
            Backend::CpuF32(e) => format!("cpu ({}), f32", e.describe()),
            Backend::CudaF32(e) => format!("cuda: {}, f32", e.describe()),
        }
    }

    /// The time-step maxima of the forces at the current layer (the accelerations stay with
    /// the engine; see [`Backend::accelerations`]).
    pub fn forces(&mut self) -> Result<Forces, StepError> {
        each!(self, e => e.forces())
    }

    /// Advance by τ from the current layer (its forces computed by [`Backend::forces`]).
    pub fn advance(&mut self, state: &mut State, tau: f64) -> Result<(), StepError> {
        each!(self, e => e.advance(state, tau))
    }

    /// The forces at the current layer and the step toward `t_target` (nothing is advanced):
    /// the planner's rule on this engine's maxima and, for the explicit drag, its limit.
    pub fn plan(
        &mut self,
        planner: &StepPlanner,
        state: &State,
        t_target: f64,
    ) -> Result<Taken, StepError> {
        let forces = self.forces()?;
        let drag = self.timed_drag_limit()?;
        match planner.plan(&forces, drag, state.t, state.step, t_target) {
            Ok(plan) => Ok(Taken { plan, forces }),
            Err(PlanError::NoLimit(m)) => Err(StepError::Blowup(m)),
            Err(PlanError::Collapsed(m)) => {
                Err(StepError::Blowup(format!("{m}; {}", self.dt_culprits()?)))
            }
        }
    }

    /// Take a planned step; on landing the time is set to the target exactly.
    pub fn take(&mut self, state: &mut State, plan: &Plan) -> Result<(), StepError> {
        self.advance(state, plan.dt)?;
        if plan.landing {
            state.t = plan.t_target;
        }
        Ok(())
    }

    /// One step toward `t_target`: forces, plan, advance.
    pub fn step(
        &mut self,
        planner: &StepPlanner,
        state: &mut State,
        t_target: f64,
    ) -> Result<Taken, StepError> {
        let taken = self.plan(planner, state, t_target)?;
        self.take(state, &taken.plan)?;
        Ok(taken)
    }

    /// The explicit drag's step limit, timed as a stage of the run (+∞ with IDIC).
    pub fn timed_drag_limit(&mut self) -> Result<f64, StepError> {
        if !self.stages().explicit_drag {
            return Ok(f64::INFINITY);
        }
        let t0 = std::time::Instant::now();
        let d = self.drag_dt_limit()?;
        self.timers_mut().add(
            "explicit drag time-step limit (τ ≤ 0.9/Λ)",
            t0.elapsed().as_secs_f64(),
        );
        Ok(d)
    }

    /// The gas accelerations A (pressure + viscosity) at the current layer, per particle in the
    /// engine's order (call [`Backend::sync`] for the matching state).
    pub fn accelerations(&mut self) -> Result<Vec<[f64; 3]>, StepError> {
        each!(self, e => e.accelerations())
    }

    /// Each gas particle's |A| and signal speed at the current layer, in the engine's order
    /// (the time bins' census; the step that follows is unchanged).
    pub fn particle_limits(&mut self) -> Result<(Vec<[f64; 3]>, Vec<f64>), StepError> {
        each!(self, e => e.particle_limits())
    }

    /// The gas particles that set the time step (largest |A|, largest c_s), for messages.
    pub fn dt_culprits(&mut self) -> Result<String, StepError> {
        each!(self, e => e.dt_culprits())
    }

    /// One step of size τ with the gas forces set to zero: the drag pass, the drift and the new
    /// layer alone (for checks of the coupling).
    pub fn advance_drag_only(&mut self, state: &mut State, tau: f64) -> Result<(), StepError> {
        each!(self, e => {
            e.zero_forces()?;
            e.advance(state, tau)
        })
    }

    /// Sparse cell tables from now on (what a cloud too spread out for dense tables gets):
    /// the step must not change (tests/launch.rs).
    pub fn force_sparse_tables(&mut self, state: &mut State) -> Result<(), StepError> {
        each!(self, e => {
            e.force_sparse_tables()?;
            Ok(e.sync(state)?)
        })
    }

    /// The explicit drag baseline's step limit (+∞ for IDIC, which never limits the step).
    pub fn drag_dt_limit(&mut self) -> Result<f64, StepError> {
        each!(self, e => e.drag_dt_limit())
    }

    /// Bring the host state up to date with the engine.
    pub fn momentum(&mut self) -> Result<Momentum, StepError> {
        each!(self, e => Ok(e.momentum()?))
    }

    /// See [`Engine::lagrange_jacobi`].
    pub fn lagrange_jacobi(&mut self, dim: u32) -> Result<(f64, f64), StepError> {
        each!(self, e => Ok(e.lagrange_jacobi(dim)?))
    }

    pub fn sync(&mut self, state: &mut State) -> Result<(), StepError> {
        each!(self, e => Ok(e.sync(state)?))
    }

    /// See [`Engine::set_ghosts`].
    pub fn set_ghosts(
        &mut self,
        sync: Box<dyn GhostSync>,
        keys: crate::particles::KeySet,
        fresh: bool,
    ) -> Result<(), StepError> {
        each!(self, e => e.set_ghosts(sync, keys, fresh))
    }

    /// See [`Engine::layer_norms`].
    pub fn layer_norms(&self) -> Result<Option<[Vec<f64>; 2]>, StepError> {
        each!(self, e => Ok(e.layer_norms()?))
    }

    /// See [`Engine::keep_norms`].
    pub fn keep_norms(&mut self, given: [Vec<f64>; 2]) -> Result<(), StepError> {
        each!(self, e => Ok(e.keep_norms(given)?))
    }

    /// See [`Engine::norms_now`].
    pub fn norms_now(&mut self) -> Result<(), StepError> {
        each!(self, e => e.norms_now())
    }

    /// See [`Engine::free_refresh_buffers`].
    pub fn free_refresh_buffers(&mut self) {
        each!(self, e => e.free_refresh_buffers())
    }

    /// See [`Engine::ghost_flags`].
    pub fn ghost_flags(&self) -> Option<Vec<bool>> {
        each!(self, e => e.ghost_flags())
    }

    /// See [`Engine::owned_motion`].
    pub fn owned_motion(
        &self,
        each: &mut dyn FnMut(usize, [f64; 3], [f64; 3]),
    ) -> Result<Option<engine::OwnedMotion>, StepError> {
        each!(self, e => Ok(e.owned_motion(each)?))
    }

    /// See [`Engine::dust_density_as_after_step`].
    pub fn dust_density_as_after_step(&mut self) {
        each!(self, e => e.dust_density_as_after_step())
    }

    /// Dust densities (for output) and the host state brought up to date.
    pub fn refresh_dust_density(&mut self, state: &mut State) -> Result<(), StepError> {
        each!(self, e => e.refresh_dust_density(state))
    }

    pub fn dust_stopping_times(&mut self, state: &mut State) -> Result<Vec<Vec<f64>>, StepError> {
        each!(self, e => e.dust_stopping_times(state))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `auto` whose GPU attempt fails after touching the state (as a failed first launch
    /// would) runs on the CPU from the untouched state, and says why in one line.
    #[test]
    fn auto_falls_back_when_the_gpu_fails_at_start() {
        let loaded = crate::scene::load(
            std::path::Path::new(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/configs/dustybox.toml"
            )),
            &[],
        )
        .unwrap();
        let su = crate::setup::build(&loaded.scene).unwrap();
        let phys = Physics::from_scene(&loaded.scene, su.h, su.domain);
        let mut reference = su.state.clone();
        let _cpu = Backend::new(DeviceChoice::Cpu, phys.clone(), &mut reference).unwrap();
        let mut state = su.state.clone();
        let (eng, note) = start_resolved(
            DeviceChoice::Auto,
            DeviceChoice::Cuda,
            None,
            phys.clone(),
            &mut state,
            |_, s| {
                s.gas.ph.x.reverse();
                s.gas.ph.rho.iter_mut().for_each(|r| *r = f64::NAN);
                Err(StepError::Blowup("CUDA_ERROR_INVALID_PTX".into()))
            },
        )
        .unwrap();
        assert!(eng.is_cpu());
        drop(_cpu);
        let note = note.expect("a note");
        assert!(
            note.contains("GPU failed at start") && note.contains("CUDA_ERROR_INVALID_PTX"),
            "{note}"
        );
        assert!(!note.contains('\n'));
        assert_eq!(state.gas.ph.x, reference.gas.ph.x);
        assert_eq!(state.gas.ph.rho, reference.gas.ph.rho);
        // `cuda` asked explicitly never falls back: without a usable GPU it is an error.
        if launch::probe().is_ok() {
            return;
        }
        let mut s2 = su.state.clone();
        let r = start_resolved(
            DeviceChoice::Cuda,
            DeviceChoice::Cuda,
            None,
            phys,
            &mut s2,
            |p, s| Backend::new(DeviceChoice::Cuda, p, s),
        );
        assert!(r.is_err());
    }
}
