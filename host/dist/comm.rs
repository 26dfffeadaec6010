//! The processes a run is shared over (docs/scaling.md, "Start"): the transport [`Comm`]
//! (one process [`Alone`]; MPI ranks in [`mpi`] with the `mpi` feature; threads in tests),
//! the collectives every rank code calls, written once over it and counted in this process's
//! [`Traffic`], and [`World`], the communicator a run over ranks owns.
//!
//! Only the transports know their library: the rank code (`ranks`, `halo`, `farm`, the
//! outputs by share) compiles and is tested without OpenMPI.
#[cfg(feature = "mpi")]
pub mod mpi;

use super::Traffic;
use std::sync::Mutex;

/// An element-wise reduction over the processes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reduce {
    Min,
    Max,
    Sum,
}

/// What a group of processes provides; everything above it (the counting, the typed
/// exchanges, the agreement on errors) is written once, over it. Every call is collective
/// except the point-to-point stream (`send_raw`, `receive_raw`).
pub trait Comm: Send {
    fn rank(&self) -> u32;
    fn size(&self) -> u32;
    /// `v` reduced element-wise over the processes, in place, on every process.
    fn reduce_f64(&self, v: &mut [f64], op: Reduce);
    fn reduce_u64(&self, v: &mut [u64], op: Reduce);
    /// Every process's bytes, in rank order, on every process.
    fn all_gather_raw(&self, mine: &[u8]) -> Vec<Vec<u8>>;
    /// Every process's bytes, in rank order, on process 0 only (`None` elsewhere).
    fn gather_raw(&self, mine: &[u8]) -> Option<Vec<Vec<u8>>>;
    /// One message of the stream between process 0 and process `to` (one way or the other).
    fn send_raw(&self, to: u32, bytes: &[u8]);
    /// The next message of the stream from process `from`.
    fn receive_raw(&self, from: u32) -> Vec<u8>;
    /// All-to-all of one count per process: what every process sends here, in rank order.
    fn all_to_all_counts(&self, send: &[i32]) -> Vec<i32>;
    /// All-to-all of bytes: `send_counts[q]` bytes of `send` (laid out rank by rank) to
    /// process q, and `recv_counts[q]` from it into `recv` (laid out rank by rank).
    fn all_to_all_raw(
        &self,
        send: &[u8],
        send_counts: &[i32],
        recv: &mut [u8],
        recv_counts: &[i32],
    );
    /// The same processes in a message space of their own (the ghost refresh an engine calls
    /// inside its step, the output's farm).
    fn dup(&self) -> Box<dyn Comm>;
    /// Stop every process of the job now, with `code`: for a failure inside a step whose
    /// other processes wait in an exchange it will not reach.
    fn abort(&self, code: i32) -> !;

    /// Element-wise minimum over the processes.
    fn min_f64(&self, v: &mut [f64]) {
        counted_collective(|| self.reduce_f64(v, Reduce::Min))
    }
    /// Element-wise maximum over the processes.
    fn max_f64(&self, v: &mut [f64]) {
        counted_collective(|| self.reduce_f64(v, Reduce::Max))
    }
    /// Element-wise sum over the processes.
    fn sum_f64(&self, v: &mut [f64]) {
        counted_collective(|| self.reduce_f64(v, Reduce::Sum))
    }
    /// Element-wise sum over the processes.
    fn sum_u64(&self, v: &mut [u64]) {
        counted_collective(|| self.reduce_u64(v, Reduce::Sum))
    }
    /// Whether any process says so (every process must call it: the clean stop of all).
    fn any(&self, flag: bool) -> bool {
        let mut n = [flag as u64];
        self.sum_u64(&mut n);
        n[0] > 0
    }
    /// Every process's bytes, in rank order, on every process.
    fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        counted_collective(|| self.all_gather_raw(mine))
    }
    /// Every process's bytes, in rank order, on process 0 only (`None` elsewhere): small
    /// gathers (an output stream's counts, `mpi-check`'s states).
    fn gather_bytes(&self, mine: &[u8]) -> Option<Vec<Vec<u8>>> {
        let start = std::time::Instant::now();
        let out = self.gather_raw(mine);
        let sent = if self.rank() == 0 { 0 } else { mine.len() };
        count(|t| {
            t.gather_bytes += sent as u64;
            t.gather_seconds += start.elapsed().as_secs_f64();
        });
        out
    }
    /// `bytes` to process 0, one message of a stream it reads with [`Comm::receive_from`]
    /// (a snapshot's chunks written by share), counted as gathered. One process never sends
    /// to itself.
    fn send_to_root(&self, bytes: &[u8]) {
        let start = std::time::Instant::now();
        self.send_raw(0, bytes);
        count(|t| {
            t.gather_bytes += bytes.len() as u64;
            t.gather_seconds += start.elapsed().as_secs_f64();
        });
    }
    /// On process 0, the next message of process `from`'s stream; its wait counted as
    /// gathered.
    fn receive_from(&self, from: u32) -> Vec<u8> {
        let start = std::time::Instant::now();
        let got = self.receive_raw(from);
        count(|t| t.gather_seconds += start.elapsed().as_secs_f64());
        got
    }
    /// `bytes` from process 0 to process `to` (an output's chunks to deflate: `dist::farm`),
    /// its time counted as gathered.
    fn send_to(&self, to: u32, bytes: &[u8]) {
        let start = std::time::Instant::now();
        self.send_raw(to, bytes);
        count(|t| t.gather_seconds += start.elapsed().as_secs_f64());
    }
    /// The next message from process 0 ([`Comm::send_to`]).
    fn receive_from_root(&self) -> Vec<u8> {
        self.receive_from(0)
    }
    /// `counts[q]` bytes of `send` (laid out rank by rank) to process q: what every process
    /// sent here, in rank order.
    fn exchange_bytes(&self, send: &[u8], counts: &[usize]) -> Result<Vec<u8>, String> {
        let mut recv = Vec::new();
        exchange_bytes_into(self, send, counts, &mut recv)?;
        Ok(recv)
    }
}

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

