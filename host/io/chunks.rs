//! A chunked dataset's shuffle + deflate filters run on every core: each chunk is filtered
//! here (rayon) and handed to HDF5 as it will be stored (`H5Dwrite_chunk`). HDF5 runs its
//! filters on one thread, which made the snapshots of a GPU run most of its wall time (the seed
//! ball on an H200: 3.9 of 6.1 s; docs/gpu.md). Readers see the same file as before: the
//! dataset declares HDF5's own shuffle and deflate filters, and its chunks hold what they
//! would have produced.
use std::io::Write as _;
use std::path::Path;

use hdf5::{Dataset, H5Type};
use rayon::prelude::*;

use super::IoError;

/// HDF5's shuffle filter (H5Zshuffle.c) of a chunk of `chunk_bytes` whose first bytes are
/// `raw` and the rest zeros: byte `j` of element `i` goes to `j·n + i`, so that bytes of
/// equal significance lie together for deflate.
fn shuffle(raw: &[u8], elem: usize, chunk_bytes: usize) -> Vec<u8> {
    let mut out = vec![0u8; chunk_bytes];
    if elem <= 1 {
        out[..raw.len()].copy_from_slice(raw);
        return out;
    }
    let n = chunk_bytes / elem;
    for (i, e) in raw.chunks_exact(elem).enumerate() {
        for (j, &b) in e.iter().enumerate() {
            out[j * n + i] = b;
        }
    }
    out
}

/// Filters a dataset's chunks (shuffle, then deflate at `level`): here on every core
/// ([`OnCores`]), or over MPI ranks (`dist::farm`: rank 0 writes a snapshot while the other
/// ranks deflate a share of its chunks). Either gives the same bytes.
pub trait ChunkFilter {
    /// The stored bytes of each chunk: `chunks[c]` holds its raw bytes (fewer than
    /// `chunk_bytes` for the edge chunk, whose rows past the end are zeros), `elem` bytes an
    /// element.
    fn filter(
        &self,
        chunks: &[&[u8]],
        elem: usize,
        chunk_bytes: usize,
        level: u8,
    ) -> Result<Vec<Vec<u8>>, String>;
}

/// The chunks filtered on this process's cores (rayon).
pub struct OnCores;

impl ChunkFilter for OnCores {
    fn filter(
        &self,
        chunks: &[&[u8]],
        elem: usize,
        chunk_bytes: usize,
        level: u8,
    ) -> Result<Vec<Vec<u8>>, String> {
        (chunks.par_iter())
            .map(|raw| filter_chunk(raw, elem, chunk_bytes, level).map_err(|e| e.to_string()))
            .collect()
    }
}

/// One chunk's stored bytes: shuffled, then deflated at `level` (an edge chunk is stored
/// whole, the rows past the end zeros).
pub fn filter_chunk(
    raw: &[u8],
    elem: usize,
    chunk_bytes: usize,
    level: u8,
) -> std::io::Result<Vec<u8>> {
    let mut z = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(chunk_bytes / 4),
        flate2::Compression::new(level.into()),
    );
    z.write_all(&shuffle(raw, elem, chunk_bytes))?;
    z.finish()
}

