//! GADGET/GIZMO-style HDF5 snapshots: gas in `PartType0`, every dust fraction concatenated in
//! `PartType3` with a `FractionIndex` column, run metadata in the `Header` group's attributes.

use std::borrow::Cow;
use std::fs;
use std::path::Path;
use std::str::FromStr;

use hdf5::types::{FixedAscii, TypeDescriptor, VarLenAscii, VarLenUnicode};
use hdf5::{File, Group, H5Type, Location};
use ndarray::{ArrayViewD, IxDyn};

use super::chunks::RowShare;
use super::{commit_tmp, remove_stale, require_parent_dir, tmp_path, IoError, WithPath};

/// Value of the `Code` header attribute.
pub const CODE_NAME: &str = "dustsph";
const CODE_LEN: usize = CODE_NAME.len();
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

/// Shuffle + deflate only: every HDF5 build and reader has them, unlike blosc.
pub const DEFLATE_LEVEL: u8 = 4;
/// Rows per chunk: 256 KiB for scalars, 768 KiB for 3-vectors, so a chunk fits HDF5's default
/// 1 MiB chunk cache.
const CHUNK_ROWS: usize = 1 << 15;

/// [`CHUNK_ROWS`], or `DUSTSPH_CHUNK_ROWS` where set (tests/mpi.rs writes a small run's
/// snapshots in many chunks, so that every rank deflates some).
fn chunk_rows() -> usize {
    crate::env::count("DUSTSPH_CHUNK_ROWS", CHUNK_ROWS)
}

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

