//! Processes as threads, for tests of the code that runs over MPI ranks (`Collective`).

/// Processes as threads: every collective sends each thread's part to every thread (pair
/// channels, in call order) and reads every thread's in rank order; the stream to process 0
/// has channels of its own.
pub struct Threads {
    rank: usize,
    to: Vec<std::sync::mpsc::Sender<Vec<u8>>>,
    from: Vec<std::sync::mpsc::Receiver<Vec<u8>>>,
    root: std::sync::mpsc::Sender<Vec<u8>>,
    streams: Vec<std::sync::mpsc::Receiver<Vec<u8>>>,
}

impl Threads {
    pub fn group(n: usize) -> Vec<Threads> {
        use std::sync::mpsc::channel;
        let mut tx: Vec<Vec<_>> = (0..n).map(|_| Vec::new()).collect();
        let mut rx: Vec<Vec<_>> = (0..n).map(|_| Vec::new()).collect();
        for (a, to) in tx.iter_mut().enumerate() {
            for from in rx.iter_mut() {
                let (t, r) = channel();
                to.push(t);
                from.push((a, r));
            }
        }
        let (stx, srx): (Vec<_>, Vec<_>) = (0..n).map(|_| channel()).unzip();
        let mut srx = Some(srx);
        (tx.into_iter().zip(rx).zip(stx).enumerate())
            .map(|(rank, ((to, mut from), root))| {
                from.sort_by_key(|f| f.0);
                Threads {
                    rank,
                    to,
                    from: from.into_iter().map(|f| f.1).collect(),
                    root,
                    streams: if rank == 0 {
                        srx.take().unwrap()
                    } else {
                        Vec::new()
                    },
                }
            })
            .collect()
    }

    fn all(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        for t in &self.to {
            t.send(mine.to_vec()).unwrap();
        }
        self.from.iter().map(|r| r.recv().unwrap()).collect()
    }

    fn fold(&self, v: &mut [f64], f: fn(f64, f64) -> f64) {
        let all = self.all(bytemuck::cast_slice(v));
        for (i, x) in v.iter_mut().enumerate() {
            *x = (all.iter())
                .map(|b| bytemuck::pod_read_unaligned::<f64>(&b[8 * i..8 * i + 8]))
                .reduce(f)
                .unwrap();
        }
    }
}

impl crate::dist::Collective for Threads {
    fn rank(&self) -> u32 {
        self.rank as u32
    }
    fn size(&self) -> u32 {
        self.to.len() as u32
    }
    fn max_f64(&self, v: &mut [f64]) {
        self.fold(v, f64::max)
    }
    fn sum_f64(&self, v: &mut [f64]) {
        self.fold(v, |a, b| a + b)
    }
    fn sum_u64(&self, v: &mut [u64]) {
        let all = self.all(bytemuck::cast_slice(v));
        for (i, x) in v.iter_mut().enumerate() {
            *x = (all.iter())
                .map(|b| bytemuck::pod_read_unaligned::<u64>(&b[8 * i..8 * i + 8]))
                .sum();
        }
    }
    fn all_gather_bytes(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        self.all(mine)
    }
    fn exchange_bytes(&self, send: &[u8], counts: &[usize]) -> Result<Vec<u8>, String> {
        let mut at = 0;
        for (t, &n) in self.to.iter().zip(counts) {
            t.send(send[at..at + n].to_vec()).unwrap();
            at += n;
        }
        Ok(self.from.iter().flat_map(|r| r.recv().unwrap()).collect())
    }
    fn send_to_root(&self, bytes: &[u8]) {
        self.root.send(bytes.to_vec()).unwrap();
    }
    fn receive_from(&self, from: u32) -> Vec<u8> {
        self.streams[from as usize].recv().unwrap()
    }
}
