//! Reading a snapshot back: its header alone, or every particle.
use std::fs;
use std::path::Path;

use hdf5::File;

use super::schema::*;
use super::{PhaseData, SnapshotData};
use crate::io::h5::{
    get_column, get_counts, get_f64s, get_optional, get_scalar, get_string, get_vec3, h5err,
};
use crate::io::{IoError, WithPath};

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

/// Reads a snapshot written by [`write_snapshot`](super::write_snapshot).
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