/// The columns of one particle group, borrowed where no copy is needed.
struct Columns<'a> {
    x: Cow<'a, [[f64; 3]]>,
    v: Cow<'a, [[f64; 3]]>,
    m: Cow<'a, [f64]>,
    rho: Cow<'a, [f64]>,
    h: Vec<f64>,
    id: Cow<'a, [u64]>,
    e: Option<Cow<'a, [f64]>>,
    p: Option<Cow<'a, [f64]>>,
    t_stop: Option<Cow<'a, [f64]>>,
    fraction: Option<Vec<u32>>,
}

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
    fn of_extent(snap: &SnapshotView, pad: f64, lo: [f64; 3], hi: [f64; 3]) -> Frame {
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
fn extent(snap: &SnapshotView) -> ([f64; 3], [f64; 3]) {
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

impl<'a> Columns<'a> {
    fn gas(g: &PhaseView<'a>) -> Self {
        Columns {
            x: Cow::Borrowed(g.x),
            v: Cow::Borrowed(g.v),
            m: Cow::Borrowed(g.m),
            rho: Cow::Borrowed(g.rho),
            h: g.smoothing_lengths().collect(),
            id: Cow::Borrowed(g.id),
            e: g.e.map(Cow::Borrowed),
            p: g.p.map(Cow::Borrowed),
            t_stop: g.t_stop.map(Cow::Borrowed),
            fraction: None,
        }
    }

    /// Concatenates the dust fractions. A fraction without stopping times gets NaN ("not
    /// available") when another fraction has them, so the column stays aligned.
    fn dust(fractions: &[PhaseView<'a>], path: &Path) -> Result<Self, IoError> {
        if let [f] = fractions {
            // One fraction: its columns as they are (a copy of each beside the state was part
            // of the peak memory of a run's output).
            return Ok(Columns {
                x: Cow::Borrowed(f.x),
                v: Cow::Borrowed(f.v),
                m: Cow::Borrowed(f.m),
                rho: Cow::Borrowed(f.rho),
                h: f.smoothing_lengths().collect(),
                id: Cow::Borrowed(f.id),
                e: None,
                p: None,
                t_stop: f.t_stop.map(Cow::Borrowed),
                fraction: Some(vec![0; f.len()]),
            });
        }
        let n: usize = fractions.iter().map(PhaseView::len).sum();
        let any_t_stop = fractions.iter().any(|f| f.t_stop.is_some());
        let (mut x, mut v) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let (mut m, mut rho, mut h) = (
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
        );
        let (mut id, mut fraction) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let mut t_stop = any_t_stop.then(|| Vec::with_capacity(n));
        for (k, f) in fractions.iter().enumerate() {
            let k = u32::try_from(k).map_err(|_| {
                IoError::invalid(path, format!("dust fraction index {k} does not fit in u32"))
            })?;
            x.extend_from_slice(f.x);
            v.extend_from_slice(f.v);
            m.extend_from_slice(f.m);
            rho.extend_from_slice(f.rho);
            h.extend(f.smoothing_lengths());
            id.extend_from_slice(f.id);
            fraction.resize(fraction.len() + f.len(), k);
            if let Some(t) = t_stop.as_mut() {
                match f.t_stop {
                    Some(ts) => t.extend_from_slice(ts),
                    None => t.resize(t.len() + f.len(), f64::NAN),
                }
            }
        }
        Ok(Columns {
            x: Cow::Owned(x),
            v: Cow::Owned(v),
            m: Cow::Owned(m),
            rho: Cow::Owned(rho),
            h,
            id: Cow::Owned(id),
            e: None,
            p: None,
            t_stop: t_stop.map(Cow::Owned),
            fraction: Some(fraction),
        })
    }

    /// Positions in the file's frame.
    fn shift(mut self, f: &Frame) -> Self {
        let o = f.offset;
        // In place where the columns own their positions (copied once where they borrow).
        for x in self.x.to_mut() {
            *x = [x[0] - o[0], x[1] - o[1], x[2] - o[2]];
        }
        self
    }
}

/// Maps an HDF5 error to an [`IoError`] naming the file and the object inside it.
pub(crate) fn h5err<'a>(
    path: &'a Path,
    object: &'a str,
) -> impl FnOnce(hdf5::Error) -> IoError + 'a {
    move |e| IoError::hdf5(path, object, e)
}

fn validate(path: &Path, snap: &SnapshotView) -> Result<SceneTexts, IoError> {
    if !(1..=3).contains(&snap.dim) {
        return Err(IoError::invalid(
            path,
            format!("dimension must be 1, 2 or 3, got {}", snap.dim),
        ));
    }
    if let Some(g) = &snap.gas {
        g.check("gas", path)?;
    }
    for (k, d) in snap.dust.iter().enumerate() {
        d.check(&format!("dust fraction {k}"), path)?;
    }
    // HDF5 strings are C strings: an interior NUL would silently truncate the scene.
    let text = |s: &str| {
        VarLenUnicode::from_str(s)
            .map_err(|e| IoError::invalid(path, format!("scene text cannot be stored: {e}")))
    };
    let overrides = serde_json::to_string(snap.source.overrides)
        .map_err(|e| IoError::invalid(path, format!("overrides cannot be stored: {e}")))?;
    Ok(SceneTexts {
        effective: text(snap.scene_text)?,
        model: text(snap.scene_model)?,
        file: text(snap.source.file)?,
        file_text: text(snap.source.text)?,
        overrides: text(&overrides)?,
        initial_conditions: match snap.source.initial_conditions {
            Some((p, d)) => Some((text(p)?, text(d)?)),
            None => None,
        },
    })
}

/// The Header's scene attributes, checked storable before the file is touched.
struct SceneTexts {
    effective: VarLenUnicode,
    model: VarLenUnicode,
    file: VarLenUnicode,
    file_text: VarLenUnicode,
    overrides: VarLenUnicode,
    initial_conditions: Option<(VarLenUnicode, VarLenUnicode)>,
}

/// Writes the snapshot to `path` atomically: write to a temporary name in the same directory
/// (e.g. ".snapshot_0003.h5.tmp"), flush/close, then rename. No half-written file ever carries
/// the final name.
pub fn write_snapshot(path: &Path, snap: &SnapshotView) -> Result<(), IoError> {
    let (c, filter) = (&crate::dist::Alone, &super::chunks::OnCores);
    write_snapshot_shared(path, snap, c, filter).map(|_| ())
}

/// The snapshot of particles every process of `c` holds a share of (collective; `snap`: this
/// process's, in its order): one file, the layout of [`write_snapshot`], each part of a group
/// (the gas; each dust fraction) process by process, each share in its process's order.
/// Process 0 writes the file (to a temporary name, renamed when whole); each chunk is filtered
/// where most of its rows are ([`super::chunks::write_rows_shared`]), so no process holds
/// every particle. Everything is checked on every process first; every process returns the
/// first process's error. Returns the rows of the gas and of the dust in all.
pub fn write_snapshot_shared(
    path: &Path,
    snap: &SnapshotView,
    c: &dyn crate::dist::Comm,
    filter: &dyn super::chunks::ChunkFilter,
) -> Result<[u64; 2], IoError> {
    // Check everything that can be checked before touching the disk.
    let checked = validate(path, snap).and_then(|scene| {
        let gas = snap.gas.as_ref().map(Columns::gas);
        let dust = if snap.dust.is_empty() {
            None
        } else {
            Some(Columns::dust(&snap.dust, path)?)
        };
        Ok((scene, gas, dust))
    });
    // Which columns this process has, and its rows of each part.
    let mine = match &checked {
        Ok((_, gas, dust)) => {
            let has = |x: bool| x as u64;
            let mut v = vec![
                has(gas.is_some()),
                has(gas.as_ref().is_some_and(|g| g.e.is_some())),
                has(gas.as_ref().is_some_and(|g| g.p.is_some())),
                has(gas.as_ref().is_some_and(|g| g.t_stop.is_some())),
                has(dust.as_ref().is_some_and(|d| d.t_stop.is_some())),
                snap.dust.len() as u64,
                snap.gas.as_ref().map_or(0, |g| g.len() as u64),
            ];
            v.extend(snap.dust.iter().map(|d| d.len() as u64));
            v
        }
        Err(_) => Vec::new(),
    };
    let (scene, gas, dust) = go_on(c, path, checked)?;
    let all = same_columns(c, path, &mine, 6)?;
    let me = c.rank() as usize;
    let gas_share = RowShare::of(&all.iter().map(|v| vec![v[6]]).collect::<Vec<_>>(), me);
    let dust_share = RowShare::of(&all.iter().map(|v| v[7..].to_vec()).collect::<Vec<_>>(), me);
    // The box over every process's particles.
    let (lo, hi) = extent(snap);
    let mut most = [snap.pad, -lo[0], -lo[1], -lo[2], hi[0], hi[1], hi[2]];
    c.max_f64(&mut most);
    let lo = [-most[1], -most[2], -most[3]];
    let frame = Frame::of_extent(snap, most[0], lo, [most[4], most[5], most[6]]);
    let gas = gas.map(|g| g.shift(&frame));
    let dust = dust.map(|d| d.shift(&frame));
    let mut num_part = [0u64; 6];
    num_part[GAS_TYPE] = if gas.is_some() { gas_share.total } else { 0 };
    num_part[DUST_TYPE] = if dust.is_some() { dust_share.total } else { 0 };
    let header = |f: &File| write_header(f, path, snap, &frame, &scene, &num_part);
    let (tmp, file) = create_shared(c, path, header)?;
    let result = (|| {
        let groups = [
            (GAS_GROUP, gas.as_ref(), &gas_share),
            (DUST_GROUP, dust.as_ref(), &dust_share),
        ];
        for (name, cols, share) in groups {
            if let Some(cols) = cols {
                write_group(file.as_ref(), name, cols, share, path, c, filter)?;
            }
        }
        // Explicit close so a failed final flush is reported instead of lost in Drop.
        let closed = match file {
            Some(f) => (f.close().map_err(h5err(path, ""))).and_then(|()| commit_tmp(&tmp, path)),
            None => Ok(()),
        };
        go_on(c, path, closed)
    })();
    if result.is_err() && me == 0 {
        // Best effort: the original error matters more than a failed cleanup.
        let _ = fs::remove_file(&tmp);
    }
    result.map(|()| [num_part[GAS_TYPE], num_part[DUST_TYPE]])
}

/// Every process's `mine` (counts), in rank order, once every process has checked that its
/// first `same` entries (which columns it has) are everyone's (collective).
pub(crate) fn same_columns(
    c: &dyn crate::dist::Comm,
    path: &Path,
    mine: &[u64],
    same: usize,
) -> Result<Vec<Vec<u64>>, IoError> {
    let all: Vec<Vec<u64>> = (c.all_gather_bytes(bytemuck::cast_slice(mine)).iter())
        .map(|b| {
            (b.chunks_exact(8))
                .map(|w| u64::from_le_bytes(w.try_into().expect("8 bytes")))
                .collect()
        })
        .collect();
    if all.iter().any(|v| v[..same] != mine[..same]) {
        return Err(IoError::invalid(
            path,
            "the processes hold different columns or dust fractions",
        ));
    }
    Ok(all)
}

/// A file written by share: on process 0 a new file under a temporary name beside `path`
/// (`create_excl`: never through something that appeared under that name), begun by `begin`;
/// the temporary name, and the file on process 0 (collective: every process goes on, or none).
pub(crate) fn create_shared(
    c: &dyn crate::dist::Comm,
    path: &Path,
    begin: impl FnOnce(&File) -> Result<(), IoError>,
) -> Result<(std::path::PathBuf, Option<File>), IoError> {
    if c.rank() != 0 {
        go_on(c, path, Ok(()))?;
        go_on(c, path, Ok(()))?;
        return Ok((path.to_path_buf(), None));
    }
    let tmp = go_on(
        c,
        path,
        require_parent_dir(path).and_then(|()| tmp_path(path)),
    )?;
    let made = remove_stale(&tmp)
        .and_then(|()| File::create_excl(&tmp).with_path(&tmp))
        .and_then(|f| begin(&f).map(|()| f));
    if made.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    Ok((tmp, Some(go_on(c, path, made)?)))
}

/// A copy of an error to agree on (the original is returned where it arose).
pub(crate) fn clone_err(e: &IoError) -> IoError {
    IoError::invalid(e.path(), e.to_string())
}

/// This process's `mine` once every process of `c` has said whether it can go on
/// (collective): its own error as it arose, else the first other process's, else its value.
pub(crate) fn go_on<T>(
    c: &dyn crate::dist::Comm,
    path: &Path,
    mine: Result<T, IoError>,
) -> Result<T, IoError> {
    let said = agreed(c, path, mine.as_ref().map(|_| ()).map_err(clone_err));
    match (mine, said) {
        (Err(e), _) | (Ok(_), Err(e)) => Err(e),
        (Ok(t), Ok(())) => Ok(t),
    }
}

fn write_header(
    file: &File,
    path: &Path,
    snap: &SnapshotView,
    frame: &Frame,
    scene: &SceneTexts,
    num_part: &[u64; 6],
) -> Result<(), IoError> {
    let obj = format!("/{HEADER_GROUP}");
    let g = file.create_group(HEADER_GROUP).map_err(h5err(path, &obj))?;
    let dim = snap.dim as i32; // validated to 1..=3
                               // Fixed-length ASCII, as GADGET and SWIFT write it: yt's frontend detection calls
                               // `.decode()` on `Code`, which only works when h5py returns bytes, not str.
    let code = FixedAscii::<CODE_LEN>::from_ascii(CODE_NAME).expect("code name is ASCII");
    put_scalar(&g, "Time", &snap.time, path)?;
    put_array(&g, "NumPart_ThisFile", num_part, path)?;
    put_array(&g, "NumPart_Total", num_part, path)?;
    put_array(&g, "MassTable", &[0.0f64; 6], path)?;
    put_scalar(&g, "NumFilesPerSnapshot", &1i32, path)?;
    // GADGET's one BoxSize (yt takes the domain as [0, BoxSize)³ and cannot read more than
    // one value): the largest extent; the extent per axis beside it (for yt's
    // `bounding_box`, README "Output"); CoordinateOffset turns Coordinates back into
    // positions; SmoothingLength is the support radius 2h.
    let largest = frame.size.iter().fold(0.0f64, |a, &b| a.max(b));
    put_scalar(&g, "BoxSize", &largest, path)?;
    put_array(&g, "BoxSizePerAxis", &frame.size, path)?;
    put_array(&g, "CoordinateOffset", &frame.offset, path)?;
    put_scalar(&g, "SmoothingLengthPerH", &SMOOTHING_LENGTH_PER_H, path)?;
    put_scalar(&g, "Dimension", &dim, path)?;
    put_scalar(&g, "Code", &code, path)?;
    // The scene as run (what readers parse), and how it was made.
    put_scalar(&g, "Scene", &scene.effective, path)?;
    put_scalar(&g, "SceneModel", &scene.model, path)?;
    put_scalar(&g, "SceneFile", &scene.file, path)?;
    put_scalar(&g, "SceneFileText", &scene.file_text, path)?;
    put_scalar(&g, "SceneOverrides", &scene.overrides, path)?;
    if let Some((file, digest)) = &scene.initial_conditions {
        put_scalar(&g, "InitialConditionsFile", file, path)?;
        put_scalar(&g, "InitialConditionsSHA256", digest, path)?;
    }
    if let Some(u) = snap.source.units {
        write_units(file, &g, u, path)?;
    }
    // Conventional GADGET fields: older yt releases and other GADGET readers index them
    // unconditionally; OmegaLambda = 0 marks the run as non-cosmological.
    put_array(&g, "NumPart_Total_HighWord", &[0u32; 6], path)?;
    put_scalar(&g, "Redshift", &0.0f64, path)?;
    put_scalar(&g, "Omega0", &0.0f64, path)?;
    put_scalar(&g, "OmegaLambda", &0.0f64, path)?;
    put_scalar(&g, "HubbleParam", &1.0f64, path)?;
    Ok(())
}

/// The unit system where readers look for it: GADGET-4/AREPO's `UnitLength_in_cm`,
/// `UnitMass_in_g`, `UnitVelocity_in_cm_per_s` in the Header (yt's GADGET frontend takes them
/// as `unit_base`) and in a `Units` group, with SWIFT's names there too (`Unit length in cgs
/// (U_L)`, …; current and temperature are 1: dustsph has neither).
fn write_units(file: &File, header: &Group, u: [f64; 3], path: &Path) -> Result<(), IoError> {
    let [l, m, t] = u;
    let gadget = [
        ("UnitLength_in_cm", l),
        ("UnitMass_in_g", m),
        ("UnitVelocity_in_cm_per_s", l / t),
        ("UnitTime_in_s", t),
    ];
    for (name, v) in gadget {
        put_scalar(header, name, &v, path)?;
    }
    let obj = "/Units";
    let g = file.create_group("Units").map_err(h5err(path, obj))?;
    let swift = [
        ("Unit length in cgs (U_L)", l),
        ("Unit mass in cgs (U_M)", m),
        ("Unit time in cgs (U_t)", t),
        ("Unit current in cgs (U_I)", 1.0),
        ("Unit temperature in cgs (U_T)", 1.0),
    ];
    for (name, v) in gadget.into_iter().chain(swift) {
        put_array(&g, name, &[v], path)?;
    }
    Ok(())
}

pub(crate) fn put_scalar<T: H5Type>(
    g: &Group,
    name: &str,
    value: &T,
    path: &Path,
) -> Result<(), IoError> {
    let obj = format!("{}/{name}", g.name());
    g.new_attr::<T>()
        .shape(())
        .create(name)
        .and_then(|a| a.write_scalar(value))
        .map_err(h5err(path, &obj))
}

fn put_array<T: H5Type>(g: &Group, name: &str, values: &[T], path: &Path) -> Result<(), IoError> {
    let obj = format!("{}/{name}", g.name());
    g.new_attr::<T>()
        .shape(values.len())
        .create(name)
        .and_then(|a| a.write_raw(values))
        .map_err(h5err(path, &obj))
}

fn write_group(
    file: Option<&File>,
    name: &str,
    cols: &Columns,
    share: &RowShare,
    path: &Path,
    c: &dyn crate::dist::Comm,
    filter: &dyn super::chunks::ChunkFilter,
) -> Result<(), IoError> {
    let obj = format!("/{name}");
    let g = file.map(|f| f.create_group(name).map_err(h5err(path, &obj)));
    let at = SharedGroup {
        g: g.as_ref(),
        share,
        path,
        c,
        filter,
    };
    at.put(COORDINATES, cols.x.as_flattened(), 3)?;
    at.put(VELOCITIES, cols.v.as_flattened(), 3)?;
    at.put(MASSES, &cols.m, 1)?;
    at.put(DENSITY, &cols.rho, 1)?;
    if let Some(e) = &cols.e {
        at.put(INTERNAL_ENERGY, e, 1)?;
    }
    if let Some(p) = &cols.p {
        at.put(PRESSURE, p, 1)?;
    }
    at.put(SMOOTHING_LENGTH, &cols.h, 1)?;
    at.put(PARTICLE_IDS, &cols.id, 1)?;
    if let Some(f) = &cols.fraction {
        at.put(FRACTION_INDEX, f, 1)?;
    }
    if let Some(t) = &cols.t_stop {
        at.put(STOPPING_TIME, t, 1)?;
    }
    Ok(())
}

/// A group written by share: process 0's group (or why it has none; `None` elsewhere), where
/// each process's rows lie, and how the chunks are filtered.
pub(crate) struct SharedGroup<'a> {
    pub g: Option<&'a Result<Group, IoError>>,
    pub share: &'a RowShare,
    pub path: &'a Path,
    pub c: &'a dyn crate::dist::Comm,
    pub filter: &'a dyn super::chunks::ChunkFilter,
}

