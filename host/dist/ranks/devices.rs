//! The device each rank steps on: its own GPU (rank r on device r mod count) or the CPU.
use crate::particles::State;
use crate::step::backend::{Backend, DeviceChoice};
use crate::step::engine::InitialLayer;
use crate::step::Physics;

/// The launcher a rank steps on, kept across its steps (a GPU's kernels are loaded once).
pub(super) enum RankDevice {
    Cpu,
    Cuda(crate::launch::Cuda),
}

impl RankDevice {
    /// The engine on this device for the rank's local state of one step.
    pub(super) fn engine(
        &self,
        phys: Physics,
        state: &mut State,
        layer: InitialLayer,
    ) -> Result<Backend, crate::step::StepError> {
        match self {
            RankDevice::Cpu => Backend::on_cpu_at(phys, state, layer),
            RankDevice::Cuda(d) => Backend::on_cuda_at(d.clone(), phys, state, layer),
        }
    }
}

/// Rank `me`'s device for `asked` (`--device`): with a GPU, device `me` mod the count this
/// process sees, tried on the rank's share before anything is written; `auto` falls back to
/// the CPU (with a note) where that fails, `cuda` stops. `Err` is the rank's message.
pub(super) fn rank_device(
    asked: DeviceChoice,
    me: u32,
    phys: &Physics,
    share: &State,
) -> Result<(RankDevice, Option<String>), String> {
    use crate::launch::Cuda;
    let (device, note) = crate::step::backend::select(asked)?;
    if device != DeviceChoice::Cuda {
        return Ok((RankDevice::Cpu, note));
    }
    let tried = crate::launch::cuda::device_count()
        .and_then(|n| {
            let ordinal = me as usize % n.max(1);
            Cuda::new(ordinal, crate::launch::PTX)
                .map_err(|e| format!("CUDA device {ordinal}: {e}"))
        })
        .and_then(|d| {
            if share.gas.ph.x.is_empty() && share.dust.iter().all(|p| p.x.is_empty()) {
                return Ok(d);
            }
            // Tried on a copy: the share stays as set up (an engine sorts and lays out its
            // state).
            Backend::on_cuda(d.clone(), phys.clone(), &mut share.clone())
                .map(|_| d)
                .map_err(|e| e.to_string())
        });
    match (tried, asked) {
        (Ok(d), _) => Ok((RankDevice::Cuda(d), None)),
        (Err(e), DeviceChoice::Auto) => Ok((
            RankDevice::Cpu,
            Some(format!("rank {me}: no GPU used ({e}); stepping on the CPU")),
        )),
        (Err(e), _) => Err(format!("--device cuda on rank {me}: {e}")),
    }
}
