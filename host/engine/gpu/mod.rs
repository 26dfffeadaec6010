//! The GPU backend: the whole step on the device, particle data resident for the run.
//!
//! One step, as kernels (method.md §3.6, same order as the CPU path): forces at layer n (with a
//! max-reduction for the time step) → IDIC union of occupied cells, cell step, gas and dust
//! velocities, drag heat → drift and energy → grid rebuild (bounds reduction, keys, counting sort
//! by cell, per-cell order restored, gathers) → density and EOS → check. The host reads back
//! only a few numbers per step (the two time-step limits, the six bounds of the grid, one
//! failure flag); particle arrays come back only for snapshots, checkpoints and the summary.
//!
//! The engine is generic over [`Launcher`]: [`Cuda`] runs the embedded PTX, [`Rayon`] runs
//! the same kernel code on the CPU, which is how CI checks it against the CPU engine.
pub mod launch;

use super::timers::Timers;
use super::{Forces, StepError};
use super::{Physics, Pipeline};
use crate::grid::{merge_bounds, Grid, EMPTY_BOUNDS};
use crate::particles::{Phase, State};
use crate::scene::{ListChoice, PositionUpdate};
use bytemuck::Pod;
use dustsph_device::eos::Eos;
use dustsph_device::kernel::{KernelAt, SUPPORT};
use dustsph_device::kernel_table::{self as kt, FloatKernels, Kernel};
use dustsph_device::kernels::{from_ordered_bits, MAX_FRACTIONS};
use dustsph_device::sph::Sym3;
use dustsph_device::threads::{self as th, LawParam, PhaseBufs, StepParams};
use dustsph_device::Real;
pub use launch::{probe, Cuda, GpuError, Launcher, Rayon};
use rayon::prelude::*;
use std::marker::PhantomData;

/// The kernels, as PTX built from `device/` by build.rs (empty when that build was skipped).
pub const PTX: &str = include_str!(concat!(env!("OUT_DIR"), "/dustsph.ptx"));
/// How the PTX was (or was not) built.
pub const PTX_NOTE: &str = env!("DUSTSPH_PTX_NOTE");
/// Device memory a run needs per particle (gas or dust), by precision: measured with the rayon
/// launcher, which allocates the very buffers a GPU does (`tests/launch.rs`,
/// `device_memory_estimate_bounds_what_the_engine_allocates`: at most 516 B (f64) and 326 B
/// (f32) per particle over the 23 parity scenes after three steps, the leapfrog with the
/// kernel coupling the largest), with a margin for the dense tables of sparser clouds. Without
/// neighbour lists (the GPU kernels have none).
pub const DEVICE_BYTES_PER_PARTICLE: [f64; 2] = [700.0, 420.0];

/// Threads per chunk of the device scan (each thread scans one chunk serially).
const SCAN_CHUNK: usize = 512;

type V3 = [f64; 3];

/// The float type the step runs in (`--precision`, docs/accuracy.md): f64, or f32 with the
/// same kernels instantiated for it (PTX entry points with the suffix `_f32`). The host's state,
/// time, step and grid stay f64; buffers are converted at upload and download only.
pub trait Float:
    Real + Pod + CopyKernel + FloatKernels + std::fmt::Debug + Send + Sync + 'static
{
    /// "f64" or "f32" (summary.json, messages).
    const NAME: &'static str;
}
impl Float for f64 {
    const NAME: &'static str = "f64";
}
impl Float for f32 {
    const NAME: &'static str = "f32";
}

/// A typed device buffer of `len` elements.
pub struct Buf<L: Launcher, T> {
    mem: L::Mem,
    len: usize,
    _t: PhantomData<T>,
}

/// A launcher with typed buffers, copies and launches over it.
struct Device<L: Launcher> {
    launcher: L,
    /// Bytes allocated so far (the rayon launcher allocates exactly what a GPU would: the
    /// device-memory estimate [`DEVICE_BYTES_PER_PARTICLE`] is measured with it).
    allocated: std::cell::Cell<usize>,
}

impl<L: Launcher> Device<L> {
    fn buf<T: Copy>(&self, len: usize) -> Result<Buf<L, T>, GpuError> {
        let bytes = len * std::mem::size_of::<T>();
        self.allocated.set(self.allocated.get() + bytes.max(1));
        Ok(Buf {
            mem: self.launcher.alloc(bytes)?,
            len,
            _t: PhantomData,
        })
    }
    // Host ↔ device copies take plain-old-data only (bytemuck::Pod: no padding, every bit
    // pattern valid); kernel-only buffers (e.g. per-particle kernels) are never copied.
    fn from<T: Pod>(&self, data: &[T]) -> Result<Buf<L, T>, GpuError> {
        let mut b = self.buf(data.len())?;
        self.put(&mut b, data)?;
        Ok(b)
    }
    fn put<T: Pod>(&self, b: &mut Buf<L, T>, data: &[T]) -> Result<(), GpuError> {
        assert!(data.len() <= b.len, "upload larger than the buffer");
        self.launcher.upload(&mut b.mem, bytemuck::cast_slice(data))
    }
    /// Upload into `b`, reallocating (with room to grow) only when it is too small.
    fn put_growing<T: Pod>(&self, b: &mut Buf<L, T>, data: &[T]) -> Result<(), GpuError> {
        if b.len < data.len() {
            *b = self.buf(data.len() + data.len() / 2)?;
        }
        self.put(b, data)
    }
    /// Upload f64 host data into a buffer of the step's precision.
    fn upload_f64<R: Float>(&self, data: &[f64]) -> Result<Buf<L, R>, GpuError> {
        self.from(&data.iter().map(|&x| R::from_f64(x)).collect::<Vec<R>>())
    }
    fn upload_v3<R: Float>(&self, data: &[V3]) -> Result<Buf<L, [R; 3]>, GpuError> {
        let c = |v: &V3| v.map(R::from_f64);
        self.from(&data.iter().map(c).collect::<Vec<_>>())
    }
    /// Download a buffer of the step's precision as f64 (exact; for f64 the same vector).
    fn get_f64<R: Float>(&self, b: &Buf<L, R>, n: usize) -> Result<Vec<f64>, GpuError> {
        Ok(self.get(b, n)?.into_iter().map(R::to_f64).collect())
    }
    fn get_v3<R: Float>(&self, b: &Buf<L, [R; 3]>, n: usize) -> Result<Vec<V3>, GpuError> {
        Ok(self
            .get(b, n)?
            .into_iter()
            .map(|v| v.map(R::to_f64))
            .collect())
    }
    fn get<T: Pod>(&self, b: &Buf<L, T>, n: usize) -> Result<Vec<T>, GpuError> {
        assert!(n <= b.len, "download larger than the buffer");
        let mut v = vec![T::zeroed(); n];
        self.launcher
            .download(&b.mem, bytemuck::cast_slice_mut(&mut v))?;
        Ok(v)
    }
    fn ptr<T>(&self, b: &Buf<L, T>) -> *mut T {
        self.launcher.addr(&b.mem) as *mut T
    }
    fn opt<T>(&self, b: &Option<Buf<L, T>>) -> *mut T {
        b.as_ref().map_or(std::ptr::null_mut(), |b| self.ptr(b))
    }
    /// Grow `b` to at least `len` elements (contents are not kept) and zero its first `len`
    /// on the device (a memset, no host copy; allocation only when it must grow).
    fn zeroed<T: Copy>(&self, b: &mut Buf<L, T>, len: usize) -> Result<(), GpuError> {
        if b.len < len {
            *b = self.buf(len + len / 2)?;
        } else {
            self.launcher
                .zero(&mut b.mem, len * std::mem::size_of::<T>())?;
        }
        Ok(())
    }
    fn run<A: Copy>(&self, k: Kernel<A>, n: usize, a: &A) -> Result<(), GpuError> {
        self.launcher.launch(k, n, a)
    }

    /// dst[..n] = src[..n] (f64 or 3-vectors).
    fn copy<T: Copy + CopyKernel>(
        &self,
        src: &Buf<L, T>,
        dst: &Buf<L, T>,
        n: usize,
    ) -> Result<(), GpuError> {
        let a = th::CopyArgs {
            src: self.ptr(src),
            dst: self.ptr(dst),
            n: n as u32,
        };
        self.run(T::COPY, n, &a)
    }

    /// Exclusive prefix sum of `data[..len]` in place (three launches).
    fn scan(&self, data: &Buf<L, u32>, len: usize, sums: &mut Buf<L, u32>) -> Result<(), GpuError> {
        let chunks = len.div_ceil(SCAN_CHUNK);
        if sums.len < chunks + 1 {
            *sums = self.buf(chunks + 1 + chunks / 2)?;
        }
        let a = th::ScanArgs {
            data: self.ptr(data),
            len: len as u32,
            chunk: SCAN_CHUNK as u32,
            sums: self.ptr(sums),
        };
        self.run(kt::SCAN_SUMS, chunks, &a)?;
        self.run(kt::SCAN_TOTALS, 1, &a)?;
        self.run(kt::SCAN_CHUNKS, chunks, &a)
    }
}

/// Element types with a copy kernel.
pub trait CopyKernel: Sized + 'static {
    const COPY: Kernel<th::CopyArgs<Self>>;
}
impl CopyKernel for f64 {
    const COPY: Kernel<th::CopyArgs<f64>> = <f64 as FloatKernels>::COPY_REAL;
}
impl CopyKernel for f32 {
    const COPY: Kernel<th::CopyArgs<f32>> = <f32 as FloatKernels>::COPY_REAL;
}
impl<R: Float> CopyKernel for [R; 3] {
    const COPY: Kernel<th::CopyArgs<[R; 3]>> = R::COPY_V3;
}

/// A step's parameters: the host's copy (for the host's own arithmetic: table sizes) and the
/// device copy the kernels read ([`th::Params`]).
#[derive(Clone, Copy)]
struct Hp<R> {
    host: StepParams<R>,
    dev: th::Params<R>,
}

impl<R> std::ops::Deref for Hp<R> {
    type Target = StepParams<R>;
    fn deref(&self) -> &StepParams<R> {
        &self.host
    }
}

/// Device copies of the step parameters: a ring of slots, a new one per distinct value; the
/// last few values are looked up (a step uses a handful: τ = 0, τ, τ/2, and the grid changes
/// once per step), so a repeated value reuses its slot without a search through the ring. A
/// slot is overwritten only 256 distinct values later, and on the stream after the launches
/// that read it.
struct ParamSlots<L: Launcher, R> {
    mem: Vec<L::Mem>,
    /// (value, slot) of the most recent distinct values, newest last.
    recent: Vec<(StepParams<R>, usize)>,
    /// Distinct values uploaded so far (the next slot is this modulo `PARAM_SLOTS`).
    uploads: usize,
}

const PARAM_SLOTS: usize = 256;
const PARAM_RECENT: usize = 8;

/// One phase buffer set: gas (one group) or all dust fractions back to back.
struct DevPhase<L: Launcher, R: Float> {
    n: usize,
    groups: usize,
    off: [u32; MAX_FRACTIONS + 1],
    /// Positions, f64 in every precision (`th::PhaseBufs::x`).
    x: Buf<L, V3>,
    v: Buf<L, [R; 3]>,
    m: Buf<L, R>,
    rho: Buf<L, R>,
    fixed: Option<Buf<L, u8>>,
    id: Buf<L, u64>,
    keys: Buf<L, u64>,
    /// Counts, then (scanned) the dense start table over the search cells.
    dense: Buf<L, u32>,
    /// Sparse mode: the occupied cells' combined keys (also kept on the host for the IDIC
    /// union) and their starts; `ncells` = 0 in dense mode.
    ckeys: Buf<L, u64>,
    cstart: Buf<L, u32>,
    ncells: usize,
    host_ckeys: Vec<u64>,
    cursor: Buf<L, u32>,
    perm: Buf<L, u32>,
    s_v3: Buf<L, [R; 3]>,
    s_x: Buf<L, V3>,
    s_f64: Buf<L, R>,
    s_u64: Buf<L, u64>,
    s_u8: Option<Buf<L, u8>>,
    /// Kinetic energy lost in the drag update (drag heating only).
    loss: Option<Buf<L, R>>,
    /// The neighbour list of the current layer, when this phase keeps one.
    nl: Option<NeighbourList<L>>,
}

