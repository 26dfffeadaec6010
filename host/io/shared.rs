//! One HDF5 file from every process's share (snapshots, checkpoints): each step agreed by
//! every process (all go on, or none with the first error), and the chunked, compressed datasets.
use std::fs;
use std::path::Path;

use hdf5::{File, Group, H5Type};
use ndarray::{ArrayViewD, IxDyn};

use super::chunks::RowShare;
use super::h5::h5err;
use super::{remove_stale, require_parent_dir, tmp_path, IoError, WithPath};

/// Shuffle + deflate only: every HDF5 build and reader has them, unlike blosc.
pub const DEFLATE_LEVEL: u8 = 4;
/// Rows per chunk: 256 KiB for scalars, 768 KiB for 3-vectors, so a chunk fits HDF5's default
/// 1 MiB chunk cache.
pub(crate) const CHUNK_ROWS: usize = 1 << 15;

/// [`CHUNK_ROWS`], or `DUSTSPH_CHUNK_ROWS` where set (tests/mpi.rs writes a small run's
/// snapshots in many chunks, so that every rank deflates some).
fn chunk_rows() -> usize {
    crate::env::count("DUSTSPH_CHUNK_ROWS", CHUNK_ROWS)
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