/// A small collective, its time counted.
fn counted_collective<R>(f: impl FnOnce() -> R) -> R {
    let start = std::time::Instant::now();
    let out = f();
    count(|t| t.collective_seconds += start.elapsed().as_secs_f64());
    out
}

/// All-to-all of bytes laid out rank by rank in `send` (`counts[q]` of them to process q):
/// what every process sent here, in rank order, into `recv`, whose allocation is reused (a
/// refresh's buffers are kept across refreshes: fresh pages of tens of MB per refresh cost
/// more than the copy, docs/scaling.md "Measured costs"); returns how many bytes came from
/// each process. Per pair at most 2 GiB (MPI's int counts).
pub fn exchange_bytes_into<C: Comm + ?Sized>(
    c: &C,
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
    let got = exchange_into(c, send, counts, into)?;
    recv.truncate(got.iter().sum());
    Ok(got)
}

/// The all-to-all of [`exchange_bytes_into`], received into the `total` bytes that
/// `into(total)` provides; counted.
fn exchange_into<'a, C: Comm + ?Sized>(
    c: &C,
    send: &[u8],
    counts: &[usize],
    into: impl FnOnce(usize) -> &'a mut [u8],
) -> Result<Vec<usize>, String> {
    let start = std::time::Instant::now();
    let me = c.rank() as usize;
    let size = c.size() as usize;
    assert_eq!(counts.len(), size, "one count per rank");
    assert_eq!(
        counts.iter().sum::<usize>(),
        send.len(),
        "counts of the send"
    );
    let mut send_counts = Vec::with_capacity(size);
    for &bytes in counts {
        send_counts.push(
            i32::try_from(bytes)
                .map_err(|_| format!("{bytes} B to one rank: above MPI's 2 GiB"))?,
        );
    }
    let recv_counts = c.all_to_all_counts(&send_counts);
    let total: usize = recv_counts.iter().map(|&c| c as usize).sum();
    // Never an empty buffer: an empty slice's dangling address is 0x1, which OpenMPI reads as
    // MPI_IN_PLACE (MPI_ERR_ARG here) even with no data.
    let mut none = Vec::with_capacity(1);
    let recv: &mut [u8] = if total == 0 {
        &mut none[..]
    } else {
        into(total)
    };
    c.all_to_all_raw(send, &send_counts, recv, &recv_counts);
    let sent = send.len() - counts[me];
    count(|t| {
        t.exchanges += 1;
        t.exchange_bytes += sent as u64;
        t.exchange_seconds += start.elapsed().as_secs_f64();
    });
    Ok(recv_counts.iter().map(|&c| c as usize).collect())
}

/// A communicator a run over ranks owns: a transport, with the typed exchanges of the rank
/// code.
pub struct World(Box<dyn Comm>);

