//! GADGET/GIZMO-style HDF5 snapshots: gas in `PartType0`, every dust fraction concatenated in
//! `PartType3` with a `FractionIndex` column, run metadata in the `Header` group's attributes.
//!
//! The layout's names (`schema`), the writer and the reader are submodules; the HDF5 helpers
//! and the collective protocol that checkpoints also use are `io::h5` and `io::shared`.
mod reader;
mod schema;
mod writer;

use std::path::Path;

// The writer names the chunk filters `super::chunks` (io's), as it did inside this file.
use super::chunks;
use super::IoError;

pub use super::shared::DEFLATE_LEVEL;
pub use reader::{read_header, read_snapshot, SnapshotHeader};
pub use schema::*;
pub use writer::{write_snapshot, write_snapshot_shared};

/// A borrowed view of one particle phase for output.
#[derive(Clone, Copy, Debug)]
pub struct PhaseView<'a> {
    /// Positions (unused coordinates are 0).
    pub x: &'a [[f64; 3]],
    pub v: &'a [[f64; 3]],
    pub m: &'a [f64],
    pub rho: &'a [f64],
    /// Global smoothing length (kernel support 2h), written per particle as `SmoothingLength`
    /// = 2h, GADGET's convention (the radius where the kernel vanishes).
    pub h: f64,
    /// Per-particle h where it varies (variable-h gas); overrides `h`.
    pub h_each: Option<&'a [f64]>,
    pub id: &'a [u64],
    /// Gas internal energy.
    pub e: Option<&'a [f64]>,
    /// Gas pressure.
    pub p: Option<&'a [f64]>,
    /// Dust stopping time (may hold +inf where a particle is uncoupled).
    pub t_stop: Option<&'a [f64]>,
}

impl PhaseView<'_> {
    /// Number of particles (the length of `x`).
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Each particle's `SmoothingLength` (2h: its own h where h varies, else the global one).
    fn smoothing_lengths(&self) -> impl Iterator<Item = f64> + '_ {
        let each = self.h_each.map(|he| he.iter().copied());
        let global = std::iter::repeat_n(self.h, if each.is_some() { 0 } else { self.len() });
        each.into_iter()
            .flatten()
            .chain(global)
            .map(|h| SMOOTHING_LENGTH_PER_H * h)
    }

    /// Every per-particle array must have as many entries as `x`.
    fn check(&self, label: &str, path: &Path) -> Result<(), IoError> {
        let n = self.len();
        let lens = [
            ("v", Some(self.v.len())),
            ("m", Some(self.m.len())),
            ("rho", Some(self.rho.len())),
            ("id", Some(self.id.len())),
            ("e", self.e.map(<[f64]>::len)),
            ("p", self.p.map(<[f64]>::len)),
            ("t_stop", self.t_stop.map(<[f64]>::len)),
            ("h_each", self.h_each.map(<[f64]>::len)),
        ];
        for (name, len) in lens {
            if let Some(len) = len {
                if len != n {
                    return Err(IoError::invalid(
                        path,
                        format!("{label}: `{name}` has {len} entries but `x` has {n}"),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Everything one snapshot holds, borrowed from the simulation.
#[derive(Clone, Debug)]
pub struct SnapshotView<'a> {
    pub time: f64,
    pub dim: u32,
    /// Periodic axes (lower end, length); the box of the file is the period there and the
    /// particles' extent plus `pad` on each side elsewhere.
    pub periodic: [Option<(f64, f64)>; 3],
    /// Margin around the particles on open axes (the kernel support).
    pub pad: f64,
    /// The effective scene as TOML (the file with its `--set` overrides applied): the
    /// `Scene` attribute every reader parses.
    pub scene_text: &'a str,
    /// The resolved scene model as TOML (`Scene::to_toml`: every default applied): the
    /// `SceneModel` attribute, for readers; `Scene` is what parses back to the run.
    pub scene_model: &'a str,
    /// Where the effective scene came from.
    pub source: SceneSource<'a>,
    pub gas: Option<PhaseView<'a>>,
    /// One per dust fraction; index = fraction index.
    pub dust: Vec<PhaseView<'a>>,
}

/// How a run's scene was made: the file as given, its text verbatim (comments included), and
/// the `--set` overrides (Header attributes `SceneFile`, `SceneFileText`, `SceneOverrides`).
#[derive(Clone, Copy, Debug, Default)]
pub struct SceneSource<'a> {
    pub file: &'a str,
    pub text: &'a str,
    pub overrides: &'a [String],
    /// Initial conditions from a file: its path and SHA-256 (Header attributes
    /// `InitialConditionsFile`, `InitialConditionsSHA256`).
    pub initial_conditions: Option<(&'a str, &'a str)>,
    /// `[units]`: cm, g and s per code length, mass and time (None: no unit system).
    pub units: Option<[f64; 3]>,
}

/// One phase read back from a snapshot.
#[derive(Clone, Debug, PartialEq)]
pub struct PhaseData {
    pub x: Vec<[f64; 3]>,
    pub v: Vec<[f64; 3]>,
    pub m: Vec<f64>,
    pub rho: Vec<f64>,
    pub h: Vec<f64>,
    pub id: Vec<u64>,
    pub e: Option<Vec<f64>>,
    pub p: Option<Vec<f64>>,
    pub t_stop: Option<Vec<f64>>,
    pub fraction: Option<Vec<u32>>,
}

/// A snapshot read back (for tests and analysis).
#[derive(Clone, Debug, PartialEq)]
pub struct SnapshotData {
    pub time: f64,
    pub dim: u32,
    /// The file's box: `Coordinates` lie in [0, box_size) per axis (GADGET's convention); the
    /// positions read back (`x`) have `offset` added again.
    pub box_size: [f64; 3],
    pub offset: [f64; 3],
    pub scene_text: String,
    pub num_part: [u64; 6],
    pub gas: Option<PhaseData>,
    /// All dust fractions together; `fraction` tells them apart.
    pub dust: Option<PhaseData>,
}

#[cfg(test)]
mod tests;