impl SharedGroup<'_> {
    /// One dataset of this process's rows `data` (`width` values a row), agreed by every
    /// process before the next: no process sends chunks process 0 stopped reading.
    pub(crate) fn put<T: H5Type + Copy + Sync>(
        &self,
        name: &str,
        data: &[T],
        width: usize,
    ) -> Result<(), IoError> {
        let g = self.g.map(|r| r.as_ref().map_err(clone_err));
        let (share, path, c) = (self.share, self.path, self.c);
        let put = put_dataset_shared(g, name, data, width, share, path, c, self.filter);
        agreed(c, path, put)
    }
}

/// Every process's verdict on a step of a shared write: the first process's error on each.
fn agreed(
    c: &dyn crate::dist::Comm,
    path: &Path,
    mine: Result<(), IoError>,
) -> Result<(), IoError> {
    crate::dist::agree(c, mine, IoError::to_string, |why| {
        IoError::invalid(path, format!("another process: {why}"))
    })
}

/// Writes `data` as an N (width 1) or N×width dataset, chunked and compressed unless empty
/// (the filters run on every core: [`super::chunks`]).
#[cfg(test)]
pub(crate) fn put_dataset<T: H5Type + Copy + Sync>(
    g: &Group,
    name: &str,
    data: &[T],
    width: usize,
    path: &Path,
) -> Result<(), IoError> {
    let share = RowShare::whole((data.len() / width) as u64);
    let (c, filter) = (&crate::dist::Alone, &super::chunks::OnCores);
    put_dataset_shared(Some(Ok(g)), name, data, width, &share, path, c, filter)
}

