//! The backend a run steps on: the rayon CPU engine, or the GPU engine on a CUDA device (or
//! its kernels emulated on the CPU, for checking). Chosen by `--device auto|cpu|cuda|emulate`.
use super::cpu::{CpuEngine, Forces, StepError};
use super::gpu::{self, Cuda, Emulated, GpuEngine};
use super::timers::Timers;
use super::{Physics, Pipeline};
use crate::particles::State;

/// What the user asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum DeviceChoice {
    /// A CUDA GPU when one is usable, else the CPU (with a one-line note).
    #[default]
    Auto,
    Cpu,
    Cuda,
    /// The GPU kernels run on the CPU (slow; checks the GPU path without a GPU).
    Emulate,
}

// The CPU engine is held inline: it is the common case and lives for the whole run.
#[allow(clippy::large_enum_variant)]
pub enum Backend {
    Cpu(CpuEngine),
    Cuda(Box<GpuEngine<Cuda>>),
    Emulated(Box<GpuEngine<Emulated>>),
}

/// Either the backend, or a message for the user (bad choice for this machine).
pub fn select(choice: DeviceChoice) -> Result<(DeviceChoice, Option<String>), String> {
    let why_not = || -> Option<String> {
        if gpu::PTX.is_empty() {
            return Some(format!("the GPU kernels were {}", gpu::PTX_NOTE));
        }
        gpu::probe().err()
    };
    match choice {
        DeviceChoice::Auto => Ok(match why_not() {
            None => (DeviceChoice::Cuda, None),
            Some(w) => (
                DeviceChoice::Cpu,
                Some(format!(
                    "no GPU used ({w}); running on the CPU with {} threads",
                    rayon::current_num_threads()
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

/// Device memory in use on CUDA device 0 (None for other backends or without a driver).
pub fn device_memory_used(choice: DeviceChoice) -> Option<usize> {
    if choice != DeviceChoice::Cuda {
        return None;
    }
    Cuda::new(0, gpu::PTX).ok()?.memory_used().ok()
}

impl Backend {
    /// Build the engine for a resolved choice (`select` first); sorts `state` in place.
    pub fn new(
        choice: DeviceChoice,
        phys: Physics,
        state: &mut State,
    ) -> Result<Backend, StepError> {
        Ok(match choice {
            DeviceChoice::Cpu | DeviceChoice::Auto => Backend::Cpu(CpuEngine::new(phys, state)?),
            DeviceChoice::Cuda => {
                let dev = Cuda::new(0, gpu::PTX)?;
                Backend::Cuda(Box::new(GpuEngine::new(phys, state, dev)?))
            }
            DeviceChoice::Emulate => {
                Backend::Emulated(Box::new(GpuEngine::new(phys, state, Emulated)?))
            }
        })
    }

    pub fn phys(&self) -> &Physics {
        match self {
            Backend::Cpu(e) => &e.phys,
            Backend::Cuda(e) => &e.phys,
            Backend::Emulated(e) => &e.phys,
        }
    }

    pub fn pipe(&self) -> &Pipeline {
        match self {
            Backend::Cpu(e) => &e.pipe,
            Backend::Cuda(e) => &e.pipe,
            Backend::Emulated(e) => &e.pipe,
        }
    }

    pub fn timers(&self) -> &Timers {
        match self {
            Backend::Cpu(e) => &e.timers,
            Backend::Cuda(e) => &e.timers,
            Backend::Emulated(e) => &e.timers,
        }
    }

    pub fn timers_mut(&mut self) -> &mut Timers {
        match self {
            Backend::Cpu(e) => &mut e.timers,
            Backend::Cuda(e) => &mut e.timers,
            Backend::Emulated(e) => &mut e.timers,
        }
    }

    /// Where the run steps, for the summary.
    pub fn describe(&self) -> String {
        match self {
            Backend::Cpu(_) => format!("cpu (rayon, {} threads)", rayon::current_num_threads()),
            Backend::Cuda(e) => format!("cuda: {}", e.describe()),
            Backend::Emulated(e) => format!("emulate: {}", e.describe()),
        }
    }

    /// Whether the host `State` is current after every step (else call [`Backend::sync`]).
    pub fn host_state_live(&self) -> bool {
        matches!(self, Backend::Cpu(_))
    }

    pub fn forces(&mut self, state: &State) -> Result<Forces, StepError> {
        match self {
            Backend::Cpu(e) => {
                let mut t = std::mem::take(&mut e.timers);
                let f = t.time("gas forces", || e.forces(state));
                e.timers = t;
                Ok(f)
            }
            Backend::Cuda(e) => e.forces(),
            Backend::Emulated(e) => e.forces(),
        }
    }

    pub fn advance(&mut self, state: &mut State, f: &Forces, tau: f64) -> Result<(), StepError> {
        match self {
            Backend::Cpu(e) => e.advance(state, f, tau),
            Backend::Cuda(e) => e.advance(state, tau),
            Backend::Emulated(e) => e.advance(state, tau),
        }
    }

    /// The explicit drag baseline's step limit (+∞ for IDIC, which never limits the step; the
    /// baseline runs on the CPU only).
    pub fn drag_dt_limit(&mut self, state: &State) -> f64 {
        match self {
            Backend::Cpu(e) => e.drag_dt_limit(state),
            _ => f64::INFINITY,
        }
    }

    /// Bring the host state up to date with the device (a no-op on the CPU).
    pub fn sync(&mut self, state: &mut State) -> Result<(), StepError> {
        match self {
            Backend::Cpu(_) => Ok(()),
            Backend::Cuda(e) => Ok(e.sync(state)?),
            Backend::Emulated(e) => Ok(e.sync(state)?),
        }
    }

    /// Dust densities (for output) and the host state brought up to date.
    pub fn refresh_dust_density(&mut self, state: &mut State) -> Result<(), StepError> {
        match self {
            Backend::Cpu(e) => e.refresh_dust_density(state),
            Backend::Cuda(e) => Ok(e.refresh_dust_density(state)?),
            Backend::Emulated(e) => Ok(e.refresh_dust_density(state)?),
        }
    }

    pub fn dust_stopping_times(&mut self, state: &mut State) -> Result<Vec<Vec<f64>>, StepError> {
        match self {
            Backend::Cpu(e) => e.dust_stopping_times(state),
            Backend::Cuda(e) => Ok(e.dust_stopping_times(state)?),
            Backend::Emulated(e) => Ok(e.dust_stopping_times(state)?),
        }
    }
}
