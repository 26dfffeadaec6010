//! The snapshot layout: group, dataset and attribute names, and the box coordinates are given in.
use super::SnapshotView;

/// Value of the `Code` header attribute.
pub const CODE_NAME: &str = "dustsph";
pub(super) const CODE_LEN: usize = CODE_NAME.len();
pub const HEADER_GROUP: &str = "Header";
pub const GAS_GROUP: &str = "PartType0";
pub const DUST_GROUP: &str = "PartType3";
pub const GAS_TYPE: usize = 0;
pub const DUST_TYPE: usize = 3;

pub const COORDINATES: &str = "Coordinates";
pub const VELOCITIES: &str = "Velocities";
pub const MASSES: &str = "Masses";
pub const DENSITY: &str = "Density";
pub const INTERNAL_ENERGY: &str = "InternalEnergy";
pub const PRESSURE: &str = "Pressure";
pub const SMOOTHING_LENGTH: &str = "SmoothingLength";
pub const PARTICLE_IDS: &str = "ParticleIDs";
pub const FRACTION_INDEX: &str = "FractionIndex";
pub const STOPPING_TIME: &str = "StoppingTime";

/// The box a snapshot is written in: `Coordinates` = position − `offset`, inside [0, `size`)
/// along every axis, as GADGET readers (yt, …) take the domain to be [0, BoxSize).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub offset: [f64; 3],
    pub size: [f64; 3],
}

/// `SmoothingLength` / h: GADGET's smoothing length is the kernel's support radius, 2h here.
pub const SMOOTHING_LENGTH_PER_H: f64 = 2.0;

impl Frame {
    /// The period on periodic axes; elsewhere the particles' extent plus `pad` (the kernel
    /// support) on both sides, so no particle's kernel reaches a face; unused axes get a
    /// width of 2 `pad` with the particles (at 0) in the middle.
    pub fn of(snap: &SnapshotView) -> Frame {
        let (lo, hi) = extent(snap);
        Frame::of_extent(snap, snap.pad, lo, hi)
    }

    /// [`Frame::of`] for particles spanning `lo`..`hi` (over every process's share), with the
    /// margin `pad`.
    pub(super) fn of_extent(snap: &SnapshotView, pad: f64, lo: [f64; 3], hi: [f64; 3]) -> Frame {
        let pad = if pad.is_finite() && pad > 0.0 {
            pad
        } else {
            1.0
        };
        let mut f = Frame {
            offset: [-pad; 3],
            size: [2.0 * pad; 3],
        };
        for k in 0..snap.dim as usize {
            if let Some((lo, len)) = snap.periodic[k] {
                (f.offset[k], f.size[k]) = (lo, len);
                continue;
            }
            if lo[k] <= hi[k] {
                f.offset[k] = lo[k] - pad;
                f.size[k] = hi[k] - lo[k] + 2.0 * pad;
            }
        }
        f
    }
}

/// The particles' least and largest coordinate per axis (+∞ and −∞ without particles).
pub(super) fn extent(snap: &SnapshotView) -> ([f64; 3], [f64; 3]) {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for ph in snap.gas.iter().chain(&snap.dust) {
        for x in ph.x {
            for k in 0..3 {
                lo[k] = lo[k].min(x[k]);
                hi[k] = hi[k].max(x[k]);
            }
        }
    }
    (lo, hi)
}