/// [`put_dataset`] of the rows every process of `c` holds a share of (`data`: this process's;
/// `share`: where they lie), into `g` (process 0's group, or why it has none; `None`
/// elsewhere), the chunks filtered by `filter` (collective).
#[allow(clippy::too_many_arguments)]
fn put_dataset_shared<T: H5Type + Copy + Sync>(
    g: Option<Result<&Group, IoError>>,
    name: &str,
    data: &[T],
    width: usize,
    share: &RowShare,
    path: &Path,
    c: &dyn crate::dist::Comm,
    filter: &dyn super::chunks::ChunkFilter,
) -> Result<(), IoError> {
    let rows = share.total as usize;
    let shape = if width == 1 {
        vec![rows]
    } else {
        vec![rows, width]
    };
    let obj = |g: &Group| format!("{}/{name}", g.name());
    if rows == 0 {
        // Chunk dimensions must be positive and there is nothing to compress: plain contiguous.
        return match g {
            Some(Ok(g)) => {
                let view = ArrayViewD::from_shape(IxDyn(&shape), data)
                    .map_err(|e| IoError::invalid(path, format!("{}: {e}", obj(g))))?;
                g.new_dataset_builder()
                    .with_data(view)
                    .no_chunk()
                    .create(name)
                    .map(|_| ())
                    .map_err(h5err(path, &obj(g)))
            }
            Some(Err(e)) => Err(e),
            None => Ok(()),
        };
    }
    let chunk_rows = rows.min(chunk_rows());
    let mut chunk = shape.clone();
    chunk[0] = chunk_rows;
    // Shuffle first: it groups bytes of equal significance, which deflate then packs.
    let ds = g.map(|g| {
        g.and_then(|g| {
            g.new_dataset::<T>()
                .shape(shape)
                .chunk(chunk)
                .shuffle()
                .deflate(DEFLATE_LEVEL)
                .create(name)
                .map_err(h5err(path, &obj(g)))
        })
    });
    let ds_ref = ds.as_ref().map(|r| r.as_ref().map_err(clone_err));
    let label =
        (ds.as_ref().and_then(|r| r.as_ref().ok())).map_or_else(|| name.to_string(), |d| d.name());
    super::chunks::write_rows_shared(
        ds_ref,
        data,
        width,
        share,
        (chunk_rows, DEFLATE_LEVEL),
        c,
        filter,
        (path, &label),
    )
}