/// A phase's neighbour list ([`dustsph_device::kernels::NeighbourList`]): built after each
/// sort (and after the search radius widens), stale from the next drift on.
struct NeighbourList<L: Launcher> {
    index: Buf<L, u32>,
    count: Buf<L, u32>,
    /// The largest neighbour count recorded since the list was allocated.
    max: Buf<L, u32>,
    stride: usize,
    valid: std::cell::Cell<bool>,
}

/// The first list's slots per particle (grown to 9/8 of the largest count, in steps of 8).
const LIST_STRIDE0: usize = 64;
/// Beyond this many neighbours per particle the phase drops its list: the pair work then
/// dominates the cell scan, and the list would cost 4 B per slot per particle.
const LIST_STRIDE_MAX: usize = 512;
/// The most a gas particle's neighbour list takes (slots and count; CPU memory: the GPU
/// kernels are built without lists).
pub const LIST_BYTES_PER_GAS_PARTICLE: f64 = 4.0 * (LIST_STRIDE_MAX as f64 + 1.0);

impl<L: Launcher, R: Float> DevPhase<L, R> {
    fn new(d: &Device<L>, phases: &[&Phase], heating: bool) -> Result<DevPhase<L, R>, GpuError> {
        let cat = |f: &dyn Fn(&Phase) -> Vec<f64>| phases.iter().flat_map(|p| f(p)).collect();
        let x: Vec<V3> = phases.iter().flat_map(|p| p.x.iter().copied()).collect();
        let v: Vec<V3> = phases.iter().flat_map(|p| p.v.iter().copied()).collect();
        let m: Vec<f64> = cat(&|p| p.m.clone());
        let rho: Vec<f64> = cat(&|p| {
            if p.rho.len() == p.len() {
                p.rho.clone()
            } else {
                vec![0.0; p.len()]
            }
        });
        let id: Vec<u64> = phases.iter().flat_map(|p| p.id.iter().copied()).collect();
        let any_fixed = phases.iter().any(|p| p.fixed.is_some());
        let fixed: Option<Vec<u8>> = any_fixed.then(|| {
            phases
                .iter()
                .flat_map(|p| (0..p.len()).map(|i| p.is_fixed(i) as u8))
                .collect()
        });
        let mut off = [0u32; MAX_FRACTIONS + 1];
        for (g, p) in phases.iter().enumerate() {
            off[g + 1] = off[g] + p.len() as u32;
        }
        let end = off[phases.len()];
        for o in off.iter_mut().skip(phases.len() + 1) {
            *o = end;
        }
        let n = x.len();
        Ok(DevPhase {
            n,
            groups: phases.len().max(1),
            off,
            x: d.from(&x)?,
            v: d.upload_v3(&v)?,
            m: d.upload_f64(&m)?,
            rho: d.upload_f64(&rho)?,
            fixed: fixed.as_deref().map(|f| d.from(f)).transpose()?,
            id: d.from(&id)?,
            keys: d.buf(n)?,
            dense: d.buf(1)?,
            ckeys: d.buf(1)?,
            cstart: d.buf(1)?,
            ncells: 0,
            host_ckeys: Vec::new(),
            cursor: d.buf(1)?,
            perm: d.buf(n)?,
            s_v3: d.buf(n)?,
            s_x: d.buf(n)?,
            s_f64: d.buf(n)?,
            s_u64: d.buf(n)?,
            s_u8: if any_fixed { Some(d.buf(n)?) } else { None },
            loss: if heating { Some(d.buf(n)?) } else { None },
            nl: None,
        })
    }

    fn bufs(&self, d: &Device<L>) -> PhaseBufs<R> {
        let b = PhaseBufs {
            x: d.ptr(&self.x),
            v: d.ptr(&self.v),
            m: d.ptr(&self.m),
            rho: d.ptr(&self.rho),
            fixed: d.opt(&self.fixed),
            keys: d.ptr(&self.keys),
            dense: d.ptr(&self.dense),
            ckeys: d.ptr(&self.ckeys),
            cstart: d.ptr(&self.cstart),
            ncells: self.ncells as u32,
            n: self.n as u32,
            groups: self.groups as u32,
            off: self.off,
            nl: std::ptr::null_mut(),
            nl_count: std::ptr::null_mut(),
            nl_max: std::ptr::null_mut(),
            nl_stride: 0,
        };
        match &self.nl {
            Some(l) if l.valid.get() => PhaseBufs {
                nl: d.ptr(&l.index),
                nl_count: d.ptr(&l.count),
                nl_max: d.ptr(&l.max),
                nl_stride: l.stride as u32,
                ..b
            },
            _ => b,
        }
    }

    /// The list no longer matches the positions or the grid.
    fn stale_list(&self) {
        if let Some(l) = &self.nl {
            l.valid.set(false);
        }
    }

    /// Sort by combined cell key (counting sort, then each cell's particles back in index
    /// order) and permute every per-particle array; `extra` are further f64 fields to carry.
    fn sort(
        &mut self,
        d: &Device<L>,
        p: &Hp<R>,
        sums: &mut Buf<L, u32>,
        extra: &mut [&mut Buf<L, R>],
        extra_v3: &mut [&mut Buf<L, [R; 3]>],
        sparse: bool,
    ) -> Result<(), GpuError> {
        self.stale_list();
        if sparse {
            self.sort_on_host(d, p)?;
        } else {
            self.ncells = 0;
            self.host_ckeys.clear();
            // The dense table has one slot per search cell of each group.
            let nkeys = self.groups * p.stride();
            d.zeroed(&mut self.dense, nkeys + 1)?;
            let ka = th::KeysArgs {
                ph: self.bufs(d),
                p: p.dev,
                counts: d.ptr(&self.dense),
            };
            d.run(R::KEYS, self.n, &ka)?;
            d.scan(&self.dense, nkeys + 1, sums)?;
            d.zeroed(&mut self.cursor, nkeys)?;
            let sa = th::ScatterArgs {
                keys: d.ptr(&self.keys),
                n: self.n as u32,
                dense: d.ptr(&self.dense),
                cursor: d.ptr(&self.cursor),
                perm: d.ptr(&self.perm),
                p: p.dev,
            };
            d.run(R::SCATTER, self.n, &sa)?;
            let seg = th::SegmentArgs {
                dense: d.ptr(&self.dense),
                nkeys: nkeys as u32,
                perm: d.ptr(&self.perm),
                keys: d.ptr(&self.keys),
                n: self.n as u32,
            };
            d.run(kt::SORT_SEGMENTS, nkeys, &seg)?;
        }
        let perm = d.ptr(&self.perm);
        let n = self.n;
        macro_rules! carry {
            ($field:expr, $scratch:expr, $kernel:expr) => {{
                let a = th::GatherArgs {
                    src: d.ptr(&$field),
                    dst: d.ptr(&$scratch),
                    perm,
                    n: n as u32,
                };
                d.run($kernel, n, &a)?;
                std::mem::swap(&mut $field, &mut $scratch);
            }};
        }
        carry!(self.x, self.s_x, kt::GATHER_X);
        carry!(self.v, self.s_v3, R::GATHER_V3);
        carry!(self.m, self.s_f64, R::GATHER_REAL);
        carry!(self.rho, self.s_f64, R::GATHER_REAL);
        carry!(self.id, self.s_u64, kt::GATHER_U64);
        carry!(self.keys, self.s_u64, kt::GATHER_U64);
        if let (Some(f), Some(s)) = (&mut self.fixed, &mut self.s_u8) {
            carry!(*f, *s, kt::GATHER_U8);
        }
        for e in extra.iter_mut() {
            carry!(**e, self.s_f64, R::GATHER_REAL);
        }
        for e in extra_v3.iter_mut() {
            carry!(**e, self.s_v3, R::GATHER_V3);
        }
        Ok(())
    }

    /// "gas", or "dust fraction k" for particle i of the dust buffer (for messages).
    fn phase_name(&self, gas: bool, i: usize) -> String {
        if gas {
            return "gas".into();
        }
        let g = (0..self.groups)
            .find(|&g| i < self.off[g + 1] as usize)
            .unwrap_or(0);
        format!("dust fraction {g}")
    }

    /// Sparse mode: keys on the device, the (key, index) sort on the host (the dense path's
    /// order), and the occupied cells' keys and starts uploaded for binary-search lookups.
    fn sort_on_host(&mut self, d: &Device<L>, p: &Hp<R>) -> Result<(), GpuError> {
        let ka = th::KeysArgs {
            ph: self.bufs(d),
            p: p.dev,
            counts: std::ptr::null_mut(),
        };
        d.run(R::KEYS, self.n, &ka)?;
        let keys = d.get(&self.keys, self.n)?;
        let mut kp: Vec<(u64, u32)> = keys
            .iter()
            .enumerate()
            .map(|(i, &k)| (k, i as u32))
            .collect();
        kp.par_sort_unstable();
        let perm: Vec<u32> = kp.iter().map(|&(_, i)| i).collect();
        let (mut ck, mut cs) = (Vec::new(), Vec::new());
        for (i, &(k, _)) in kp.iter().enumerate() {
            if ck.last() != Some(&k) {
                ck.push(k);
                cs.push(i as u32);
            }
        }
        cs.push(self.n as u32);
        self.ncells = ck.len();
        d.put_growing(&mut self.ckeys, &ck)?;
        d.put_growing(&mut self.cstart, &cs)?;
        self.host_ckeys = ck;
        d.put(&mut self.perm, &perm)
    }

    /// Download into host phases (split by group).
    fn download(&self, d: &Device<L>, phases: &mut [&mut Phase]) -> Result<(), GpuError> {
        let x = d.get(&self.x, self.n)?;
        let v = d.get_v3(&self.v, self.n)?;
        let m = d.get_f64(&self.m, self.n)?;
        let rho = d.get_f64(&self.rho, self.n)?;
        let id = d.get(&self.id, self.n)?;
        let fixed = self.fixed.as_ref().map(|f| d.get(f, self.n)).transpose()?;
        for (g, ph) in phases.iter_mut().enumerate() {
            let r = self.off[g] as usize..self.off[g + 1] as usize;
            ph.x = x[r.clone()].to_vec();
            ph.v = v[r.clone()].to_vec();
            ph.m = m[r.clone()].to_vec();
            ph.rho = rho[r.clone()].to_vec();
            ph.id = id[r.clone()].to_vec();
            if ph.fixed.is_some() {
                ph.fixed = fixed
                    .as_ref()
                    .map(|f| f[r.clone()].iter().map(|&b| b != 0).collect());
            }
        }
        Ok(())
    }
}

/// The kernel coupling's buffers (docs/method.md §K): normalisers of every particle, the
/// increments and stopping times of every gas particle's means.
struct DevCoupling<L: Launcher, R: Float> {
    /// Scatter form: the deposit sums of every gas particle (`th::DEPOSIT_SLOTS` per phase).
    /// f64 in every precision (see `th::ScatterDepositArgs::sums`).
    sums: Option<Buf<L, f64>>,
    s_gas: Buf<L, R>,
    s_dust: Buf<L, R>,
    dv: Buf<L, [R; 3]>,
    du: Buf<L, [R; 3]>,
    t_stop: Buf<L, R>,
    /// Drag heating: the heat per unit mass of every gas particle.
    heat: Option<Buf<L, R>>,
    /// Variable h: the weights use each gas particle's kernel (the engine's `sm.kat`).
    per_particle_kernels: bool,
}

