//! External dust acceleration and the kernel coupling (docs/method.md §K): the coupling's buffers
//! here; its rows, the solve (gathered or scattered) and the return in submodules.
use super::*;

mod returns;
mod rows;
mod scatter;
mod solve;
pub use returns::*;
pub use rows::*;
pub use scatter::*;
pub use solve::*;

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

/// |B| of dust particle t without the zones' damping ([`crate::timestep::dust_pull`]) into the
/// step's acceleration limit (the force limit √(h/|A|) then holds for the dust under a point
/// mass too), and its edge zones' damping rate.
pub unsafe fn dust_accel_limit<R: Real>(t: usize, a: &DustLimitArgs<R>) {
    let d = &a.acc.ph;
    if t >= d.len() || kernels::is_fixed(d.fixed(), t) {
        return;
    }
    let p = &a.acc.p;
    let ext = p.ext_dust.map(|c| c.to_f64());
    let m = R::from_f64(crate::timestep::dust_pull(&p.gravity, ext, d.x()[t]));
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
