//! Initial conditions from an HDF5 file in the layout dustsph writes and GADGET/SWIFT readers
//! expect: `PartType0` gas (`Coordinates`, `Velocities`, `Masses`; optional `Density`,
//! `SmoothingLength`, `InternalEnergy`, `ParticleIDs`), `PartType3` dust (the same, with
//! `FractionIndex`), and an optional `Header` (`Time`, `Dimension`, `BoxSize` or
//! `BoxSizePerAxis`, `CoordinateOffset`, `SmoothingLengthPerH`, `NumPart_Total`).
//!
//! Everything that can be checked without the scene is checked here (shapes, lengths, finite
//! values, positive masses, densities and smoothing lengths, unique IDs); each error names
//! the file, the dataset and the first offending row. The scene's own checks (fractions,
//! periodic box, dimension) are the set-up's (host/setup/file.rs).
//!
//! Over MPI ranks each rank reads only its share of the rows ([`crate::dist::share_rows`],
//! whole blocks of [`row_block`]), and the checks that span rows (unique IDs) run across the
//! ranks; an error names the row in the file, found by whichever rank holds it.
use std::path::Path;

use hdf5::{File, Group};

use super::h5::{get_scalar, h5err};
use super::snapshot::{
    COORDINATES, DENSITY, DUST_GROUP, FRACTION_INDEX, GAS_GROUP, HEADER_GROUP, INTERNAL_ENERGY,
    MASSES, PARTICLE_IDS, SMOOTHING_LENGTH, VELOCITIES,
};
use super::IoError;
use crate::dist::{agree, agree_first, share_rows, Alone, Comm};

/// Rows per block of a shared read: a rank's share is whole blocks, and sums over the rows
/// (the mean spacing) are taken block by block, so they come out the same on any number of
/// ranks.
pub const ROW_BLOCK: usize = 4096;

/// [`ROW_BLOCK`], or `DUSTSPH_ROW_BLOCK` where set (tests/mpi.rs shares a small file's rows
/// between every rank).
pub fn row_block() -> usize {
    crate::env::count("DUSTSPH_ROW_BLOCK", ROW_BLOCK)
}

/// One particle type of an initial-conditions file, positions in the run's frame
/// (`Coordinates` + `CoordinateOffset`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IcPhase {
    pub x: Vec<[f64; 3]>,
    pub v: Vec<[f64; 3]>,
    pub m: Vec<f64>,
    pub rho: Option<Vec<f64>>,
    /// h (the file's `SmoothingLength` divided by `SmoothingLengthPerH`).
    pub h: Option<Vec<f64>>,
    pub e: Option<Vec<f64>>,
    pub id: Option<Vec<u64>>,
    /// Dust only.
    pub fraction: Option<Vec<i64>>,
    /// The file's row of the first row here (rows `first..first + len()` of `total`).
    pub first: usize,
    /// The particle type's rows in the file (over every rank).
    pub total: usize,
}