/// What a snapshot's header says about the run that wrote it.
#[derive(Debug, Clone, PartialEq)]
pub struct SnapshotHeader {
    pub time: f64,
    pub dim: u32,
    pub scene_text: String,
    /// The scene file's verbatim text and the overrides (None in snapshots written before
    /// the Header recorded them, whose `Scene` is the file's text alone).
    pub source_text: Option<String>,
    pub overrides: Option<Vec<String>>,
    /// The resolved scene model (`SceneModel`; None in snapshots written before it).
    pub scene_model: Option<String>,
    pub num_part: [u64; 6],
}

/// The header of a snapshot only (no particle arrays).
pub fn read_header(path: &Path) -> Result<SnapshotHeader, IoError> {
    Ok(open_header(path)?.1)
}

/// The file and its header (a plain stat first gives "No such file" instead of an opaque HDF5
/// message).
fn open_header(path: &Path) -> Result<(File, SnapshotHeader), IoError> {
    fs::metadata(path).with_path(path)?;
    let file = File::open(path).map_err(h5err(path, ""))?;
    let obj = format!("/{HEADER_GROUP}");
    let header = file.group(HEADER_GROUP).map_err(h5err(path, &obj))?;
    let dim: i32 = get_scalar(&header, "Dimension", path)?;
    let h =
        SnapshotHeader {
            time: get_scalar(&header, "Time", path)?,
            dim: u32::try_from(dim)
                .map_err(|_| IoError::invalid(path, format!("/Header/Dimension is {dim}")))?,
            scene_text: get_string(&header, "Scene", path)?,
            source_text: match header.attr("SceneFileText") {
                Ok(_) => Some(get_string(&header, "SceneFileText", path)?),
                Err(_) => None,
            },
            overrides: match header.attr("SceneOverrides") {
                Ok(_) => {
                    let json = get_string(&header, "SceneOverrides", path)?;
                    Some(serde_json::from_str(&json).map_err(|e| {
                        IoError::invalid(path, format!("/Header/SceneOverrides: {e}"))
                    })?)
                }
                Err(_) => None,
            },
            scene_model: match header.attr("SceneModel") {
                Ok(_) => Some(get_string(&header, "SceneModel", path)?),
                Err(_) => None,
            },
            num_part: get_counts(&header, "NumPart_Total", path)?,
        };
    Ok((file, h))
}

