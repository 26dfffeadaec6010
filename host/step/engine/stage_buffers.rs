//! The buffers of the stages a scene may run: the kernel coupling's (normalisers, the pairs of
//! a layer), the IDIC cells', the leapfrog's and those of variable h and IAD; each allocated
//! only where the scene's stages use it.
use super::*;

/// The kernel coupling's buffers (docs/method.md §K): normalisers of every particle, the
/// increments and stopping times of every gas particle's means.
pub(super) struct CouplingBuffers<L: Launcher, R: Float> {
    /// Scatter form: the deposit sums of every gas particle (`th::DEPOSIT_SLOTS` per phase).
    /// f64 in every precision (see `th::ScatterDepositArgs::sums`).
    pub(super) sums: Option<Buf<L, f64>>,
    pub(super) s_gas: Buf<L, R>,
    pub(super) s_dust: Buf<L, R>,
    pub(super) dv: Buf<L, [R; 3]>,
    pub(super) du: Buf<L, [R; 3]>,
    pub(super) t_stop: Buf<L, R>,
    /// Drag heating: the heat per unit mass of every gas particle.
    pub(super) heat: Option<Buf<L, R>>,
    /// `idic.dispersion = "damped"`: V^{n+1}, U^{n+1}, the gas's deviations, the dust's losses
    /// (`th::CouplingBufs`).
    pub(super) damping: Option<[Buf<L, [R; 3]>; 4]>,
    /// The damping's gradients (`th::CouplingBufs::grad`), with linear sampling.
    pub(super) grad: Option<Buf<L, [R; 3]>>,
    /// Variable h: the weights use each gas particle's kernel (the engine's `sm.kernel_at`).
    pub(super) per_particle_kernels: bool,
    /// The pairs of this layer (`th::PairBufs`).
    pub(super) pairs: PairBuffers<L, R>,
}

/// The kernel coupling's pairs of one layer (`th::PairBufs`, docs/method.md §K): the return
/// rows, `cap` slots per particle (gas, then dust), and the deposit rows, compact.
pub(super) struct PairBuffers<L: Launcher, R: Float> {
    pub(super) ret_idx: Buf<L, u32>,
    pub(super) ret_w: Buf<L, R>,
    pub(super) ret_cnt: Buf<L, u32>,
    /// Slots per return row: 0 until the first layer's rows are counted, then 9/8 of the
    /// longest row seen (in steps of 8).
    pub(super) cap: usize,
    pub(super) ret_max: Buf<L, u32>,
    pub(super) dep_off: Buf<L, u32>,
    pub(super) dep_cur: Buf<L, u32>,
    pub(super) dep_idx: Buf<L, u32>,
    pub(super) dep_w: Buf<L, R>,
    /// The chunked transposition's counters (`th::DepositRowsArgs::counts`).
    pub(super) dep_counts: Buf<L, u32>,
    /// The pairs of the last layer (the deposit rows' entries).
    pub(super) pairs: usize,
    /// The deposit rows belong to the current return rows (built once per layer, after the
    /// normalisers' refresh).
    pub(super) deposits_fresh: bool,
}

impl<L: Launcher, R: Float> PairBuffers<L, R> {
    fn new(d: &Device<L>, ng: usize, nd: usize) -> Result<Self, GpuError> {
        Ok(PairBuffers {
            ret_idx: d.buf(1)?,
            ret_w: d.buf(1)?,
            ret_cnt: d.buf((ng + nd).max(1))?,
            cap: 0,
            ret_max: d.buf(1)?,
            dep_off: d.buf(1)?,
            dep_cur: d.buf(1)?,
            dep_idx: d.buf(1)?,
            dep_w: d.buf(1)?,
            dep_counts: d.buf(1)?,
            pairs: 0,
            deposits_fresh: false,
        })
    }

    pub(super) fn bufs(&self, d: &Device<L>) -> th::PairBufs<R> {
        th::PairBufs {
            ret_idx: d.ptr(&self.ret_idx),
            ret_w: d.ptr(&self.ret_w),
            ret_cnt: d.ptr(&self.ret_cnt),
            cap: self.cap as u32,
            ret_max: d.ptr(&self.ret_max),
            dep_off: d.ptr(&self.dep_off),
            dep_cur: d.ptr(&self.dep_cur),
            dep_idx: d.ptr(&self.dep_idx),
            dep_w: d.ptr(&self.dep_w),
        }
    }
}

