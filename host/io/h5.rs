//! HDF5 attribute and dataset helpers shared by snapshots, checkpoints and initial conditions;
//! every error names the file and the object inside it.
use std::path::Path;

use hdf5::types::{TypeDescriptor, VarLenAscii, VarLenUnicode};
use hdf5::{Group, H5Type, Location};

use super::IoError;

/// Maps an HDF5 error to an [`IoError`] naming the file and the object inside it.
pub(crate) fn h5err<'a>(
    path: &'a Path,
    object: &'a str,
) -> impl FnOnce(hdf5::Error) -> IoError + 'a {
    move |e| IoError::hdf5(path, object, e)
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

pub(crate) fn put_array<T: H5Type>(
    g: &Group,
    name: &str,
    values: &[T],
    path: &Path,
) -> Result<(), IoError> {
    let obj = format!("{}/{name}", g.name());
    g.new_attr::<T>()
        .shape(values.len())
        .create(name)
        .and_then(|a| a.write_raw(values))
        .map_err(h5err(path, &obj))
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
pub(crate) fn get_f64s(loc: &Location, name: &str, path: &Path) -> Result<Vec<f64>, IoError> {
    let obj = format!("{}/{name}", loc.name());
    loc.attr(name)
        .and_then(|a| a.read_raw())
        .map_err(h5err(path, &obj))
}

pub(crate) fn get_counts(loc: &Location, name: &str, path: &Path) -> Result<[u64; 6], IoError> {
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
