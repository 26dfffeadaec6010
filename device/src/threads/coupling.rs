//! External dust acceleration and the kernel coupling (docs/method.md §K).
use super::*;
use crate::kernels::Centre;

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct DustAccelArgs<R> {
    pub ph: PhaseBufs<R>,
    pub p: Params<R>,
}

/// ũ = u + τB of dust particle t (B = `ext_dust` + the point mass's pull; fixed particles
/// keep u): the drag pass then reads the dust velocities as ũ, as on the CPU.
pub unsafe fn dust_accel<R: Real>(t: usize, a: &DustAccelArgs<R>) {
    let d = &a.ph;
    if t >= d.len() || kernels::is_fixed(d.fixed(), t) {
        return;
    }
    let b = dust_external(t, a);
    *d.v.add(t) = crate::axpy(*d.v.add(t), a.p.tau, b);
}

/// B of dust particle t: `ext_dust` plus the point mass's acceleration and its edge zones'
/// damping.
#[inline(always)]
unsafe fn dust_external<R: Real>(t: usize, a: &DustAccelArgs<R>) -> Vec3<R> {
    let g = &a.p.gravity;
    if g.is_on() {
        let x = a.ph.x()[t];
        let damp = g.damping(x, a.ph.v()[t].map(|c| c.to_f64()));
        crate::add(a.p.ext_dust, crate::add(g.accel(x), damp).map(R::from_f64))
    } else {
        a.p.ext_dust
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct DustLimitArgs<R> {
    pub acc: DustAccelArgs<R>,
    /// The step's limits ([vsig, |A|, damping rate] as ordered bits, as the forces kernel
    /// writes them).
    pub limits: *mut u64,
}

/// |B| of dust particle t into the step's acceleration limit (the force limit √(h/|A|) then
/// holds for the dust under a point mass too), and its edge zones' damping rate.
pub unsafe fn dust_accel_limit<R: Real>(t: usize, a: &DustLimitArgs<R>) {
    let d = &a.acc.ph;
    if t >= d.len() || kernels::is_fixed(d.fixed(), t) {
        return;
    }
    let b = dust_external(t, &a.acc);
    let m = Real::sqrt(crate::dot(b, b));
    atomic_max_u64(a.limits.add(1), kernels::ordered_bits(m));
    let rate = a.acc.p.gravity.damp_rate(d.x()[t]);
    if rate > 0.0 {
        atomic_max_u64(a.limits.add(2), kernels::ordered_bits(R::from_f64(rate)));
    }
}

/// The kernel coupling's pairs of one layer (docs/method.md §K, "The pairs, once per layer"):
/// found once, when the positions change, and summed over by every drag pass of the layer.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct PairBufs<R> {
    /// The return rows: per gas particle q (row q) and dust particle j (row n_gas + j), the gas
    /// particles a with W(r_qa, h_a) > 0 in the neighbour walk's order, `cap` slots per row at
    /// row·cap, with W itself (the row's sum is the normaliser S_q).
    pub ret_idx: *mut u32,
    pub ret_w: *mut R,
    /// Per row its length; above `cap` the row is incomplete (the host then widens `cap` and
    /// finds the pairs again: [`PairBufs::ret_max`]).
    pub ret_cnt: *mut u32,
    pub cap: u32,
    /// The longest row (atomic max).
    pub ret_max: *mut u32,
    /// The deposit rows: per gas particle a and phase slot s (0 gas, 1 + k fraction k), row
    /// a(1 + nf) + s spans dep_off[row]..dep_off[row + 1] of `dep_idx` (the depositing gas or
    /// dust particle) and `dep_w` (w_qa = W(r_qa, h_a)/S_q), in ascending particle order: the
    /// return rows transposed ([`coupling_deposit_count`], [`coupling_deposit_fill`],
    /// [`coupling_deposit_sort`]).
    pub dep_off: *mut u32,
    /// Per deposit row, the fill's cursor (zeroed before the fill).
    pub dep_cur: *mut u32,
    pub dep_idx: *mut u32,
    pub dep_w: *mut R,
}

impl<R: Real> PairBufs<R> {
    /// Return row `row` (gas particle, or n_gas + dust particle): gas indices and W.
    #[inline(always)]
    unsafe fn ret(&self, row: usize) -> (&[u32], &[R]) {
        let cap = self.cap as usize;
        let n = (*self.ret_cnt.add(row) as usize).min(cap);
        (
            sl(self.ret_idx.add(row * cap), n),
            sl(self.ret_w.add(row * cap), n),
        )
    }
    /// Deposit row of phase slot `slot` on gas particle a (`stride` = 1 + nf).
    #[inline(always)]
    unsafe fn dep(&self, a: usize, slot: usize, stride: usize) -> (&[u32], &[R]) {
        let row = a * stride + slot;
        let (lo, hi) = (
            *self.dep_off.add(row) as usize,
            *self.dep_off.add(row + 1) as usize,
        );
        (
            sl(self.dep_idx.add(lo), hi - lo),
            sl(self.dep_w.add(lo), hi - lo),
        )
    }
}

/// Per-particle buffers of the kernel coupling.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CouplingBufs<R> {
    /// S of every gas / dust particle (0: fixed or no gas within reach).
    pub s_gas: *mut R,
    pub s_dust: *mut R,
    /// Per gas particle: new − old mean of the gas, and of fraction k at a·nf + k.
    pub dv: *mut Vec3<R>,
    pub du: *mut Vec3<R>,
    /// Per gas particle and fraction (a·nf + k): t_k* of its means (+∞ where uncoupled).
    pub t_stop: *mut R,
    /// `idic.dispersion = "damped"` (null otherwise): per gas particle its new gas mean V^{n+1}
    /// (`v_new`), per gas particle and fraction the new dust mean U^{n+1} (`u_new`, a·nf + k),
    /// per gas particle its own deviation v_a − Σ_c w_ac V_c^{n+1} (`gas_dev`), and per dust
    /// particle the velocity the damping took from it (`react`).
    pub v_new: *mut Vec3<R>,
    pub u_new: *mut Vec3<R>,
    pub gas_dev: *mut Vec3<R>,
    pub react: *mut Vec3<R>,
    /// `idic.dispersion = "damped"` with `idic.sampling = "linear"` (null otherwise): per gas
    /// particle a its fitted velocity gradient G_a (rows 3a..3a+3, G[i] = ∇v_i), zeros where
    /// the fit fails: the damping reads each gas particle's field at the particle it serves.
    pub grad: *mut Vec3<R>,
    /// The gas kernels of the weights, one per gas particle (variable h: W(r, h_a)); null:
    /// one shared kernel at the reference h.
    pub kernel_at: *const KernelAt<R>,
    /// Per gas particle, 1 where its solve and heat are left to its owner: over MPI ranks a
    /// ghost, whose values the refresh after the pass brings (docs/scaling.md); null: none.
    pub gas_skip: *const u8,
    /// The pairs of this layer.
    pub pairs: PairBufs<R>,
}

