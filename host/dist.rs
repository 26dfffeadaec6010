//! Runs over several processes (issue 14, docs/scaling.md): how this process was launched, and
//! with the `mpi` feature the communicator and the particle exchange over it (rsmpi over the
//! system's OpenMPI).
//!
//! Built: the decomposition of a cloud into Morton key ranges agreed by every rank (global
//! bounds and cell counts by all-reduce, [`crate::decomp::Partition`]), the migration of
//! particles to the rank owning their cell, the halo exchange, and stepping over ranks with a
//! thin halo refreshed between the step's passes ([`ranks`]): `mpirun -n R dustsph run` (rank 0
//! gathers and writes the output).
//! Every other command runs on one process and refuses to start as one of several ranks.

/// The rank and the rank count this process was started as by an MPI launcher (`mpirun`,
/// `mpiexec`), read from the launcher's environment without any MPI call; `None` outside one.
pub fn launched() -> Option<(u32, u32)> {
    let get = |k: &str| std::env::var(k).ok()?.trim().parse::<u32>().ok();
    let size = get("OMPI_COMM_WORLD_SIZE").or_else(|| get("PMI_SIZE"))?;
    let rank = get("OMPI_COMM_WORLD_RANK")
        .or_else(|| get("PMI_RANK"))
        .unwrap_or(0);
    Some((rank, size))
}

/// Refuse to run a single-process command as one of several MPI ranks: every rank would run
/// the whole scene and write the same output directory. The message names the rank count.
pub fn refuse_many_ranks(what: &str) -> Result<(), String> {
    match launched() {
        Some((rank, size)) if size > 1 => Err(format!(
            "{what} runs on one process: launched as rank {rank} of {size} MPI ranks, every rank \
             would run the whole scene into the same output; run it without mpirun (or with \
             -n 1). Only `dustsph run` and `dustsph resume` (in a build with the mpi feature) \
             and `dustsph mpi-check` split over ranks"
        )),
        _ => Ok(()),
    }
}

pub mod comm;
pub use comm::{Alone, Comm, World};

/// Every process's verdict on a collective task: the error of the lowest rank that failed,
/// on every process (`text` makes the message sent), or each process's own result.
pub fn agree<T, E>(
    c: &dyn Comm,
    mine: Result<T, E>,
    text: impl Fn(&E) -> String,
    from_other: impl Fn(String) -> E,
) -> Result<T, E> {
    agree_first(c, mine.map_err(|e| (0, e)), text, from_other)
}

/// [`agree`] where each error comes with its place among the checks (`order`): the error of
/// the least place, of the lowest rank at that place. Checks taken in the same order on every
/// process, each over the rows in rank order, so name the error one process would.
pub fn agree_first<T, E>(
    c: &dyn Comm,
    mine: Result<T, (u64, E)>,
    text: impl Fn(&E) -> String,
    from_other: impl Fn(String) -> E,
) -> Result<T, E> {
    let said = match &mine {
        Ok(_) => Vec::new(),
        Err((order, e)) => [&order.to_le_bytes()[..], text(e).as_bytes()].concat(),
    };
    // One byte ahead: an error with an empty message still counts.
    let sent = [&[mine.is_err() as u8][..], &said[..]].concat();
    let all = c.all_gather_bytes(&sent);
    let order = |b: &Vec<u8>| u64::from_le_bytes(b[1..9].try_into().expect("8 bytes"));
    let first = (0..all.len())
        .filter(|&r| all[r].first() == Some(&1))
        .min_by_key(|&r| (order(&all[r]), r));
    match (mine, first) {
        (Err((_, e)), Some(r)) if r == c.rank() as usize => Err(e),
        (_, Some(r)) => Err(from_other(
            String::from_utf8_lossy(&all[r][9..]).into_owned(),
        )),
        (Ok(t), None) => Ok(t),
        (Err(_), None) => unreachable!("this process's error was gathered"),
    }
}