/// Reads a snapshot written by [`write_snapshot`].
pub fn read_snapshot(path: &Path) -> Result<SnapshotData, IoError> {
    let (file, h) = open_header(path)?;
    let obj = format!("/{HEADER_GROUP}");
    let header = file.group(HEADER_GROUP).map_err(h5err(path, &obj))?;
    // Files before the box-relative frame: one BoxSize, true coordinates, SmoothingLength = h.
    let box_size = if header.attr("BoxSizePerAxis").is_ok() {
        <[f64; 3]>::try_from(get_f64s(&header, "BoxSizePerAxis", path)?.as_slice())
            .map_err(|_| IoError::invalid(path, "/Header/BoxSizePerAxis must have 3 values"))?
    } else {
        [get_scalar::<f64>(&header, "BoxSize", path)?; 3]
    };
    let offset = if header.attr("CoordinateOffset").is_ok() {
        <[f64; 3]>::try_from(get_f64s(&header, "CoordinateOffset", path)?.as_slice())
            .map_err(|_| IoError::invalid(path, "/Header/CoordinateOffset must have 3 values"))?
    } else {
        [0.0; 3]
    };
    let per_h = if header.attr("SmoothingLengthPerH").is_ok() {
        get_scalar(&header, "SmoothingLengthPerH", path)?
    } else {
        1.0
    };
    let SnapshotHeader {
        time,
        dim,
        scene_text,
        num_part,
        ..
    } = h;
    let this_file = get_counts(&header, "NumPart_ThisFile", path)?;
    if this_file != num_part {
        return Err(IoError::invalid(
            path,
            format!(
                "NumPart_ThisFile {this_file:?} differs from NumPart_Total {num_part:?}; \
                 multi-file snapshots are not supported"
            ),
        ));
    }
    let back = |p: Option<PhaseData>| {
        p.map(|mut p| {
            for x in &mut p.x {
                for k in 0..3 {
                    x[k] += offset[k];
                }
            }
            for h in &mut p.h {
                *h /= per_h;
            }
            p
        })
    };
    let gas = back(read_group(&file, GAS_GROUP, num_part[GAS_TYPE], path)?);
    let dust = back(read_group(&file, DUST_GROUP, num_part[DUST_TYPE], path)?);
    Ok(SnapshotData {
        time,
        dim,
        box_size,
        offset,
        scene_text,
        num_part,
        gas,
        dust,
    })
}

