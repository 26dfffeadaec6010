//! Processes as threads: a [`Comm`] transport for tests of the code that runs over MPI ranks,
//! without OpenMPI.
use crate::dist::comm::{Comm, Reduce};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Mutex};

/// Processes as threads: every collective sends each thread's part to every thread (pair
/// channels, in call order) and reads every thread's in rank order; the streams between
/// process 0 and the others have channels of their own. A duplicate shares its original's
/// channels: it is used from the same thread, in call order, as MPI's duplicates are here.
pub struct Threads {
    rank: usize,
    to: Arc<Vec<Sender<Vec<u8>>>>,
    from: Arc<Mutex<Vec<Receiver<Vec<u8>>>>>,
    /// To process q's stream channel from this process.
    stream_to: Arc<Vec<Sender<Vec<u8>>>>,
    /// From process q's stream to this one.
    stream_from: Arc<Mutex<Vec<Receiver<Vec<u8>>>>>,
}

impl Threads {
    pub fn group(n: usize) -> Vec<Threads> {
        let pairs = || {
            let mut tx: Vec<Vec<_>> = (0..n).map(|_| Vec::new()).collect();
            let mut rx: Vec<Vec<_>> = (0..n).map(|_| Vec::new()).collect();
            for to in tx.iter_mut() {
                for from in rx.iter_mut() {
                    let (t, r) = channel();
                    to.push(t);
                    from.push(r);
                }
            }
            // rx[b][a]: what a sent to b, as b reads it.
            (tx, rx)
        };
        let (tx, rx) = pairs();
        let (stx, srx) = pairs();
        (tx.into_iter()
            .zip(rx)
            .zip(stx.into_iter().zip(srx))
            .enumerate())
        .map(|(rank, ((to, from), (stream_to, stream_from)))| Threads {
            rank,
            to: Arc::new(to),
            from: Arc::new(Mutex::new(from)),
            stream_to: Arc::new(stream_to),
            stream_from: Arc::new(Mutex::new(stream_from)),
        })
        .collect()
    }

    fn all(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        for t in self.to.iter() {
            t.send(mine.to_vec()).unwrap();
        }
        let from = self.from.lock().unwrap();
        from.iter().map(|r| r.recv().unwrap()).collect()
    }

    fn fold<T: bytemuck::Pod>(&self, v: &mut [T], f: impl Fn(T, T) -> T) {
        let all = self.all(bytemuck::cast_slice(v));
        let w = std::mem::size_of::<T>();
        for (i, x) in v.iter_mut().enumerate() {
            *x = (all.iter())
                .map(|b| bytemuck::pod_read_unaligned::<T>(&b[w * i..w * (i + 1)]))
                .reduce(&f)
                .unwrap();
        }
    }
}

impl Comm for Threads {
    fn rank(&self) -> u32 {
        self.rank as u32
    }
    fn size(&self) -> u32 {
        self.to.len() as u32
    }
    fn reduce_f64(&self, v: &mut [f64], op: Reduce) {
        match op {
            Reduce::Min => self.fold(v, f64::min),
            Reduce::Max => self.fold(v, f64::max),
            Reduce::Sum => self.fold(v, |a, b| a + b),
        }
    }
    fn reduce_u64(&self, v: &mut [u64], op: Reduce) {
        match op {
            Reduce::Min => self.fold(v, u64::min),
            Reduce::Max => self.fold(v, u64::max),
            Reduce::Sum => self.fold(v, |a, b| a + b),
        }
    }
    fn all_gather_raw(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        self.all(mine)
    }
    fn gather_raw(&self, mine: &[u8]) -> Option<Vec<Vec<u8>>> {
        let all = self.all(mine);
        (self.rank == 0).then_some(all)
    }
    fn send_raw(&self, to: u32, bytes: &[u8]) {
        self.stream_to[to as usize].send(bytes.to_vec()).unwrap();
    }
    fn receive_raw(&self, from: u32) -> Vec<u8> {
        self.stream_from.lock().unwrap()[from as usize]
            .recv()
            .unwrap()
    }
    fn all_to_all_counts(&self, send: &[i32]) -> Vec<i32> {
        let all = self.all(bytemuck::cast_slice(send));
        let at = 4 * self.rank;
        (all.iter())
            .map(|b| bytemuck::pod_read_unaligned::<i32>(&b[at..at + 4]))
            .collect()
    }
    fn all_to_all_raw(&self, send: &[u8], send_counts: &[i32], recv: &mut [u8], _: &[i32]) {
        let mut at = 0;
        for (t, &n) in self.to.iter().zip(send_counts) {
            t.send(send[at..at + n as usize].to_vec()).unwrap();
            at += n as usize;
        }
        let from = self.from.lock().unwrap();
        let mut at = 0;
        for r in from.iter() {
            let got = r.recv().unwrap();
            recv[at..at + got.len()].copy_from_slice(&got);
            at += got.len();
        }
    }
    fn dup(&self) -> Box<dyn Comm> {
        Box::new(Threads {
            rank: self.rank,
            to: self.to.clone(),
            from: self.from.clone(),
            stream_to: self.stream_to.clone(),
            stream_from: self.stream_from.clone(),
        })
    }
    fn abort(&self, code: i32) -> ! {
        panic!(
            "process {} of the threads aborted the job with code {code}",
            self.rank
        )
    }
}
