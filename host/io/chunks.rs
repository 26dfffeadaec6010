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

/// Where the rows of one particle group lie in its datasets when every process holds a share
/// of them (over MPI ranks; one process holds the whole group): each process's runs of rows,
/// (first row in the dataset, rows), in its own row order. The group is laid out part by part
/// (the gas is one part, the dust one per fraction), each part process by process.
pub struct RowShare {
    me: usize,
    runs: Vec<Vec<(u64, u64)>>,
    /// Every non-empty run as (first row, its process), in row order: who holds a row.
    starts: Vec<(u64, usize)>,
    pub total: u64,
}

impl RowShare {
    /// `counts[q][k]`: process q's rows of part k; this process is `me`.
    pub fn of(counts: &[Vec<u64>], me: usize) -> RowShare {
        let parts = counts.first().map_or(0, Vec::len);
        let mut runs = vec![Vec::with_capacity(parts); counts.len()];
        let mut starts = Vec::new();
        let mut at = 0;
        for k in 0..parts {
            for (q, c) in counts.iter().enumerate() {
                runs[q].push((at, c[k]));
                if c[k] > 0 {
                    starts.push((at, q));
                }
                at += c[k];
            }
        }
        RowShare {
            me,
            runs,
            starts,
            total: at,
        }
    }

    /// One process holding every row (`rows` of them).
    pub fn whole(rows: u64) -> RowShare {
        RowShare::of(&[vec![rows]], 0)
    }

    /// The process holding row `row` (< total).
    fn holder(&self, row: u64) -> usize {
        let i = self.starts.partition_point(|&(s, _)| s <= row);
        self.starts[i - 1].1
    }
}

/// Where a piece of a chunk lies on the process that filters the chunk: its own rows from
/// row `Local(l)`, or the bytes another process sent from `Received(at)`.
enum Piece {
    Local(usize),
    Received(usize),
}

/// Writes this process's rows `data` (rows of `width` values; where they lie: `share`) into a
/// dataset of `share.total` rows in chunks of `chunk_rows` rows, shuffled then deflated at
/// `level` (collective over `c`). Each chunk is filtered by `filter` on the process that holds
/// its first row, which the other holders send their rows of it; process 0 stores every
/// chunk (`H5Dwrite_chunk` into `ds`: its dataset, or why it has none; `None` elsewhere) as
/// each process's filtered chunks reach it, so that no process holds the whole dataset. One
/// process ([`RowShare::whole`]) filters its chunks from its rows in place.
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_rows_shared<T: H5Type + Copy + Sync>(
    ds: Option<Result<&Dataset, IoError>>,
    data: &[T],
    width: usize,
    share: &RowShare,
    (chunk_rows, level): (usize, u8),
    c: &dyn crate::dist::Comm,
    filter: &dyn ChunkFilter,
    (path, obj): (&Path, &str),
) -> Result<(), IoError> {
    let elem = std::mem::size_of::<T>();
    let row = width * elem;
    // SAFETY: `T` is plain data (an HDF5 scalar type) whose in-memory bytes are the dataset's
    // native file type: the bytes of `data`, read only.
    let bytes = unsafe {
        std::slice::from_raw_parts(data.as_ptr().cast::<u8>(), std::mem::size_of_val(data))
    };
    let cr = chunk_rows as u64;
    let me = share.me;
    let size = c.size() as usize;
    let (mut pieces, out) = sort_rows(bytes, row, cr, share, size);
    let failed = |why: String| IoError::invalid(path, format!("{obj}: {why}"));
    let got = if size > 1 {
        let counts: Vec<usize> = out.iter().map(Vec::len).collect();
        c.exchange_bytes(&out.concat(), &counts).map_err(failed)?
    } else {
        Vec::new()
    };
    drop(out);
    receive_pieces(&got, row, cr, &mut pieces, &failed)?;
    let raw = whole_chunks(&pieces, bytes, &got, row, cr, share.total, &failed)?;
    let views: Vec<&[u8]> = raw.iter().map(|r| &r[..]).collect();
    let chunk_bytes = chunk_rows * row;
    let chunks: Vec<u64> = pieces.keys().copied().collect();
    let stored = (filter.filter(&views, elem, chunk_bytes, level)).and_then(|v| match v.len() {
        n if n == chunks.len() => Ok(v),
        n => Err(format!("{n} of {} chunks filtered", chunks.len())),
    });
    drop(views);
    drop(raw);
    let Some(ds) = ds else {
        if me != 0 {
            c.send_to_root(&pack(&chunks, &stored));
        }
        return stored.map(|_| ()).map_err(failed);
    };
    // Process 0 reads every process's message even where it cannot store them (they wait).
    let (ds, first_err) = match ds {
        Ok(ds) => (Some(ds), None),
        Err(e) => (None, Some(e)),
    };
    let mut root = RootStore {
        ds,
        first_err,
        cr,
        failed: &failed,
    };
    root.store(&pack(&chunks, &stored), 0);
    drop(stored);
    for q in 1..size {
        root.store(&c.receive_from(q as u32), q);
    }
    root.first_err.map_or(Ok(()), Err)
}