/// Reads a one-value attribute; accepts shape () or (1,) as other writers use both.
pub(crate) fn get_scalar<T: H5Type>(loc: &Location, name: &str, path: &Path) -> Result<T, IoError> {
    let obj = format!("{}/{name}", loc.name());
    let mut v: Vec<T> = loc
        .attr(name)
        .and_then(|a| a.read_raw())
        .map_err(h5err(path, &obj))?;
    match v.len() {
        1 => Ok(v.remove(0)),
        n => Err(IoError::invalid(
            path,
            format!("{obj}: expected one value, found {n}"),
        )),
    }
}

/// Reads a float attribute of any length.
fn get_f64s(loc: &Location, name: &str, path: &Path) -> Result<Vec<f64>, IoError> {
    let obj = format!("{}/{name}", loc.name());
    loc.attr(name)
        .and_then(|a| a.read_raw())
        .map_err(h5err(path, &obj))
}

fn get_counts(loc: &Location, name: &str, path: &Path) -> Result<[u64; 6], IoError> {
    let obj = format!("{}/{name}", loc.name());
    let v: Vec<u64> = loc
        .attr(name)
        .and_then(|a| a.read_raw())
        .map_err(h5err(path, &obj))?;
    <[u64; 6]>::try_from(v.as_slice())
        .map_err(|_| IoError::invalid(path, format!("{obj}: expected 6 values, found {}", v.len())))
}

