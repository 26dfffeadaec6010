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

/// A count a test may set smaller through the environment variable `name` (a positive
/// integer; otherwise `default`): tests/mpi.rs splits small runs into many pieces this way.
pub fn count_from_env(name: &str, default: usize) -> usize {
    (std::env::var(name).ok())
        .and_then(|v| v.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(default)
}

/// The processes a task is shared over: this process's rank among them and the collectives
/// that sums and checks over every process's share need (docs/scaling.md, "Start"). One
/// process is [`Alone`]; MPI ranks are [`comm::World`]. Every call is collective.
pub trait Collective {
    fn rank(&self) -> u32;
    fn size(&self) -> u32;
    /// Element-wise maximum over the processes.
    fn max_f64(&self, v: &mut [f64]);
    /// Element-wise sum over the processes.
    fn sum_u64(&self, v: &mut [u64]);
    /// Element-wise sum over the processes.
    fn sum_f64(&self, v: &mut [f64]);
    /// Every process's bytes, in rank order, on every process.
    fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>>;
    /// `counts[q]` bytes of `send` (laid out rank by rank) to process q: what every process
    /// sent here, in rank order.
    fn exchange_bytes(&self, send: &[u8], counts: &[usize]) -> Result<Vec<u8>, String>;
    /// `bytes` to process 0, one message of a stream it reads with
    /// [`Collective::receive_from`] (a snapshot's chunks written by share). One process never
    /// sends to itself.
    fn send_to_root(&self, _bytes: &[u8]) {
        unreachable!("one process sends nothing to itself")
    }
    /// On process 0, the next message of process `from`'s stream.
    fn receive_from(&self, _from: u32) -> Vec<u8> {
        unreachable!("one process hears from no other")
    }
}

/// One process: every collective is the identity.
pub struct Alone;

impl Collective for Alone {
    fn rank(&self) -> u32 {
        0
    }
    fn size(&self) -> u32 {
        1
    }
    fn max_f64(&self, _: &mut [f64]) {}
    fn sum_u64(&self, _: &mut [u64]) {}
    fn sum_f64(&self, _: &mut [f64]) {}
    fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        vec![mine.to_vec()]
    }
    fn exchange_bytes(&self, send: &[u8], _: &[usize]) -> Result<Vec<u8>, String> {
        Ok(send.to_vec())
    }
}

