//! Device buffers: typed memory on a launcher, the step's parameter slots and constants, and
//! the buffer sets of the particles (per phase); the stages' own sets are in
//! `stage_buffers.rs`.
use super::*;

/// Threads per chunk of the device scan (each thread scans one chunk serially).
pub(super) const SCAN_CHUNK: usize = 512;

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
    pub(super) mem: L::Mem,
    pub(super) len: usize,
    pub(super) _t: PhantomData<T>,
    /// The engine's memory count, which this buffer's bytes leave when it is dropped.
    held: std::sync::Arc<MemoryUse>,
    bytes: usize,
}

impl<L: Launcher, T> Drop for Buf<L, T> {
    fn drop(&mut self) {
        self.held.now.fetch_sub(self.bytes, Relaxed);
    }
}

/// The device memory an engine's buffers hold now and have held at most, in bytes (the rayon
/// launcher allocates exactly what a GPU would: the device-memory estimate
/// [`DEVICE_BYTES_PER_PARTICLE`] is measured with it). A buffer grown is allocated before the
/// old one is freed: both count at that moment, as on a GPU.
#[derive(Default)]
pub(super) struct MemoryUse {
    now: std::sync::atomic::AtomicUsize,
    peak: std::sync::atomic::AtomicUsize,
}

use std::sync::atomic::Ordering::Relaxed;

impl MemoryUse {
    pub(super) fn peak(&self) -> usize {
        self.peak.load(Relaxed)
    }
}

/// A launcher with typed buffers, copies and launches over it.
pub(super) struct Device<L: Launcher> {
    pub(super) launcher: L,
    pub(super) memory: std::sync::Arc<MemoryUse>,
}

impl<L: Launcher> Device<L> {
    pub(super) fn buf<T: Copy>(&self, len: usize) -> Result<Buf<L, T>, GpuError> {
        let bytes = len * std::mem::size_of::<T>();
        let mem = self.launcher.alloc(bytes)?;
        let m = &self.memory;
        let now = m.now.fetch_add(bytes.max(1), Relaxed) + bytes.max(1);
        m.peak.fetch_max(now, Relaxed);
        Ok(Buf {
            mem,
            len,
            _t: PhantomData,
            held: m.clone(),
            bytes: bytes.max(1),
        })
    }
    // Host ↔ device copies take plain-old-data only (bytemuck::Pod: no padding, every bit
    // pattern valid); kernel-only buffers (e.g. per-particle kernels) are never copied.
    pub(super) fn from<T: Pod>(&self, data: &[T]) -> Result<Buf<L, T>, GpuError> {
        let mut b = self.buf(data.len())?;
        self.put(&mut b, data)?;
        Ok(b)
    }
    pub(super) fn put<T: Pod>(&self, b: &mut Buf<L, T>, data: &[T]) -> Result<(), GpuError> {
        assert!(data.len() <= b.len, "upload larger than the buffer");
        self.launcher.upload(&mut b.mem, bytemuck::cast_slice(data))
    }
    /// Upload into `b`, reallocating (with room to grow) only when it is too small.
    pub(super) fn put_growing<T: Pod>(
        &self,
        b: &mut Buf<L, T>,
        data: &[T],
    ) -> Result<(), GpuError> {
        if b.len < data.len() {
            *b = self.buf(data.len() + data.len() / 2)?;
        }
        self.put(b, data)
    }
    /// Upload f64 host data into a buffer of the step's precision.
    pub(super) fn upload_f64<R: Float>(&self, data: &[f64]) -> Result<Buf<L, R>, GpuError> {
        self.from(&data.iter().map(|&x| R::from_f64(x)).collect::<Vec<R>>())
    }
    pub(super) fn upload_v3<R: Float>(&self, data: &[V3]) -> Result<Buf<L, [R; 3]>, GpuError> {
        let c = |v: &V3| v.map(R::from_f64);
        self.from(&data.iter().map(c).collect::<Vec<_>>())
    }
    /// Download a buffer of the step's precision as f64 (exact; for f64 the same vector).
    pub(super) fn get_f64<R: Float>(&self, b: &Buf<L, R>, n: usize) -> Result<Vec<f64>, GpuError> {
        let mut v = Vec::new();
        self.get_f64_into(b, n, &mut v)?;
        Ok(v)
    }
    /// [`Device::get_f64`] into `out`, its allocation reused (the host copy synced after every
    /// step over ranks: no fresh pages each time).
    pub(super) fn get_f64_into<R: Float>(
        &self,
        b: &Buf<L, R>,
        n: usize,
        out: &mut Vec<f64>,
    ) -> Result<(), GpuError> {
        self.get_widened_into(b, n, out, R::to_f64)
    }
    /// [`Device::get_f64_into`] of 3-vectors.
    pub(super) fn get_v3_into<R: Float>(
        &self,
        b: &Buf<L, [R; 3]>,
        n: usize,
        out: &mut Vec<V3>,
    ) -> Result<(), GpuError> {
        self.get_widened_into(b, n, out, |v| v.map(R::to_f64))
    }
    /// Download `b` into `out` (its allocation reused), each element widened by `widen`: where
    /// the two types are one (the step in f64) the bytes go straight in.
    fn get_widened_into<S: Pod, D: Pod>(
        &self,
        b: &Buf<L, S>,
        n: usize,
        out: &mut Vec<D>,
        widen: impl Fn(S) -> D,
    ) -> Result<(), GpuError> {
        if std::any::TypeId::of::<S>() != std::any::TypeId::of::<D>() {
            let v = self.get(b, n)?;
            out.clear();
            out.extend(v.into_iter().map(widen));
            return Ok(());
        }
        assert!(n <= b.len, "download larger than the buffer");
        out.clear();
        out.resize(n, D::zeroed());
        self.launcher
            .download(&b.mem, bytemuck::cast_slice_mut(out))
    }
    pub(super) fn get_v3<R: Float>(
        &self,
        b: &Buf<L, [R; 3]>,
        n: usize,
    ) -> Result<Vec<V3>, GpuError> {
        Ok(self
            .get(b, n)?
            .into_iter()
            .map(|v| v.map(R::to_f64))
            .collect())
    }
    pub(super) fn get<T: Pod>(&self, b: &Buf<L, T>, n: usize) -> Result<Vec<T>, GpuError> {
        let mut v = Vec::new();
        self.get_into(b, n, &mut v)?;
        Ok(v)
    }
    /// [`Device::get`] into `out`, its allocation reused (a refresh's rows: no fresh pages
    /// each time).
    pub(super) fn get_into<T: Pod>(
        &self,
        b: &Buf<L, T>,
        n: usize,
        out: &mut Vec<T>,
    ) -> Result<(), GpuError> {
        assert!(n <= b.len, "download larger than the buffer");
        out.clear();
        out.resize(n, T::zeroed());
        self.launcher
            .download(&b.mem, bytemuck::cast_slice_mut(out))
    }
    pub(super) fn ptr<T>(&self, b: &Buf<L, T>) -> *mut T {
        self.launcher.addr(&b.mem) as *mut T
    }
    pub(super) fn opt<T>(&self, b: &Option<Buf<L, T>>) -> *mut T {
        b.as_ref().map_or(std::ptr::null_mut(), |b| self.ptr(b))
    }
    /// Grow `b` to at least `len` elements (contents are not kept) and zero its first `len`
    /// on the device (a memset, no host copy; allocation only when it must grow).
    pub(super) fn zeroed<T: Copy>(&self, b: &mut Buf<L, T>, len: usize) -> Result<(), GpuError> {
        if b.len < len {
            *b = self.buf(len + len / 2)?;
        } else {
            self.launcher
                .zero(&mut b.mem, len * std::mem::size_of::<T>())?;
        }
        Ok(())
    }
    pub(super) fn run<A: Copy>(&self, k: Kernel<A>, n: usize, a: &A) -> Result<(), GpuError> {
        self.launcher.launch(k, n, a)
    }

