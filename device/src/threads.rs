//! The GPU step, one function per kernel, written as "what thread `t` does" over raw buffers.
//!
//! Each kernel takes one `#[repr(C)]` argument struct of pointers and parameters. On the GPU the
//! `extern "ptx-kernel"` entry points of [`crate::ptx`] compute the global thread index and call
//! these functions; on the host, the rayon launcher calls the very same functions for every
//! thread index, so the kernel code itself — not a model of it — runs in CI. The bodies they call
//! ([`crate::kernels`]) hold the physics; [`crate::kernel_table`] pairs each with its entry point.
//!
//! Layout: a phase buffer holds one or more groups (gas: one; dust: one per fraction, stored one
//! after another). Particles are sorted by a combined key `group · (T + 1) + cell key` (T cells in
//! the grid box), so one counting sort orders every fraction at once and the dense start table
//! of the combined keys is every group's table back to back, in absolute particle indices.
//!
//! Safety (for every function here): the pointers must be valid for the lengths the argument
//! struct states, writes of different threads go to different elements except through the
//! atomics used here, and `t` indexes one thread of a launch.
#![allow(unsafe_code, clippy::missing_safety_doc)]

use crate::drag::StoppingLaw;
use crate::eos::Eos;
use crate::grid::{CellLookup, GridGeom};
use crate::kernel::KernelAt;
use crate::kernels::{self, GasView, Sorted, MAX_FRACTIONS};
use crate::sph::{Sym3, Viscosity};
use crate::{dot, drag, update, Real, Vec3};
use core::slice;
use core::sync::atomic::{AtomicU32, AtomicU64, Ordering};

/// A stopping-time law as plain data: `kind` 0 = constant t (value t), 1 = constant K (value K),
/// 2 = Epstein (value s·ρ_s).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LawParam<R> {
    pub kind: u32,
    pub value: R,
}

impl<R: Real> LawParam<R> {
    pub fn from_law(l: &StoppingLaw<R>) -> LawParam<R> {
        match *l {
            StoppingLaw::ConstantTime { t_stop } => LawParam {
                kind: 0,
                value: t_stop,
            },
            StoppingLaw::ConstantK { k } => LawParam { kind: 1, value: k },
            StoppingLaw::Epstein { s_rho } => LawParam {
                kind: 2,
                value: s_rho,
            },
        }
    }

    #[inline(always)]
    pub fn law(&self) -> StoppingLaw<R> {
        match self.kind {
            0 => StoppingLaw::ConstantTime { t_stop: self.value },
            1 => StoppingLaw::ConstantK { k: self.value },
            _ => StoppingLaw::Epstein { s_rho: self.value },
        }
    }
}

/// The physics and grid of one step. Kernels read it through [`Params`] (a pointer to one
/// copy in device memory), not by value: a by-value struct of ≈1 kB is copied into every
/// thread's local memory (stack) on the GPU.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepParams<R> {
    /// The grid, in f64 in every precision (positions are f64: see `kernels::Sorted`).
    pub geom: GridGeom<f64>,
    /// Cells in the grid box (T); combined keys run over groups · (T + 1).
    pub total: u64,
    pub h: R,
    pub tau: R,
    pub dim: u32,
    /// 0 isothermal (value c_s), 1 adiabatic (value γ).
    pub eos_kind: u32,
    pub eos_value: R,
    /// 1 when artificial viscosity is on.
    pub av: u32,
    pub alpha: R,
    pub beta: R,
    pub nu2_factor: R,
    pub nf: u32,
    pub needs_gas_state: u32,
    pub laws: [LawParam<R>; MAX_FRACTIONS],
    /// Constant external accelerations of the gas (added to A^n) and of the dust (B^n).
    pub ext_gas: Vec3<R>,
    pub ext_dust: Vec3<R>,
    /// 1: the explicit (forward-Euler) drag baseline instead of IDIC.
    pub explicit_drag: u32,
}

/// Where a kernel finds its [`StepParams`]: one copy in device memory (host memory for the
/// rayon launcher), shared by every thread; read through `Deref`.
#[repr(transparent)]
#[derive(Clone, Copy, Debug)]
pub struct Params<R>(pub *const StepParams<R>);

impl<R> core::ops::Deref for Params<R> {
    type Target = StepParams<R>;
    #[inline(always)]
    fn deref(&self) -> &StepParams<R> {
        // SAFETY: the engine passes the address of a live StepParams for the launch (the
        // kernels' contract, module docs), written before the launch and not during it.
        unsafe { &*self.0 }
    }
}

impl<R: Real> StepParams<R> {
    #[inline(always)]
    pub fn eos(&self) -> Eos<R> {
        if self.eos_kind == 0 {
            Eos::Isothermal { cs: self.eos_value }
        } else {
            Eos::Adiabatic {
                gamma: self.eos_value,
            }
        }
    }

    #[inline(always)]
    pub fn viscosity(&self) -> Option<Viscosity<R>> {
        (self.av != 0).then_some(Viscosity {
            alpha: self.alpha,
            beta: self.beta,
            nu2_factor: self.nu2_factor,
        })
    }

    /// The same step in another precision (the host builds it in f64).
    pub fn cast<S: Real>(&self) -> StepParams<S> {
        let c = |x: R| S::from_f64(x.to_f64());
        StepParams {
            geom: self.geom,
            total: self.total,
            h: c(self.h),
            tau: c(self.tau),
            dim: self.dim,
            eos_kind: self.eos_kind,
            eos_value: c(self.eos_value),
            av: self.av,
            alpha: c(self.alpha),
            beta: c(self.beta),
            nu2_factor: c(self.nu2_factor),
            nf: self.nf,
            needs_gas_state: self.needs_gas_state,
            laws: self.laws.map(|l| LawParam {
                kind: l.kind,
                value: c(l.value),
            }),
            ext_gas: self.ext_gas.map(c),
            ext_dust: self.ext_dust.map(c),
            explicit_drag: self.explicit_drag,
        }
    }

    /// The stopping-time laws of the fractions.
    #[inline(always)]
    pub fn stopping_laws(&self) -> [StoppingLaw<R>; MAX_FRACTIONS] {
        let mut l = [StoppingLaw::ConstantTime { t_stop: R::ZERO }; MAX_FRACTIONS];
        for (l, p) in l.iter_mut().zip(&self.laws).take(self.nf as usize) {
            *l = p.law();
        }
        l
    }

    /// IDIC cells per search cell.
    #[inline(always)]
    pub fn sub_cells(&self) -> usize {
        (self.geom.sub[0] * self.geom.sub[1] * self.geom.sub[2]) as usize
    }

    /// Entries per group of the dense start tables: one per search cell ("bucket") of the grid
    /// box, + 1. The tables are per search cell, not per IDIC cell, so they are `sub_cells`
    /// times smaller (8 in 3D with IDIC cells of 0.5h).
    #[inline(always)]
    pub fn stride(&self) -> usize {
        self.total as usize / self.sub_cells() + 1
    }