impl IcPhase {
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// An initial-conditions file as read.
#[derive(Debug, Clone, PartialEq)]
pub struct Ics {
    /// `Header/Time` (0 without it).
    pub time: f64,
    /// `Header/Dimension`, if given.
    pub dim: Option<u32>,
    /// `Header/BoxSizePerAxis` (or a `BoxSize` of one or three values), if given.
    pub box_size: Option<[f64; 3]>,
    /// `Header/CoordinateOffset` (0 without it): the lower corner of the box.
    pub offset: [f64; 3],
    pub gas: IcPhase,
    pub dust: Option<IcPhase>,
}

/// The file's `SmoothingLength` per h when the header does not say: GADGET's convention, the
/// kernel's support radius 2h (dustsph writes the same, with `SmoothingLengthPerH` = 2).
pub const DEFAULT_SMOOTHING_LENGTH_PER_H: f64 = 2.0;

/// Reads and checks an initial-conditions file.
pub fn read_ics(path: &Path) -> Result<Ics, IoError> {
    read_ics_on(path, &Alone)
}

/// Reads this process's share of an initial-conditions file's rows ([`share_rows`]) and
/// checks them, the IDs' uniqueness across every process's (collective: every process gets
/// the same error, the lowest failing rank's).
pub fn read_ics_on(path: &Path, c: &dyn Comm) -> Result<Ics, IoError> {
    // Each check's place in the order one process takes them: the error named is the first
    // check's that fails anywhere, at its lowest row.
    let step = std::cell::Cell::new(0u64);
    let read = read_share(path, c, &step).map_err(|e| (step.get(), e));
    // The message without the path, which every process's error adds again.
    let text = |e: &IoError| match e {
        IoError::Invalid { reason, .. } => reason.clone(),
        e => {
            let full = e.to_string();
            let lead = format!("{}: ", path.display());
            full.strip_prefix(&lead).map_or(full.clone(), String::from)
        }
    };
    let ics = agree_first(c, read, text, |m| IoError::invalid(path, m))?;
    let dup = unique_ids(&ics.gas, ics.dust.as_ref(), path, c);
    agree(c, dup, text, |m| IoError::invalid(path, m))?;
    Ok(ics)
}

/// [`read_ics_on`] without its collective checks; `step` counts the checks of the rows taken.
fn read_share(path: &Path, c: &dyn Comm, step: &std::cell::Cell<u64>) -> Result<Ics, IoError> {
    std::fs::metadata(path).map_err(|e| IoError::io(path, e))?;
    let file = File::open(path).map_err(|e| {
        IoError::invalid(
            path,
            format!("cannot be opened as an HDF5 file (is it one?): {e}"),
        )
    })?;
    let header = file.group(HEADER_GROUP).ok();
    let IcHeader {
        time,
        dim,
        box_size,
        offset,
        per_h,
    } = read_ic_header(header.as_ref(), path)?;
    if !file.link_exists(GAS_GROUP) {
        return Err(IoError::invalid(
            path,
            format!("has no group /{GAS_GROUP} (the gas particles)"),
        ));
    }
    let gas = read_phase(&file, GAS_GROUP, (offset, per_h), path, c, step)?;
    let dust = if file.link_exists(DUST_GROUP) {
        Some(read_phase(
            &file,
            DUST_GROUP,
            (offset, per_h),
            path,
            c,
            step,
        )?)
    } else {
        None
    };
    if let Some(h) = &header {
        check_num_part(h, path, gas.total, dust.as_ref().map_or(0, |d| d.total))?;
    }
    Ok(Ics {
        time,
        dim,
        box_size,
        offset,
        gas,
        dust,
    })
}

/// The header's attributes an initial-conditions file may give: its time, dimension, box,
/// coordinate offset and smoothing length per h.
struct IcHeader {
    time: f64,
    dim: Option<u32>,
    box_size: Option<[f64; 3]>,
    offset: [f64; 3],
    per_h: f64,
}

/// Reads and checks the header's attributes (`header`: none where the file has no header).
fn read_ic_header(header: Option<&Group>, path: &Path) -> Result<IcHeader, IoError> {
    let time = match header_f64s(header, path, "Time")? {
        None => 0.0,
        Some(v) if v.len() == 1 => v[0],
        Some(v) => return Err(one_value(path, "Time", v.len())),
    };
    let dim = match header {
        Some(h) if h.attr("Dimension").is_ok() => {
            let d: i64 = get_scalar(h, "Dimension", path)?;
            match u32::try_from(d) {
                Ok(d @ 1..=3) => Some(d),
                _ => {
                    return Err(IoError::invalid(
                        path,
                        format!("/{HEADER_GROUP}/Dimension is {d} (must be 1, 2 or 3)"),
                    ))
                }
            }
        }
        _ => None,
    };
    let box_size = match header_f64s(header, path, "BoxSizePerAxis")? {
        Some(v) => Some(three_values(path, "BoxSizePerAxis", v)?),
        None => header_f64s(header, path, "BoxSize")?
            .map(|v| three_values(path, "BoxSize", v))
            .transpose()?,
    };
    let offset = header_f64s(header, path, "CoordinateOffset")?
        .map(|v| three_values(path, "CoordinateOffset", v))
        .transpose()?
        .unwrap_or([0.0; 3]);
    let per_h = match header_f64s(header, path, "SmoothingLengthPerH")? {
        None => DEFAULT_SMOOTHING_LENGTH_PER_H,
        Some(v) if v.len() == 1 && v[0] > 0.0 => v[0],
        Some(v) => {
            return Err(IoError::invalid(
                path,
                format!("/{HEADER_GROUP}/SmoothingLengthPerH must be one value > 0 (got {v:?})"),
            ))
        }
    };
    Ok(IcHeader {
        time,
        dim,
        box_size,
        offset,
        per_h,
    })
}

/// A header attribute's values, each finite (`None` where the header or attribute is absent).
fn header_f64s(
    header: Option<&Group>,
    path: &Path,
    name: &str,
) -> Result<Option<Vec<f64>>, IoError> {
    let Some(h) = header else { return Ok(None) };
    if h.attr(name).is_err() {
        return Ok(None);
    }
    let obj = format!("/{HEADER_GROUP}/{name}");
    let v: Vec<f64> = h
        .attr(name)
        .and_then(|a| a.read_raw())
        .map_err(h5err(path, &obj))?;
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(IoError::invalid(
            path,
            format!("{obj}[{i}] is {} (must be finite)", v[i]),
        ));
    }
    Ok(Some(v))
}