/// Every process's verdict on a collective task: the error of the lowest rank that failed,
/// on every process (`text` makes the message sent), or each process's own result.
pub fn agree<T, E>(
    c: &dyn Collective,
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
    c: &dyn Collective,
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
pub fn route<T: bytemuck::Pod>(c: &dyn Collective, to: Vec<Vec<T>>) -> Result<Vec<T>, String> {
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

#[cfg(feature = "mpi")]
pub mod farm;
#[cfg(feature = "mpi")]
pub mod halo;
pub mod motion;
#[cfg(feature = "mpi")]
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

#[cfg(feature = "mpi")]
pub mod comm {
    //! The communicator and the collective operations the decomposition needs.
    use super::Traffic;
    use mpi::collective::SystemOperation;
    use mpi::datatype::{Partition, PartitionMut};
    use mpi::traits::*;
    use mpi::Count;
    use std::sync::Mutex;

    /// The tag of the messages streamed to rank 0 (the only point-to-point messages).
    const STREAM_TAG: mpi::Tag = 17;

    /// This process's traffic (every communicator of it, duplicates included).
    static TRAFFIC: Mutex<Traffic> = Mutex::new(Traffic {
        exchanges: 0,
        exchange_bytes: 0,
        exchange_seconds: 0.0,
        gather_bytes: 0,
        gather_seconds: 0.0,
        collective_seconds: 0.0,
    });

    /// This process's traffic so far.
    pub fn traffic() -> Traffic {
        *TRAFFIC.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn count(f: impl FnOnce(&mut Traffic)) {
        f(&mut TRAFFIC.lock().unwrap_or_else(|e| e.into_inner()));
    }

    /// A small collective that began at `start`, counted.
    fn collective(start: std::time::Instant) {
        count(|t| t.collective_seconds += start.elapsed().as_secs_f64());
    }

    pub struct World {
        world: mpi::topology::SimpleCommunicator,
        // Finalises MPI when dropped (the initial world only): declared last, dropped last.
        _universe: Option<mpi::environment::Universe>,
    }

    // The communicator is used from the thread that made it (the engine's ghost refresh runs
    // on the stepping thread, between its rayon passes).
    unsafe impl Send for World {}

    impl World {
        /// Initialise MPI (once per process).
        pub fn init() -> Result<World, String> {
            let universe = mpi::initialize().ok_or("MPI was already initialised")?;
            Ok(World {
                world: universe.world(),
                _universe: Some(universe),
            })
        }

        /// A duplicate of this communicator (its own message space), e.g. for the ghost refresh
        /// an engine calls inside its step.
        pub fn dup(&self) -> World {
            World {
                world: self.world.duplicate(),
                _universe: None,
            }
        }

        /// Stop every rank of the job now (MPI_Abort), with `code`: for a failure inside a
        /// step whose other ranks wait in an exchange it will not reach.
        pub fn abort(&self, code: i32) -> ! {
            self.world.abort(code)
        }

        pub fn rank(&self) -> u32 {
            self.world.rank() as u32
        }

        pub fn size(&self) -> u32 {
            self.world.size() as u32
        }

        /// Element-wise minimum over ranks.
        pub fn min_f64(&self, v: &mut [f64]) {
            let start = std::time::Instant::now();
            let send = v.to_vec();
            self.world
                .all_reduce_into(&send[..], v, SystemOperation::min());
            collective(start);
        }

        /// Element-wise maximum over ranks.
        pub fn max_f64(&self, v: &mut [f64]) {
            let start = std::time::Instant::now();
            let send = v.to_vec();
            self.world
                .all_reduce_into(&send[..], v, SystemOperation::max());
            collective(start);
        }

        /// Element-wise sum over ranks.
        pub fn sum_f64(&self, v: &mut [f64]) {
            let start = std::time::Instant::now();
            let send = v.to_vec();
            self.world
                .all_reduce_into(&send[..], v, SystemOperation::sum());
            collective(start);
        }

        pub fn sum_u64(&self, v: &mut [u64]) {
            let start = std::time::Instant::now();
            let send = v.to_vec();
            self.world
                .all_reduce_into(&send[..], v, SystemOperation::sum());
            collective(start);
        }

        /// Whether any rank says so (every rank must call it: the clean stop of all ranks).
        pub fn any(&self, flag: bool) -> bool {
            let mut n = [flag as u64];
            self.sum_u64(&mut n);
            n[0] > 0
        }

        /// Every rank's bytes, in rank order, on every rank.
        pub fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>> {
            let start = std::time::Instant::now();
            let held = real(mine);
            let mine = &held[..];
            let mut counts = vec![0 as Count; self.size() as usize];
            self.world
                .all_gather_into(&(mine.len() as Count), &mut counts[..]);
            let displs = displacements(&counts);
            let total: usize = counts.iter().map(|&c| c as usize).sum();
            let mut buf = vec![0u8; total.max(1)];
            {
                let mut part = PartitionMut::new(&mut buf[..total], &counts[..], &displs[..]);
                self.world.all_gather_varcount_into(mine, &mut part);
            }
            collective(start);
            split(&buf[..total], &counts, &displs)
        }

        /// Every rank's bytes, in rank order, on rank 0 only (`None` elsewhere): small gathers
        /// (an output stream's counts, `mpi-check`'s states; MPI_Gatherv, the other ranks
        /// receive nothing).
        pub fn gather_bytes(&self, mine: &[u8]) -> Option<Vec<Vec<u8>>> {
            let (buf, counts, displs) = self.gather_counted(mine)?;
            Some(split(&buf, &counts, &displs))
        }

        /// `bytes` to rank 0, one message of an output's stream ([`World::receive_from`]),
        /// counted as gathered; returns when the buffer may be reused.
        pub fn send_to_root(&self, bytes: &[u8]) {
            let start = std::time::Instant::now();
            let held = real(bytes);
            (self.world.process_at_rank(0)).send_with_tag(&held[..], STREAM_TAG);
            count(|t| {
                t.gather_bytes += bytes.len() as u64;
                t.gather_seconds += start.elapsed().as_secs_f64();
            });
        }

        /// The next message of rank `from`'s stream to rank 0 ([`World::send_to_root`]).
        pub fn receive_from(&self, from: u32) -> Vec<u8> {
            let start = std::time::Instant::now();
            let (got, _) =
                (self.world.process_at_rank(from as i32)).receive_vec_with_tag::<u8>(STREAM_TAG);
            count(|t| t.gather_seconds += start.elapsed().as_secs_f64());
            got
        }

        /// `bytes` from rank 0 to rank `to` (an output's chunks to deflate: `dist::farm`),
        /// counted as gathered.
        pub fn send_to(&self, to: u32, bytes: &[u8]) {
            let start = std::time::Instant::now();
            let held = real(bytes);
            (self.world.process_at_rank(to as i32)).send_with_tag(&held[..], STREAM_TAG);
            count(|t| t.gather_seconds += start.elapsed().as_secs_f64());
        }

        /// The next message from rank 0 ([`World::send_to`]); its wait counted as gathered.
        pub fn receive_from_root(&self) -> Vec<u8> {
            self.receive_from(0)
        }

        /// The gather, its bytes and time counted: on rank 0 the buffer, every rank's count
        /// and displacement in it.
        fn gather_counted(&self, mine: &[u8]) -> Option<(Vec<u8>, Vec<Count>, Vec<Count>)> {
            let start = std::time::Instant::now();
            let out = self.gather_uncounted(mine);
            let sent = if self.rank() == 0 { 0 } else { mine.len() };
            count(|t| {
                t.gather_bytes += sent as u64;
                t.gather_seconds += start.elapsed().as_secs_f64();
            });
            out
        }

        fn gather_uncounted(&self, mine: &[u8]) -> Option<(Vec<u8>, Vec<Count>, Vec<Count>)> {
            let held = real(mine);
            let mine = &held[..];
            let root = self.world.process_at_rank(0);
            let n = mine.len() as Count;
            if self.rank() != 0 {
                root.gather_into(&n);
                root.gather_varcount_into(mine);
                return None;
            }
            let mut counts = vec![0 as Count; self.size() as usize];
            root.gather_into_root(&n, &mut counts[..]);
            let displs = displacements(&counts);
            let total: usize = counts.iter().map(|&c| c as usize).sum();
            let mut buf = vec![0u8; total.max(1)];
            {
                let mut part = PartitionMut::new(&mut buf[..total], &counts[..], &displs[..]);
                root.gather_varcount_into_root(mine, &mut part);
            }
            buf.truncate(total);
            Some((buf, counts, displs))
        }

        /// All-to-all of plain records: `sends[q]` goes to rank q; returns what every rank sent
        /// here, in rank order. Per rank pair at most 2 GiB (MPI's int counts).
        pub fn exchange<T: bytemuck::Pod>(&self, sends: &[Vec<T>]) -> Result<Vec<T>, String> {
            let counts: Vec<usize> = sends.iter().map(Vec::len).collect();
            self.exchange_flat(&sends.concat(), &counts)
        }

        /// [`World::exchange`] of records laid out rank by rank in `send` (`counts[q]` of them
        /// to rank q), received straight into the records returned (no byte buffer between:
        /// a halo's records are tens of MB, and each fresh buffer's pages cost time to fault in).
        pub fn exchange_flat<T: bytemuck::Pod>(
            &self,
            send: &[T],
            counts: &[usize],
        ) -> Result<Vec<T>, String> {
            Ok(self.exchange_flat_from(send, counts)?.0)
        }

        /// [`World::exchange_flat`], and how many records came from each rank.
        pub fn exchange_flat_from<T: bytemuck::Pod>(
            &self,
            send: &[T],
            counts: &[usize],
        ) -> Result<(Vec<T>, Vec<usize>), String> {
            let item = std::mem::size_of::<T>();
            let bytes: Vec<usize> = counts.iter().map(|&c| c * item).collect();
            let mut out: Vec<T> = Vec::new();
            let o = &mut out;
            let into = move |total: usize| {
                let o = o;
                o.resize(total.div_ceil(item), T::zeroed());
                &mut bytemuck::cast_slice_mut::<T, u8>(o.as_mut_slice())[..total]
            };
            let got = self.exchange_into(bytemuck::cast_slice(send), &bytes, into)?;
            Ok((out, got.iter().map(|b| b / item).collect()))
        }

        /// All-to-all of bytes laid out rank by rank in `send` (`counts[q]` of them to rank
        /// q): what every rank sent here, in rank order, into `recv`, whose allocation is
        /// reused (a refresh's buffers are kept across refreshes: fresh pages of tens of MB
        /// per refresh cost more than the copy, docs/scaling.md "Measured costs"); returns how
        /// many bytes came from each rank. Per rank pair at most 2 GiB (MPI's int counts).
        pub fn exchange_bytes(
            &self,
            send: &[u8],
            counts: &[usize],
            recv: &mut Vec<u8>,
        ) -> Result<Vec<usize>, String> {
            // Resized, not cleared: only bytes beyond its last length are zeroed first.
            let r = &mut *recv;
            let into = move |total: usize| {
                let r = r;
                r.resize(total, 0);
                &mut r[..]
            };
            let got = self.exchange_into(send, counts, into)?;
            recv.truncate(got.iter().sum());
            Ok(got)
        }

        /// The all-to-all of [`World::exchange_bytes`], received into the `total` bytes that
        /// `into(total)` provides.
        fn exchange_into<'a>(
            &self,
            send: &[u8],
            counts: &[usize],
            into: impl FnOnce(usize) -> &'a mut [u8],
        ) -> Result<Vec<usize>, String> {
            let start = std::time::Instant::now();
            let me = self.rank() as usize;
            let size = self.size() as usize;
            assert_eq!(counts.len(), size, "one count per rank");
            assert_eq!(
                counts.iter().sum::<usize>(),
                send.len(),
                "counts of the send"
            );
            let mut send_counts = Vec::with_capacity(size);
            for &bytes in counts {
                send_counts.push(
                    Count::try_from(bytes)
                        .map_err(|_| format!("{bytes} B to one rank: above MPI's 2 GiB"))?,
                );
            }
            let mut recv_counts = vec![0 as Count; size];
            self.world
                .all_to_all_into(&send_counts[..], &mut recv_counts[..]);
            let sd = displacements(&send_counts);
            let rd = displacements(&recv_counts);
            let total: usize = recv_counts.iter().map(|&c| c as usize).sum();
            // Never an empty buffer: an empty slice's dangling address is 0x1, which OpenMPI
            // reads as MPI_IN_PLACE (MPI_ERR_ARG here) even with no data.
            let held = real(send);
            let mut none = Vec::with_capacity(1);
            let recv: &mut [u8] = if total == 0 {
                &mut none[..]
            } else {
                into(total)
            };
            {
                let sp = Partition::new(&held[..], &send_counts[..], &sd[..]);
                let mut rp = PartitionMut::new(recv, &recv_counts[..], &rd[..]);
                self.world.all_to_all_varcount_into(&sp, &mut rp);
            }
            let sent = send.len() - counts[me];
            count(|t| {
                t.exchanges += 1;
                t.exchange_bytes += sent as u64;
                t.exchange_seconds += start.elapsed().as_secs_f64();
            });
            Ok(recv_counts.iter().map(|&c| c as usize).collect())
        }
    }

    impl super::Collective for World {
        fn rank(&self) -> u32 {
            World::rank(self)
        }
        fn size(&self) -> u32 {
            World::size(self)
        }
        fn max_f64(&self, v: &mut [f64]) {
            World::max_f64(self, v)
        }
        fn sum_u64(&self, v: &mut [u64]) {
            World::sum_u64(self, v)
        }
        fn sum_f64(&self, v: &mut [f64]) {
            World::sum_f64(self, v)
        }
        fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>> {
            World::all_gather_bytes(self, mine)
        }
        fn send_to_root(&self, bytes: &[u8]) {
            World::send_to_root(self, bytes)
        }
        fn receive_from(&self, from: u32) -> Vec<u8> {
            World::receive_from(self, from)
        }
        fn exchange_bytes(&self, send: &[u8], counts: &[usize]) -> Result<Vec<u8>, String> {
            let mut recv = Vec::new();
            World::exchange_bytes(self, send, counts, &mut recv)?;
            Ok(recv)
        }
    }

    /// `b`, or where it is empty an empty slice of a real allocation: an empty slice's dangling
    /// address is 0x1, which OpenMPI reads as MPI_IN_PLACE (an error on a non-root rank of a
    /// gather, and a silent in-place operation in an all-gather).
    fn real(b: &[u8]) -> std::borrow::Cow<'_, [u8]> {
        if b.is_empty() {
            std::borrow::Cow::Owned(Vec::with_capacity(1))
        } else {
            std::borrow::Cow::Borrowed(b)
        }
    }

    fn displacements(counts: &[Count]) -> Vec<Count> {
        counts
            .iter()
            .scan(0, |acc, &c| {
                let d = *acc;
                *acc += c;
                Some(d)
            })
            .collect()
    }

    fn split(buf: &[u8], counts: &[Count], displs: &[Count]) -> Vec<Vec<u8>> {
        counts
            .iter()
            .zip(displs)
            .map(|(&c, &d)| buf[d as usize..(d + c) as usize].to_vec())
            .collect()
    }
}

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
