//! An output's chunks deflated on every rank. Over MPI ranks rank 0 writes each snapshot from
//! the gathered state while the other ranks would wait for it: they deflate a share of its
//! chunks instead (chunk c on rank c mod R), and rank 0 stores what comes back as it is, the
//! same bytes it would have made itself (docs/scaling.md, "Outputs").
use super::comm::{Comm, World};
use crate::io::chunks::{filter_chunk, ChunkFilter, OnCores};

/// Rank 0's side: a [`ChunkFilter`] that hands every R-th chunk to each other rank. Every
/// other rank serves it ([`serve`]) until [`Farm::finish`].
pub struct Farm {
    world: World,
}

impl Farm {
    /// On rank 0, over `world` (a communicator of its own: its messages are the farm's only).
    pub fn new(world: World) -> Farm {
        Farm { world }
    }

    /// Tell every other rank that the output is written (also after a failure: they wait for
    /// it).
    pub fn finish(&self) {
        for r in 1..self.world.size() {
            self.world.send_to(r, &[]);
        }
    }
}

/// A chunk request: element size, chunk bytes, level, then each chunk's length and bytes.
fn request(chunks: &[&[u8]], elem: usize, chunk_bytes: usize, level: u8) -> Vec<u8> {
    let mut m = Vec::with_capacity(24 + chunks.iter().map(|c| 8 + c.len()).sum::<usize>());
    for x in [elem as u64, chunk_bytes as u64, level as u64] {
        m.extend_from_slice(&x.to_le_bytes());
    }
    for c in chunks {
        m.extend_from_slice(&(c.len() as u64).to_le_bytes());
        m.extend_from_slice(c);
    }
    m
}

/// Length-prefixed byte strings, in order (a request's chunks after its header, or a reply).
fn pieces(mut b: &[u8]) -> Result<Vec<&[u8]>, String> {
    let mut out = Vec::new();
    while !b.is_empty() {
        let n = b
            .get(..8)
            .map(|x| u64::from_le_bytes(x.try_into().expect("8 bytes")) as usize)
            .ok_or("a chunk message cut inside a length")?;
        let body = b
            .get(8..8 + n)
            .ok_or("a chunk message shorter than its lengths")?;
        out.push(body);
        b = &b[8 + n..];
    }
    Ok(out)
}

impl ChunkFilter for Farm {
    fn filter(
        &self,
        chunks: &[&[u8]],
        elem: usize,
        chunk_bytes: usize,
        level: u8,
    ) -> Result<Vec<Vec<u8>>, String> {
        let ranks = self.world.size() as usize;
        let mine =
            |r: usize| -> Vec<&[u8]> { chunks.iter().copied().skip(r).step_by(ranks).collect() };
        for r in 1..ranks {
            self.world
                .send_to(r as u32, &request(&mine(r), elem, chunk_bytes, level));
        }
        let own = OnCores.filter(&mine(0), elem, chunk_bytes, level)?;
        let mut out: Vec<Vec<u8>> = vec![Vec::new(); chunks.len()];
        for (k, f) in own.into_iter().enumerate() {
            out[k * ranks] = f;
        }
        for r in 1..ranks {
            let reply = self.world.receive_from(r as u32);
            let got = pieces(&reply).map_err(|e| format!("rank {r}'s deflated chunks: {e}"))?;
            let want = mine(r).len();
            if got.len() != want {
                return Err(format!("rank {r} deflated {} chunks of {want}", got.len()));
            }
            for (k, f) in got.into_iter().enumerate() {
                out[r + k * ranks] = f.to_vec();
            }
        }
        Ok(out)
    }
}

/// A rank other than 0: deflate the chunks rank 0 sends until it says the output is written
/// (an empty message).
pub fn serve(world: &World) -> Result<(), String> {
    loop {
        let m = world.receive_from_root();
        if m.is_empty() {
            return Ok(());
        }
        let head = |k: usize| -> Result<usize, String> {
            (m.get(8 * k..8 * k + 8))
                .map(|x| u64::from_le_bytes(x.try_into().expect("8 bytes")) as usize)
                .ok_or_else(|| format!("rank 0's chunk request of {} bytes has no header", m.len()))
        };
        let (elem, chunk_bytes, level) = (head(0)?, head(1)?, head(2)? as u8);
        let chunks = pieces(&m[24..]).map_err(|e| format!("rank 0's chunk request: {e}"))?;
        let mut reply = Vec::new();
        for c in &chunks {
            let f = filter_chunk(c, elem, chunk_bytes, level).map_err(|e| e.to_string())?;
            reply.extend_from_slice(&(f.len() as u64).to_le_bytes());
            reply.extend_from_slice(&f);
        }
        world.send_to_root(&reply);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A request's chunks come back out as they went in, the empty one and the edge one too.
    #[test]
    fn a_chunk_request_reads_back_as_it_was_made() {
        let a = vec![1u8; 40];
        let b: Vec<u8> = Vec::new();
        let c = vec![7u8, 8, 9];
        let m = request(&[&a, &b, &c], 8, 40, 4);
        assert_eq!(
            &m[..24],
            &[8, 0, 0, 0, 0, 0, 0, 0, 40, 0, 0, 0, 0, 0, 0, 0, 4, 0, 0, 0, 0, 0, 0, 0]
        );
        let p = pieces(&m[24..]).unwrap();
        assert_eq!(p, vec![&a[..], &b[..], &c[..]]);
        assert!(pieces(&m[24..m.len() - 1]).is_err());
    }
}