/// A header attribute of one value per axis, or one for all three.
fn three_values(path: &Path, name: &str, v: Vec<f64>) -> Result<[f64; 3], IoError> {
    match v.len() {
        1 => Ok([v[0]; 3]),
        3 => Ok([v[0], v[1], v[2]]),
        n => Err(IoError::invalid(
            path,
            format!("/{HEADER_GROUP}/{name} has {n} values (expected 1 or 3)"),
        )),
    }
}

/// The header's `NumPart_Total`, where given, agrees with the gas's and the dust's rows.
fn check_num_part(h: &Group, path: &Path, gas: usize, dust: usize) -> Result<(), IoError> {
    if h.attr("NumPart_Total").is_ok() {
        let obj = format!("/{HEADER_GROUP}/NumPart_Total");
        let n: Vec<u64> = h
            .attr("NumPart_Total")
            .and_then(|a| a.read_raw())
            .map_err(h5err(path, &obj))?;
        let found = [(0, gas), (3, dust)];
        for (k, len) in found {
            if let Some(&c) = n.get(k) {
                if c != len as u64 {
                    return Err(IoError::invalid(
                        path,
                        format!("{obj}[{k}] = {c} but PartType{k} holds {len} particles"),
                    ));
                }
            }
        }
    }
    Ok(())
}

fn one_value(path: &Path, name: &str, n: usize) -> IoError {
    IoError::invalid(
        path,
        format!("/{HEADER_GROUP}/{name} has {n} values (expected one)"),
    )
}