    /// Combined particle key = group · (T + 1) + IDIC cell key.
    #[inline(always)]
    fn key_stride(&self) -> usize {
        self.total as usize + 1
    }

    /// Dense-table slot (group · stride + search cell) of a combined key.
    #[inline(always)]
    fn bucket_of(&self, combined: u64) -> usize {
        let ks = self.key_stride() as u64;
        let (g, k) = (combined / ks, combined % ks);
        g as usize * self.stride() + k as usize / self.sub_cells()
    }
}

/// Union index of IDIC cell `k`: the occupied cells of search cell b = k / sub are
/// ukey[ubidx[b] .. ubidx[b + 1]], sorted. `None` when no phase occupies k. Plain slices, so
/// the host reads the union the same way.
#[inline(always)]
pub fn union_index(ubidx: &[u32], ukey: &[u64], sub_cells: usize, k: u64) -> Option<usize> {
    let b = k as usize / sub_cells;
    let (lo, hi) = (ubidx[b] as usize, ubidx[b + 1] as usize);
    let run = &ukey[lo..hi];
    let i = run.partition_point(|&u| u < k);
    (i < run.len() && run[i] == k).then_some(lo + i)
}

/// One phase buffer on the device (or in host memory, for the rayon launcher).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct PhaseBufs<R> {
    /// Positions, f64 in every precision.
    pub x: *mut Vec3<f64>,
    pub v: *mut Vec3<R>,
    pub m: *mut R,
    pub rho: *mut R,
    /// 0/1 per particle; null when no particle is fixed.
    pub fixed: *mut u8,
    /// Combined sort key per particle.
    pub keys: *mut u64,
    /// Dense start table over the search cells: groups · stride + 1 entries (dense mode).
    pub dense: *mut u32,
    /// Sparse mode (a grid box too large for dense tables, e.g. a few particles flung far
    /// away): the occupied IDIC cells' combined keys, sorted, and where each cell's particles
    /// start (`ncells` + 1 entries); `ncells` = 0 in dense mode.
    pub ckeys: *const u64,
    pub cstart: *const u32,
    pub ncells: u32,
    pub n: u32,
    pub groups: u32,
    /// Group g holds particles off[g]..off[g + 1].
    pub off: [u32; MAX_FRACTIONS + 1],
    /// The neighbour list of the current layer ([`kernels::NeighbourList`]): `nl_stride`
    /// slots per particle, the counts and their maximum; null when the phase has none.
    pub nl: *mut u32,
    pub nl_count: *mut u32,
    pub nl_max: *mut u32,
    pub nl_stride: u32,
}

#[inline(always)]
unsafe fn sl<'a, T>(p: *const T, n: usize) -> &'a [T] {
    if p.is_null() || n == 0 {
        &[]
    } else {
        slice::from_raw_parts(p, n)
    }
}

#[inline(always)]
unsafe fn sl_mut<'a, T>(p: *mut T, n: usize) -> &'a mut [T] {
    if p.is_null() || n == 0 {
        &mut []
    } else {
        slice::from_raw_parts_mut(p, n)
    }
}

impl<R: Real> PhaseBufs<R> {
    #[inline(always)]
    fn len(&self) -> usize {
        self.n as usize
    }
    #[inline(always)]
    unsafe fn x(&self) -> &[Vec3<f64>] {
        sl(self.x, self.len())
    }
    #[inline(always)]
    unsafe fn v(&self) -> &[Vec3<R>] {
        sl(self.v, self.len())
    }
    #[inline(always)]
    unsafe fn m(&self) -> &[R] {
        sl(self.m, self.len())
    }
    #[inline(always)]
    unsafe fn rho(&self) -> &[R] {
        sl(self.rho, self.len())
    }
    #[inline(always)]
    unsafe fn fixed(&self) -> &[bool] {
        // 0/1 bytes are valid bools.
        sl(self.fixed as *const bool, self.len())
    }
    #[inline(always)]
    unsafe fn dense(&self, p: &StepParams<R>) -> &[u32] {
        sl(self.dense, self.groups as usize * p.stride() + 1)
    }
    #[inline(always)]
    unsafe fn list(&self) -> kernels::NeighbourList<'_> {
        if self.nl_count.is_null() {
            return kernels::NeighbourList::default();
        }
        let stride = self.nl_stride as usize;
        let n = self.len();
        kernels::NeighbourList {
            index: sl(self.nl as *const AtomicU32, n * stride),
            count: sl(self.nl_count as *const AtomicU32, n),
            max: Some(AtomicU32::from_ptr(self.nl_max)),
            stride,
        }
    }
    /// Group of particle i (≤ 32 groups: a linear scan).
    #[inline(always)]
    fn group_of(&self, i: usize) -> usize {
        let mut g = 0;
        while g + 1 < self.groups as usize && i >= self.off[g + 1] as usize {
            g += 1;
        }
        g
    }
    /// The neighbour-walk view of group g.
    #[inline(always)]
    unsafe fn sorted<'a>(&'a self, p: &'a StepParams<R>, g: usize) -> Sorted<'a, R> {
        if self.ncells > 0 {
            let nc = self.ncells as usize;
            return Sorted {
                geom: &p.geom,
                look: CellLookup {
                    keys: sl(self.ckeys, nc),
                    start: sl(self.cstart, nc + 1),
                    dense: &[],
                    dense_stride: 1,
                    key_offset: (g * p.key_stride()) as u64,
                },
                x: self.x(),
                list: self.list(),
                _r: core::marker::PhantomData,
            };
        }
        let s = p.stride();
        Sorted {
            geom: &p.geom,
            look: CellLookup {
                keys: &[],
                start: &[],
                dense: &self.dense(p)[g * s..(g + 1) * s],
                dense_stride: p.sub_cells() as u64,
                key_offset: 0,
            },
            x: self.x(),
            list: self.list(),
            _r: core::marker::PhantomData,
        }
    }
    /// Particle range of group g in the IDIC cell with (grid) key k: its search cell's range
    /// from the dense table, then the run of key k inside it (sorted by key).
    #[inline(always)]
    unsafe fn cell_range(&self, p: &StepParams<R>, g: usize, k: u64) -> (usize, usize) {
        let c = (g * p.key_stride()) as u64 + k;
        if self.ncells > 0 {
            let nc = self.ncells as usize;
            let (keys, start) = (sl(self.ckeys, nc), sl(self.cstart, nc + 1));
            let i = keys.partition_point(|&x| x < c);
            return if i < nc && keys[i] == c {
                (start[i] as usize, start[i + 1] as usize)
            } else {
                (0, 0)
            };
        }
        let d = self.dense(p);
        let i = g * p.stride() + k as usize / p.sub_cells();
        let (lo, hi) = (d[i] as usize, d[i + 1] as usize);
        let keys = sl(self.keys, self.len());
        let a = lo + keys[lo..hi].partition_point(|&x| x < c);
        let b = a + keys[a..hi].partition_point(|&x| x == c);
        (a, b)
    }
}