/// The pieces of the chunks a process filters, by chunk: (first row within the chunk, rows,
/// where they lie).
type Pieces = std::collections::BTreeMap<u64, Vec<(usize, usize, Piece)>>;

/// This process's rows (`bytes`, `row` bytes each) by chunk of `cr` rows: kept where it holds
/// the chunk's first row, else sent to the process that does, as blocks (first row, rows,
/// their bytes) in the returned messages, one per process.
fn sort_rows(
    bytes: &[u8],
    row: usize,
    cr: u64,
    share: &RowShare,
    size: usize,
) -> (Pieces, Vec<Vec<u8>>) {
    let me = share.me;
    let mut pieces = Pieces::new();
    let mut out: Vec<Vec<u8>> = vec![Vec::new(); size];
    let mut local = 0usize;
    for &(start, len) in &share.runs[me] {
        let mut g = start;
        while g < start + len {
            let ch = g / cr;
            let n = ((ch + 1) * cr).min(start + len) - g;
            let holder = share.holder(ch * cr);
            let rows = &bytes[local * row..(local + n as usize) * row];
            if holder == me {
                let within = (g - ch * cr) as usize;
                pieces
                    .entry(ch)
                    .or_default()
                    .push((within, n as usize, Piece::Local(local)));
            } else {
                out[holder].extend_from_slice(&g.to_le_bytes());
                out[holder].extend_from_slice(&n.to_le_bytes());
                out[holder].extend_from_slice(rows);
            }
            g += n;
            local += n as usize;
        }
    }
    (pieces, out)
}

/// Adds the blocks of rows the other processes sent (`got`) to `pieces`; a cut block is an
/// error.
fn receive_pieces(
    got: &[u8],
    row: usize,
    cr: u64,
    pieces: &mut Pieces,
    failed: &dyn Fn(String) -> IoError,
) -> Result<(), IoError> {
    let mut at = 0;
    while at < got.len() {
        let word = |i: usize| -> Result<u64, IoError> {
            (got.get(i..i + 8))
                .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
                .ok_or_else(|| failed("a process sent a cut block of rows".into()))
        };
        let (g, n) = (word(at)?, word(at + 8)? as usize);
        at += 16;
        if at + n * row > got.len() {
            return Err(failed("a process sent a cut block of rows".into()));
        }
        let ch = g / cr;
        (pieces.entry(ch).or_default()).push(((g - ch * cr) as usize, n, Piece::Received(at)));
        at += n * row;
    }
    Ok(())
}