/// This process's rows of one particle type: required columns, then the optional ones, every
/// one the same length; `step` counts the columns' checks.
fn read_phase(
    file: &File,
    name: &str,
    (offset, per_h): ([f64; 3], f64),
    path: &Path,
    c: &dyn Comm,
    step: &std::cell::Cell<u64>,
) -> Result<IcPhase, IoError> {
    let next = || step.set(step.get() + 1);
    let g = file.group(name).map_err(h5err(path, &format!("/{name}")))?;
    let obj = |d: &str| format!("/{name}/{d}");
    if !g.link_exists(COORDINATES) {
        return Err(IoError::invalid(
            path,
            format!("{} is missing (required)", obj(COORDINATES)),
        ));
    }
    let total = rows(&g, COORDINATES, 3, path)?;
    let n = share_rows(total, row_block(), c.rank(), c.size());
    let first = n.0;
    let vec3 = |d: &str| -> Result<Vec<[f64; 3]>, IoError> {
        next();
        let flat: Vec<f64> = column(&g, d, total, n, 3, path)?;
        finite(&flat, 3, first, &obj(d), path)?;
        Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
    };
    let scalar = |d: &str, positive: bool| -> Result<Option<Vec<f64>>, IoError> {
        next();
        if !g.link_exists(d) {
            return Ok(None);
        }
        let v: Vec<f64> = column(&g, d, total, n, 1, path)?;
        finite(&v, 1, first, &obj(d), path)?;
        let bad = |x: f64| if positive { x <= 0.0 } else { x < 0.0 };
        if let Some(i) = v.iter().position(|&x| bad(x)) {
            let want = if positive { "> 0" } else { "≥ 0" };
            return Err(IoError::invalid(
                path,
                format!("{}[{}] is {} (must be {want})", obj(d), first + i, v[i]),
            ));
        }
        Ok(Some(v))
    };
    let required = |d: &str| -> Result<(), IoError> {
        if g.link_exists(d) {
            Ok(())
        } else {
            Err(IoError::invalid(
                path,
                format!("{} is missing (required)", obj(d)),
            ))
        }
    };
    required(VELOCITIES)?;
    required(MASSES)?;
    let x = vec3(COORDINATES)?
        .into_iter()
        .map(|c| [c[0] + offset[0], c[1] + offset[1], c[2] + offset[2]])
        .collect();
    let v = vec3(VELOCITIES)?;
    let m = scalar(MASSES, true)?.unwrap_or_default();
    let rho = scalar(DENSITY, true)?;
    let h = scalar(SMOOTHING_LENGTH, true)?.map(|s| s.into_iter().map(|s| s / per_h).collect());
    let e = scalar(INTERNAL_ENERGY, false)?;
    next();
    let id = read_ids(&g, &obj(PARTICLE_IDS), total, n, path)?;
    next();
    let fraction = if g.link_exists(FRACTION_INDEX) {
        Some(column::<i64>(&g, FRACTION_INDEX, total, n, 1, path)?)
    } else {
        None
    };
    Ok(IcPhase {
        x,
        v,
        m,
        rho,
        h,
        e,
        id,
        fraction,
        first,
        total,
    })
}

/// The optional particle ids of this process's rows `n` of a phase's `total`, each ≥ 0
/// (`obj`: the column's name in messages).
fn read_ids(
    g: &Group,
    obj: &str,
    total: usize,
    n: (usize, usize),
    path: &Path,
) -> Result<Option<Vec<u64>>, IoError> {
    if !g.link_exists(PARTICLE_IDS) {
        return Ok(None);
    }
    let first = n.0;
    let v: Vec<i64> = column(g, PARTICLE_IDS, total, n, 1, path)?;
    if let Some(i) = v.iter().position(|&x| x < 0) {
        return Err(IoError::invalid(
            path,
            format!("{}[{}] is {} (must be ≥ 0)", obj, first + i, v[i]),
        ));
    }
    Ok(Some(v.into_iter().map(|x| x as u64).collect()))
}

/// The number of rows of a dataset that must be (N, `width`) (or (N) for width 1).
fn rows(g: &Group, d: &str, width: usize, path: &Path) -> Result<usize, IoError> {
    let obj = format!("{}/{d}", g.name());
    let ds = g.dataset(d).map_err(h5err(path, &obj))?;
    let shape = ds.shape();
    let ok = match (shape.as_slice(), width) {
        ([_], 1) => true,
        ([_, w], _) => *w == width,
        _ => false,
    };
    if !ok {
        let want = if width == 1 {
            "(N,)".to_string()
        } else {
            format!("(N, {width})")
        };
        return Err(IoError::invalid(
            path,
            format!("{obj} has shape {shape:?}; expected {want}"),
        ));
    }
    Ok(shape[0])
}