/// Atomic max on a u64 shared by every thread of a launch: a plain read first, and the
/// read-modify-write only when it would raise the value. The maximum settles early, so most
/// threads only read (no contention on the one address, on the GPU or on the CPU's cores).
#[inline(always)]
unsafe fn atomic_max_u64(p: *mut u64, v: u64) {
    let a = AtomicU64::from_ptr(p);
    if a.load(Ordering::Relaxed) < v {
        a.fetch_max(v, Ordering::Relaxed);
    }
}

/// Atomic add on a u32 in memory (the counting sort's per-cell counters).
#[inline(always)]
unsafe fn atomic_add_u32(p: *mut u32, v: u32) -> u32 {
    AtomicU32::from_ptr(p).fetch_add(v, Ordering::Relaxed)
}

// ---------------------------------------------------------------------------------------------
// Grid rebuild: bounds, keys, counting sort, gathers.

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BoundsArgs {
    /// Positions: f64 in every precision of the step.
    pub x: *const Vec3<f64>,
    pub n: u32,
    /// Particles per thread.
    pub chunk: u32,
    /// [min x, min y, min z, max x, max y, max z] as [`kernels::ordered_bits`]; initialise to
    /// (u64::MAX ×3, 0 ×3).
    pub out: *mut u64,
}