impl<L: Launcher, R: Float> CouplingBuffers<L, R> {
    /// `kernel_at`: the engine's per-gas-particle kernels (used with variable h).
    pub(super) fn bufs(
        &self,
        d: &Device<L>,
        kernel_at: &Buf<L, KernelAt<R>>,
    ) -> th::CouplingBufs<R> {
        th::CouplingBufs {
            s_gas: d.ptr(&self.s_gas),
            s_dust: d.ptr(&self.s_dust),
            dv: d.ptr(&self.dv),
            du: d.ptr(&self.du),
            t_stop: d.ptr(&self.t_stop),
            v_new: self
                .damping
                .as_ref()
                .map_or(std::ptr::null_mut(), |b| d.ptr(&b[0])),
            u_new: self
                .damping
                .as_ref()
                .map_or(std::ptr::null_mut(), |b| d.ptr(&b[1])),
            gas_dev: self
                .damping
                .as_ref()
                .map_or(std::ptr::null_mut(), |b| d.ptr(&b[2])),
            react: self
                .damping
                .as_ref()
                .map_or(std::ptr::null_mut(), |b| d.ptr(&b[3])),
            grad: self
                .grad
                .as_ref()
                .map_or(std::ptr::null_mut(), |b| d.ptr(b)),
            kernel_at: if self.per_particle_kernels {
                d.ptr(kernel_at)
            } else {
                std::ptr::null()
            },
            // The engine sets it where it has ghosts (`Engine::coupling_bufs`).
            gas_skip: std::ptr::null(),
            pairs: self.pairs.bufs(d),
        }
    }
}

/// Per union cell results of the IDIC cell step.
pub(super) struct CellBuffers<L: Launcher, R: Float> {
    pub(super) uidx: Buf<L, u32>,
    pub(super) ukey: Buf<L, u64>,
    pub(super) gas_mass: Buf<L, R>,
    pub(super) v_new: Buf<L, [R; 3]>,
    pub(super) eps: Buf<L, R>,
    pub(super) beta: Buf<L, R>,
    pub(super) t_stop: Buf<L, R>,
    pub(super) u_new: Buf<L, [R; 3]>,
    pub(super) heat: Buf<L, R>,
    /// Per union cell, whether it holds a particle of this rank's own (`th::CellBufs::mine`).
    pub(super) mine: Buf<L, u8>,
    /// Sparse mode: the union was built at the sort (its size); `None`: dense, built by the
    /// union kernels.
    pub(super) sparse: Option<u32>,
    /// The dense union matches the current sort (it depends on the positions only: built once
    /// per layer, not once per kick).
    pub(super) union_fresh: bool,
}

impl<L: Launcher, R: Float> CellBuffers<L, R> {
    pub(super) fn bufs(&self, d: &Device<L>) -> th::CellBufs<R> {
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
            mine: d.ptr(&self.mine),
        }
    }
}

/// The leapfrog's state: the closing forces' maxima (the forces stay in `acc`, `dedt`, `vsig`)
/// and the half-step values kept across the predictor.
pub(super) struct LeapfrogBuffers<L: Launcher, R: Float> {
    pub(super) closing: Option<Forces>,
    pub(super) vsig: Option<Buf<L, R>>,
    pub(super) v_save: Buf<L, [R; 3]>,
    pub(super) u_save: Buf<L, [R; 3]>,
    pub(super) e_save: Option<Buf<L, R>>,
}

/// Buffers of variable h and of the IAD gradient (empty when the scene uses neither).
pub(super) struct SmoothingBuffers<L: Launcher, R: Float> {
    /// h and Ω of every gas particle (variable h; carried by the sort).
    pub(super) gas_h: Option<Buf<L, R>>,
    pub(super) gas_omega: Option<Buf<L, R>>,
    /// The solve's outputs (swapped in on success) and its iteration counts.
    pub(super) h_new: Buf<L, R>,
    pub(super) omega_new: Buf<L, R>,
    pub(super) iters: Buf<L, u32>,
    /// Per gas particle: kernel constants and pressure term (variable h or IAD), IAD matrix.
    pub(super) kernel_at: Buf<L, KernelAt<R>>,
    pub(super) pt: Buf<L, R>,
    pub(super) iad: Buf<L, Sym3<R>>,
    pub(super) hmax: Buf<L, u64>,
}

impl<L: Launcher, R: Float> CellBuffers<L, R> {
    /// Room for `cap` union cells of `nf` fractions.
    pub(super) fn new(d: &Device<L>, cap: usize, nf: usize) -> Result<Self, GpuError> {
        Ok(CellBuffers {
            uidx: d.buf(1)?,
            ukey: d.buf(cap)?,
            gas_mass: d.buf(cap)?,
            v_new: d.buf(cap)?,
            eps: d.buf(cap * nf.max(1))?,
            beta: d.buf(cap * nf.max(1))?,
            t_stop: d.buf(cap * nf.max(1))?,
            u_new: d.buf(cap * nf.max(1))?,
            heat: d.buf(cap)?,
            mine: d.buf(cap)?,
            sparse: None,
            union_fresh: false,
        })
    }
}