/// Rows `lo..hi` of a dataset of `n` rows of `width` values, flattened (read in the type
/// asked for: HDF5 converts floats and integers of other widths).
fn column<T: hdf5::H5Type>(
    g: &Group,
    d: &str,
    n: usize,
    (lo, hi): (usize, usize),
    width: usize,
    path: &Path,
) -> Result<Vec<T>, IoError> {
    let obj = format!("{}/{d}", g.name());
    let found = rows(g, d, width, path)?;
    if found != n {
        return Err(IoError::invalid(
            path,
            format!(
                "{obj} has {found} rows but {}/{COORDINATES} has {n}: the columns of one \
                 particle type must have the same length",
                g.name()
            ),
        ));
    }
    if lo == hi {
        return Ok(Vec::new());
    }
    let ds = g.dataset(d).map_err(h5err(path, &obj))?;
    let read = if ds.ndim() == 1 {
        ds.read_slice_1d::<T, _>(lo..hi)
            .map(|a| a.into_raw_vec_and_offset().0)
    } else {
        (ds.read_slice_2d::<T, _>((lo..hi, ..))).map(|a| a.into_raw_vec_and_offset().0)
    };
    read.map_err(h5err(path, &obj))
}

/// The first non-finite value of a flattened column, as its row in the file (the column's
/// first row is the file's `first`).
fn finite(v: &[f64], width: usize, first: usize, obj: &str, path: &Path) -> Result<(), IoError> {
    match v.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) => Err(IoError::invalid(
            path,
            format!(
                "{obj}[{}] holds {} (must be finite)",
                first + i / width,
                v[i]
            ),
        )),
    }
}

/// `ParticleIDs` unique over gas and dust together (where given), over every process's rows:
/// each ID goes with its particle type and row to the process that checks it
/// ([`crate::dist::checker_of`]), which finds its least repeated ID; the least over the
/// processes is the one named (collective).
fn unique_ids(
    gas: &IcPhase,
    dust: Option<&IcPhase>,
    path: &Path,
    c: &dyn Comm,
) -> Result<(), IoError> {
    // (id, particle type: 0 gas, 1 dust, row in the file) by the process that checks it.
    let mut to: Vec<Vec<[u64; 3]>> = vec![Vec::new(); c.size() as usize];
    for (t, ph) in [Some(gas), dust].into_iter().enumerate() {
        if let Some((ids, ph)) = ph.and_then(|p| Some((p.id.as_ref()?, p))) {
            for (i, &id) in ids.iter().enumerate() {
                to[crate::dist::checker_of(id, c.size())].push([
                    id,
                    t as u64,
                    (ph.first + i) as u64,
                ]);
            }
        }
    }
    let mut all = crate::dist::route(c, to)
        .map_err(|e| IoError::invalid(path, format!("the IDs' check across ranks: {e}")))?;
    all.sort_unstable();
    let first_dup = all
        .windows(2)
        .find(|w| w[0][0] == w[1][0])
        .map(|w| (w[0], w[1]));
    // The least repeated ID over the processes (u64::MAX: none here).
    let least = first_dup.map_or(u64::MAX, |(a, _)| a[0]);
    let every = c.all_gather_bytes(&least.to_le_bytes());
    let least_all = (every.iter())
        .map(|b| u64::from_le_bytes(b[..8].try_into().expect("8 bytes")))
        .min()
        .unwrap_or(u64::MAX);
    match first_dup {
        Some((a, b)) if a[0] == least_all => {
            let group = |t: u64| if t == 0 { GAS_GROUP } else { DUST_GROUP };
            Err(IoError::invalid(
                path,
                format!(
                    "ParticleIDs are not unique: /{}/{PARTICLE_IDS}[{}] and /{}/{PARTICLE_IDS}[{}] are both {}",
                    group(a[1]),
                    a[2],
                    group(b[1]),
                    b[2],
                    a[0]
                ),
            ))
        }
        _ => Ok(()),
    }
}