impl<L: Launcher, R: Float> DevCoupling<L, R> {
    /// `kat`: the engine's per-gas-particle kernels (used with variable h).
    fn bufs(&self, d: &Device<L>, kat: &Buf<L, KernelAt<R>>) -> th::CouplingBufs<R> {
        th::CouplingBufs {
            s_gas: d.ptr(&self.s_gas),
            s_dust: d.ptr(&self.s_dust),
            dv: d.ptr(&self.dv),
            du: d.ptr(&self.du),
            t_stop: d.ptr(&self.t_stop),
            kat: if self.per_particle_kernels {
                d.ptr(kat)
            } else {
                std::ptr::null()
            },
        }
    }
}

/// Per union cell results of the IDIC cell step.
struct DevCells<L: Launcher, R: Float> {
    uidx: Buf<L, u32>,
    ukey: Buf<L, u64>,
    gas_mass: Buf<L, R>,
    v_new: Buf<L, [R; 3]>,
    eps: Buf<L, R>,
    beta: Buf<L, R>,
    t_stop: Buf<L, R>,
    u_new: Buf<L, [R; 3]>,
    heat: Buf<L, R>,
    /// Sparse mode: the union was built at the sort (its size); `None`: dense, built by the
    /// union kernels.
    sparse: Option<u32>,
    /// The dense union matches the current sort (it depends on the positions only: built once
    /// per layer, not once per kick).
    union_fresh: bool,
}

impl<L: Launcher, R: Float> DevCells<L, R> {
    fn bufs(&self, d: &Device<L>) -> th::CellBufs<R> {
        th::CellBufs {
            uidx: d.ptr(&self.uidx),
            sparse: self.sparse.is_some() as u32,
            sparse_count: self.sparse.unwrap_or(0),
            ukey: d.ptr(&self.ukey),
            gas_mass: d.ptr(&self.gas_mass),
            v_new: d.ptr(&self.v_new),
            eps: d.ptr(&self.eps),
            beta: d.ptr(&self.beta),
            t_stop: d.ptr(&self.t_stop),
            u_new: d.ptr(&self.u_new),
        }
    }
}

pub struct GpuEngine<L: Launcher, R: Float> {
    pub phys: Physics,
    pub pipe: Pipeline,
    pub timers: Timers,
    d: Device<L>,
    /// The step's constants, in f64 (cast to the step's precision per launch).
    base: StepParams<f64>,
    grid: Grid,
    gas: DevPhase<L, R>,
    dust: DevPhase<L, R>,
    pres: Buf<L, R>,
    cs: Buf<L, R>,
    e: Option<Buf<L, R>>,
    acc: Buf<L, [R; 3]>,
    zero_acc: Buf<L, [R; 3]>,
    dedt: Option<Buf<L, R>>,
    cells: DevCells<L, R>,
    /// Kernel coupling (`idic.coupling = "kernel"`): its per-particle buffers.
    coupling: Option<DevCoupling<L, R>>,
    sums: Buf<L, u32>,
    limits: Buf<L, u64>,
    bounds: Buf<L, u64>,
    bad: Buf<L, u32>,
    dust_density_fresh: bool,
    /// The state's step count and time (for messages).
    step: u64,
    t: f64,
    /// Always use the sparse cell tables (checks that both forms give the same step).
    pub force_sparse: bool,
    /// The gas keeps a neighbour list per layer (`numerics.neighbour_list`).
    lists: bool,
    /// Variable h and IAD (`sph.variable_h`, `sph.gradient = "iad"`).
    sm: DevSmoothing<L, R>,
    /// The leapfrog (`time.integrator = "kdk"`).
    kdk: DevKdk<L, R>,
    params: std::cell::RefCell<ParamSlots<L, R>>,
    /// Over MPI ranks with a thin halo: the ghost particles and their refresh.
    ghosts: Option<Ghosts<L>>,
}

/// The leapfrog's state: the closing forces' maxima (the forces stay in `acc`, `dedt`, `vsig`)
/// and the half-step values kept across the predictor.
struct DevKdk<L: Launcher, R: Float> {
    closing: Option<(f64, f64)>,
    vsig: Option<Buf<L, R>>,
    v_save: Buf<L, [R; 3]>,
    u_save: Buf<L, [R; 3]>,
    e_save: Option<Buf<L, R>>,
}

/// Buffers of variable h and of the IAD gradient (empty when the scene uses neither).
struct DevSmoothing<L: Launcher, R: Float> {
    /// h and Ω of every gas particle (variable h; carried by the sort).
    gas_h: Option<Buf<L, R>>,
    gas_omega: Option<Buf<L, R>>,
    /// The solve's outputs (swapped in on success) and its iteration counts.
    h_new: Buf<L, R>,
    omega_new: Buf<L, R>,
    iters: Buf<L, u32>,
    /// Per gas particle: kernel constants and pressure term (variable h or IAD), IAD matrix.
    kat: Buf<L, KernelAt<R>>,
    pt: Buf<L, R>,
    iad: Buf<L, Sym3<R>>,
    hmax: Buf<L, u64>,
}

/// Phantom's tolerance of the h solve (as the CPU path).
const H_TOL: f64 = 1e-4;
/// The dust's h solve when its density is computed only for an output: converged to
/// round-off (a correction below 1e-8 leaves an error of order 1e-16 after Newton's quadratic
/// step), so that it does not depend on its warm start, i.e. on when the previous output was
/// written (at `H_TOL` the dust density moved with the output cadence by ≈3e-10; a run over MPI
/// ranks, which refreshes it every step, then differed from one process by as much).
const H_TOL_OUTPUT: f64 = 1e-8;

/// Ghost particles: copies of particles another MPI rank owns, within one interaction reach of
/// this rank's own (docs/scaling.md, "A thin halo"). Between the step's neighbour passes the
/// engine hands every particle's per-particle values to [`GhostSync::refresh`], which writes
/// the owners' values into the ghosts' rows; the ghosts keep their density, h and forces out
/// of those passes (their neighbourhoods are cut off at the halo's edge) and out of the step's
/// maxima.
pub trait GhostSync: Send {
    /// Overwrite the ghosts' rows (gas first, then the dust) with their owners' (collective).
    fn refresh(&mut self, tables: &mut [GhostRows<'_>]) -> Result<(), String>;
}

/// One phase's particles as rows of bytes: `keys[i]` = (phase: 0 gas, 1 + k dust fraction k,
/// particle id); row i is `data[i * row .. (i + 1) * row]`, every per-particle buffer's value.
pub struct GhostRows<'a> {
    pub keys: &'a [(u64, u64)],
    pub row: usize,
    pub data: Vec<u8>,
}

/// The ghosts of an engine: the refresh, the ghosts' keys, and per phase a mask (fixed or ghost)
/// that the density, h and force passes take in place of `fixed`.
struct Ghosts<L: Launcher> {
    sync: Box<dyn GhostSync>,
    keys: crate::particles::KeySet,
    mask: [Option<Buf<L, u8>>; 2],
    /// 1 for a ghost only (not a wall), per phase: the explicit drag limit's cells.
    only: [Option<Buf<L, u8>>; 2],
    /// Every slot's key (phase, id), per phase, in the order of the last sort.
    slots: [Vec<(u64, u64)>; 2],
}

/// Whether an engine computes its first layer's densities or takes the state's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layer {
    /// From the positions (a run's start, a resume).
    Compute,
    /// The state's own: it was stepped by this code and its densities are exact.
    Given,
}

impl From<GpuError> for StepError {
    fn from(e: GpuError) -> Self {
        StepError::Blowup(format!("GPU: {e}"))
    }
}

impl<L: Launcher, R: Float> GpuEngine<L, R> {
    /// Upload the state, sort it, and compute densities and pressures at the initial layer.
    /// The host `state` is then sorted the same way (as the CPU engine leaves it).
    pub fn new(
        phys: Physics,
        state: &mut State,
        launcher: L,
    ) -> Result<GpuEngine<L, R>, StepError> {
        Self::with_layer(phys, state, launcher, Layer::Compute)
    }