/// Whether gas particle t's solve and heat are left to its owner ([`CouplingBufs::gas_skip`]).
#[inline(always)]
unsafe fn gas_skipped<R>(cb: &CouplingBufs<R>, t: usize) -> bool {
    !cb.gas_skip.is_null() && *cb.gas_skip.add(t) != 0
}

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

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CoupleArgs<R> {
    pub gas: PhaseBufs<R>,
    pub dust: PhaseBufs<R>,
    /// A^n of the gas (ṽ = v + τ(A + ext_gas)).
    pub acc: *const Vec3<R>,
    pub pres: *const R,
    pub cb: CouplingBufs<R>,
    pub p: Params<R>,
}

/// Gas particle t: the deposits of the gas and of every fraction on it (summed over its deposit
/// rows), the implicit solve, and the increments of its means (and its t_k*).
pub unsafe fn coupling_solve<R: Real>(t: usize, a: &CoupleArgs<R>) {
    let g = &a.gas;
    if t >= g.len() {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let mut dust_dep = [kernels::Deposit::default(); MAX_FRACTIONS];
    if kernels::is_fixed(g.fixed(), t) || gas_skipped(&a.cb, t) {
        store_gradient(t, &a.cb, &[[R::ZERO; 3]; 3]);
        return coupling_finish(t, a, &kernels::Deposit::default(), &dust_dep);
    }
    let pr = &a.cb.pairs;
    let (idx, w) = pr.dep(t, 0, 1 + nf);
    let mut gas_dep = kernels::deposit_rows(
        idx,
        w,
        g.m(),
        g.rho(),
        |b| gas_base_velocity(a, b),
        |b| gas_sound(a, b),
    );
    let d = &a.dust;
    let u = d.v();
    for (f, dep) in dust_dep.iter_mut().enumerate().take(nf) {
        let (idx, w) = pr.dep(t, 1 + f, 1 + nf);
        *dep = kernels::deposit_rows(idx, w, d.m(), d.rho(), |j| u[j], |_| R::ZERO);
    }
    if p.linear_sampling != 0 {
        read_at_particle(t, a, &mut gas_dep, &mut dust_dep);
    }
    coupling_finish(t, a, &gas_dep, &dust_dep);
}

/// Every deposit on gas particle t read at x_t, not at its particles' mass-weighted centroid:
/// corrected by the gas's velocity gradient fitted over t's gas row (method.md §K, "Sampling
/// offsets"). Gas and dust centroids about a gas particle differ by a fraction of h wherever
/// the two lattices differ, and in a Keplerian shear that offset alone reads as a relative
/// velocity of the order of the drift; unchanged where the row does not span the dimensions.
#[inline(always)]
unsafe fn read_at_particle<R: Real>(
    t: usize,
    a: &CoupleArgs<R>,
    gas_dep: &mut kernels::Deposit<R>,
    dust_dep: &mut [kernels::Deposit<R>; MAX_FRACTIONS],
) {
    let (g, d, p) = (&a.gas, &a.dust, &a.p);
    let nf = p.nf as usize;
    let pr = &a.cb.pairs;
    let xt = g.x()[t];
    let dx = |x: Vec3<f64>| p.geom.separation(x, xt).map(R::from_f64);
    let vt = gas_base_velocity(a, t);
    let (idx, w) = pr.dep(t, 0, 1 + nf);
    let Some((grad, first)) = kernels::row_gradient(
        idx,
        w,
        g.m(),
        |b| dx(g.x()[b]),
        |b| crate::sub(gas_base_velocity(a, b), vt),
        p.dim as usize,
    ) else {
        return store_gradient(t, &a.cb, &[[R::ZERO; 3]; 3]);
    };
    store_gradient(t, &a.cb, &grad);
    kernels::read_at_centre(gas_dep, &grad, first);
    for (f, dep) in dust_dep.iter_mut().enumerate().take(nf) {
        let (idx, w) = pr.dep(t, 1 + f, 1 + nf);
        let first = kernels::row_moment(idx, w, d.m(), |j| dx(d.x()[j]));
        kernels::read_at_centre(dep, &grad, first);
    }
}

/// Keep gas particle t's fitted gradient for the damping ([`CouplingBufs::grad`]), if kept.
#[inline(always)]
unsafe fn store_gradient<R: Real>(t: usize, cb: &CouplingBufs<R>, g: &[Vec3<R>; 3]) {
    if !cb.grad.is_null() {
        for (i, gi) in g.iter().enumerate() {
            *cb.grad.add(3 * t + i) = *gi;
        }
    }
}

/// Gas particle g's field `f` read at x (its gradient times x − x_g added where kept).
#[inline(always)]
unsafe fn field_at<R: Real>(a: &ReturnArgs<R>, g: usize, f: Vec3<R>, x: Vec3<f64>) -> Vec3<R> {
    if a.cb.grad.is_null() {
        return f;
    }
    let d = a.p.geom.separation(x, a.gas.x()[g]).map(R::from_f64);
    let gr = a.cb.grad.add(3 * g);
    [
        f[0] + crate::dot(*gr, d),
        f[1] + crate::dot(*gr.add(1), d),
        f[2] + crate::dot(*gr.add(2), d),
    ]
}

/// ṽ_b = v_b + τ(A_b + ext_gas) of gas particle b.
#[inline(always)]
unsafe fn gas_base_velocity<R: Real>(a: &CoupleArgs<R>, b: usize) -> Vec3<R> {
    crate::axpy(
        *a.gas.v.add(b),
        a.p.tau,
        crate::add(*a.acc.add(b), a.p.ext_gas),
    )
}

/// sqrt(p/ρ) of gas particle b where a stopping-time law needs it, else 0.
#[inline(always)]
unsafe fn gas_sound<R: Real>(a: &CoupleArgs<R>, b: usize) -> R {
    if a.p.needs_gas_state != 0 {
        let rho = *a.gas.rho.add(b);
        a.p.eos().isothermal_speed(rho, *a.pres.add(b))
    } else {
        R::ZERO
    }
}

/// The implicit solve of gas particle t from its deposits; writes the increments of its means
/// and its t_k* (zeros and +∞ for a fixed particle, whose deposits are empty).
#[inline(always)]
unsafe fn coupling_finish<R: Real>(
    t: usize,
    a: &CoupleArgs<R>,
    gas_dep: &kernels::Deposit<R>,
    dust_dep: &[kernels::Deposit<R>; MAX_FRACTIONS],
) {
    let p = &a.p;
    let nf = p.nf as usize;
    let laws = p.stopping_laws();
    let inc = kernels::kernel_increments(
        gas_dep,
        &dust_dep[..nf],
        &laws[..nf],
        p.tau,
        p.eos().gamma_root(),
    );
    *a.cb.dv.add(t) = inc.dv;
    for f in 0..nf {
        *a.cb.du.add(t * nf + f) = inc.du[f];
        *a.cb.t_stop.add(t * nf + f) = inc.t_stop[f];
    }
    if p.damp_dispersion != 0 {
        let mean = |d: &kernels::Deposit<R>| {
            if d.mass > R::ZERO {
                crate::scale(R::ONE / d.mass, d.mom)
            } else {
                [R::ZERO; 3]
            }
        };
        *a.cb.v_new.add(t) = crate::add(mean(gas_dep), inc.dv);
        for (f, dep) in dust_dep.iter().enumerate().take(nf) {
            *a.cb.u_new.add(t * nf + f) = crate::add(mean(dep), inc.du[f]);
        }
    }
}

/// Slots of one phase's deposit on one gas particle in the scatter form's sums: Σ w m,
/// Σ w m ṽ (3), Σ w m ρ, Σ w m sqrt(p/ρ).
pub const DEPOSIT_SLOTS: usize = 6;

/// Atomic f64 add (compare-and-swap on the bits: the same code on the GPU and on the CPU's cores).
/// The scatter sums stay f64 in every precision: their order is the hardware's anyway.
#[inline(always)]
unsafe fn atomic_add_f64(p: *mut f64, v: f64) {
    let a = AtomicU64::from_ptr(p as *mut u64);
    let mut old = a.load(Ordering::Relaxed);
    loop {
        let new = (f64::from_bits(old) + v).to_bits();
        match a.compare_exchange_weak(old, new, Ordering::Relaxed, Ordering::Relaxed) {
            Ok(_) => return,
            Err(x) => old = x,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct ScatterDepositArgs<R> {
    pub couple: CoupleArgs<R>,
    /// The depositing phase (the gas, or the dust), and 1 when it is the gas.
    pub ph: PhaseBufs<R>,
    pub is_gas: u32,
    /// Per gas particle a, phase slot s (0 gas, 1 + k fraction k): DEPOSIT_SLOTS sums at
    /// (a·(1 + nf) + s)·DEPOSIT_SLOTS; zeroed before the launch. f64 in every precision.
    pub sums: *mut f64,
}

/// Scatter form of the deposits (the design card's atomicAdd): particle t adds its share to
/// each gas particle of its return row. The sums' order is the hardware's: not bit-reproducible.
pub unsafe fn coupling_scatter<R: Real>(t: usize, a: &ScatterDepositArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() || kernels::is_fixed(ph.fixed(), t) {
        return;
    }
    let c = &a.couple;
    let p = &c.p;
    let gas = a.is_gas != 0;
    let s = if gas {
        *c.cb.s_gas.add(t)
    } else {
        *c.cb.s_dust.add(t)
    };
    if s <= R::ZERO {
        return;
    }
    let (vel, cs, slot) = if gas {
        (gas_base_velocity(c, t), gas_sound(c, t), 0)
    } else {
        (*ph.v.add(t), R::ZERO, 1 + ph.group_of(t))
    };
    let (m, rho) = (*ph.m.add(t), *ph.rho.add(t));
    let stride = 1 + p.nf as usize;
    let row = if gas { t } else { c.gas.len() + t };
    let (idx, ws) = c.cb.pairs.ret(row);
    for (&g, &w) in idx.iter().zip(ws) {
        let wm = w / s * m;
        let o = a.sums.add((g as usize * stride + slot) * DEPOSIT_SLOTS);
        atomic_add_f64(o, wm.to_f64());
        for (d, v) in vel.iter().enumerate() {
            atomic_add_f64(o.add(1 + d), (wm * *v).to_f64());
        }
        atomic_add_f64(o.add(4), (wm * rho).to_f64());
        atomic_add_f64(o.add(5), (wm * cs).to_f64());
    }
}

/// The solve of gas particle t from the scatter form's sums.
pub unsafe fn coupling_solve_sums<R: Real>(t: usize, a: &ScatterDepositArgs<R>) {
    let c = &a.couple;
    if t >= c.gas.len() {
        return;
    }
    let nf = c.p.nf as usize;
    let stride = 1 + nf;
    let dep = |slot: usize| {
        let o = a.sums.add((t * stride + slot) * DEPOSIT_SLOTS);
        kernels::Deposit {
            mass: R::from_f64(*o),
            mom: [
                R::from_f64(*o.add(1)),
                R::from_f64(*o.add(2)),
                R::from_f64(*o.add(3)),
            ],
            rho: R::from_f64(*o.add(4)),
            cs: R::from_f64(*o.add(5)),
        }
    };
    let mut dust_dep = [kernels::Deposit::default(); MAX_FRACTIONS];
    for (f, d) in dust_dep.iter_mut().enumerate().take(nf) {
        *d = dep(1 + f);
    }
    coupling_finish(t, c, &dep(0), &dust_dep);
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct ReturnArgs<R> {
    pub gas: PhaseBufs<R>,
    /// The phase that receives its increments (the gas itself, or the dust).
    pub ph: PhaseBufs<R>,
    /// A^n for the gas (its base velocity is ṽ = v + τ(A + ext_gas)); null for the dust (ũ).
    pub acc: *const Vec3<R>,
    /// 1: `ph` is the gas.
    pub is_gas: u32,
    pub cb: CouplingBufs<R>,
    /// For [`coupling_tstop`]: the stopping time of every particle of `ph`.
    pub out: *mut R,
    /// Drag heating: the kinetic energy each particle of `ph` loses; null without heating.
    pub loss: *mut R,
    pub p: Params<R>,
}

/// Return row of particle t of `a.ph` (gas t, or n_gas + dust t).
#[inline(always)]
unsafe fn ret_row<R: Real>(t: usize, a: &ReturnArgs<R>) -> (&[u32], &[R]) {
    let row = if a.is_gas != 0 { t } else { a.gas.len() + t };
    a.cb.pairs.ret(row)
}

/// Particle t of `ph` gets its base velocity plus Σ_a w_ta Δ_a.
pub unsafe fn coupling_return<R: Real>(t: usize, a: &ReturnArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() || kernels::is_fixed(ph.fixed(), t) {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let v = *ph.v.add(t);
    let is_gas = a.is_gas != 0;
    let (base, s, f) = if is_gas {
        let acc = crate::add(*a.acc.add(t), p.ext_gas);
        (crate::axpy(v, p.tau, acc), *a.cb.s_gas.add(t), 0)
    } else {
        (v, *a.cb.s_dust.add(t), ph.group_of(t))
    };
    let (idx, w) = ret_row(t, a);
    let inc = kernels::gather_rows(idx, w, s, |g| {
        if is_gas {
            *a.cb.dv.add(g)
        } else {
            *a.cb.du.add(g * nf + f)
        }
    });
    let new = crate::add(base, inc);
    if !a.loss.is_null() {
        *a.loss.add(t) = drag::kinetic_loss(*ph.m.add(t), base, new);
    }
    *ph.v.add(t) = new;
}

/// `idic.dispersion = "damped"` (method.md §K, "The unresolved dispersion"), after the return
/// of both phases. A gas particle records its deviation from its smoothed new field,
/// d_a = v_a − Σ_c w_ac V_c^{n+1}; then (a second launch, once every d_a is there) a dust
/// particle j relaxes its own deviation from the smoothed field it should follow,
/// δ_j = u_j − Σ_a w_ja (U_a^{n+1} + d_a), by β/(1 + β), β = τ/t_j (backward Euler, t_j =
/// Σ_a w_ja t_k,a), and records what it lost for [`coupling_react`]. For a smooth field carried
/// alike by gas and dust the gas's deviation equals the dust's to high order, so only what the
/// kernel does not resolve is damped. A kernel of its own: the return stays as lean as without.
pub unsafe fn coupling_damp<R: Real>(t: usize, a: &ReturnArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() || kernels::is_fixed(ph.fixed(), t) {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let is_gas = a.is_gas != 0;
    let (s, f) = if is_gas {
        (*a.cb.s_gas.add(t), 0)
    } else {
        (*a.cb.s_dust.add(t), ph.group_of(t))
    };
    let v = ph.v.add(t);
    if s <= R::ZERO {
        if is_gas {
            *a.cb.gas_dev.add(t) = [R::ZERO; 3];
        } else {
            *a.cb.react.add(t) = [R::ZERO; 3];
        }
        return;
    }
    let (idx, ws) = ret_row(t, a);
    if is_gas {
        let x = ph.x()[t];
        let smooth = kernels::gather_rows(idx, ws, s, |c| field_at(a, c, *a.cb.v_new.add(c), x));
        *a.cb.gas_dev.add(t) = crate::sub(*v, smooth);
        return;
    }
    // One sweep for the target and the stopping time the particle feels.
    let (mut target, mut t_stop) = ([R::ZERO; 3], R::ZERO);
    let x = ph.x()[t];
    for (&g, &w) in idx.iter().zip(ws) {
        let (g, w) = (g as usize, w / s);
        let u = field_at(a, g, *a.cb.u_new.add(g * nf + f), x);
        let aim = crate::add(u, *a.cb.gas_dev.add(g));
        target = crate::axpy(target, w, aim);
        t_stop += w * *a.cb.t_stop.add(g * nf + f);
    }
    let beta = p.tau / t_stop;
    let share = if beta.is_finite() && beta > R::ZERO {
        beta / (R::ONE + beta)
    } else {
        R::ZERO
    };
    let lost = crate::scale(share, crate::sub(*v, target));
    *a.cb.react.add(t) = lost;
    *v = crate::sub(*v, lost);
}

/// `idic.dispersion = "damped"`: gas particle t takes the momentum the damping took from the
/// dust around it, with the deposit's weights (Σ_j w_jt m_j Δu_j / m_t): Σ_a w_ja = 1, so the
/// total momentum is exact.
pub unsafe fn coupling_react<R: Real>(t: usize, a: &CoupleArgs<R>) {
    let g = &a.gas;
    if t >= g.len() || kernels::is_fixed(g.fixed(), t) {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let d = &a.dust;
    let mut gained = [R::ZERO; 3];
    for f in 0..nf {
        let (idx, w) = a.cb.pairs.dep(t, 1 + f, 1 + nf);
        let dep =
            kernels::deposit_rows(idx, w, d.m(), d.rho(), |j| *a.cb.react.add(j), |_| R::ZERO);
        gained = crate::add(gained, dep.mom);
    }
    let v = g.v.add(t);
    *v = crate::axpy(*v, R::ONE / *g.m.add(t), gained);
}

/// The stopping time dust particle t feels: Σ_a w_ta t_k,a (+∞ without gas within reach).
pub unsafe fn coupling_tstop<R: Real>(t: usize, a: &ReturnArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let nf = a.p.nf as usize;
    let s = *a.cb.s_dust.add(t);
    let out = if s <= R::ZERO {
        R::from_f64(f64::INFINITY)
    } else {
        let f = ph.group_of(t);
        let (idx, w) = ret_row(t, a);
        kernels::gather_rows(idx, w, s, |g| {
            [*a.cb.t_stop.add(g * nf + f), R::ZERO, R::ZERO]
        })[0]
    };
    *a.out.add(t) = out;
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CouplingHeatArgs<R> {
    pub couple: CoupleArgs<R>,
    /// Kinetic energy lost per gas / dust particle in this drag pass ([`coupling_return`]).
    pub loss_gas: *const R,
    pub loss_dust: *const R,
    /// Out: drag heat per unit mass of every gas particle.
    pub heat: *mut R,
}

/// Drag heat of gas particle t under the kernel coupling: Σ_q w_qt ΔE_q / m_t, every particle's
/// loss spread with its own weights (Σ_a w_qa = 1: the gas gains what the particles lose), as
/// the deposit of the losses as masses (method.md §K).
pub unsafe fn coupling_heat<R: Real>(t: usize, a: &CouplingHeatArgs<R>) {
    let c = &a.couple;
    let g = &c.gas;
    if t >= g.len() {
        return;
    }
    let p = &c.p;
    if kernels::is_fixed(g.fixed(), t) || gas_skipped(&c.cb, t) {
        *a.heat.add(t) = R::ZERO;
        return;
    }
    let stride = 1 + p.nf as usize;
    let zero = [R::ZERO; 3];
    let pr = &c.cb.pairs;
    let (idx, w) = pr.dep(t, 0, stride);
    let loss_gas = sl(a.loss_gas, g.len());
    let mut q = kernels::deposit_rows(idx, w, loss_gas, g.rho(), |_| zero, |_| R::ZERO).mass;
    let d = &c.dust;
    let loss_dust = sl(a.loss_dust, d.len());
    for f in 0..p.nf as usize {
        let (idx, w) = pr.dep(t, 1 + f, stride);
        q += kernels::deposit_rows(idx, w, loss_dust, d.rho(), |_| zero, |_| R::ZERO).mass;
    }
    *a.heat.add(t) = q / *g.m.add(t);
}
