//! MPI ranks as a [`Comm`] transport (rsmpi over the system's OpenMPI): the only code that
//! names the MPI library.
use super::{Comm, Reduce};
use mpi::collective::SystemOperation;
use mpi::datatype::{Partition, PartitionMut};
use mpi::traits::*;
use mpi::Count;

/// The tag of the messages streamed between rank 0 and the others (the only point-to-point
/// messages).
const STREAM_TAG: mpi::Tag = 17;

pub struct Mpi {
    world: mpi::topology::SimpleCommunicator,
    // Finalises MPI when dropped (the initial world only): declared last, dropped last.
    _universe: Option<mpi::environment::Universe>,
}

// The communicator is used from the thread that made it (the engine's ghost refresh runs on
// the stepping thread, between its rayon passes).
unsafe impl Send for Mpi {}

impl Mpi {
    /// Initialise MPI (once per process).
    pub fn init() -> Result<Mpi, String> {
        let universe = mpi::initialize().ok_or("MPI was already initialised")?;
        Ok(Mpi {
            world: universe.world(),
            _universe: Some(universe),
        })
    }
}

fn operation(op: Reduce) -> SystemOperation {
    match op {
        Reduce::Min => SystemOperation::min(),
        Reduce::Max => SystemOperation::max(),
        Reduce::Sum => SystemOperation::sum(),
    }
}

impl Comm for Mpi {
    fn rank(&self) -> u32 {
        self.world.rank() as u32
    }

    fn size(&self) -> u32 {
        self.world.size() as u32
    }

    fn reduce_f64(&self, v: &mut [f64], op: Reduce) {
        let send = v.to_vec();
        self.world.all_reduce_into(&send[..], v, operation(op));
    }

    fn reduce_u64(&self, v: &mut [u64], op: Reduce) {
        let send = v.to_vec();
        self.world.all_reduce_into(&send[..], v, operation(op));
    }

    fn all_gather_raw(&self, mine: &[u8]) -> Vec<Vec<u8>> {
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
        split(&buf[..total], &counts, &displs)
    }

    // MPI_Gatherv: the other ranks receive nothing.
    fn gather_raw(&self, mine: &[u8]) -> Option<Vec<Vec<u8>>> {
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
        Some(split(&buf, &counts, &displs))
    }

    // Returns when the buffer may be reused.
    fn send_raw(&self, to: u32, bytes: &[u8]) {
        let held = real(bytes);
        (self.world.process_at_rank(to as i32)).send_with_tag(&held[..], STREAM_TAG);
    }

    fn receive_raw(&self, from: u32) -> Vec<u8> {
        let (got, _) =
            (self.world.process_at_rank(from as i32)).receive_vec_with_tag::<u8>(STREAM_TAG);
        got
    }

    fn all_to_all_counts(&self, send: &[i32]) -> Vec<i32> {
        let mut recv = vec![0 as Count; self.size() as usize];
        self.world.all_to_all_into(send, &mut recv[..]);
        recv
    }

    fn all_to_all_raw(
        &self,
        send: &[u8],
        send_counts: &[i32],
        recv: &mut [u8],
        recv_counts: &[i32],
    ) {
        let sd = displacements(send_counts);
        let rd = displacements(recv_counts);
        let held = real(send);
        let sp = Partition::new(&held[..], send_counts, &sd[..]);
        let mut rp = PartitionMut::new(recv, recv_counts, &rd[..]);
        self.world.all_to_all_varcount_into(&sp, &mut rp);
    }

    fn dup(&self) -> Box<dyn Comm> {
        Box::new(Mpi {
            world: self.world.duplicate(),
            _universe: None,
        })
    }

    fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
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