    /// As [`GpuEngine::new`]; with [`Layer::Given`] the state's densities, pressures and sound
    /// speeds are its layer's (a step over MPI ranks rebuilds its engine on particles that
    /// their owners stepped): the gas's summation density is not redone, and the dust's only
    /// where its drag needs it each step (and then it is the state's too).
    pub fn with_layer(
        phys: Physics,
        state: &mut State,
        launcher: L,
        layer: Layer,
    ) -> Result<GpuEngine<L, R>, StepError> {
        let pipe = Pipeline::from_physics(&phys);
        let nf = state.dust.len();
        if nf > MAX_FRACTIONS {
            return Err(StepError::Unsupported(format!(
                "{nf} dust fractions: the GPU path supports at most {MAX_FRACTIONS}"
            )));
        }
        let d = Device {
            launcher,
            allocated: std::cell::Cell::new(0),
        };
        let (eos_kind, eos_value) = match phys.eos {
            Eos::Isothermal { cs } => (0, cs),
            Eos::Adiabatic { gamma } => (1, gamma),
        };
        let mut laws = [LawParam::default(); MAX_FRACTIONS];
        for (l, p) in laws.iter_mut().zip(&phys.laws) {
            *l = LawParam::from_law(p);
        }
        let grid = Grid::build(&phys.domain, phys.cell_size, phys.support(), &[])?;
        let base = StepParams {
            geom: grid.geom,
            total: 0,
            h: phys.h,
            tau: 0.0,
            dim: phys.dim,
            eos_kind,
            eos_value,
            av: phys.av.is_some() as u32,
            alpha: phys.av.map_or(0.0, |a| a.alpha),
            beta: phys.av.map_or(0.0, |a| a.beta),
            nu2_factor: phys.av.map_or(0.0, |a| a.nu2_factor),
            nf: nf as u32,
            needs_gas_state: phys.laws.iter().any(|l| l.needs_gas_state()) as u32,
            laws,
            ext_gas: phys.ext_gas,
            ext_dust: phys.ext_dust,
            explicit_drag: pipe.explicit_drag as u32,
        };
        let heating = pipe.heating;
        let gas = DevPhase::new(&d, &[&state.gas.ph], heating)?;
        let dust_refs: Vec<&Phase> = state.dust.iter().collect();
        let dust = DevPhase::new(&d, &dust_refs, heating)?;
        let ng = gas.n;
        let cap = (gas.n + dust.n).max(1);
        let g = &state.gas;
        // A resumed leapfrog run carries its closing forces: the first step starts from them.
        let rows = g
            .next_forces
            .as_deref()
            .filter(|r| pipe.kdk && r.len() == ng);
        let col = |k: usize| rows.map(|r| r.iter().map(|x| x[k]).collect::<Vec<f64>>());
        let mut eng = GpuEngine {
            pres: d.upload_f64(&fill(&g.p, ng))?,
            cs: d.upload_f64(&fill(&g.c, ng))?,
            e: g.e.as_deref().map(|e| d.upload_f64(e)).transpose()?,
            acc: match rows {
                Some(r) => {
                    d.upload_v3(&r.iter().map(|x| [x[0], x[1], x[2]]).collect::<Vec<V3>>())?
                }
                None => d.buf(ng)?,
            },
            zero_acc: d.buf(ng)?,
            dedt: match (pipe.energy, col(3)) {
                (false, _) => None,
                (true, Some(c)) => Some(d.upload_f64(&c)?),
                (true, None) => Some(d.buf(ng)?),
            },
            cells: DevCells {
                uidx: d.buf(1)?,
                ukey: d.buf(cap)?,
                gas_mass: d.buf(cap)?,
                v_new: d.buf(cap)?,
                eps: d.buf(cap * nf.max(1))?,
                beta: d.buf(cap * nf.max(1))?,
                t_stop: d.buf(cap * nf.max(1))?,
                u_new: d.buf(cap * nf.max(1))?,
                heat: d.buf(cap)?,
                sparse: None,
                union_fresh: false,
            },
            coupling: if pipe.kernel_coupling {
                Some(DevCoupling {
                    sums: if phys.deposit_scatter {
                        Some(d.buf((ng * (1 + nf) * th::DEPOSIT_SLOTS).max(1))?)
                    } else {
                        None
                    },
                    s_gas: d.buf(ng.max(1))?,
                    s_dust: d.buf(dust.n.max(1))?,
                    dv: d.buf(ng.max(1))?,
                    du: d.buf((ng * nf).max(1))?,
                    t_stop: d.buf((ng * nf).max(1))?,
                    heat: if pipe.heating {
                        Some(d.buf(ng.max(1))?)
                    } else {
                        None
                    },
                    per_particle_kernels: pipe.variable_h,
                })
            } else {
                None
            },
            sums: d.buf(1)?,
            limits: d.buf(2)?,
            bounds: d.buf(6)?,
            bad: d.buf(1)?,
            step: state.step,
            t: state.t,
            force_sparse: false,
            lists: match phys.neighbour_list {
                ListChoice::On => true,
                ListChoice::Off => false,
                ListChoice::Auto => d.launcher.lists_by_default(),
            },
            kdk: {
                let k = pipe.kdk;
                let save = k || phys.position_update == PositionUpdate::Old;
                let closing = rows.map(|r| {
                    let f = Forces::from_rows(r, true);
                    (f.vsig_max, f.acc_max)
                });
                DevKdk {
                    closing,
                    vsig: if k {
                        Some(match col(4) {
                            Some(c) => d.upload_f64(&c)?,
                            None => d.buf(ng.max(1))?,
                        })
                    } else {
                        None
                    },
                    v_save: d.buf(if save { ng.max(1) } else { 1 })?,
                    u_save: d.buf(if save { dust.n.max(1) } else { 1 })?,
                    e_save: if k && pipe.energy {
                        Some(d.buf(ng.max(1))?)
                    } else {
                        None
                    },
                }
            },
            sm: {
                let vh = pipe.variable_h;
                // On resume the state carries h and Ω of the last step: kept as they are.
                let resumed = vh && g.h.is_some() && g.omega.is_some();
                let per_gas = if vh || pipe.iad { ng.max(1) } else { 1 };
                let solve = if vh { ng.max(dust.n).max(1) } else { 1 };
                DevSmoothing {
                    gas_h: if resumed {
                        Some(d.upload_f64(g.h.as_deref().unwrap_or(&[]))?)
                    } else {
                        None
                    },
                    gas_omega: if resumed {
                        Some(d.upload_f64(g.omega.as_deref().unwrap_or(&[]))?)
                    } else {
                        None
                    },
                    h_new: d.buf(solve)?,
                    omega_new: d.buf(solve)?,
                    iters: d.buf(solve)?,
                    kat: d.buf(per_gas)?,
                    pt: d.buf(per_gas)?,
                    iad: d.buf(if pipe.iad { ng.max(1) } else { 1 })?,
                    hmax: d.buf(1)?,
                }
            },
            phys,
            pipe,
            timers: Timers::default(),
            d,
            base,
            grid,
            gas,
            dust,
            dust_density_fresh: false,
            params: std::cell::RefCell::new(ParamSlots {
                mem: Vec::new(),
                recent: Vec::new(),
                uploads: 0,
            }),
            ghosts: None,
        };
        eng.regrid()?;
        let given = layer == Layer::Given;
        if given && !eng.pipe.variable_h {
            // Summation or continuity density: ρ is the state's; only p and c_s from it.
            eng.eos()?;
        } else {
            eng.gas_density_eos(None)?;
        }
        // A resumed variable-h run keeps its dust densities too: the next solve starts from
        // them (as the uninterrupted run's does), so the resume stays bit-identical.
        let g = &state.gas;
        let dust_rho_valid = state
            .dust
            .iter()
            .all(|d| d.rho.len() == d.len() && d.rho.iter().all(|r| *r > 0.0 && r.is_finite()));
        eng.dust_density_fresh = if given {
            eng.pipe.dust_density_each_step && dust_rho_valid
        } else {
            eng.pipe.variable_h && g.h.is_some() && g.omega.is_some() && dust_rho_valid
        };
        if !given || eng.pipe.dust_density_each_step {
            eng.dust_density()?;
        }
        eng.sync(state)?;
        eng.check(state)?;
        Ok(eng)
    }

    pub fn describe(&self) -> String {
        self.d.launcher.describe()
    }

    /// Bytes of device memory the engine has allocated (buffers grown and replaced count
    /// again: an upper bound of what it holds).
    pub fn device_bytes(&self) -> usize {
        self.d.allocated.get()
    }

    /// The particle farthest from the origin (or with a non-finite position): phase, id and
    /// position, for the message of a grid that cannot be built.
    fn farthest_particle(&self) -> Result<String, GpuError> {
        let d = &self.d;
        let mut best: Option<(f64, String)> = None;
        for (ph, gas) in [(&self.gas, true), (&self.dust, false)] {
            if ph.n == 0 {
                continue;
            }
            let x = d.get(&ph.x, ph.n)?;
            let id = d.get(&ph.id, ph.n)?;
            for (i, p) in x.iter().enumerate() {
                let r = p.iter().map(|c| c.abs()).fold(0.0, f64::max);
                let r = if r.is_finite() { r } else { f64::INFINITY };
                if best.as_ref().is_none_or(|b| r > b.0) {
                    let what = ph.phase_name(gas, i);
                    best = Some((r, format!("{what} particle id {} at {:?}", id[i], p)));
                }
            }
        }
        Ok(best.map_or_else(|| "none".into(), |b| b.1))
    }

    /// Use the sparse cell tables from the next grid rebuild on (and rebuild now).
    pub fn force_sparse_tables(&mut self) -> Result<(), StepError> {
        self.force_sparse = true;
        self.regrid()?;
        // The densities of this layer are kept (variable h: the gas's h and the dust's
        // densities seed the next solves; re-solving from them would not be the dense run).
        self.gas_density_eos(None)?;
        self.dust_density()
    }

    /// The step's parameters at time step τ, on the host and in device memory.
    fn params(&self, tau: f64) -> Result<Hp<R>, GpuError> {
        let host: StepParams<R> = self.host_params(tau);
        let mut slots = self.params.borrow_mut();
        let i = match slots.recent.iter().rev().find(|q| q.0 == host) {
            Some(&(_, i)) => i,
            None => {
                let i = slots.uploads % PARAM_SLOTS;
                slots.uploads += 1;
                if slots.mem.len() <= i {
                    let m = self
                        .d
                        .launcher
                        .alloc(std::mem::size_of::<StepParams<R>>())?;
                    slots.mem.push(m);
                }
                self.d.launcher.upload_value(&mut slots.mem[i], &host)?;
                if slots.recent.len() == PARAM_RECENT {
                    slots.recent.remove(0);
                }
                slots.recent.push((host, i));
                i
            }
        };
        let dev = th::Params(self.d.launcher.addr(&slots.mem[i]) as *const StepParams<R>);
        Ok(Hp { host, dev })
    }

    /// The host's copy of the step's parameters at time step τ.
    fn host_params(&self, tau: f64) -> StepParams<R> {
        StepParams {
            geom: self.grid.geom,
            total: self.grid.total_cells(),
            tau,
            ..self.base
        }
        .cast()
    }

    /// Rebuild the grid over the current positions and sort every phase by cell.
    fn regrid(&mut self) -> Result<(), StepError> {
        let d = &self.d;
        let mut b = EMPTY_BOUNDS;
        for ph in [&self.gas, &self.dust] {
            if ph.n == 0 {
                continue;
            }
            d.put(&mut self.bounds, &[u64::MAX, u64::MAX, u64::MAX, 0, 0, 0])?;
            let chunk = 64usize;
            let a = th::BoundsArgs {
                x: d.ptr(&ph.x),
                n: ph.n as u32,
                chunk: chunk as u32,
                out: d.ptr(&self.bounds),
            };
            d.run(kt::BOUNDS, ph.n.div_ceil(chunk), &a)?;
            let o = d.get(&self.bounds, 6)?;
            let dec = |k: usize| from_ordered_bits(o[k]);
            b = merge_bounds(b, ([dec(0), dec(1), dec(2)], [dec(3), dec(4), dec(5)]));
        }
        let support = self.search_support()?;
        self.grid = match Grid::from_bounds(&self.phys.domain, self.phys.cell_size, support, b) {
            Ok(g) => g,
            // A run-time stop names the step, the time and the particle that caused it.
            Err(e) => {
                return Err(StepError::Grid(crate::grid::GridError(format!(
                    "step {}, t = {:e}: {e}; farthest particle: {}",
                    self.step,
                    self.t,
                    self.farthest_particle()?
                ))))
            }
        };
        // Dense start tables over the search cells of the grid box when they are small enough;
        // else (a few particles flung far away) sorted cell lists and binary searches.
        let search_cells = self.host_params(0.0).stride() as u64 - 1;
        let sparse = self.force_sparse
            || !crate::grid::dense_table_fits(search_cells, self.gas.n + self.dust.n);
        let groups = (self.gas.groups.max(self.dust.groups)) as u128;
        if groups * (self.grid.total_cells() as u128 + 1) >= 1u128 << 64 {
            return Err(StepError::Grid(crate::grid::GridError(format!(
                "step {}: the particles span {} cells: too many for 64-bit keys of {groups} \
                 groups (the cloud has spread too far for this cell size)",
                self.step,
                self.grid.total_cells()
            ))));
        }
        let p = self.params(0.0)?;
        let mut extra: Vec<&mut Buf<L, R>> = vec![&mut self.pres, &mut self.cs];
        if let Some(e) = &mut self.e {
            extra.push(e);
        }
        if let Some(h) = &mut self.sm.gas_h {
            extra.push(h);
        }
        if let Some(o) = &mut self.sm.gas_omega {
            extra.push(o);
        }
        // The leapfrog's forces follow their particles (the predictor and a resumed first step
        // read them after the sort).
        let mut extra_v3: Vec<&mut Buf<L, [R; 3]>> = Vec::new();
        if self.pipe.kdk {
            extra_v3.push(&mut self.acc);
            if let Some(dedt) = &mut self.dedt {
                extra.push(dedt);
            }
            if let Some(v) = &mut self.kdk.vsig {
                extra.push(v);
            }
        }
        self.gas.sort(
            &self.d,
            &p,
            &mut self.sums,
            &mut extra,
            &mut extra_v3,
            sparse,
        )?;
        self.dust
            .sort(&self.d, &p, &mut self.sums, &mut [], &mut [], sparse)?;
        self.cells.sparse = None;
        self.cells.union_fresh = false;
        if sparse {
            // The IDIC union: every occupied cell of any phase, sorted.
            let ks = self.grid.total_cells() + 1;
            let mut u: Vec<u64> = self.gas.host_ckeys.clone();
            u.extend(self.dust.host_ckeys.iter().map(|&c| c % ks));
            u.par_sort_unstable();
            u.dedup();
            self.d.put(&mut self.cells.ukey, &u)?;
            self.cells.sparse = Some(u.len() as u32);
        }
        self.reset_list()?;
        Ok(self.ghost_masks()?)
    }

