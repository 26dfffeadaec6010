//! The kernel coupling's rows: each particle's return row, and the deposit rows on each gas
//! particle (counted, placed, filled and sorted).
use super::*;
use crate::kernels::Centre;

/// Calls `f` with the gas kernels of the weights: one per gas particle, or one shared
/// ([`kernels::kernel_of`] tells them apart by length, as on the CPU).
#[inline(always)]
unsafe fn with_gas_kernels<R: Real, T>(
    kernel_at: *const KernelAt<R>,
    n_gas: usize,
    p: &StepParams<R>,
    f: impl FnOnce(&[KernelAt<R>]) -> T,
) -> T {
    if kernel_at.is_null() {
        f(&[KernelAt::new(p.h, p.dim)])
    } else {
        f(sl(kernel_at, n_gas))
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct PairRowsArgs<R> {
    pub gas: PhaseBufs<R>,
    /// The phase whose rows and normalisers are found (the gas itself, or the dust).
    pub ph: PhaseBufs<R>,
    /// The phase's first return row (0 for the gas, n_gas for the dust).
    pub row0: u32,
    pub s: *mut R,
    /// 1 where a particle's S comes from its owner (over MPI ranks, a ghost: 0 here until the
    /// refresh; its row is found all the same, for the deposits on the gas it reaches); null:
    /// none.
    pub ghost: *const u8,
    /// As [`CouplingBufs::kernel_at`].
    pub kernel_at: *const KernelAt<R>,
    /// 1 where a particle's S of this layer is already in `s` (over MPI ranks, carried from
    /// the engine its halo was rebuilt from); null: none.
    pub keep: *const u8,
    pub pairs: PairBufs<R>,
    pub p: Params<R>,
}

/// Particle t of `ph`: its return row (the free gas particles b with W(r_tb, h_b) > 0, in the
/// neighbour walk's order) and S_t = Σ_b W(r_tb, h_b), summed in that order (0 when fixed).
pub unsafe fn coupling_rows<R: Real>(t: usize, a: &PairRowsArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let pr = &a.pairs;
    let row = a.row0 as usize + t;
    let cap = pr.cap as usize;
    let (mut k, mut s) = (0usize, R::ZERO);
    if !kernels::is_fixed(ph.fixed(), t) {
        let idx = sl_mut(pr.ret_idx.add(row * cap), cap);
        let w = sl_mut(pr.ret_w.add(row * cap), cap);
        with_gas_kernels(a.kernel_at, a.gas.len(), &a.p, |kk| {
            // The gas's own rows replay its neighbour list.
            let at = if core::ptr::eq(ph.x, a.gas.x) {
                Centre::Own(t)
            } else {
                Centre::Point(ph.x()[t])
            };
            kernels::coupling_row_at(&a.gas.sorted(&a.p, 0), kk, a.gas.fixed(), at, |b, wb| {
                if k < cap {
                    idx[k] = b as u32;
                    w[k] = wb;
                }
                k += 1;
                s += wb;
            })
        });
    }
    *pr.ret_cnt.add(row) = k as u32;
    let m = AtomicU32::from_ptr(pr.ret_max);
    if m.load(Ordering::Relaxed) < k as u32 {
        m.fetch_max(k as u32, Ordering::Relaxed);
    }
    if !a.keep.is_null() && *a.keep.add(t) != 0 {
        return;
    }
    let ghost = !a.ghost.is_null() && *a.ghost.add(t) != 0;
    *a.s.add(t) = if ghost { R::ZERO } else { s };
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct DepositRowsArgs<R> {
    pub gas: PhaseBufs<R>,
    pub dust: PhaseBufs<R>,
    pub cb: CouplingBufs<R>,
    /// 0: one thread per particle (gas, then dust), the rows' cursors atomic and each row
    /// sorted after ([`coupling_deposit_sort`]; the GPU's form). Else each thread takes a chunk
    /// of this many particles, in order, with counters of its own in `counts` (chunk · rows +
    /// row): no atomics, and each row comes out in ascending order (the CPU's form, where
    /// atomics cost the transposition half its time).
    pub chunk: u32,
    pub counts: *mut u32,
    pub p: Params<R>,
}

impl<R: Real> DepositRowsArgs<R> {
    /// Deposit rows: one per gas particle and phase slot.
    #[inline(always)]
    fn rows(&self) -> usize {
        self.gas.len() * (1 + self.p.nf as usize)
    }
    /// The particles (return rows) of thread t: itself, or its chunk.
    #[inline(always)]
    fn particles(&self, t: usize) -> core::ops::Range<usize> {
        let n = self.gas.len() + self.dust.len();
        if self.chunk == 0 {
            t..(t + 1).min(n)
        } else {
            let c = self.chunk as usize;
            (t * c).min(n)..((t + 1) * c).min(n)
        }
    }
}

/// The deposits particle q (return row q: gas q, or dust q − n_gas) makes: `f(deposit row,
/// w_qa)` for each gas particle a of its return row, w_qa = W(r_qa, h_a)/S_q (none when fixed
/// or uncoupled).
#[inline(always)]
unsafe fn for_deposits<R: Real>(q: usize, a: &DepositRowsArgs<R>, mut f: impl FnMut(usize, R)) {
    let ng = a.gas.len();
    let (ph, t, is_gas) = if q < ng {
        (&a.gas, q, true)
    } else {
        (&a.dust, q - ng, false)
    };
    if kernels::is_fixed(ph.fixed(), t) {
        return;
    }
    let cb = &a.cb;
    let s = if is_gas {
        *cb.s_gas.add(t)
    } else {
        *cb.s_dust.add(t)
    };
    if s <= R::ZERO {
        return;
    }
    let slot = if is_gas { 0 } else { 1 + ph.group_of(t) };
    let stride = 1 + a.p.nf as usize;
    let (idx, w) = cb.pairs.ret(q);
    for (&g, &wg) in idx.iter().zip(w) {
        let w = wg / s;
        if w > R::ZERO {
            f(g as usize * stride + slot, w);
        }
    }
}

/// The deposit rows' lengths: each particle of thread t counts itself into the row of each
/// gas particle it deposits on: atomically into `dep_off` (zeroed before; scanned after), or
/// into its chunk's own counters.
pub unsafe fn coupling_deposit_count<R: Real>(t: usize, a: &DepositRowsArgs<R>) {
    let rows = a.rows();
    for q in a.particles(t) {
        if a.chunk == 0 {
            let off = a.cb.pairs.dep_off;
            for_deposits(q, a, |row, _| {
                atomic_add_u32(off.add(row), 1);
            });
        } else {
            let cnt = a.counts.add(t * rows);
            for_deposits(q, a, |row, _| *cnt.add(row) += 1);
        }
    }
}

/// Chunked form, thread t = deposit row t: its length, the sum of the chunks' counts, into
/// `dep_off` (then scanned).
pub unsafe fn coupling_deposit_total<R: Real>(t: usize, a: &DepositRowsArgs<R>) {
    let rows = a.rows();
    if t >= rows {
        return;
    }
    let chunks = (a.gas.len() + a.dust.len()).div_ceil(a.chunk as usize);
    let mut n = 0;
    for c in 0..chunks {
        n += *a.counts.add(c * rows + t);
    }
    *a.cb.pairs.dep_off.add(t) = n;
}

/// Chunked form, thread t = deposit row t, after the scan: each chunk's counter becomes where
/// its first entry in the row goes (the chunks in order).
pub unsafe fn coupling_deposit_starts<R: Real>(t: usize, a: &DepositRowsArgs<R>) {
    let rows = a.rows();
    if t >= rows {
        return;
    }
    let chunks = (a.gas.len() + a.dust.len()).div_ceil(a.chunk as usize);
    let mut at = *a.cb.pairs.dep_off.add(t);
    for c in 0..chunks {
        let n = *a.counts.add(c * rows + t);
        *a.counts.add(c * rows + t) = at;
        at += n;
    }
}

/// The deposit rows filled: each particle of thread t writes itself and its weight into the
/// row of each gas particle it deposits on, at the slot its chunk's counter holds, or that the
/// row's atomic cursor hands out (then [`coupling_deposit_sort`] orders each row).
pub unsafe fn coupling_deposit_fill<R: Real>(t: usize, a: &DepositRowsArgs<R>) {
    let pr = &a.cb.pairs;
    let rows = a.rows();
    let ng = a.gas.len();
    for q in a.particles(t) {
        // The row holds one phase: its own index.
        let own = if q < ng { q } else { q - ng };
        let put = |at: usize, w: R| {
            *pr.dep_idx.add(at) = own as u32;
            *pr.dep_w.add(at) = w;
        };
        if a.chunk == 0 {
            for_deposits(q, a, |row, w| {
                let at = *pr.dep_off.add(row) + atomic_add_u32(pr.dep_cur.add(row), 1);
                put(at as usize, w);
            });
        } else {
            let next = a.counts.add(t * rows);
            for_deposits(q, a, |row, w| {
                let at = *next.add(row);
                *next.add(row) = at + 1;
                put(at as usize, w);
            });
        }
    }
}

/// Deposit row t in ascending particle order (an insertion sort: rows hold tens of pairs), so
/// that its sums do not depend on the threads' order: the same bits on every launcher and
/// thread count, and as the chunked form.
pub unsafe fn coupling_deposit_sort<R: Real>(t: usize, a: &DepositRowsArgs<R>) {
    if t >= a.rows() {
        return;
    }
    let pr = &a.cb.pairs;
    let (lo, hi) = (*pr.dep_off.add(t) as usize, *pr.dep_off.add(t + 1) as usize);
    let idx = sl_mut(pr.dep_idx.add(lo), hi - lo);
    let w = sl_mut(pr.dep_w.add(lo), hi - lo);
    for i in 1..idx.len() {
        let (q, wq) = (idx[i], w[i]);
        let mut j = i;
        while j > 0 && idx[j - 1] > q {
            idx[j] = idx[j - 1];
            w[j] = w[j - 1];
            j -= 1;
        }
        idx[j] = q;
        w[j] = wq;
    }
}
