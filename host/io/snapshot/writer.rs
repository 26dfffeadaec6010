//! Writing a snapshot: its checks, the header, and each group's columns from every process's share.
use std::borrow::Cow;
use std::fs;
use std::path::Path;
use std::str::FromStr;

use hdf5::types::{FixedAscii, VarLenUnicode};
use hdf5::{File, Group};

use super::schema::*;
use super::{PhaseView, SnapshotView};
use crate::io::chunks::RowShare;
use crate::io::h5::{h5err, put_array, put_scalar};
use crate::io::shared::{create_shared, go_on, same_columns, SharedGroup};
use crate::io::{commit_tmp, IoError};

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