/// Each item of `to[q]` to process q: what every process sent here, in rank order
/// (collective). The sizes are agreed first, so that an exchange too large for MPI's counts
/// fails on every process alike, before any of them enters it.
pub fn route<T: bytemuck::Pod>(c: &dyn Comm, to: Vec<Vec<T>>) -> Result<Vec<T>, String> {
    let item = std::mem::size_of::<T>();
    let counts: Vec<usize> = to.iter().map(|v| v.len() * item).collect();
    let mut total: Vec<u64> = counts.iter().map(|&b| b as u64).collect();
    c.sum_u64(&mut total);
    if let Some(q) = total.iter().position(|&b| b > i32::MAX as u64) {
        return Err(format!(
            "{} B for rank {q} in one exchange, above MPI's 2 GiB",
            total[q]
        ));
    }
    let send: Vec<u8> = to
        .iter()
        .flat_map(|v| bytemuck::cast_slice(v).to_vec())
        .collect();
    drop(to);
    let got = c.exchange_bytes(&send, &counts)?;
    Ok(got
        .chunks_exact(item)
        .map(bytemuck::pod_read_unaligned)
        .collect())
}

/// The process that checks key `k` of a check spread over `size` processes: `k` mixed
/// (SplitMix64's finaliser) before the modulus, so that keys of one stride spread out too.
pub fn checker_of(k: u64, size: u32) -> usize {
    let mut z = k.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    ((z ^ (z >> 31)) % size as u64) as usize
}

/// Rows `[lo, hi)` of `n` that process `rank` of `size` holds: whole blocks of `block` rows,
/// as even as the blocks allow, in rank order (a sum over blocks is then the same sum for any
/// process count).
pub fn share_rows(n: usize, block: usize, rank: u32, size: u32) -> (usize, usize) {
    let blocks = n.div_ceil(block);
    let at = |r: u32| ((r as usize * blocks) / size as usize * block).min(n);
    (at(rank), at(rank + 1))
}

pub mod farm;
pub mod halo;
pub mod motion;
pub mod ranks;
pub mod records;
#[cfg(test)]
pub mod threads;

/// What this process sent to other ranks and how long it waited in the exchanges, since it
/// started (docs/scaling.md, "Measured"): the particle exchanges (migration, halo copies, the
/// ghost refreshes between the step's passes) and the output's gather onto rank 0.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct Traffic {
    /// All-to-all exchanges this rank took part in.
    pub exchanges: u64,
    /// Bytes this rank sent in them to other ranks.
    pub exchange_bytes: u64,
    /// Seconds this rank spent in them (packing excluded; waiting for the slowest included).
    pub exchange_seconds: f64,
    /// Bytes this rank sent to rank 0's gathers (outputs, the final state).
    pub gather_bytes: u64,
    pub gather_seconds: f64,
    /// Seconds in the small collectives (the step size's and the motion's reductions, the
    /// agreement of every rank to go on): mostly the wait for the slowest rank.
    pub collective_seconds: f64,
}

impl Traffic {
    /// Seconds this rank spent in MPI (waiting for the other ranks, mostly).
    pub fn blocked_seconds(&self) -> f64 {
        self.exchange_seconds + self.gather_seconds + self.collective_seconds
    }
}

// SAFETY: `repr(C)` of 8-byte fields only (no padding), and every bit pattern is a valid
// u64 or f64.
unsafe impl bytemuck::Zeroable for Traffic {}
unsafe impl bytemuck::Pod for Traffic {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_tile_the_rows_in_whole_blocks_in_rank_order() {
        for n in [0, 1, 7, 8, 9, 63, 64, 65, 1000] {
            for size in 1..=5 {
                let mut next = 0;
                for r in 0..size {
                    let (lo, hi) = share_rows(n, 8, r, size);
                    assert_eq!(lo, next, "n {n} size {size} rank {r}");
                    assert!(
                        lo <= hi && (lo % 8 == 0 || lo == n),
                        "n {n} rank {r}: {lo}..{hi}"
                    );
                    next = hi;
                }
                assert_eq!(next, n, "n {n} size {size}: every row once");
            }
        }
    }

    #[test]
    fn checks_spread_keys_of_one_stride_over_every_process() {
        let mut hits = [0usize; 4];
        for k in 0..4000u64 {
            hits[checker_of(4 * k, 4)] += 1;
        }
        assert!(hits.iter().all(|&h| h > 800), "{hits:?}");
    }
}