impl<L: Launcher, R: Float> CouplingBuffers<L, R> {
    /// The kernel coupling's buffers for `ng` gas and `nd` dust particles of `nf` fractions
    /// (`None` without the kernel coupling).
    pub(super) fn new(
        d: &Device<L>,
        phys: &Physics,
        stages: &Stages,
        ng: usize,
        nd: usize,
        nf: usize,
    ) -> Result<Option<Self>, GpuError> {
        if !stages.kernel_coupling {
            return Ok(None);
        }
        Ok(Some(CouplingBuffers {
            sums: if phys.deposit_scatter {
                Some(d.buf((ng * (1 + nf) * th::DEPOSIT_SLOTS).max(1))?)
            } else {
                None
            },
            s_gas: d.buf(ng.max(1))?,
            s_dust: d.buf(nd.max(1))?,
            dv: d.buf(ng.max(1))?,
            du: d.buf((ng * nf).max(1))?,
            t_stop: d.buf((ng * nf).max(1))?,
            heat: if stages.heating {
                Some(d.buf(ng.max(1))?)
            } else {
                None
            },
            damping: if phys.damp_dispersion {
                Some([
                    d.buf(ng.max(1))?,
                    d.buf((ng * nf).max(1))?,
                    d.buf(ng.max(1))?,
                    d.buf(nd.max(1))?,
                ])
            } else {
                None
            },
            grad: if phys.damp_dispersion && phys.linear_sampling {
                Some(d.buf((3 * ng).max(1))?)
            } else {
                None
            },
            per_particle_kernels: stages.variable_h,
            pairs: PairBuffers::new(d, ng, nd)?,
        }))
    }
}

impl<L: Launcher, R: Float> LeapfrogBuffers<L, R> {
    /// The leapfrog's buffers (the saved velocities also serve the authors' position update);
    /// `rows`: a resumed leapfrog run's closing forces (A, ė, v_sig per gas particle).
    pub(super) fn new(
        d: &Device<L>,
        phys: &Physics,
        stages: &Stages,
        rows: Option<&[crate::particles::ClosingForces]>,
        (gas_h, gas_fixed): (Option<&[f64]>, Option<&[bool]>),
        ng: usize,
        nd: usize,
    ) -> Result<Self, GpuError> {
        let k = stages.kdk;
        let save = k || phys.position_update == PositionUpdate::Old;
        let own_h = gas_h.filter(|_| stages.variable_h).map(|hs| (phys.h, hs));
        let closing = rows.map(|r| Forces::from_rows(r, own_h, gas_fixed));
        let vsig = rows.map(|r| r.iter().map(|x| x.vsig).collect::<Vec<f64>>());
        Ok(LeapfrogBuffers {
            closing,
            vsig: if k {
                Some(match vsig {
                    Some(c) => d.upload_f64(&c)?,
                    None => d.buf(ng.max(1))?,
                })
            } else {
                None
            },
            v_save: d.buf(if save { ng.max(1) } else { 1 })?,
            u_save: d.buf(if save { nd.max(1) } else { 1 })?,
            e_save: if k && stages.energy {
                Some(d.buf(ng.max(1))?)
            } else {
                None
            },
        })
    }
}

impl<L: Launcher, R: Float> SmoothingBuffers<L, R> {
    /// Variable h's and IAD's buffers; a resumed variable-h state's h and Ω are kept as they
    /// are.
    pub(super) fn new(
        d: &Device<L>,
        stages: &Stages,
        g: &crate::particles::Gas,
        ng: usize,
        nd: usize,
    ) -> Result<Self, GpuError> {
        let vh = stages.variable_h;
        let resumed = vh && g.h.is_some() && g.omega.is_some();
        let per_gas = if vh || stages.iad { ng.max(1) } else { 1 };
        let solve = if vh { ng.max(nd).max(1) } else { 1 };
        let kept = |v: &Option<Vec<f64>>| -> Result<Option<Buf<L, R>>, GpuError> {
            match (resumed, v) {
                (true, Some(v)) => Ok(Some(d.upload_f64(v)?)),
                _ => Ok(None),
            }
        };
        Ok(SmoothingBuffers {
            gas_h: kept(&g.h)?,
            gas_omega: kept(&g.omega)?,
            h_new: d.buf(solve)?,
            omega_new: d.buf(solve)?,
            iters: d.buf(solve)?,
            kernel_at: d.buf(per_gas)?,
            pt: d.buf(per_gas)?,
            iad: d.buf(if stages.iad { ng.max(1) } else { 1 })?,
            hmax: d.buf(1)?,
        })
    }
}