    /// dst[..n] = src[..n] (f64 or 3-vectors).
    pub(super) fn copy<T: Copy + CopyKernel>(
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
    pub(super) fn scan(
        &self,
        data: &Buf<L, u32>,
        len: usize,
        sums: &mut Buf<L, u32>,
    ) -> Result<(), GpuError> {
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
pub(super) struct LaunchParams<R> {
    pub(super) host: StepParams<R>,
    pub(super) dev: th::Params<R>,
}

impl<R> std::ops::Deref for LaunchParams<R> {
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
pub(super) struct ParamSlots<L: Launcher, R> {
    pub(super) mem: Vec<L::Mem>,
    /// (value, slot) of the most recent distinct values, newest last.
    pub(super) recent: Vec<(StepParams<R>, usize)>,
    /// Distinct values uploaded so far (the next slot is this modulo `PARAM_SLOTS`).
    pub(super) uploads: usize,
}

pub(super) const PARAM_SLOTS: usize = 256;

pub(super) const PARAM_RECENT: usize = 8;

/// One phase buffer set: gas (one group) or all dust fractions back to back.
pub(super) struct PhaseBuffers<L: Launcher, R: Float> {
    pub(super) n: usize,
    pub(super) groups: usize,
    pub(super) off: [u32; MAX_FRACTIONS + 1],
    /// Positions, f64 in every precision (`th::PhaseBufs::x`).
    pub(super) x: Buf<L, V3>,
    pub(super) v: Buf<L, [R; 3]>,
    pub(super) m: Buf<L, R>,
    pub(super) rho: Buf<L, R>,
    pub(super) fixed: Option<Buf<L, u8>>,
    pub(super) id: Buf<L, u64>,
    pub(super) keys: Buf<L, u64>,
    /// Counts, then (scanned) the dense start table over the search cells.
    pub(super) dense: Buf<L, u32>,
    /// Sparse mode: the occupied cells' combined keys (also kept on the host for the IDIC
    /// union) and their starts; `ncells` = 0 in dense mode.
    pub(super) ckeys: Buf<L, u64>,
    pub(super) cstart: Buf<L, u32>,
    pub(super) ncells: usize,
    pub(super) host_ckeys: Vec<u64>,
    pub(super) cursor: Buf<L, u32>,
    pub(super) perm: Buf<L, u32>,
    pub(super) s_v3: Buf<L, [R; 3]>,
    pub(super) s_x: Buf<L, V3>,
    pub(super) s_f64: Buf<L, R>,
    pub(super) s_u64: Buf<L, u64>,
    pub(super) s_u8: Option<Buf<L, u8>>,
    /// Kinetic energy lost in the drag update (drag heating only).
    pub(super) loss: Option<Buf<L, R>>,
    /// The neighbour list of the current layer, when this phase keeps one.
    pub(super) nl: Option<NeighbourList<L>>,
}

/// A phase's neighbour list ([`dustsph_device::kernels::NeighbourList`]): built after each
/// sort (and after the search radius widens), stale from the next drift on.
pub(super) struct NeighbourList<L: Launcher> {
    pub(super) index: Buf<L, u32>,
    pub(super) count: Buf<L, u32>,
    /// The largest neighbour count recorded since the list was allocated.
    pub(super) max: Buf<L, u32>,
    pub(super) stride: usize,
    pub(super) valid: std::cell::Cell<bool>,
}

/// The first list's slots per particle (grown to 9/8 of the largest count, in steps of 8).
pub(super) const LIST_STRIDE0: usize = 64;

/// Beyond this many neighbours per particle the phase drops its list: the pair work then
/// dominates the cell scan, and the list would cost 4 B per slot per particle.
pub(super) const LIST_STRIDE_MAX: usize = 512;

/// The most a gas particle's neighbour list takes (slots and count; CPU memory: the GPU
/// kernels are built without lists).
pub const LIST_BYTES_PER_GAS_PARTICLE: f64 = 4.0 * (LIST_STRIDE_MAX as f64 + 1.0);

impl<L: Launcher, R: Float> PhaseBuffers<L, R> {
    pub(super) fn new(
        d: &Device<L>,
        phases: &[&Phase],
        heating: bool,
    ) -> Result<PhaseBuffers<L, R>, GpuError> {
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
        Ok(PhaseBuffers {
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

    pub(super) fn bufs(&self, d: &Device<L>) -> PhaseBufs<R> {
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
    pub(super) fn stale_list(&self) {
        if let Some(l) = &self.nl {
            l.valid.set(false);
        }
    }

    /// "gas", or "dust fraction k" for particle i of the dust buffer (for messages).
    pub(super) fn phase_name(&self, gas: bool, i: usize) -> String {
        if gas {
            return "gas".into();
        }
        let g = (0..self.groups)
            .find(|&g| i < self.off[g + 1] as usize)
            .unwrap_or(0);
        format!("dust fraction {g}")
    }

    /// Download into host phases (split by group).
    pub(super) fn download(
        &self,
        d: &Device<L>,
        phases: &mut [&mut Phase],
    ) -> Result<(), GpuError> {
        if let [ph] = phases {
            // One group (the gas, or one dust fraction): straight into the phase's vectors,
            // their allocations reused.
            d.get_into(&self.x, self.n, &mut ph.x)?;
            d.get_v3_into(&self.v, self.n, &mut ph.v)?;
            d.get_f64_into(&self.m, self.n, &mut ph.m)?;
            d.get_f64_into(&self.rho, self.n, &mut ph.rho)?;
            d.get_into(&self.id, self.n, &mut ph.id)?;
            if let (Some(f), Some(_)) = (&self.fixed, &ph.fixed) {
                ph.fixed = Some(d.get(f, self.n)?.iter().map(|&b| b != 0).collect());
            }
            return Ok(());
        }
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

pub(super) fn fill(v: &[f64], n: usize) -> Vec<f64> {
    if v.len() == n {
        v.to_vec()
    } else {
        vec![0.0; n]
    }
}

/// The step's constants (f64; cast to the step's precision per launch) for a physics.
pub(super) fn step_params(
    phys: &Physics,
    stages: &Stages,
    nf: usize,
    grid: &Grid,
) -> StepParams<f64> {
    let (eos_kind, eos_value) = match phys.eos {
        Eos::Isothermal { cs } => (0, cs),
        Eos::Adiabatic { gamma } => (1, gamma),
    };
    let mut laws = [LawParam::default(); MAX_FRACTIONS];
    for (l, p) in laws.iter_mut().zip(&phys.laws) {
        *l = LawParam::from_law(p);
    }
    StepParams {
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
        kappa_alpha_ss: phys
            .av
            .and_then(|a| a.disc)
            .map_or(0.0, |d| d.kappa_alpha_ss),
        nf: nf as u32,
        needs_gas_state: phys.laws.iter().any(|l| l.needs_gas_state()) as u32,
        laws,
        ext_gas: phys.ext_gas,
        ext_dust: phys.ext_dust,
        explicit_drag: stages.explicit_drag as u32,
        damp_dispersion: (phys.damp_dispersion && phys.coupling == crate::step::Coupling::Kernel)
            as u32,
        linear_sampling: (phys.linear_sampling && phys.coupling == crate::step::Coupling::Kernel)
            as u32,
        gravity: phys.gravity,
        local_cs: phys.local_cs,
    }
}