    /// A fresh neighbour list for the gas's current layer (when lists are on): emptied, to be
    /// recorded by the layer's first neighbour pass and replayed by the others (h solve or
    /// density, IAD matrices, forces). The stride grows to 9/8 of the largest count seen.
    fn reset_list(&mut self) -> Result<(), GpuError> {
        if !self.lists || self.gas.n == 0 {
            return Ok(());
        }
        let n = self.gas.n;
        let d = &self.d;
        let mut stride = LIST_STRIDE0;
        if let Some(l) = &self.gas.nl {
            stride = l.stride;
            let most = d.get(&l.max, 1)?[0] as usize;
            if most > stride {
                stride = (most + most / 8).next_multiple_of(8);
                self.gas.nl = None;
                if stride > LIST_STRIDE_MAX {
                    // Too many neighbours for a list to pay (or to fit): the cell walk stays.
                    self.lists = false;
                    return Ok(());
                }
            }
        }
        if self.gas.nl.is_none() {
            // A list is a speed-up, never a reason to run out of memory: only while it fits
            // in a quarter of what the machine has free (host memory: the CPU launcher).
            let bytes = (n * (stride + 1) * 4) as f64;
            if crate::setup::available_memory().is_some_and(|free| bytes > 0.25 * free) {
                self.lists = false;
                return Ok(());
            }
            self.gas.nl = Some(NeighbourList {
                index: d.buf(n * stride)?,
                count: d.buf(n)?,
                max: d.buf(1)?,
                stride,
                valid: std::cell::Cell::new(false),
            });
        }
        let l = self.gas.nl.as_mut().expect("allocated above");
        d.zeroed(&mut l.count, n)?;
        l.valid.set(true);
        Ok(())
    }

    fn density(&self, gas: bool) -> Result<(), GpuError> {
        let a = th::DensityArgs {
            ph: self.masked(gas),
            p: self.params(0.0)?.dev,
        };
        let n = if gas { self.gas.n } else { self.dust.n };
        self.d.run(R::DENSITY, n, &a)
    }

    /// A phase's buffers for the density, h and force passes, where ghosts count as fixed
    /// (they keep their values, and stay out of the maxima, until their owners' arrive).
    fn masked(&self, gas: bool) -> PhaseBufs<R> {
        let ph = if gas { &self.gas } else { &self.dust };
        let mut b = ph.bufs(&self.d);
        if let Some(m) = self
            .ghosts
            .as_ref()
            .and_then(|g| g.mask[!gas as usize].as_ref())
        {
            b.fixed = self.d.ptr(m);
        }
        b
    }

    /// Make particles ghosts (`keys`: phase 0 gas, 1 + k dust fraction k; id) refreshed by
    /// `sync` between the step's neighbour passes, and refresh them now.
    pub fn set_ghosts(
        &mut self,
        sync: Box<dyn GhostSync>,
        keys: crate::particles::KeySet,
    ) -> Result<(), StepError> {
        self.ghosts = Some(Ghosts {
            sync,
            keys,
            mask: [None, None],
            only: [None, None],
            slots: [Vec::new(), Vec::new()],
        });
        self.ghost_masks()?;
        self.ghost_sync()
    }

    /// Every slot's key (phase, id) of a phase, in the current order.
    fn slot_keys(&self, gas: bool) -> Result<Vec<(u64, u64)>, GpuError> {
        let ph = if gas { &self.gas } else { &self.dust };
        let ids = self.d.get(&ph.id, ph.n)?;
        Ok(ids
            .iter()
            .enumerate()
            .map(|(i, &id)| {
                let phase = if gas {
                    0
                } else {
                    1 + (0..ph.groups)
                        .find(|&g| (i as u32) < ph.off[g + 1])
                        .unwrap_or(0) as u64
                };
                (phase, id)
            })
            .collect())
    }

    /// The slots' keys and the ghost masks in the current order (after each sort).
    fn ghost_masks(&mut self) -> Result<(), GpuError> {
        let Some(g) = &self.ghosts else {
            return Ok(());
        };
        let mut masks: [Option<Buf<L, u8>>; 2] = [None, None];
        let mut only: [Option<Buf<L, u8>>; 2] = [None, None];
        let mut slots = [Vec::new(), Vec::new()];
        for (k, gas) in [true, false].into_iter().enumerate() {
            let ph = if gas { &self.gas } else { &self.dust };
            slots[k] = self.slot_keys(gas)?;
            if ph.n == 0 {
                continue;
            }
            let fixed = match &ph.fixed {
                Some(f) => self.d.get(f, ph.n)?,
                None => vec![0; ph.n],
            };
            let ghost: Vec<u8> = slots[k]
                .iter()
                .map(|key| g.keys.contains(key) as u8)
                .collect();
            let m: Vec<u8> = (ghost.iter().zip(&fixed)).map(|(&g, &f)| g | f).collect();
            masks[k] = Some(self.d.from(&m)?);
            only[k] = Some(self.d.from(&ghost)?);
        }
        if let Some(g) = &mut self.ghosts {
            g.mask = masks;
            g.only = only;
            g.slots = slots;
        }
        Ok(())
    }

    /// Refresh the ghosts from their owners (a no-op without ghosts): every per-particle
    /// buffer, as bytes, row by row.
    fn ghost_sync(&mut self) -> Result<(), StepError> {
        if self.ghosts.is_none() {
            return Ok(());
        }
        let mut rows = Vec::with_capacity(2);
        for gas in [true, false] {
            let n = if gas { self.gas.n } else { self.dust.n };
            let cols = self.ghost_columns(gas, None)?;
            let row: usize = cols.iter().map(|c| c.len() / n.max(1)).sum();
            let mut data = vec![0u8; n * row];
            let mut at = 0;
            for c in &cols {
                let w = c.len() / n.max(1);
                for i in 0..n {
                    data[i * row + at..i * row + at + w].copy_from_slice(&c[i * w..(i + 1) * w]);
                }
                at += w;
            }
            rows.push((row, data));
        }
        // The slots' keys of the last sort (ghost_masks): no id download per refresh.
        let Ghosts { sync, slots, .. } = self.ghosts.as_mut().expect("checked above");
        let mut tables: Vec<GhostRows<'_>> = (slots.iter().zip(rows))
            .map(|(keys, (row, data))| GhostRows { keys, row, data })
            .collect();
        sync.refresh(&mut tables)
            .map_err(|e| StepError::Blowup(format!("halo exchange: {e}")))?;
        let rows: Vec<(usize, Vec<u8>)> = tables.into_iter().map(|t| (t.row, t.data)).collect();
        for ((row, data), gas) in rows.iter().zip([true, false]) {
            self.ghost_columns(gas, Some((*row, data)))?;
        }
        Ok(())
    }

    /// A phase's per-particle buffers as byte columns (`put` = None), or written back from
    /// the rows of `put`; those this scene's pipeline does not use are left out.
    fn ghost_columns(
        &mut self,
        gas: bool,
        put: Option<(usize, &[u8])>,
    ) -> Result<Vec<Vec<u8>>, GpuError> {
        /// Buffer `b` with `per` values per particle, particle-major.
        fn one<L: Launcher, T: Copy>(
            d: &Device<L>,
            b: Option<&mut Buf<L, T>>,
            n: usize,
            per: usize,
            put: Option<((usize, &[u8]), &mut usize)>,
            out: &mut Vec<Vec<u8>>,
        ) -> Result<(), GpuError> {
            let Some(b) = b else { return Ok(()) };
            if n == 0 || per == 0 {
                return Ok(());
            }
            let w = std::mem::size_of::<T>() * per;
            match put {
                None => {
                    let mut bytes = vec![0u8; n * w];
                    d.launcher.download(&b.mem, &mut bytes)?;
                    out.push(bytes);
                }
                Some(((row, data), at)) => {
                    let mut bytes = vec![0u8; n * w];
                    for i in 0..n {
                        bytes[i * w..(i + 1) * w]
                            .copy_from_slice(&data[i * row + *at..i * row + *at + w]);
                    }
                    *at += w;
                    d.launcher.upload(&mut b.mem, &bytes)?;
                }
            }
            Ok(())
        }
        let mut out = Vec::new();
        let mut at = 0usize;
        let d = &self.d;
        // Which buffers: by the scene's pipeline (the same on every rank), never by a length.
        let save = self.pipe.kdk || self.phys.position_update == PositionUpdate::Old;
        let smooth = self.pipe.variable_h || self.pipe.iad;
        let iad = self.pipe.iad;
        macro_rules! col {
            ($b:expr, $n:expr) => {
                one(d, $b, $n, 1, put.map(|t| (t, &mut at)), &mut out)?
            };
            ($b:expr, $n:expr, $per:expr) => {
                one(d, $b, $n, $per, put.map(|t| (t, &mut at)), &mut out)?
            };
        }
        let nf = self.dust.groups;
        if gas {
            let n = self.gas.n;
            col!(Some(&mut self.gas.x), n);
            col!(Some(&mut self.gas.v), n);
            col!(Some(&mut self.gas.m), n);
            col!(Some(&mut self.gas.rho), n);
            col!(self.gas.loss.as_mut(), n);
            col!(Some(&mut self.pres), n);
            col!(Some(&mut self.cs), n);
            col!(self.e.as_mut(), n);
            col!(Some(&mut self.acc), n);
            col!(self.dedt.as_mut(), n);
            col!(self.kdk.vsig.as_mut(), n);
            col!(save.then_some(&mut self.kdk.v_save), n);
            col!(self.kdk.e_save.as_mut(), n);
            col!(self.sm.gas_h.as_mut(), n);
            col!(self.sm.gas_omega.as_mut(), n);
            col!(smooth.then_some(&mut self.sm.kat), n);
            col!(smooth.then_some(&mut self.sm.pt), n);
            col!(iad.then_some(&mut self.sm.iad), n);
            if let Some(c) = &mut self.coupling {
                col!(Some(&mut c.s_gas), n);
                col!(Some(&mut c.dv), n);
                col!(Some(&mut c.du), n, nf);
                col!(Some(&mut c.t_stop), n, nf);
                col!(c.heat.as_mut(), n);
            }
        } else {
            let n = self.dust.n;
            col!(Some(&mut self.dust.x), n);
            col!(Some(&mut self.dust.v), n);
            col!(Some(&mut self.dust.m), n);
            col!(Some(&mut self.dust.rho), n);
            col!(self.dust.loss.as_mut(), n);
            col!(save.then_some(&mut self.kdk.u_save), n);
            if let Some(c) = &mut self.coupling {
                col!(Some(&mut c.s_dust), n);
            }
        }
        Ok(out)
    }

    /// The grid's search radius: the support 2h; with variable h, 2 max h_a plus 0.1% (the
    /// CPU path's rule, so both build the same grid).
    fn search_support(&mut self) -> Result<f64, GpuError> {
        let base = self.phys.support();
        let (Some(h), true) = (&self.sm.gas_h, self.pipe.variable_h) else {
            return Ok(base);
        };
        let d = &self.d;
        d.put(&mut self.sm.hmax, &[0])?;
        let chunk = 256usize;
        let a = th::MaxArgs {
            x: d.ptr(h),
            n: self.gas.n as u32,
            chunk: chunk as u32,
            out: d.ptr(&self.sm.hmax),
        };
        d.run(R::MAX_OF, self.gas.n.div_ceil(chunk), &a)?;
        let b = d.get(&self.sm.hmax, 1)?[0];
        let hmax = if b == 0 { 0.0 } else { from_ordered_bits(b) };
        Ok(base.max(SUPPORT * hmax * (1.0 + 1e-3)))
    }