impl Comm for World {
    fn rank(&self) -> u32 {
        self.0.rank()
    }
    fn size(&self) -> u32 {
        self.0.size()
    }
    fn reduce_f64(&self, v: &mut [f64], op: Reduce) {
        self.0.reduce_f64(v, op)
    }
    fn reduce_u64(&self, v: &mut [u64], op: Reduce) {
        self.0.reduce_u64(v, op)
    }
    fn all_gather_raw(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        self.0.all_gather_raw(mine)
    }
    fn gather_raw(&self, mine: &[u8]) -> Option<Vec<Vec<u8>>> {
        self.0.gather_raw(mine)
    }
    fn send_raw(&self, to: u32, bytes: &[u8]) {
        self.0.send_raw(to, bytes)
    }
    fn receive_raw(&self, from: u32) -> Vec<u8> {
        self.0.receive_raw(from)
    }
    fn all_to_all_counts(&self, send: &[i32]) -> Vec<i32> {
        self.0.all_to_all_counts(send)
    }
    fn all_to_all_raw(
        &self,
        send: &[u8],
        send_counts: &[i32],
        recv: &mut [u8],
        recv_counts: &[i32],
    ) {
        self.0.all_to_all_raw(send, send_counts, recv, recv_counts)
    }
    fn dup(&self) -> Box<dyn Comm> {
        self.0.dup()
    }
    fn abort(&self, code: i32) -> ! {
        self.0.abort(code)
    }
}

impl World {
    /// A communicator over `comm`.
    pub fn over(comm: Box<dyn Comm>) -> World {
        World(comm)
    }

    /// The world of this MPI job (MPI initialised once per process); an error in a build
    /// without the `mpi` feature.
    pub fn init() -> Result<World, String> {
        #[cfg(feature = "mpi")]
        return Ok(World(Box::new(mpi::Mpi::init()?)));
        #[cfg(not(feature = "mpi"))]
        Err("this dustsph was built without MPI (cargo feature `mpi`)".into())
    }

    /// A duplicate of this communicator (its own message space), e.g. for the ghost refresh
    /// an engine calls inside its step.
    pub fn duplicate(&self) -> World {
        World(self.0.dup())
    }

    /// All-to-all of plain records: `sends[q]` goes to rank q; returns what every rank sent
    /// here, in rank order. Per rank pair at most 2 GiB (MPI's int counts).
    pub fn exchange<T: bytemuck::Pod>(&self, sends: &[Vec<T>]) -> Result<Vec<T>, String> {
        let counts: Vec<usize> = sends.iter().map(Vec::len).collect();
        self.exchange_flat(&sends.concat(), &counts)
    }

    /// [`World::exchange`] of records laid out rank by rank in `send` (`counts[q]` of them to
    /// rank q), received straight into the records returned (no byte buffer between: a halo's
    /// records are tens of MB, and each fresh buffer's pages cost time to fault in).
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
        let got = exchange_into(self, bytemuck::cast_slice(send), &bytes, into)?;
        Ok((out, got.iter().map(|b| b / item).collect()))
    }

    /// [`exchange_bytes_into`] over this communicator.
    pub fn exchange_bytes_into(
        &self,
        send: &[u8],
        counts: &[usize],
        recv: &mut Vec<u8>,
    ) -> Result<Vec<usize>, String> {
        exchange_bytes_into(self, send, counts, recv)
    }
}

/// One process: every collective is the identity.
pub struct Alone;

impl Comm for Alone {
    fn rank(&self) -> u32 {
        0
    }
    fn size(&self) -> u32 {
        1
    }
    fn reduce_f64(&self, _: &mut [f64], _: Reduce) {}
    fn reduce_u64(&self, _: &mut [u64], _: Reduce) {}
    fn all_gather_raw(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        vec![mine.to_vec()]
    }
    fn gather_raw(&self, mine: &[u8]) -> Option<Vec<Vec<u8>>> {
        Some(vec![mine.to_vec()])
    }
    fn send_raw(&self, _: u32, _: &[u8]) {
        unreachable!("one process sends nothing to itself")
    }
    fn receive_raw(&self, _: u32) -> Vec<u8> {
        unreachable!("one process hears from no other")
    }
    fn all_to_all_counts(&self, send: &[i32]) -> Vec<i32> {
        send.to_vec()
    }
    fn all_to_all_raw(&self, send: &[u8], _: &[i32], recv: &mut [u8], _: &[i32]) {
        recv[..send.len()].copy_from_slice(send);
    }
    fn dup(&self) -> Box<dyn Comm> {
        Box::new(Alone)
    }
    fn abort(&self, code: i32) -> ! {
        std::process::exit(code)
    }
}