/// Reads a variable-length string attribute (UTF-8 or ASCII).
pub(crate) fn get_string(loc: &Location, name: &str, path: &Path) -> Result<String, IoError> {
    let obj = format!("{}/{name}", loc.name());
    let attr = loc.attr(name).map_err(h5err(path, &obj))?;
    let desc = attr
        .dtype()
        .and_then(|t| t.to_descriptor())
        .map_err(h5err(path, &obj))?;
    match desc {
        TypeDescriptor::VarLenUnicode => attr
            .read_scalar::<VarLenUnicode>()
            .map(|s| s.as_str().to_owned())
            .map_err(h5err(path, &obj)),
        TypeDescriptor::VarLenAscii => attr
            .read_scalar::<VarLenAscii>()
            .map(|s| s.as_str().to_owned())
            .map_err(h5err(path, &obj)),
        other => Err(IoError::invalid(
            path,
            format!("{obj}: expected a variable-length string, found {other}"),
        )),
    }
}

fn read_group(
    file: &File,
    name: &str,
    count: u64,
    path: &Path,
) -> Result<Option<PhaseData>, IoError> {
    if !file.link_exists(name) {
        if count > 0 {
            return Err(IoError::invalid(
                path,
                format!("header counts {count} particles but group /{name} is missing"),
            ));
        }
        return Ok(None);
    }
    let obj = format!("/{name}");
    let g = file.group(name).map_err(h5err(path, &obj))?;
    let n = usize::try_from(count)
        .map_err(|_| IoError::invalid(path, format!("{obj}: {count} particles is too many")))?;
    Ok(Some(PhaseData {
        x: get_vec3(&g, COORDINATES, n, path)?,
        v: get_vec3(&g, VELOCITIES, n, path)?,
        m: get_column(&g, MASSES, n, path)?,
        rho: get_column(&g, DENSITY, n, path)?,
        h: get_column(&g, SMOOTHING_LENGTH, n, path)?,
        id: get_column(&g, PARTICLE_IDS, n, path)?,
        e: get_optional(&g, INTERNAL_ENERGY, n, path)?,
        p: get_optional(&g, PRESSURE, n, path)?,
        t_stop: get_optional(&g, STOPPING_TIME, n, path)?,
        fraction: get_optional(&g, FRACTION_INDEX, n, path)?,
    }))
}

/// Reads a dataset whose shape must be exactly `shape`, flattened row-major.
pub(crate) fn get_shaped<T: H5Type>(
    g: &Group,
    name: &str,
    shape: &[usize],
    path: &Path,
) -> Result<Vec<T>, IoError> {
    get_rows(g, name, shape, 0..shape.first().copied().unwrap_or(0), path)
}

/// Rows `rows` of a dataset whose shape must be exactly `shape`, flattened row-major (a
/// process's share of a file written by several).
pub(crate) fn get_rows<T: H5Type>(
    g: &Group,
    name: &str,
    shape: &[usize],
    rows: std::ops::Range<usize>,
    path: &Path,
) -> Result<Vec<T>, IoError> {
    let obj = format!("{}/{name}", g.name());
    let ds = g.dataset(name).map_err(h5err(path, &obj))?;
    let found = ds.shape();
    if found != shape {
        return Err(IoError::invalid(
            path,
            format!("{obj}: shape {found:?}, expected {shape:?} from the header counts"),
        ));
    }
    let whole = 0..shape.first().copied().unwrap_or(0);
    let read = if rows == whole {
        ds.read_raw()
    } else if rows.is_empty() {
        Ok(Vec::new())
    } else if shape.len() == 1 {
        (ds.read_slice_1d::<T, _>(rows)).map(|a| a.into_raw_vec_and_offset().0)
    } else {
        (ds.read_slice_2d::<T, _>((rows, ..))).map(|a| a.into_raw_vec_and_offset().0)
    };
    read.map_err(h5err(path, &obj))
}

pub(crate) fn get_column<T: H5Type>(
    g: &Group,
    name: &str,
    n: usize,
    path: &Path,
) -> Result<Vec<T>, IoError> {
    get_shaped(g, name, &[n], path)
}

pub(crate) fn get_optional<T: H5Type>(
    g: &Group,
    name: &str,
    n: usize,
    path: &Path,
) -> Result<Option<Vec<T>>, IoError> {
    if g.link_exists(name) {
        get_column(g, name, n, path).map(Some)
    } else {
        Ok(None)
    }
}

pub(crate) fn get_vec3(
    g: &Group,
    name: &str,
    n: usize,
    path: &Path,
) -> Result<Vec<[f64; 3]>, IoError> {
    get_vec3_rows(g, name, n, 0..n, path)
}

/// Rows `rows` of an n × 3 dataset, as vectors.
pub(crate) fn get_vec3_rows(
    g: &Group,
    name: &str,
    n: usize,
    rows: std::ops::Range<usize>,
    path: &Path,
) -> Result<Vec<[f64; 3]>, IoError> {
    let flat: Vec<f64> = get_rows(g, name, &[n, 3], rows, path)?;
    Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

#[cfg(test)]
mod tests;