    /// Variable h of the gas (`gas = true`, from its current h, or the reference h at the
    /// start) or of every dust fraction (from the h of its last density): h, ρ (and Ω) by Newton–Raphson.
    /// A particle whose h runs into the search radius widens the grid's reach (same cells and
    /// order) and the solve is repeated, as on the CPU.
    fn solve_h(&mut self, gas: bool, step: u64, tol: f64) -> Result<(), StepError> {
        let hfact = self.phys.variable_h.expect("variable h");
        let eps = if std::mem::size_of::<R>() == 4 {
            f32::EPSILON as f64
        } else {
            f64::EPSILON
        };
        for _attempt in 0..40 {
            let d = &self.d;
            d.put(&mut self.bad, &[u32::MAX])?;
            let ph = if gas { &self.gas } else { &self.dust };
            let a = th::HSolveArgs {
                ph: self.masked(gas),
                h0: match (&self.sm.gas_h, gas) {
                    (Some(h), true) => d.ptr(h),
                    _ => std::ptr::null(),
                },
                // The dust starts from its last density's h: one Newton pass a step instead of
                // two from the reference h (docs/performance.md).
                warm: (!gas) as u32,
                h: d.ptr(&self.sm.h_new),
                omega: if gas {
                    d.ptr(&self.sm.omega_new)
                } else {
                    std::ptr::null_mut()
                },
                iters: d.ptr(&self.sm.iters),
                bad: d.ptr(&self.bad),
                hfact: R::from_f64(hfact),
                h_max: R::from_f64(self.grid.geom.support / SUPPORT),
                // Not below a few roundings of R (f32: 1.2e-7), which a correction never beats.
                tol: R::from_f64(tol.max(16.0 * eps)),
                p: self.params(0.0)?.dev,
            };
            d.run(R::SOLVE_H, ph.n, &a)?;
            let bad = d.get(&self.bad, 1)?[0];
            if bad == u32::MAX {
                if gas {
                    // The solved h and Ω become the gas's; its old buffers become the next
                    // scratch (no allocation in the step, once both are of the scratch's size).
                    let len = self.sm.h_new.len;
                    for (cur, new) in [
                        (&mut self.sm.gas_h, &mut self.sm.h_new),
                        (&mut self.sm.gas_omega, &mut self.sm.omega_new),
                    ] {
                        let spare = match cur.take() {
                            Some(b) if b.len == len => b,
                            _ => d.buf(len)?,
                        };
                        *cur = Some(std::mem::replace(new, spare));
                    }
                }
                return Ok(());
            }
            let i = bad as usize;
            let iters = d.get(&self.sm.iters, i + 1)?[i];
            if iters < 30 && self.grid.geom.support < 1e300 {
                self.grid = self.grid.with_support(1.02 * self.grid.geom.support);
                self.reset_list()?;
                continue;
            }
            let ids = d.get(&ph.id, i + 1)?;
            let h = d.get_f64(&self.sm.h_new, i + 1)?[i];
            let what = ph.phase_name(gas, i);
            return Err(StepError::Blowup(format!(
                "step {step}: variable h did not converge for {what} particle id {} (h = {h:e})",
                ids[i]
            )));
        }
        Err(StepError::Blowup(format!(
            "step {step}: variable h of the {} outgrew every search radius",
            if gas { "gas" } else { "dust" }
        )))
    }

    /// Pressure and sound speed from the density (and energy).
    fn eos(&self) -> Result<(), GpuError> {
        let d = &self.d;
        let a = th::EosArgs {
            rho: d.ptr(&self.gas.rho),
            e: d.opt(&self.e),
            pres: d.ptr(&self.pres),
            c: d.ptr(&self.cs),
            n: self.gas.n as u32,
            p: self.params(0.0)?.dev,
        };
        d.run(R::EOS, self.gas.n, &a)
    }

    /// Gas density at the current (new) positions, then the EOS: variable h, summation, or the
    /// continuity equation ρ += τ dρ/dt. `tau` is `None` at start-up and on resume, where a
    /// resumed variable-h state and a continuity density are kept as they are (the CPU's rule).
    fn gas_density_eos(&mut self, tau: Option<f64>) -> Result<(), StepError> {
        if self.pipe.variable_h {
            let resumed = tau.is_none() && self.sm.gas_h.is_some();
            if !resumed {
                self.solve_h(true, self.step, H_TOL)?;
            }
        } else if !self.pipe.continuity_density {
            self.density(true)?;
        } else if let Some(tau) = tau {
            let a = th::DensityArgs {
                ph: self.gas.bufs(&self.d),
                p: self.params(tau)?.dev,
            };
            self.d.run(R::DENSITY_CONTINUITY, self.gas.n, &a)?;
        }
        Ok(self.eos()?)
    }

    /// The explicit drag's step limit at the current layer, [`drag::EXPLICIT_SAFETY`]/Λ with Λ
    /// the fastest drag rate of any cell; +∞ with IDIC (the drag never limits its step).
    pub fn drag_dt_limit(&mut self) -> Result<f64, StepError> {
        if !self.pipe.explicit_drag {
            return Ok(f64::INFINITY);
        }
        // ε_k and t_k* do not depend on the velocities handed to the cell sums.
        self.cell_step(0.0, true)?;
        let d = &self.d;
        d.put(&mut self.limits, &[0, 0])?;
        let only = |k: usize| -> *const u8 {
            (self.ghosts.as_ref())
                .and_then(|g| g.only[k].as_ref())
                .map_or(std::ptr::null(), |b| d.ptr(b) as *const u8)
        };
        let a = th::LimitArgs {
            cells: self.cells.bufs(d),
            rate: d.ptr(&self.limits),
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            gas_ghost: only(0),
            dust_ghost: only(1),
            p: self.params(0.0)?.dev,
        };
        d.run(R::EXPLICIT_LIMIT, self.cells.ukey.len, &a)?;
        let b = d.get(&self.limits, 1)?[0];
        let rate = if b == 0 { 0.0 } else { from_ordered_bits(b) };
        Ok(if rate > 0.0 {
            dustsph_device::drag::EXPLICIT_SAFETY / rate
        } else {
            f64::INFINITY
        })
    }

    fn dust_density(&mut self) -> Result<(), StepError> {
        if !self.dust_density_fresh {
            if self.pipe.variable_h && self.dust.n > 0 {
                let tol = if self.pipe.dust_density_each_step {
                    H_TOL
                } else {
                    H_TOL_OUTPUT
                };
                self.solve_h(false, self.step, tol)?;
            } else {
                self.density(false)?;
            }
            self.dust_density_fresh = true;
        }
        Ok(())
    }

    /// Non-drag gas accelerations (kept on the device) and the time-step maxima. Under the
    /// leapfrog, the previous step's closing forces (already on the device).
    pub fn forces(&mut self) -> Result<Forces, StepError> {
        if let (true, Some((vsig_max, acc_max))) = (self.pipe.kdk, self.kdk.closing) {
            return Ok(Forces {
                acc: Vec::new(),
                dedt: None,
                vsig_max,
                acc_max,
            });
        }
        let mut timers = std::mem::take(&mut self.timers);
        let f = self.compute_forces(&mut timers);
        self.timers = timers;
        f
    }

    /// The gas accelerations at the current layer, downloaded (diagnostics and tests).
    pub fn accelerations(&mut self) -> Result<Vec<V3>, StepError> {
        let mut timers = std::mem::take(&mut self.timers);
        let r = self.compute_forces(&mut timers);
        self.timers = timers;
        r?;
        Ok(self.d.get_v3(&self.acc, self.gas.n)?)
    }

    /// The gas particles that set the time step: the largest |A| (force limit) and the largest
    /// sound speed (CFL limit), with their ids and positions, for a collapsing step's message.
    pub fn dt_culprits(&mut self) -> Result<String, StepError> {
        let acc = self.accelerations()?;
        let d = &self.d;
        let n = self.gas.n;
        let (cs, id, x) = (
            d.get_f64(&self.cs, n)?,
            d.get(&self.gas.id, n)?,
            d.get(&self.gas.x, n)?,
        );
        let argmax = |v: &dyn Fn(usize) -> f64| (0..n).max_by(|&a, &b| v(a).total_cmp(&v(b)));
        let amag = |i: usize| acc[i].iter().map(|a| a * a).sum::<f64>().sqrt();
        let mut out = Vec::new();
        if let Some(i) = argmax(&amag) {
            out.push(format!(
                "largest |A| = {:e} at gas particle id {} (x = {:?})",
                amag(i),
                id[i],
                x[i]
            ));
        }
        if let Some(i) = argmax(&|i| cs[i]) {
            out.push(format!(
                "largest c_s = {:e} at gas particle id {} (x = {:?})",
                cs[i], id[i], x[i]
            ));
        }
        Ok(out.join("; "))
    }

    /// Set the gas forces of the coming step to zero (A = 0, ė = 0): the step that follows is
    /// the drag pass, the drift and the new layer alone.
    pub fn zero_forces(&mut self) -> Result<(), StepError> {
        let d = &self.d;
        d.zeroed(&mut self.acc, self.gas.n)?;
        if let Some(e) = &mut self.dedt {
            d.zeroed(e, self.gas.n)?;
        }
        self.kdk.closing = None;
        Ok(())
    }

    /// The forces at the state on the device.
    fn compute_forces(&mut self, timers: &mut Timers) -> Result<Forces, StepError> {
        let d = &self.d;
        d.put(&mut self.limits, &[0, 0])?;
        let p = self.params(0.0)?;
        let mode = if self.pipe.iad {
            2
        } else {
            u32::from(self.pipe.variable_h)
        };
        if mode != 0 {
            let a = th::PrepArgs {
                gas: self.gas.bufs(d),
                h: d.opt(&self.sm.gas_h),
                // IAD's pressure term is p/ρ² (no grad-h factor).
                omega: if mode == 1 {
                    d.opt(&self.sm.gas_omega)
                } else {
                    std::ptr::null_mut()
                },
                pres: d.ptr(&self.pres),
                kat: d.ptr(&self.sm.kat),
                pt: d.ptr(&self.sm.pt),
                p: p.dev,
            };
            d.run(R::FORCE_PREP, self.gas.n, &a)?;
        }
        if mode == 2 {
            let a = th::IadArgs {
                gas: self.gas.bufs(d),
                kat: d.ptr(&self.sm.kat),
                iad: d.ptr(&self.sm.iad),
                p: p.dev,
            };
            timers.time("gas IAD matrices (Garcia-Senz et al. 2012)", || {
                d.run(R::IAD_MATRIX, self.gas.n, &a)
            })?;
            // The forces read the neighbours' matrices.
            self.ghost_sync()?;
        }
        let d = &self.d;
        let a = th::ForcesArgs {
            gas: self.masked(true),
            pres: d.ptr(&self.pres),
            c: d.ptr(&self.cs),
            acc: d.ptr(&self.acc),
            dedt: d.opt(&self.dedt),
            limits: d.ptr(&self.limits),
            mode,
            kat: d.ptr(&self.sm.kat),
            pt: d.ptr(&self.sm.pt),
            iad: d.ptr(&self.sm.iad),
            vsig: d.opt(&self.kdk.vsig),
            p: p.dev,
        };
        let name = match (self.phys.av.is_some(), mode) {
            (false, 0) => "gas forces (pressure)",
            (true, 0) => "gas forces (pressure + artificial viscosity)",
            (false, 1) => "gas forces (pressure, grad-h)",
            (true, 1) => "gas forces (pressure + artificial viscosity, grad-h)",
            (false, _) => "gas forces (pressure, IAD gradient)",
            (true, _) => "gas forces (pressure + artificial viscosity, IAD gradient)",
        };
        timers.time(name, || d.run(R::FORCES, self.gas.n, &a))?;
        // The drag's cell sums read the cell-mates' accelerations.
        self.ghost_sync()?;
        let l = self.d.get(&self.limits, 2)?;
        let dec = |b: u64| if b == 0 { 0.0 } else { from_ordered_bits(b) };
        Ok(Forces {
            acc: Vec::new(),
            dedt: None,
            vsig_max: dec(l[0]),
            acc_max: dec(l[1]),
        })
    }

