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

/// [`Backend::start`] after `select`, with the GPU engine's constructor given (tests pass one
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
                "{why}: running on the CPU with {} threads",
                rayon::current_num_threads()
            );
            Ok((eng, Some(note)))
        }
    }
}

/// Device memory in use on CUDA device 0 (None for other backends or without a driver).
pub fn device_memory_used(choice: DeviceChoice) -> Option<usize> {
    if choice != DeviceChoice::Cuda {
        return None;
    }
    Cuda::new(0, gpu::PTX).ok()?.memory_used().ok()
}

/// Why no engine was started.
#[derive(Debug)]
pub enum StartError {
    /// The device asked for is not usable here (`--device cuda` without a GPU).
    Device(String),
    /// The engine could not set up the initial state.
    Step(StepError),
}

impl Backend {
    /// The engine for what the user asked, and a one-line note when `auto` did not use the
    /// GPU. `auto` falls back to the CPU when no GPU is usable, when the GPU path refuses the
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

    /// The explicit drag baseline's step limit (+∞ for IDIC, which never limits the step).
    pub fn drag_dt_limit(&mut self, state: &State) -> Result<f64, StepError> {
        match self {
            Backend::Cpu(e) => Ok(e.drag_dt_limit(state)),
            Backend::Cuda(e) => e.drag_dt_limit(),
            Backend::Emulated(e) => e.drag_dt_limit(),
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
        assert!(matches!(eng, Backend::Cpu(_)));
        let note = note.expect("a note");
        assert!(
            note.contains("GPU failed at start") && note.contains("CUDA_ERROR_INVALID_PTX"),
            "{note}"
        );
        assert!(!note.contains('\n'));
        assert_eq!(state.gas.ph.x, reference.gas.ph.x);
        assert_eq!(state.gas.ph.rho, reference.gas.ph.rho);
        // `cuda` asked explicitly never falls back: without a usable GPU it is an error.
        if gpu::probe().is_ok() {
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