/// Writes `data` (rows of `width` values) into `ds`, created with chunks of `chunk_rows` rows
/// (and the full width) and the filters shuffle then deflate at `level`, in that order, the
/// chunks filtered by `filter`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_shuffled_deflated<T: H5Type + Copy + Sync>(
    ds: &Dataset,
    data: &[T],
    width: usize,
    chunk_rows: usize,
    level: u8,
    filter: &dyn ChunkFilter,
    path: &Path,
    obj: &str,
) -> Result<(), IoError> {
    let elem = std::mem::size_of::<T>();
    // SAFETY: `T` is plain data (an HDF5 scalar type) whose in-memory bytes are the dataset's
    // native file type: the bytes of `data`, read only.
    let bytes = unsafe {
        std::slice::from_raw_parts(data.as_ptr().cast::<u8>(), std::mem::size_of_val(data))
    };
    let chunk_bytes = chunk_rows * width * elem;
    let chunks: Vec<&[u8]> = bytes.chunks(chunk_bytes).collect();
    let filtered = (filter.filter(&chunks, elem, chunk_bytes, level))
        .map_err(|e| IoError::invalid(path, format!("{obj}: {e}")))?;
    if filtered.len() != chunks.len() {
        return Err(IoError::invalid(
            path,
            format!(
                "{obj}: {} chunks filtered of {}",
                filtered.len(),
                chunks.len()
            ),
        ));
    }
    for (c, buf) in filtered.iter().enumerate() {
        let row0 = (c * chunk_rows) as hdf5_sys::h5::hsize_t;
        let offset = [row0, 0];
        // SAFETY: `ds` is an open chunked dataset; `offset` holds its rank's coordinates (a
        // chunk's first row, then column 0); `buf` holds `buf.len()` bytes. Under HDF5's lock.
        let status = hdf5::sync::sync(|| unsafe {
            hdf5_sys::h5d::H5Dwrite_chunk(
                ds.id(),
                hdf5_sys::h5p::H5P_DEFAULT,
                0,
                offset.as_ptr(),
                buf.len(),
                buf.as_ptr().cast(),
            )
        });
        if status < 0 {
            return Err(IoError::invalid(
                path,
                format!("{obj}: HDF5 refused chunk {c} (H5Dwrite_chunk)"),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::shuffle;
    use crate::io::snapshot::put_dataset;
    use hdf5::filters::Filter;

    /// What HDF5's own filter pipeline reads back is what was written, bit for bit, through
    /// whole and edge chunks, scalar and 3-wide rows, 8-, 4- and 1-byte types.
    #[test]
    fn chunks_filtered_here_read_back_through_hdf5s_own_filters() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.h5");
        let rows = 70_001; // two whole chunks and an edge chunk
        let x: Vec<f64> = (0..3 * rows).map(|i| (i as f64).sin() * 1e3).collect();
        let id: Vec<u64> = (0..rows as u64).map(|i| i * 7919).collect();
        let k: Vec<u32> = (0..rows as u32).map(|i| i % 5).collect();
        let f: Vec<u8> = (0..rows).map(|i| (i % 251) as u8).collect();
        {
            let file = hdf5::File::create(&path).unwrap();
            let g = file.create_group("g").unwrap();
            put_dataset(&g, "x", &x, 3, &path).unwrap();
            put_dataset(&g, "id", &id, 1, &path).unwrap();
            put_dataset(&g, "k", &k, 1, &path).unwrap();
            put_dataset(&g, "f", &f, 1, &path).unwrap();
        }
        let file = hdf5::File::open(&path).unwrap();
        let ds = file.dataset("g/x").unwrap();
        assert_eq!(ds.shape(), vec![rows, 3]);
        assert_eq!(ds.filters(), vec![Filter::Shuffle, Filter::Deflate(4)]);
        let back: Vec<f64> = ds.read_raw().unwrap();
        assert!(back.iter().zip(&x).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert_eq!(file.dataset("g/id").unwrap().read_raw::<u64>().unwrap(), id);
        assert_eq!(file.dataset("g/k").unwrap().read_raw::<u32>().unwrap(), k);
        assert_eq!(file.dataset("g/f").unwrap().read_raw::<u8>().unwrap(), f);
    }

    #[test]
    fn shuffle_groups_bytes_by_significance() {
        let raw = [1u8, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12];
        assert_eq!(
            shuffle(&raw, 4, 12),
            [1, 5, 9, 2, 6, 10, 3, 7, 11, 4, 8, 12]
        );
        assert_eq!(shuffle(&raw, 1, 12), raw);
        // An edge chunk: the elements past the data are zeros, shuffled with the rest.
        assert_eq!(
            shuffle(&raw[..8], 4, 12),
            [1, 5, 0, 2, 6, 0, 3, 7, 0, 4, 8, 0]
        );
    }
}