pub unsafe fn bounds(t: usize, a: &BoundsArgs) {
    let x = sl(a.x, a.n as usize);
    let lo = t * a.chunk as usize;
    if lo >= x.len() {
        return;
    }
    let hi = (lo + a.chunk as usize).min(x.len());
    let mut mn = [u64::MAX; 3];
    let mut mx = [0u64; 3];
    for p in &x[lo..hi] {
        for k in 0..3 {
            // A NaN maps above +∞ (positive NaN) or below −∞ (negative NaN); the host's
            // finiteness check of the decoded bounds then reports it.
            let b = kernels::ordered_bits(p[k]);
            mn[k] = mn[k].min(b);
            mx[k] = mx[k].max(b);
        }
    }
    for k in 0..3 {
        AtomicU64::from_ptr(a.out.add(k)).fetch_min(mn[k], Ordering::Relaxed);
        AtomicU64::from_ptr(a.out.add(3 + k)).fetch_max(mx[k], Ordering::Relaxed);
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct KeysArgs<R> {
    pub ph: PhaseBufs<R>,
    pub p: Params<R>,
    /// groups · stride + 1 counters (one per search cell of each group), zeroed.
    pub counts: *mut u32,
}

pub unsafe fn keys<R: Real>(t: usize, a: &KeysArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let key = (ph.group_of(t) * a.p.key_stride()) as u64 + a.p.geom.key(ph.x()[t]);
    *ph.keys.add(t) = key;
    // Sparse mode sorts on the host: no counters.
    if !a.counts.is_null() {
        atomic_add_u32(a.counts.add(a.p.bucket_of(key)), 1);
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct ScanArgs {
    pub data: *mut u32,
    pub len: u32,
    pub chunk: u32,
    /// One entry per chunk (+1 for the total).
    pub sums: *mut u32,
}

impl ScanArgs {
    pub fn chunks(&self) -> usize {
        (self.len as usize).div_ceil(self.chunk as usize)
    }
    #[inline(always)]
    unsafe fn chunk_of<'a>(&self, t: usize) -> Option<&'a mut [u32]> {
        let lo = t * self.chunk as usize;
        if lo >= self.len as usize {
            return None;
        }
        let hi = (lo + self.chunk as usize).min(self.len as usize);
        // Only this thread's chunk is borrowed: threads never alias one another's slices.
        Some(sl_mut(self.data.add(lo), hi - lo))
    }
}

/// Scan pass 1: thread t sums chunk t.
pub unsafe fn scan_sums(t: usize, a: &ScanArgs) {
    if let Some(c) = a.chunk_of(t) {
        *a.sums.add(t) = c.iter().sum();
    }
}

/// Scan pass 2 (one thread): exclusive scan of the chunk sums; sums[chunks] = total.
pub unsafe fn scan_totals(t: usize, a: &ScanArgs) {
    if t == 0 {
        let n = a.chunks();
        let s = sl_mut(a.sums, n + 1);
        s[n] = kernels::scan_exclusive(&mut s[..n], 0);
    }
}

/// Scan pass 3: thread t turns chunk t into its exclusive prefix sums.
pub unsafe fn scan_chunks(t: usize, a: &ScanArgs) {
    if let Some(c) = a.chunk_of(t) {
        kernels::scan_exclusive(c, *a.sums.add(t));
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct ScatterArgs<R> {
    pub keys: *const u64,
    pub n: u32,
    pub dense: *const u32,
    /// One zeroed counter per dense-table slot.
    pub cursor: *mut u32,
    /// New → old particle index.
    pub perm: *mut u32,
    pub p: Params<R>,
}

pub unsafe fn scatter<R: Real>(t: usize, a: &ScatterArgs<R>) {
    if t >= a.n as usize {
        return;
    }
    let k = a.p.bucket_of(*a.keys.add(t));
    let pos = *a.dense.add(k) + atomic_add_u32(a.cursor.add(k), 1);
    *a.perm.add(pos as usize) = t as u32;
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct SegmentArgs {
    pub dense: *const u32,
    /// Number of dense-table slots.
    pub nkeys: u32,
    pub perm: *mut u32,
    /// Combined keys by old particle index (before the gathers).
    pub keys: *const u64,
    pub n: u32,
}

/// Thread t sorts the segment of search cell t by (key, old index): the order of a stable sort by cell.
pub unsafe fn sort_segments(t: usize, a: &SegmentArgs) {
    if t >= a.nkeys as usize {
        return;
    }
    let (lo, hi) = (*a.dense.add(t) as usize, *a.dense.add(t + 1) as usize);
    if hi > lo + 1 {
        kernels::sort_segment_by_key(sl_mut(a.perm.add(lo), hi - lo), sl(a.keys, a.n as usize));
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct GatherArgs<T> {
    pub src: *const T,
    pub dst: *mut T,
    pub perm: *const u32,
    pub n: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CopyArgs<T> {
    pub src: *const T,
    pub dst: *mut T,
    pub n: u32,
}

/// dst[t] = src[t] (one kernel per element type).
pub unsafe fn copy<T: Copy>(t: usize, a: &CopyArgs<T>) {
    if t < a.n as usize {
        *a.dst.add(t) = *a.src.add(t);
    }
}

/// dst[t] = src[perm[t]] (one kernel per element type).
pub unsafe fn gather<T: Copy>(t: usize, a: &GatherArgs<T>) {
    if t < a.n as usize {
        *a.dst.add(t) = *a.src.add(*a.perm.add(t) as usize);
    }
}

pub type GatherV3Args<R> = GatherArgs<[R; 3]>;
pub type CopyV3Args<R> = CopyArgs<[R; 3]>;

// The element types the step copies and gathers, one kernel each (crate::kernel_table).
pub unsafe fn gather_u64(t: usize, a: &GatherArgs<u64>) {
    gather(t, a)
}
pub unsafe fn gather_u8(t: usize, a: &GatherArgs<u8>) {
    gather(t, a)
}
pub unsafe fn gather_x(t: usize, a: &GatherArgs<[f64; 3]>) {
    gather(t, a)
}
pub unsafe fn gather_v3<R: Copy>(t: usize, a: &GatherArgs<[R; 3]>) {
    gather(t, a)
}
pub unsafe fn gather_real<R: Copy>(t: usize, a: &GatherArgs<R>) {
    gather(t, a)
}
pub unsafe fn copy_v3<R: Copy>(t: usize, a: &CopyArgs<[R; 3]>) {
    copy(t, a)
}
pub unsafe fn copy_real<R: Copy>(t: usize, a: &CopyArgs<R>) {
    copy(t, a)
}

// ---------------------------------------------------------------------------------------------
// Diagnostics.

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MomentumArgs<R> {
    pub ph: PhaseBufs<R>,
    /// Particles per thread.
    pub chunk: u32,
    /// Per thread: Σ m v_x, Σ m v_y, Σ m v_z, Σ m |v| over its chunk, in f64.
    pub out: *mut f64,
}

/// Thread t sums the momentum and the momentum scale Σ m|v| of particles
/// [t·chunk, (t+1)·chunk) in f64, in particle order; the host adds the chunks in order, so the
/// sums are the same on every launcher.
pub unsafe fn momentum<R: Real>(t: usize, a: &MomentumArgs<R>) {
    let n = a.ph.n as usize;
    let lo = t * a.chunk as usize;
    if lo >= n {
        return;
    }
    let hi = (lo + a.chunk as usize).min(n);
    let (v, m) = (sl(a.ph.v, n), sl(a.ph.m, n));
    let mut s = [0.0f64; 4];
    for i in lo..hi {
        let mi = m[i].to_f64();
        let vi = [v[i][0].to_f64(), v[i][1].to_f64(), v[i][2].to_f64()];
        for k in 0..3 {
            s[k] += mi * vi[k];
        }
        s[3] += mi * Real::sqrt(dot(vi, vi));
    }
    for (k, x) in s.iter().enumerate() {
        *a.out.add(4 * t + k) = *x;
    }
}

// ---------------------------------------------------------------------------------------------
// SPH: density, EOS, forces.

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct DensityArgs<R> {
    pub ph: PhaseBufs<R>,
    pub p: Params<R>,
}

/// Density of particle t by summation over its own group (fixed particles keep theirs).
pub unsafe fn density<R: Real>(t: usize, a: &DensityArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let g = ph.group_of(t);
    let s = ph.sorted(&a.p, g);
    let fixed = ph.fixed();
    let r = kernels::density_at(&s, ph.m(), fixed, *ph.rho.add(t), t, a.p.h, a.p.dim);
    *ph.rho.add(t) = r;
}

/// Continuity equation: ρ_t ← ρ_t + τ dρ_t/dt at the current positions and velocities
/// ([`kernels::density_rate_at`] reads only x, v and m, so the update is in place).
pub unsafe fn density_continuity<R: Real>(t: usize, a: &DensityArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let s = ph.sorted(&a.p, ph.group_of(t));
    let rate = kernels::density_rate_at(&s, ph.v(), ph.m(), ph.fixed(), t, a.p.h, a.p.dim);
    let r = ph.rho.add(t);
    *r += a.p.tau * rate;
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct EosArgs<R> {
    pub rho: *const R,
    /// Null for isothermal gas.
    pub e: *const R,
    pub pres: *mut R,
    pub c: *mut R,
    pub n: u32,
    pub p: Params<R>,
}

pub unsafe fn eos<R: Real>(t: usize, a: &EosArgs<R>) {
    if t >= a.n as usize {
        return;
    }
    let e = if a.e.is_null() { R::ZERO } else { *a.e.add(t) };
    let (p, c) = kernels::eos_at(&a.p.eos(), *a.rho.add(t), e);
    *a.pres.add(t) = p;
    *a.c.add(t) = c;
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct ForcesArgs<R> {
    pub gas: PhaseBufs<R>,
    pub pres: *const R,
    pub c: *const R,
    pub acc: *mut Vec3<R>,
    /// Null when there is no energy equation.
    pub dedt: *mut R,
    /// [max signal speed, max |A|] as [`kernels::ordered_bits`], zeroed.
    pub limits: *mut u64,
    /// 0: fixed h, standard gradient; 1: variable h (grad-h); 2: IAD gradient. Modes 1 and 2
    /// read the per-particle kernels `kernel_at` and pressure terms `pt` ([`force_prep`]); 2 also
    /// the IAD matrices `iad` ([`iad_matrix`]).
    pub mode: u32,
    pub kernel_at: *const KernelAt<R>,
    pub pt: *const R,
    pub iad: *const Sym3<R>,
    /// Per-particle signal speed (the leapfrog keeps its closing forces whole); null: not kept.
    pub vsig: *mut R,
    pub p: Params<R>,
}

pub unsafe fn forces<R: Real>(t: usize, a: &ForcesArgs<R>) {
    let g = &a.gas;
    if t >= g.len() {
        return;
    }
    let n = g.len();
    let view = GasView {
        v: g.v(),
        m: g.m(),
        rho: g.rho(),
        p: sl(a.pres, n),
        c: sl(a.c, n),
        fixed: g.fixed(),
    };
    let av = a.p.viscosity();
    let s = g.sorted(&a.p, 0);
    let r = match a.mode {
        0 => kernels::forces_at(&s, &view, t, a.p.h, a.p.dim, av.as_ref()),
        1 => kernels::forces_vh_at(&s, &view, sl(a.kernel_at, n), sl(a.pt, n), t, av.as_ref()),
        _ => kernels::forces_iad_at(
            &s,
            &view,
            sl(a.kernel_at, n),
            sl(a.pt, n),
            sl(a.iad, n),
            t,
            av.as_ref(),
        ),
    };
    *a.acc.add(t) = r.acc;
    if !a.dedt.is_null() {
        *a.dedt.add(t) = r.dedt;
    }
    if !a.vsig.is_null() {
        *a.vsig.add(t) = r.vsig;
    }
    let am = Real::sqrt(dot(r.acc, r.acc));
    atomic_max_u64(a.limits, kernels::ordered_bits(r.vsig));
    atomic_max_u64(a.limits.add(1), kernels::ordered_bits(am));
}

// ---------------------------------------------------------------------------------------------
// Variable smoothing lengths and the IAD gradient (docs/method.md; Price 2012, Garcia-Senz et
// al. 2012): the per-particle functions of `kernels`, one thread per particle.

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HSolveArgs<R> {
    pub ph: PhaseBufs<R>,
    /// Initial h per particle; null: from the phase's current density (`warm` = 1, the dust:
    /// its last solve's ρ gives its h, [`kernel::h_of_density`]) or the reference h.
    pub h0: *const R,
    pub warm: u32,
    /// Out: h, Ω (null for the dust), Newton iterations; ρ goes to the phase's `rho`.
    pub h: *mut R,
    pub omega: *mut R,
    pub iters: *mut u32,
    /// Smallest index of a particle whose solve failed; initialise to u32::MAX.
    pub bad: *mut u32,
    pub hfact: R,
    /// Half the grid's search radius: h must stay below it.
    pub h_max: R,
    pub tol: R,
    pub p: Params<R>,
}

/// h, ρ and Ω of particle t by Newton–Raphson over its own group ([`kernels::solve_h_at`]).
pub unsafe fn solve_h<R: Real>(t: usize, a: &HSolveArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let s = ph.sorted(&a.p, ph.group_of(t));
    let rho = *ph.rho.add(t);
    let h0 = if !a.h0.is_null() {
        *a.h0.add(t)
    } else if a.warm != 0 && rho > R::ZERO && rho.is_finite() {
        crate::kernel::h_of_density(ph.m()[t], rho, a.hfact, a.p.dim, a.p.h)
    } else {
        a.p.h
    };
    let o = kernels::solve_h_at(
        &s,
        ph.m(),
        ph.fixed(),
        rho,
        t,
        h0,
        a.hfact,
        a.h_max,
        a.tol,
        a.p.dim,
    );
    *a.h.add(t) = o.h;
    if !a.omega.is_null() {
        *a.omega.add(t) = o.omega;
    }
    *a.iters.add(t) = o.iterations;
    // ρ of this particle is read by no other thread of the solve (only m and x are).
    *ph.rho.add(t) = o.rho;
    if !o.ok {
        AtomicU32::from_ptr(a.bad).fetch_min(t as u32, Ordering::Relaxed);
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct PrepArgs<R> {
    pub gas: PhaseBufs<R>,
    /// h per particle, or null (the reference h).
    pub h: *const R,
    /// Ω per particle (grad-h: pt = p/(Ω ρ²)), or null (IAD: pt = p/ρ²).
    pub omega: *const R,
    pub pres: *const R,
    pub kernel_at: *mut KernelAt<R>,
    pub pt: *mut R,
    pub p: Params<R>,
}

/// Kernel constants and pressure term of gas particle t, once per force evaluation.
pub unsafe fn force_prep<R: Real>(t: usize, a: &PrepArgs<R>) {
    let g = &a.gas;
    if t >= g.len() {
        return;
    }
    let h = if a.h.is_null() { a.p.h } else { *a.h.add(t) };
    *a.kernel_at.add(t) = KernelAt::new(h, a.p.dim);
    let (p, rho) = (*a.pres.add(t), *g.rho.add(t));
    *a.pt.add(t) = if a.omega.is_null() {
        p / (rho * rho)
    } else {
        p / (*a.omega.add(t) * rho * rho)
    };
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct IadArgs<R> {
    pub gas: PhaseBufs<R>,
    pub kernel_at: *const KernelAt<R>,
    pub iad: *mut Sym3<R>,
    pub p: Params<R>,
}

/// IAD matrix C_t of gas particle t ([`kernels::iad_matrix_at`]).
pub unsafe fn iad_matrix<R: Real>(t: usize, a: &IadArgs<R>) {
    let g = &a.gas;
    if t >= g.len() {
        return;
    }
    let n = g.len();
    *a.iad.add(t) =
        kernels::iad_matrix_at(&g.sorted(&a.p, 0), g.m(), g.rho(), sl(a.kernel_at, n), t);
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MaxArgs<R> {
    pub x: *const R,
    pub n: u32,
    pub chunk: u32,
    /// The maximum as [`kernels::ordered_bits`]; zeroed before the launch.
    pub out: *mut u64,
}

/// Maximum of x over chunk t (the largest h sets the search radius).
pub unsafe fn max_of<R: Real>(t: usize, a: &MaxArgs<R>) {
    let (lo, n) = (t * a.chunk as usize, a.n as usize);
    if lo >= n {
        return;
    }
    let hi = (lo + a.chunk as usize).min(n);
    let mut m = R::from_f64(f64::NEG_INFINITY);
    for i in lo..hi {
        m = m.max(*a.x.add(i));
    }
    AtomicU64::from_ptr(a.out).fetch_max(kernels::ordered_bits(m), Ordering::Relaxed);
}

// ---------------------------------------------------------------------------------------------
// IDIC: union of occupied cells, the cell step, particle velocities, drag heat.

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct UnionArgs<R> {
    pub gas: PhaseBufs<R>,
    pub dust: PhaseBufs<R>,
    /// stride flags: the number of IDIC cells of search cell t that any phase occupies (the
    /// last stays 0); scanned afterwards into `ubidx`, where search cell t's occupied cells
    /// start in the union.
    pub flags: *mut u32,
    /// The union's keys, written by [`union_keys`] (null for [`union_flags`]).
    pub ukey: *mut u64,
    pub p: Params<R>,
}

#[inline(always)]
unsafe fn occupied<R: Real>(ph: &PhaseBufs<R>, p: &StepParams<R>, g: usize, k: u64) -> bool {
    let (a, b) = ph.cell_range(p, g, k);
    b > a
}

/// Calls `f(i, k)` for the i-th occupied IDIC cell k (in key order) of search cell t.
#[inline(always)]
unsafe fn occupied_cells<R: Real>(a: &UnionArgs<R>, t: usize, mut f: impl FnMut(usize, u64)) {
    let sc = a.p.sub_cells();
    let mut i = 0;
    for s in 0..sc {
        let k = (t * sc + s) as u64;
        let mut occ = a.gas.n > 0 && occupied(&a.gas, &a.p, 0, k);
        for g in 0..a.dust.groups as usize {
            occ |= a.dust.n > 0 && occupied(&a.dust, &a.p, g, k);
        }
        if occ {
            f(i, k);
            i += 1;
        }
    }
}

pub unsafe fn union_flags<R: Real>(t: usize, a: &UnionArgs<R>) {
    let nb = a.p.stride() - 1;
    if t > nb {
        return;
    }
    let mut count = 0;
    if t < nb {
        occupied_cells(a, t, |_, _| count += 1);
    }
    *a.flags.add(t) = count;
}

/// Search cell t writes its occupied IDIC cells' keys into the union, in key order.
pub unsafe fn union_keys<R: Real>(t: usize, a: &UnionArgs<R>) {
    if t >= a.p.stride() - 1 {
        return;
    }
    let base = *a.flags.add(t) as usize;
    occupied_cells(a, t, |i, k| *a.ukey.add(base + i) = k);
}

/// Per union cell: gas mass, v*^{n+1}, and per fraction ε, β, t*, u*^{n+1} (at u · nf + k).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CellBufs<R> {
    /// Where each search cell's occupied IDIC cells start in the union (stride entries; the
    /// last is the union count), and the union's keys. In sparse mode (`sparse_count` > 0
    /// or the phases' tables sparse) `uidx` is unused and the union has `sparse_count` keys.
    pub uidx: *const u32,
    pub sparse: u32,
    pub sparse_count: u32,
    pub ukey: *const u64,
    pub gas_mass: *mut R,
    pub v_new: *mut Vec3<R>,
    pub eps: *mut R,
    pub beta: *mut R,
    pub t_stop: *mut R,
    pub u_new: *mut Vec3<R>,
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CellArgs<R> {
    pub gas: PhaseBufs<R>,
    pub dust: PhaseBufs<R>,
    pub pres: *const R,
    pub acc: *const Vec3<R>,
    pub cells: CellBufs<R>,
    pub p: Params<R>,
}

/// The IDIC cell step of union cell t: sums (in particle order, as on the CPU), ε, t*, β and
/// the implicit solve.
pub unsafe fn cell_step<R: Real>(t: usize, a: &CellArgs<R>) {
    let p = &a.p;
    let nu = union_count(&a.cells, p);
    if t >= nu {
        return;
    }
    let k = *a.cells.ukey.add(t);
    let (g, d) = (&a.gas, &a.dust);
    let eos = p.eos();
    let tau = p.tau;
    let acc = sl(a.acc, g.len());
    let (v, lo_hi) = (g.v(), g.cell_range(p, 0, k));
    let gs = kernels::gas_cell_sums(
        lo_hi.0,
        lo_hi.1,
        g.m(),
        g.rho(),
        sl(a.pres, g.len()),
        g.fixed(),
        &eos,
        p.needs_gas_state != 0,
        // ṽ = v + τ(A + a_gas), as the gas update takes it (`gas_kick`).
        |i| crate::axpy(v[i], tau, crate::add(acc[i], p.ext_gas)),
    );
    let nf = p.nf as usize;
    let mut ds = [kernels::DustSums::default(); MAX_FRACTIONS];
    let mut laws = [StoppingLaw::ConstantTime { t_stop: R::ZERO }; MAX_FRACTIONS];
    for f in 0..nf {
        let (lo, hi) = d.cell_range(p, f, k);
        laws[f] = p.laws[f].law();
        ds[f] = kernels::dust_cell_sums(
            lo,
            hi,
            d.m(),
            d.v(),
            d.rho(),
            d.fixed(),
            laws[f].needs_dust_density(),
        );
    }
    let explicit = p.explicit_drag != 0;
    let c = kernels::cell_couple(&gs, &ds[..nf], &laws[..nf], tau, eos.gamma_root(), explicit);
    let cb = &a.cells;
    *cb.gas_mass.add(t) = gs.mass;
    *cb.v_new.add(t) = c.v_new;
    for f in 0..nf {
        let s = t * nf + f;
        *cb.eps.add(s) = c.eps[f];
        *cb.beta.add(s) = c.beta[f];
        *cb.t_stop.add(s) = c.t_stop[f];
        *cb.u_new.add(s) = c.u_new[f];
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct LimitArgs<R> {
    pub cells: CellBufs<R>,
    /// The fastest drag rate Λ of any union cell as [`kernels::ordered_bits`]; zeroed.
    pub rate: *mut u64,
    pub gas: PhaseBufs<R>,
    pub dust: PhaseBufs<R>,
    /// Over MPI ranks, 1 for a ghost (a copy of another rank's particle), per phase; null
    /// without ghosts. A cell of ghosts only may lack members beyond the halo: it is left to
    /// the rank that owns one of them.
    pub gas_ghost: *const u8,
    pub dust_ghost: *const u8,
    pub p: Params<R>,
}

/// The explicit drag's rate bound Λ of union cell t ([`drag::explicit_rate`]), max-reduced.
pub unsafe fn explicit_limit<R: Real>(t: usize, a: &LimitArgs<R>) {
    if t >= union_count(&a.cells, &a.p) {
        return;
    }
    let nf = a.p.nf as usize;
    if !a.gas_ghost.is_null() || !a.dust_ghost.is_null() {
        let k = *a.cells.ukey.add(t);
        let own = |ph: &PhaseBufs<R>, ghost: *const u8, g: usize| -> bool {
            let (lo, hi) = ph.cell_range(&a.p, g, k);
            (lo..hi).any(|i| ghost.is_null() || *ghost.add(i) == 0)
        };
        let mut any = own(&a.gas, a.gas_ghost, 0);
        for f in 0..nf {
            any |= own(&a.dust, a.dust_ghost, f);
        }
        if !any {
            return;
        }
    }
    let mut inv_t = [R::ZERO; MAX_FRACTIONS];
    for (k, r) in inv_t.iter_mut().enumerate().take(nf) {
        let ts = *a.cells.t_stop.add(t * nf + k);
        *r = if ts.is_finite() { R::ONE / ts } else { R::ZERO };
    }
    let rate = drag::explicit_rate(sl(a.cells.eps.add(t * nf), nf), &inv_t[..nf]);
    atomic_max_u64(a.rate, kernels::ordered_bits(rate));
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct KickArgs<R> {
    pub ph: PhaseBufs<R>,
    /// Gas: A^n (ṽ = v + τA); null for dust (ũ = u).
    pub acc: *const Vec3<R>,
    /// 1 when the IDIC update applies (dust in the scene); 0: v^{n+1} = ṽ.
    pub drag: u32,
    pub cells: CellBufs<R>,
    /// Kinetic energy lost per particle (drag heating); null when not needed.
    pub loss: *mut R,
    pub p: Params<R>,
}

/// Union index of the IDIC cell of particle i (its own cell is occupied, so it is found).
#[inline(always)]
unsafe fn cell_of<R: Real>(
    ph: &PhaseBufs<R>,
    p: &StepParams<R>,
    cells: &CellBufs<R>,
    i: usize,
) -> usize {
    let key = *ph.keys.add(i) % p.key_stride() as u64;
    let ukey = sl(cells.ukey, union_count(cells, p));
    if cells.sparse != 0 {
        return ukey.partition_point(|&u| u < key);
    }
    let nb = p.stride();
    union_index(sl(cells.uidx, nb), ukey, p.sub_cells(), key).unwrap_or(0)
}

/// Number of occupied IDIC cells in the union.
#[inline(always)]
unsafe fn union_count<R: Real>(cells: &CellBufs<R>, p: &StepParams<R>) -> usize {
    if cells.sparse != 0 {
        return cells.sparse_count as usize;
    }
    *cells.uidx.add(p.stride() - 1) as usize
}

/// Gas velocity update (method.md §3.3) of particle t.
pub unsafe fn gas_kick<R: Real>(t: usize, a: &KickArgs<R>) {
    let g = &a.ph;
    if t >= g.len() {
        return;
    }
    let v = *g.v.add(t);
    if kernels::is_fixed(g.fixed(), t) {
        return;
    }
    let vt = crate::axpy(v, a.p.tau, crate::add(*a.acc.add(t), a.p.ext_gas));
    let vn = if a.drag != 0 {
        let nf = a.p.nf as usize;
        let c = cell_of(g, &a.p, &a.cells, t) * nf;
        let update = if a.p.explicit_drag != 0 {
            drag::explicit_gas_update
        } else {
            drag::gas_update
        };
        update(
            vt,
            sl(a.cells.eps.add(c), nf),
            sl(a.cells.beta.add(c), nf),
            sl(a.cells.u_new.add(c), nf),
        )
    } else {
        vt
    };
    *g.v.add(t) = vn;
    if !a.loss.is_null() {
        *a.loss.add(t) = drag::kinetic_loss(*g.m.add(t), vt, vn);
    }
}

/// Dust velocity update of particle t (its fraction from its group).
pub unsafe fn dust_kick<R: Real>(t: usize, a: &KickArgs<R>) {
    let d = &a.ph;
    if t >= d.len() || kernels::is_fixed(d.fixed(), t) {
        return;
    }
    let nf = a.p.nf as usize;
    let c = cell_of(d, &a.p, &a.cells, t);
    let s = c * nf + d.group_of(t);
    let u = *d.v.add(t);
    let update = if a.p.explicit_drag != 0 {
        drag::explicit_dust_update
    } else {
        drag::dust_update
    };
    let un = update(u, *a.cells.beta.add(s), *a.cells.v_new.add(c));
    *d.v.add(t) = un;
    if !a.loss.is_null() {
        *a.loss.add(t) = drag::kinetic_loss(*d.m.add(t), u, un);
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HeatArgs<R> {
    pub gas: PhaseBufs<R>,
    pub dust: PhaseBufs<R>,
    pub loss_gas: *const R,
    pub loss_dust: *const R,
    pub cells: CellBufs<R>,
    /// Drag heat per unit gas mass of each union cell.
    pub heat: *mut R,
    pub p: Params<R>,
}

/// Drag heat of union cell t: the kinetic energy its particles lost, per unit gas mass. Summed
/// gas first, then fraction by fraction, in particle order: a fixed order, so the sums are deterministic.
pub unsafe fn heat<R: Real>(t: usize, a: &HeatArgs<R>) {
    let p = &a.p;
    if t >= union_count(&a.cells, p) {
        return;
    }
    let k = *a.cells.ukey.add(t);
    let mut q = R::ZERO;
    let (lo, hi) = a.gas.cell_range(p, 0, k);
    let gf = a.gas.fixed();
    for i in lo..hi {
        if !kernels::is_fixed(gf, i) {
            q += *a.loss_gas.add(i);
        }
    }
    let df = a.dust.fixed();
    for f in 0..p.nf as usize {
        let (lo, hi) = a.dust.cell_range(p, f, k);
        for j in lo..hi {
            if !kernels::is_fixed(df, j) {
                q += *a.loss_dust.add(j);
            }
        }
    }
    let mg = *a.cells.gas_mass.add(t);
    *a.heat.add(t) = if mg > R::ZERO { q / mg } else { R::ZERO };
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct DriftArgs<R> {
    pub ph: PhaseBufs<R>,
    pub p: Params<R>,
}

/// x ← x + τ v (wrapped); fixed particles stay.
pub unsafe fn drift<R: Real>(t: usize, a: &DriftArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let fixed = kernels::is_fixed(ph.fixed(), t);
    let x = ph.x.add(t);
    *x = kernels::drift_at(&a.p.geom, *x, *ph.v.add(t), a.p.tau, fixed);
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct EnergyArgs<R> {
    pub gas: PhaseBufs<R>,
    pub e: *mut R,
    pub dedt: *const R,
    /// Drag heat per unit gas mass per union cell (or per gas particle, `heat_per_particle`);
    /// null without heating.
    pub heat: *const R,
    pub heat_per_particle: u32,
    pub cells: CellBufs<R>,
    pub p: Params<R>,
}

pub unsafe fn energy<R: Real>(t: usize, a: &EnergyArgs<R>) {
    let g = &a.gas;
    if t >= g.len() || kernels::is_fixed(g.fixed(), t) {
        return;
    }
    let q = if a.heat.is_null() {
        R::ZERO
    } else if a.heat_per_particle != 0 {
        *a.heat.add(t)
    } else {
        *a.heat.add(cell_of(g, &a.p, &a.cells, t))
    };
    let e = a.e.add(t);
    *e = update::energy(*e, *a.dedt.add(t), a.p.tau) + q;
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CheckArgs<R> {
    pub ph: PhaseBufs<R>,
    /// Internal energy (gas), or null.
    pub e: *const R,
    pub check_rho: u32,
    /// Smallest index of a bad particle; initialise to u32::MAX.
    pub bad: *mut u32,
}

/// Flags a particle with a non-finite position or velocity, a non-positive density, or a
/// negative or non-finite energy (as `check_state` words it).
pub unsafe fn check<R: Real>(t: usize, a: &CheckArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let (x, v) = (*ph.x.add(t), *ph.v.add(t));
    let mut ok = x.iter().all(|c| c.is_finite()) && v.iter().all(|c| c.is_finite());
    if a.check_rho != 0 {
        let r = *ph.rho.add(t);
        ok &= r.is_finite() && r > R::ZERO;
    }
    if !a.e.is_null() {
        let e = *a.e.add(t);
        ok &= e.is_finite() && e >= R::ZERO;
    }
    if !ok {
        AtomicU32::from_ptr(a.bad).fetch_min(t as u32, Ordering::Relaxed);
    }
}

// ---------------------------------------------------------------------------------------------
// External dust acceleration and the kernel coupling (docs/method.md §K).

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct DustAccelArgs<R> {
    pub ph: PhaseBufs<R>,
    pub p: Params<R>,
}

/// ũ = u + τB of dust particle t (B = `ext_dust`; fixed particles keep u): the drag pass then
/// reads the dust velocities as ũ, as on the CPU.
pub unsafe fn dust_accel<R: Real>(t: usize, a: &DustAccelArgs<R>) {
    let d = &a.ph;
    if t >= d.len() || kernels::is_fixed(d.fixed(), t) {
        return;
    }
    *d.v.add(t) = crate::axpy(*d.v.add(t), a.p.tau, a.p.ext_dust);
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
    /// The gas kernels of the weights, one per gas particle (variable h: W(r, h_a)); null:
    /// one shared kernel at the reference h.
    pub kernel_at: *const KernelAt<R>,
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
pub struct NormArgs<R> {
    pub gas: PhaseBufs<R>,
    /// The phase whose normalisers are computed (the gas itself, or the dust).
    pub ph: PhaseBufs<R>,
    pub s: *mut R,
    /// As [`CouplingBufs::kernel_at`].
    pub kernel_at: *const KernelAt<R>,
    pub p: Params<R>,
}

/// S_t = Σ_b W(r_tb, h) over the free gas, for particle t of `ph` (0 when fixed).
pub unsafe fn coupling_norm<R: Real>(t: usize, a: &NormArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let s = if kernels::is_fixed(ph.fixed(), t) {
        R::ZERO
    } else {
        with_gas_kernels(a.kernel_at, a.gas.len(), &a.p, |k| {
            kernels::gas_weight_sum_at(&a.gas.sorted(&a.p, 0), k, a.gas.fixed(), ph.x()[t])
        })
    };
    *a.s.add(t) = s;
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

/// Gas particle t: the deposits of the gas and of every fraction on it (gathered by walking
/// their cells), the implicit solve, and the increments of its means (and its t_k*).
pub unsafe fn coupling_solve<R: Real>(t: usize, a: &CoupleArgs<R>) {
    let g = &a.gas;
    if t >= g.len() {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let mut dust_dep = [kernels::Deposit::default(); MAX_FRACTIONS];
    if kernels::is_fixed(g.fixed(), t) {
        return coupling_finish(t, a, &kernels::Deposit::default(), &dust_dep);
    }
    let k = with_gas_kernels(a.cb.kernel_at, g.len(), p, |k| kernels::kernel_of(k, t));
    let xa = g.x()[t];
    let gas_dep = kernels::deposit_at(
        &g.sorted(p, 0),
        sl(a.cb.s_gas, g.len()),
        g.m(),
        g.rho(),
        g.fixed(),
        xa,
        &k,
        |b| gas_base_velocity(a, b),
        |b| gas_sound(a, b),
    );
    let d = &a.dust;
    let s_dust = sl(a.cb.s_dust, d.len());
    let u = d.v();
    for (f, dep) in dust_dep.iter_mut().enumerate().take(nf) {
        *dep = kernels::deposit_at(
            &d.sorted(p, f),
            s_dust,
            d.m(),
            d.rho(),
            d.fixed(),
            xa,
            &k,
            |j| u[j],
            |_| R::ZERO,
        );
    }
    coupling_finish(t, a, &gas_dep, &dust_dep);
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
/// each gas particle within reach. The sums' order is the hardware's: not bit-reproducible.
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
    with_gas_kernels(c.cb.kernel_at, c.gas.len(), p, |k| {
        kernels::coupling_row_at(&c.gas.sorted(p, 0), k, c.gas.fixed(), ph.x()[t], |g, w| {
            let wm = w / s * m;
            let o = a.sums.add((g * stride + slot) * DEPOSIT_SLOTS);
            atomic_add_f64(o, wm.to_f64());
            for (d, v) in vel.iter().enumerate() {
                atomic_add_f64(o.add(1 + d), (wm * *v).to_f64());
            }
            atomic_add_f64(o.add(4), (wm * rho).to_f64());
            atomic_add_f64(o.add(5), (wm * cs).to_f64());
        })
    });
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

/// Particle t of `ph` gets its base velocity plus Σ_a w_ta Δ_a.
pub unsafe fn coupling_return<R: Real>(t: usize, a: &ReturnArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() || kernels::is_fixed(ph.fixed(), t) {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let v = *ph.v.add(t);
    let (base, s, f) = if a.is_gas != 0 {
        let acc = crate::add(*a.acc.add(t), p.ext_gas);
        (crate::axpy(v, p.tau, acc), *a.cb.s_gas.add(t), 0)
    } else {
        (v, *a.cb.s_dust.add(t), ph.group_of(t))
    };
    let is_gas = a.is_gas != 0;
    let inc = with_gas_kernels(a.cb.kernel_at, a.gas.len(), p, |k| {
        kernels::gather_increment_at(&a.gas.sorted(p, 0), k, a.gas.fixed(), ph.x()[t], s, |g| {
            if is_gas {
                *a.cb.dv.add(g)
            } else {
                *a.cb.du.add(g * nf + f)
            }
        })
    });
    let new = crate::add(base, inc);
    if !a.loss.is_null() {
        *a.loss.add(t) = drag::kinetic_loss(*ph.m.add(t), base, new);
    }
    *ph.v.add(t) = new;
}

/// The stopping time dust particle t feels: Σ_a w_ta t_k,a (+∞ without gas within reach).
pub unsafe fn coupling_tstop<R: Real>(t: usize, a: &ReturnArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let s = *a.cb.s_dust.add(t);
    let out = if s <= R::ZERO {
        R::from_f64(f64::INFINITY)
    } else {
        let f = ph.group_of(t);
        with_gas_kernels(a.cb.kernel_at, a.gas.len(), p, |k| {
            kernels::gather_increment_at(&a.gas.sorted(p, 0), k, a.gas.fixed(), ph.x()[t], s, |g| {
                [*a.cb.t_stop.add(g * nf + f), R::ZERO, R::ZERO]
            })[0]
        })
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
    if kernels::is_fixed(g.fixed(), t) {
        *a.heat.add(t) = R::ZERO;
        return;
    }
    let ka = with_gas_kernels(c.cb.kernel_at, g.len(), p, |k| kernels::kernel_of(k, t));
    let xa = g.x()[t];
    let zero = [R::ZERO; 3];
    let mut q = kernels::deposit_at(
        &g.sorted(p, 0),
        sl(c.cb.s_gas, g.len()),
        sl(a.loss_gas, g.len()),
        g.rho(),
        g.fixed(),
        xa,
        &ka,
        |_| zero,
        |_| R::ZERO,
    )
    .mass;
    let d = &c.dust;
    for f in 0..p.nf as usize {
        q += kernels::deposit_at(
            &d.sorted(p, f),
            sl(c.cb.s_dust, d.len()),
            sl(a.loss_dust, d.len()),
            d.rho(),
            d.fixed(),
            xa,
            &ka,
            |_| zero,
            |_| R::ZERO,
        )
        .mass;
    }
    *a.heat.add(t) = q / *g.m.add(t);
}
