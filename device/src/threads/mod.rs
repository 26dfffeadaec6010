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

mod cell;
mod coupling;
mod diagnostics;
mod smoothing;
mod sort;
mod sph;
pub use cell::*;
pub use coupling::*;
pub use diagnostics::*;
pub use smoothing::*;
pub use sort::*;
pub use sph::*;

/// A stopping-time law as plain data: `kind` 0 = constant t (value t), 1 = constant K (value K),
/// 2 = Epstein (value s·ρ_s, value2 the Stokes regime's 4s/(9λρ_g), 0 without it).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LawParam<R> {
    pub kind: u32,
    pub value: R,
    /// Epstein: the Stokes regime's 4s/(9λρ_g) (0: Epstein at every size).
    pub value2: R,
}

impl<R: Real> LawParam<R> {
    pub fn from_law(l: &StoppingLaw<R>) -> LawParam<R> {
        match *l {
            StoppingLaw::ConstantTime { t_stop } => LawParam {
                kind: 0,
                value: t_stop,
                value2: R::ZERO,
            },
            StoppingLaw::ConstantK { k } => LawParam {
                kind: 1,
                value: k,
                value2: R::ZERO,
            },
            StoppingLaw::Epstein { s_rho, stokes } => LawParam {
                kind: 2,
                value: s_rho,
                value2: stokes,
            },
        }
    }

    #[inline(always)]
    pub fn law(&self) -> StoppingLaw<R> {
        match self.kind {
            0 => StoppingLaw::ConstantTime { t_stop: self.value },
            1 => StoppingLaw::ConstantK { k: self.value },
            _ => StoppingLaw::Epstein {
                s_rho: self.value,
                stokes: self.value2,
            },
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
    /// κ α_SS of the disc viscosity (`sph.alpha_ss`; 0: the shock form), about `gravity`.
    pub kappa_alpha_ss: f64,
    pub nf: u32,
    pub needs_gas_state: u32,
    pub laws: [LawParam<R>; MAX_FRACTIONS],
    /// Constant external accelerations of the gas (added to A^n) and of the dust (B^n).
    pub ext_gas: Vec3<R>,
    pub ext_dust: Vec3<R>,
    /// 1: the explicit (forward-Euler) drag baseline instead of IDIC.
    pub explicit_drag: u32,
    /// 1: the kernel coupling damps each dust particle's unresolved velocity deviation
    /// (`idic.dispersion = "damped"`, method.md §K).
    pub damp_dispersion: u32,
    /// 1: the kernel coupling reads every deposit at its gas particle, through the gas's
    /// velocity gradient fitted over the particle's deposit row (`idic.sampling = "linear"`,
    /// method.md §K "Sampling offsets"); 0: at its particles' centroid (the plain mean).
    pub linear_sampling: u32,
    /// A central point mass (`gm` = 0: none), added to A^n and B^n.
    pub gravity: crate::gravity::PointMass,
    /// A locally isothermal gas's sound speed (`on` = 0: the EOS's own, `eos_kind`).
    pub local_cs: crate::eos::LocalSoundSpeed,
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
            disc: (self.kappa_alpha_ss > 0.0).then_some(crate::sph::DiscViscosity {
                kappa_alpha_ss: self.kappa_alpha_ss,
                gm: self.gravity.gm,
                centre: self.gravity.pos,
            }),
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
            kappa_alpha_ss: self.kappa_alpha_ss,
            nf: self.nf,
            needs_gas_state: self.needs_gas_state,
            laws: self.laws.map(|l| LawParam {
                kind: l.kind,
                value: c(l.value),
                value2: c(l.value2),
            }),
            ext_gas: self.ext_gas.map(c),
            ext_dust: self.ext_dust.map(c),
            explicit_drag: self.explicit_drag,
            damp_dispersion: self.damp_dispersion,
            linear_sampling: self.linear_sampling,
            gravity: self.gravity,
            local_cs: self.local_cs,
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