    /// Union of occupied cells and the IDIC cell step at step size τ (velocities ṽ = v + τA).
    fn cell_step(&mut self, tau: f64, acc_zero: bool) -> Result<(), GpuError> {
        let d = &self.d;
        let p = self.params(tau)?;
        let nb = p.stride();
        if self.cells.sparse.is_some() || self.cells.union_fresh {
            return self.cell_step_on_union(tau, acc_zero);
        }
        d.zeroed(&mut self.cells.uidx, nb)?;
        let mut ua = th::UnionArgs {
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            flags: d.ptr(&self.cells.uidx),
            ukey: std::ptr::null_mut(),
            p: p.dev,
        };
        d.run(R::UNION_FLAGS, nb, &ua)?;
        d.scan(&self.cells.uidx, nb, &mut self.sums)?;
        ua.ukey = d.ptr(&self.cells.ukey);
        d.run(R::UNION_KEYS, nb - 1, &ua)?;
        self.cells.union_fresh = true;
        self.cell_step_on_union(tau, acc_zero)
    }

    /// The IDIC cell step over the union built for this layer.
    fn cell_step_on_union(&mut self, tau: f64, acc_zero: bool) -> Result<(), GpuError> {
        let d = &self.d;
        let p = self.params(tau)?;
        let ca = th::CellArgs {
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            pres: d.ptr(&self.pres),
            acc: d.ptr(if acc_zero { &self.zero_acc } else { &self.acc }),
            cells: self.cells.bufs(d),
            p: p.dev,
        };
        // The union count stays on the device: launch one thread per possible cell.
        d.run(R::CELL_STEP, self.cells.ukey.len, &ca)
    }

    /// The kernel coupling's normalisers at the current positions.
    fn coupling_norms(&self) -> Result<(), GpuError> {
        let d = &self.d;
        let c = self.coupling.as_ref().expect("kernel coupling");
        if c.per_particle_kernels {
            // Variable h: the weights' kernels at the gas particles' current h.
            let a = th::PrepArgs {
                gas: self.gas.bufs(d),
                h: d.opt(&self.sm.gas_h),
                omega: std::ptr::null_mut(),
                pres: d.ptr(&self.pres),
                kat: d.ptr(&self.sm.kat),
                pt: d.ptr(&self.sm.pt),
                p: self.params(0.0)?.dev,
            };
            d.run(R::FORCE_PREP, self.gas.n, &a)?;
        }
        for (ph, s) in [(&self.gas, &c.s_gas), (&self.dust, &c.s_dust)] {
            let a = th::NormArgs {
                gas: self.gas.bufs(d),
                ph: ph.bufs(d),
                s: d.ptr(s),
                kat: c.bufs(d, &self.sm.kat).kat,
                p: self.params(0.0)?.dev,
            };
            d.run(R::COUPLING_NORM, ph.n, &a)?;
        }
        Ok(())
    }

    /// The drag pass with the kernel coupling: normalisers, the solve on every gas particle,
    /// the increments back to the gas (from ṽ) and the dust (from ũ).
    fn kernel_coupling(&mut self, tau: f64, heat: bool) -> Result<(), StepError> {
        self.coupling_norms()?;
        // The solve weighs each neighbour by its own norm.
        self.ghost_sync()?;
        let ng = self.gas.n;
        let nf = self.dust.groups;
        let d = &self.d;
        if let Some(sums) = &mut self.coupling.as_mut().expect("kernel coupling").sums {
            d.zeroed(sums, ng * (1 + nf) * th::DEPOSIT_SLOTS)?;
        }
        let c = self.coupling.as_ref().expect("kernel coupling");
        let p = self.params(tau)?;
        let ca = th::CoupleArgs {
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            acc: d.ptr(&self.acc),
            pres: d.ptr(&self.pres),
            cb: c.bufs(d, &self.sm.kat),
            p: p.dev,
        };
        match &c.sums {
            Some(sums) => {
                for (ph, gas) in [(&self.gas, true), (&self.dust, false)] {
                    let sa = th::ScatterDepositArgs {
                        couple: ca,
                        ph: ph.bufs(d),
                        is_gas: gas as u32,
                        sums: d.ptr(sums),
                    };
                    d.run(R::COUPLING_SCATTER, ph.n, &sa)?;
                }
                let sa = th::ScatterDepositArgs {
                    couple: ca,
                    ph: self.gas.bufs(d),
                    is_gas: 1,
                    sums: d.ptr(sums),
                };
                d.run(R::COUPLING_SOLVE_SUMS, ng, &sa)?;
            }
            None => d.run(R::COUPLING_SOLVE, ng, &ca)?,
        }
        // The return reads the neighbouring gas particles' solves.
        self.ghost_sync()?;
        let d = &self.d;
        let c = self.coupling.as_ref().expect("kernel coupling");
        for (ph, gas) in [(&self.gas, true), (&self.dust, false)] {
            let ra = th::ReturnArgs {
                gas: self.gas.bufs(d),
                ph: ph.bufs(d),
                acc: if gas {
                    d.ptr(&self.acc)
                } else {
                    std::ptr::null_mut()
                },
                is_gas: gas as u32,
                cb: c.bufs(d, &self.sm.kat),
                out: std::ptr::null_mut(),
                loss: if heat {
                    d.opt(&ph.loss)
                } else {
                    std::ptr::null_mut()
                },
                p: p.dev,
            };
            d.run(R::COUPLING_RETURN, ph.n, &ra)?;
        }
        if let (true, Some(_)) = (heat, &c.heat) {
            // The heat sums the neighbours' losses.
            self.ghost_sync()?;
        }
        let d = &self.d;
        let c = self.coupling.as_ref().expect("kernel coupling");
        if let (true, Some(h)) = (heat, &c.heat) {
            let ha = th::CouplingHeatArgs {
                couple: ca,
                loss_gas: d.opt(&self.gas.loss),
                loss_dust: d.opt(&self.dust.loss),
                heat: d.ptr(h),
            };
            d.run(R::COUPLING_HEAT, ng, &ha)?;
        }
        Ok(())
    }

    fn drift(&self, ph: &DevPhase<L, R>, tau: f64) -> Result<(), GpuError> {
        ph.stale_list();
        let a = th::DriftArgs {
            ph: ph.bufs(&self.d),
            p: self.params(tau)?.dev,
        };
        self.d.run(R::DRIFT, ph.n, &a)
    }

    /// Velocity kick over `dt` from the accelerations in `acc` (A^n, or zero): ũ = u + dt·B for
    /// the dust, the drag pass over `dt` (cell or kernel coupling) and the particle velocity
    /// updates, or without dust v = v + dt·A. With `heat`, the drag heat per union cell is left
    /// in `cells.heat` for [`Self::energy_step`].
    fn kick(&mut self, timers: &mut Timers, dt: f64, heat: bool) -> Result<(), StepError> {
        // The stage names are what summary.json lists as the run's pipeline.
        let drag = self.pipe.drag;
        if self.phys.ext_dust.iter().any(|a| *a != 0.0) && self.dust.n > 0 {
            let a = th::DustAccelArgs {
                ph: self.dust.bufs(&self.d),
                p: self.params(dt)?.dev,
            };
            timers.time("external dust acceleration (ũ = u + τB)", || {
                self.d.run(R::DUST_ACCEL, self.dust.n, &a)
            })?;
        }
        if drag && self.coupling.is_some() {
            // The kernel coupling updates the velocities (and spreads the heat) itself.
            let name = if heat {
                "IDIC drag, kernel coupling (gas particles as cells) + drag heating"
            } else {
                "IDIC drag, kernel coupling (gas particles as cells)"
            };
            return timers.time(name, || self.kernel_coupling(dt, heat));
        }
        let name = match (drag, self.pipe.explicit_drag) {
            (false, _) => "gas velocities (v + τA, no dust)",
            (true, false) => "IDIC drag (cell sums, implicit cell solve, particle velocities)",
            (true, true) => "explicit drag (cell means, forward-Euler particle velocities)",
        };
        timers.time(name, || -> Result<(), GpuError> {
            if drag {
                self.cell_step(dt, false)?;
            }
            let d = &self.d;
            let p = self.params(dt)?;
            let ga = th::KickArgs {
                ph: self.gas.bufs(d),
                acc: d.ptr(&self.acc),
                drag: drag as u32,
                cells: self.cells.bufs(d),
                loss: if heat {
                    d.opt(&self.gas.loss)
                } else {
                    std::ptr::null_mut()
                },
                p: p.dev,
            };
            d.run(R::GAS_KICK, self.gas.n, &ga)?;
            if drag {
                let da = th::KickArgs {
                    ph: self.dust.bufs(d),
                    acc: std::ptr::null(),
                    loss: if heat {
                        d.opt(&self.dust.loss)
                    } else {
                        std::ptr::null_mut()
                    },
                    ..ga
                };
                d.run(R::DUST_KICK, self.dust.n, &da)?;
            }
            Ok(())
        })?;
        if drag && heat {
            let d = &self.d;
            let ha = th::HeatArgs {
                gas: self.gas.bufs(d),
                dust: self.dust.bufs(d),
                loss_gas: d.opt(&self.gas.loss),
                loss_dust: d.opt(&self.dust.loss),
                cells: self.cells.bufs(d),
                heat: d.ptr(&self.cells.heat),
                p: self.params(dt)?.dev,
            };
            timers.time("drag heating (the kinetic energy lost, to the gas)", || {
                d.run(R::HEAT, self.cells.ukey.len, &ha)
            })?;
        }
        Ok(())
    }

    /// e ← e + dt·ė (+ the drag heat left by the last [`Self::kick`] when `heat`).
    fn energy_step(&self, dt: f64, heat: bool) -> Result<(), GpuError> {
        let d = &self.d;
        if let (Some(e), Some(dedt)) = (&self.e, &self.dedt) {
            let a = th::EnergyArgs {
                gas: self.gas.bufs(d),
                e: d.ptr(e),
                dedt: d.ptr(dedt),
                heat: match (heat, &self.coupling) {
                    (false, _) => std::ptr::null_mut(),
                    (true, Some(c)) => d.opt(&c.heat),
                    (true, None) => d.ptr(&self.cells.heat),
                },
                heat_per_particle: self.coupling.is_some() as u32,
                cells: self.cells.bufs(d),
                p: self.params(dt)?.dev,
            };
            d.run(R::ENERGY, self.gas.n, &a)?;
        }
        Ok(())
    }

    /// The layer after the drift: grid rebuild and sort, `before_density`, the gas density
    /// and EOS, and the dust densities where the drag needs them every step.
    fn new_layer(
        &mut self,
        timers: &mut Timers,
        tau: f64,
        before_density: impl FnOnce(&mut Self) -> Result<(), GpuError>,
    ) -> Result<(), StepError> {
        timers.time("grid rebuild + sort", || self.regrid())?;
        before_density(self)?;
        let name = if self.pipe.variable_h {
            "gas h and density (variable h, Newton–Raphson) + EOS"
        } else if self.pipe.continuity_density {
            "gas density (continuity equation) + EOS"
        } else {
            "gas density + EOS"
        };
        timers.time(name, || self.gas_density_eos(Some(tau)))?;
        self.dust_density_fresh = false;
        if self.pipe.dust_density_each_step {
            let name = if self.pipe.variable_h {
                "dust density (variable h)"
            } else {
                "dust density"
            };
            timers.time(name, || self.dust_density())?;
        }
        // The leapfrog's predicted kick reads the cell-mates' new densities.
        self.ghost_sync()
    }