/// Each chunk held here, whole, from its pieces: borrowed where this process's rows are all
/// of it; a chunk short of rows is an error.
fn whole_chunks<'a>(
    pieces: &Pieces,
    bytes: &'a [u8],
    got: &[u8],
    row: usize,
    cr: u64,
    total: u64,
    failed: &dyn Fn(String) -> IoError,
) -> Result<Vec<std::borrow::Cow<'a, [u8]>>, IoError> {
    let mut raw: Vec<std::borrow::Cow<[u8]>> = Vec::with_capacity(pieces.len());
    for (&ch, ps) in pieces {
        let rows = (cr.min(total - ch * cr)) as usize;
        if let [(0, n, Piece::Local(l))] = ps[..] {
            if n == rows {
                raw.push(std::borrow::Cow::Borrowed(&bytes[l * row..(l + n) * row]));
                continue;
            }
        }
        let mut buf = vec![0u8; rows * row];
        let mut filled = 0;
        for (within, n, p) in ps {
            let src = match *p {
                Piece::Local(l) => &bytes[l * row..(l + n) * row],
                Piece::Received(a) => &got[a..a + n * row],
            };
            buf[within * row..(within + n) * row].copy_from_slice(src);
            filled += n;
        }
        if filled != rows {
            return Err(failed(format!(
                "chunk {ch} has {filled} of its {rows} rows from the processes"
            )));
        }
        raw.push(std::borrow::Cow::Owned(buf));
    }
    Ok(raw)
}

/// A process's filtered chunks as a message for process 0, length-prefixed: a chunk's index,
/// its stored length and bytes; a failed filter sends its message instead (process 0 stops
/// the write, the others go on to the end of it).
fn pack(chunks: &[u64], stored: &Result<Vec<Vec<u8>>, String>) -> Vec<u8> {
    match stored {
        Ok(v) => {
            let mut m = vec![0u8];
            for (ch, b) in chunks.iter().zip(v) {
                m.extend_from_slice(&ch.to_le_bytes());
                m.extend_from_slice(&(b.len() as u64).to_le_bytes());
                m.extend_from_slice(b);
            }
            m
        }
        Err(e) => [&[1u8][..], e.as_bytes()].concat(),
    }
}

/// Process 0's side of the write: the dataset (none where it could not be made), the first
/// error met, the chunk's rows and how an error is told.
struct RootStore<'a> {
    ds: Option<&'a Dataset>,
    first_err: Option<IoError>,
    cr: u64,
    failed: &'a dyn Fn(String) -> IoError,
}

impl RootStore<'_> {
    /// Stores the chunks of one process's message (`from`), unless an error came first; the
    /// first error (a failed filter, a cut message, HDF5's refusal) is kept.
    fn store(&mut self, msg: &[u8], from: usize) {
        let failed = self.failed;
        let Some(ds) = self.ds else {
            return;
        };
        if self.first_err.is_some() {
            return;
        }
        match msg.first() {
            Some(0) => {}
            _ => {
                let why = String::from_utf8_lossy(msg.get(1..).unwrap_or(&[])).to_string();
                self.first_err = Some(failed(format!("process {from}: {why}")));
                return;
            }
        }
        let mut at = 1;
        while at < msg.len() {
            let word = |i: usize| {
                (msg.get(i..i + 8)).map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
            };
            let (Some(ch), Some(n)) = (word(at), word(at + 8)) else {
                self.first_err = Some(failed(format!("process {from} sent a cut chunk")));
                return;
            };
            let (lo, hi) = (at + 16, at + 16 + n as usize);
            let Some(b) = msg.get(lo..hi) else {
                self.first_err = Some(failed(format!("process {from} sent a cut chunk")));
                return;
            };
            if let Err(e) = write_chunk(ds, ch * self.cr, b) {
                self.first_err = Some(failed(format!("HDF5 refused chunk {ch} ({e})")));
                return;
            }
            at = hi;
        }
    }
}

/// One chunk's stored bytes `buf` at row `row0` of `ds` (a chunked dataset).
fn write_chunk(ds: &Dataset, row0: u64, buf: &[u8]) -> Result<(), &'static str> {
    let offset = [row0 as hdf5_sys::h5::hsize_t, 0];
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
        return Err("H5Dwrite_chunk");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::shuffle;
    use crate::io::shared::put_dataset;
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