    /// Advance one step of size τ from layer n (forces already computed at layer n).
    pub fn advance(&mut self, state: &mut State, tau: f64) -> Result<(), StepError> {
        let mut timers = std::mem::take(&mut self.timers);
        let r = if self.pipe.kdk {
            self.advance_kdk(&mut timers, tau)
        } else {
            self.advance_first_order(&mut timers, tau)
        };
        self.timers = timers;
        r?;
        state.t += tau;
        state.step += 1;
        self.step = state.step;
        self.t = state.t;
        self.check(state)
    }

    fn advance_first_order(&mut self, timers: &mut Timers, tau: f64) -> Result<(), StepError> {
        // The authors' update drifts with v^n (method.md §3.3): kept aside across the kick.
        let old = self.phys.position_update == PositionUpdate::Old;
        if old {
            self.d.copy(&self.gas.v, &self.kdk.v_save, self.gas.n)?;
            self.d.copy(&self.dust.v, &self.kdk.u_save, self.dust.n)?;
        }
        let heat = self.pipe.heating && self.pipe.drag;
        self.kick(timers, tau, heat)?;
        let name = match (self.e.is_some(), old) {
            (false, false) => "positions (x + τv^{n+1})",
            (true, false) => "positions (x + τv^{n+1}) + gas energy",
            (false, true) => "positions (x + τv^n, the authors' update)",
            (true, true) => "positions (x + τv^n, the authors' update) + gas energy",
        };
        timers.time(name, || -> Result<(), GpuError> {
            if old {
                std::mem::swap(&mut self.gas.v, &mut self.kdk.v_save);
                std::mem::swap(&mut self.dust.v, &mut self.kdk.u_save);
            }
            self.drift(&self.gas, tau)?;
            self.drift(&self.dust, tau)?;
            if old {
                std::mem::swap(&mut self.gas.v, &mut self.kdk.v_save);
                std::mem::swap(&mut self.dust.v, &mut self.kdk.u_save);
            }
            self.energy_step(tau, heat)
        })?;
        self.ghost_sync()?;
        self.new_layer(timers, tau, |_| Ok(()))
    }

    /// Kick–drift–kick leapfrog, as the CPU's `advance_kdk`: half kick (forces + drag over
    /// τ/2), drift with v^{n+1/2}, the new layer with predicted e*, predicted v*, u* (a τ/2 kick
    /// with the old forces and the drag at the new layer), forces there, then the closing half
    /// kick from v^{n+1/2} with the new forces, which are kept for the next step.
    fn advance_kdk(&mut self, timers: &mut Timers, tau: f64) -> Result<(), StepError> {
        let half = 0.5 * tau;
        let heat = self.pipe.heating && self.pipe.drag;
        self.kick(timers, half, heat)?;
        let name = if self.e.is_some() {
            "leapfrog: gas energy half step + positions (x + τv^{n+1/2})"
        } else {
            "leapfrog: positions (x + τv^{n+1/2})"
        };
        timers.time(name, || -> Result<(), GpuError> {
            self.energy_step(half, heat)?;
            self.drift(&self.gas, tau)?;
            self.drift(&self.dust, tau)
        })?;
        self.ghost_sync()?;
        // The sort carries A^n and ė^n (kdk sorts them with the gas): e* = e^{n+1/2} + τ/2 ė^n
        // sets the pressure of the new layer.
        self.new_layer(timers, tau, |eng| {
            if let (Some(e), Some(save)) = (&eng.e, &eng.kdk.e_save) {
                eng.d.copy(e, save, eng.gas.n)?;
            }
            eng.energy_step(half, false)
        })?;
        let d = &self.d;
        d.copy(&self.gas.v, &self.kdk.v_save, self.gas.n)?;
        d.copy(&self.dust.v, &self.kdk.u_save, self.dust.n)?;
        // Predicted velocities v*, u* (drag included: for stiff drag the undragged prediction
        // would be off by O(1)), timed apart from the two half kicks.
        let mut pred = Timers::default();
        self.kick(&mut pred, half, false)?;
        self.ghost_sync()?;
        let t_pred: f64 = pred.entries().iter().map(|e| e.1).sum();
        timers.add(
            "leapfrog: predicted v*, u* at the new layer (half kick + drag)",
            t_pred,
        );
        self.kdk.closing = None;
        let f1 = self.compute_forces(timers)?;
        std::mem::swap(&mut self.gas.v, &mut self.kdk.v_save);
        std::mem::swap(&mut self.dust.v, &mut self.kdk.u_save);
        if let (Some(e), Some(save)) = (&mut self.e, &mut self.kdk.e_save) {
            std::mem::swap(e, save);
        }
        self.kick(timers, half, heat)?;
        if self.e.is_some() {
            timers.time("leapfrog: closing gas energy half step + EOS", || {
                self.energy_step(half, heat)?;
                self.eos()
            })?;
        }
        self.kdk.closing = Some((f1.vsig_max, f1.acc_max));
        Ok(())
    }

    /// Copy the particle state back to the host (snapshots, checkpoints, the summary).
    pub fn sync(&self, state: &mut State) -> Result<(), GpuError> {
        let d = &self.d;
        self.gas.download(d, &mut [&mut state.gas.ph])?;
        let ng = self.gas.n;
        state.gas.p = d.get_f64(&self.pres, ng)?;
        state.gas.c = d.get_f64(&self.cs, ng)?;
        if let Some(e) = &self.e {
            state.gas.e = Some(d.get_f64(e, ng)?);
        }
        if let (Some(h), Some(o)) = (&self.sm.gas_h, &self.sm.gas_omega) {
            state.gas.h = Some(d.get_f64(h, ng)?);
            state.gas.omega = Some(d.get_f64(o, ng)?);
        }
        if let (Some(_), Some(vsig)) = (self.kdk.closing, &self.kdk.vsig) {
            let acc = d.get_v3(&self.acc, ng)?;
            let dedt = match &self.dedt {
                Some(b) => d.get_f64(b, ng)?,
                None => vec![0.0; ng],
            };
            let vsig = d.get_f64(vsig, ng)?;
            state.gas.next_forces = Some(
                (0..ng)
                    .map(|i| [acc[i][0], acc[i][1], acc[i][2], dedt[i], vsig[i]])
                    .collect(),
            );
        }
        let mut dust: Vec<&mut Phase> = state.dust.iter_mut().collect();
        self.dust.download(d, &mut dust)
    }

    /// The dust densities as after a step: fresh only where the drag needs them each step. An
    /// engine built on a gathered state (rank 0's for an output over ranks) whose dust
    /// densities the ranks did not refresh then computes them before it writes them.
    pub fn dust_density_as_after_step(&mut self) {
        self.dust_density_fresh &= self.pipe.dust_density_each_step;
    }

    /// Dust densities for output (kept fresh every step only when the drag law needs them).
    pub fn refresh_dust_density(&mut self, state: &mut State) -> Result<(), StepError> {
        self.dust_density()?;
        Ok(self.sync(state)?)
    }

    /// Stopping time of every dust particle (its cell's t_k*; +∞ where uncoupled).
    pub fn dust_stopping_times(&mut self, state: &mut State) -> Result<Vec<Vec<f64>>, StepError> {
        if state.dust.is_empty() {
            return Ok(Vec::new());
        }
        self.refresh_dust_density(state)?;
        if self.coupling.is_some() {
            return Ok(self.kernel_stopping_times()?);
        }
        self.cell_step(0.0, true)?;
        let d = &self.d;
        let p = self.params(0.0)?;
        let (nb, ks) = (p.stride(), self.grid.total_cells() + 1);
        let sparse = self.cells.sparse;
        let ubidx = match sparse {
            Some(_) => Vec::new(),
            None => d.get(&self.cells.uidx, nb)?,
        };
        let nu = sparse.map_or_else(|| ubidx[nb - 1] as usize, |n| n as usize);
        let ukey = d.get(&self.cells.ukey, nu)?;
        let nf = self.dust.groups;
        let ts = d.get_f64(&self.cells.t_stop, nu * nf)?;
        let keys = d.get(&self.dust.keys, self.dust.n)?;
        let sc = p.sub_cells();
        Ok((0..nf)
            .map(|g| {
                (self.dust.off[g] as usize..self.dust.off[g + 1] as usize)
                    .map(|j| {
                        let k = keys[j] % ks;
                        let u = match sparse {
                            Some(_) => ukey.binary_search(&k).ok(),
                            None => th::union_index(&ubidx, &ukey, sc, k),
                        };
                        ts[u.expect("a dust particle's cell is occupied") * nf + g]
                    })
                    .collect()
            })
            .collect())
    }

    /// Kernel coupling: the stopping time each dust particle feels (the CPU's
    /// `kernel_stopping_times`, kernel for kernel).
    fn kernel_stopping_times(&mut self) -> Result<Vec<Vec<f64>>, GpuError> {
        self.coupling_norms()?;
        let d = &self.d;
        let c = self.coupling.as_ref().expect("kernel coupling");
        let p = self.params(0.0)?;
        let ca = th::CoupleArgs {
            gas: self.gas.bufs(d),
            dust: self.dust.bufs(d),
            acc: d.ptr(&self.zero_acc),
            pres: d.ptr(&self.pres),
            cb: c.bufs(d, &self.sm.kat),
            p: p.dev,
        };
        d.run(R::COUPLING_SOLVE, self.gas.n, &ca)?;
        let out: Buf<L, R> = d.buf(self.dust.n.max(1))?;
        let ra = th::ReturnArgs {
            gas: self.gas.bufs(d),
            ph: self.dust.bufs(d),
            acc: std::ptr::null_mut(),
            is_gas: 0,
            cb: c.bufs(d, &self.sm.kat),
            out: d.ptr(&out),
            loss: std::ptr::null_mut(),
            p: p.dev,
        };
        d.run(R::COUPLING_TSTOP, self.dust.n, &ra)?;
        let ts = d.get_f64(&out, self.dust.n)?;
        Ok((0..self.dust.groups)
            .map(|g| ts[self.dust.off[g] as usize..self.dust.off[g + 1] as usize].to_vec())
            .collect())
    }

    /// Stop on NaN/Inf or a non-positive density, naming step, phase, particle and field:
    /// the device flags the first bad particle; the host then reads the state back and
    /// words the message exactly as the CPU path does.
    fn check(&mut self, state: &mut State) -> Result<(), StepError> {
        let mut any = false;
        for (gas, rho) in [(true, true), (false, self.dust_density_fresh)] {
            let d = &self.d;
            let ph = if gas { &self.gas } else { &self.dust };
            if ph.n == 0 {
                continue;
            }
            d.put(&mut self.bad, &[u32::MAX])?;
            let a = th::CheckArgs {
                ph: ph.bufs(d),
                e: if gas {
                    d.opt(&self.e)
                } else {
                    std::ptr::null_mut()
                },
                check_rho: rho as u32,
                bad: d.ptr(&self.bad),
            };
            d.run(R::CHECK, ph.n, &a)?;
            any |= d.get(&self.bad, 1)?[0] != u32::MAX;
        }
        if any {
            self.sync(state)?;
            super::check_state(state, self.dust_density_fresh)?;
            return Err(StepError::Blowup(format!(
                "step {}: the GPU flagged a particle with a bad value",
                state.step
            )));
        }
        Ok(())
    }
}

fn fill(v: &[f64], n: usize) -> Vec<f64> {
    if v.len() == n {
        v.to_vec()
    } else {
        vec![0.0; n]
    }
}
