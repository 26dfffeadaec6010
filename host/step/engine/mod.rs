//! The engine: the whole step as kernel launches over particle buffers resident on a launcher
//! (a CUDA GPU, or this machine's cores through rayon running the same thread functions).
//!
//! One step (method.md §3.6): the gas forces at layer n ([`forces`]), the velocity kick with
//! the implicit drag ([`drag`]), the drift and the energy, the new layer — grid rebuild and sort
//! ([`sort`]), densities and EOS ([`density`]) — and the check; [`integrate`] is that sequence,
//! for the first-order step and the leapfrog. Over MPI ranks [`halo`] refreshes the ghost
//! particles between the passes. The host reads back only a few numbers per step (the
//! time-step maxima, the grid's bounds, one failure flag); particle arrays come back for
//! snapshots, checkpoints and the summary.
mod buffers;
mod density;
mod drag;
mod forces;
mod halo;
mod integrate;
mod sort;
mod stage_buffers;

use super::timers::Timers;
use super::{Forces, Momentum, Physics, Stages, StepError};
use crate::grid::{merge_bounds, Grid, EMPTY_BOUNDS};
use crate::launch::{GpuError, Launcher};
use crate::particles::{ClosingForces, Phase, State};
use crate::scene::{ListChoice, PositionUpdate};
use buffers::*;
use bytemuck::Pod;
use dustsph_device::eos::Eos;
use dustsph_device::kernel::{KernelAt, SUPPORT};
use dustsph_device::kernel_table::{self as kt, FloatKernels, Kernel};
use dustsph_device::kernels::{from_ordered_bits, MAX_FRACTIONS};
use dustsph_device::sph::Sym3;
use dustsph_device::threads::{self as th, LawParam, PhaseBufs, StepParams};
use dustsph_device::Real;
use rayon::prelude::*;
use stage_buffers::*;
use std::marker::PhantomData;

pub use buffers::{Float, LIST_BYTES_PER_GAS_PARTICLE};
pub use halo::{GhostSync, OwnedMotion};
use halo::{Ghosts, Refresh};

/// Device memory a run needs per particle (gas or dust), by precision: measured with the rayon
/// launcher, which allocates the very buffers a GPU does (`tests/launch.rs`,
/// `device_memory_estimate_bounds_what_the_engine_allocates`: the most the buffers hold at
/// once, at most 407 B (f64) and 248 B (f32) per particle over the parity scenes without the
/// kernel coupling's pairs after three steps, explicit drag the largest), with a margin for the
/// dense tables of sparser clouds. Without neighbour lists (the GPU kernels have none).
pub const DEVICE_BYTES_PER_PARTICLE: [f64; 2] = [700.0, 420.0];

type V3 = [f64; 3];

/// Device memory the kernel coupling takes per pair (a particle and a gas particle within
/// reach): its slot in the return rows (u32 index + W) and its deposit entry (u32 index + w),
/// with the 1/8 of slack both are allocated with; f64, f32. Measured with the per-particle
/// figure ([`device_bytes_estimate`], `tests/launch.rs`).
pub const COUPLING_BYTES_PER_PAIR: [f64; 2] = [2.0 * 12.0 * 1.125, 2.0 * 8.0 * 1.125];

/// The kernel coupling's pairs, estimated before a run: every particle (gas or dust) has the
/// gas's neighbour number within reach — (2 hfact)^d times the unit ball's volume with
/// variable h, the gas's mean number density (ρ/m, or over its bounding box) times the
/// support's volume with a fixed h — and a third more for the uneven (0 without the kernel
/// coupling).
pub fn coupling_pairs_estimate(phys: &Physics, state: &State) -> f64 {
    if phys.coupling != crate::step::Coupling::Kernel || state.dust.is_empty() {
        return 0.0;
    }
    let d = phys.dim as i32;
    let ball = match d {
        1 => 2.0,
        2 => std::f64::consts::PI,
        _ => 4.0 / 3.0 * std::f64::consts::PI,
    };
    let g = &state.gas.ph.x;
    let neighbours = match phys.variable_h {
        Some(hfact) => ball * (SUPPORT * hfact).powi(d),
        None => {
            // The gas's number density: ρ/m where the state has densities (a concentrated
            // cloud, e.g. the ball, is denser than its bounding box says), else the box's.
            let ph = &state.gas.ph;
            let number = if ph.rho.len() == g.len() && ph.rho.iter().all(|r| *r > 0.0) {
                let sum: f64 = (ph.rho.iter().zip(&ph.m)).map(|(r, m)| r / m).sum();
                sum / g.len().max(1) as f64
            } else {
                let mut vol = 1.0;
                for k in 0..phys.dim as usize {
                    let lo = g.iter().map(|x| x[k]).fold(f64::INFINITY, f64::min);
                    let hi = g.iter().map(|x| x[k]).fold(f64::NEG_INFINITY, f64::max);
                    vol *= (hi - lo).max(phys.h);
                }
                g.len() as f64 / vol
            };
            number * ball * (SUPPORT * phys.h).powi(d)
        }
    };
    let n = g.len() + state.dust.iter().map(|p| p.x.len()).sum::<usize>();
    4.0 / 3.0 * neighbours * n as f64
}

/// Device memory a run of `state` takes, estimated before it starts: the particles'
/// ([`DEVICE_BYTES_PER_PARTICLE`]) and the kernel coupling's pairs
/// ([`COUPLING_BYTES_PER_PAIR`], [`coupling_pairs_estimate`]).
pub fn device_bytes_estimate(phys: &Physics, state: &State, f32: bool) -> f64 {
    let n = state.gas.ph.x.len() + state.dust.iter().map(|d| d.x.len()).sum::<usize>();
    n as f64 * DEVICE_BYTES_PER_PARTICLE[f32 as usize]
        + coupling_pairs_estimate(phys, state) * COUPLING_BYTES_PER_PAIR[f32 as usize]
}

pub struct Engine<L: Launcher, R: Float> {
    pub phys: Physics,
    pub stages: Stages,
    pub timers: Timers,
    d: Device<L>,
    /// The step's constants, in f64 (cast to the step's precision per launch).
    base: StepParams<f64>,
    grid: Grid,
    gas: PhaseBuffers<L, R>,
    dust: PhaseBuffers<L, R>,
    pres: Buf<L, R>,
    cs: Buf<L, R>,
    e: Option<Buf<L, R>>,
    acc: Buf<L, [R; 3]>,
    zero_acc: Buf<L, [R; 3]>,
    dedt: Option<Buf<L, R>>,
    cells: CellBuffers<L, R>,
    /// Kernel coupling (`idic.coupling = "kernel"`): its per-particle buffers.
    coupling: Option<CouplingBuffers<L, R>>,
    sums: Buf<L, u32>,
    limits: Buf<L, u64>,
    bounds: Buf<L, u64>,
    bad: Buf<L, u32>,
    /// This step has rebuilt the grid and sorted the particles (the halo check then compares
    /// only the fields the sort carries).
    resorted: bool,
    /// The kernel coupling's normalisers belong to the current positions and h (they are
    /// computed once per layer: the leapfrog's last two drag passes and the next step's first
    /// share a layer).
    norms_fresh: bool,
    /// Per phase (gas, dust), 1 where the normaliser of this layer was given
    /// ([`Engine::keep_norms`]): the next normalisers' pass computes only the others.
    norms_kept: [Option<Buf<L, u8>>; 2],
    /// The momentum sums of each chunk of particles ([`Engine::momentum`]).
    chunk_sums: Buf<L, f64>,
    dust_density_fresh: bool,
    /// The state's step count and time (for messages).
    step: u64,
    t: f64,
    /// Always use the sparse cell tables (checks that both forms give the same step).
    pub force_sparse: bool,
    /// The gas keeps a neighbour list per layer (`numerics.neighbour_list`).
    lists: bool,
    /// Variable h and IAD (`sph.variable_h`, `sph.gradient = "iad"`).
    sm: SmoothingBuffers<L, R>,
    /// The leapfrog (`time.integrator = "kdk"`).
    kdk: LeapfrogBuffers<L, R>,
    params: std::cell::RefCell<ParamSlots<L, R>>,
    /// Over MPI ranks with a thin halo: the ghost particles and their refresh.
    ghosts: Option<Ghosts<L>>,
}

/// Phantom's tolerance of the h solve.
const H_TOL: f64 = 1e-4;

/// The support 2h the gas's densities in `state` give its largest h (h = hfact (m/ρ)^(1/d)),
/// with a tenth to spare, at most 8× the median h's; 0 where a density is missing or not
/// positive, or h is fixed.
fn density_support(state: &State, phys: &Physics) -> f64 {
    let (Some(hfact), g) = (phys.variable_h, &state.gas.ph) else {
        return 0.0;
    };
    if g.rho.len() != g.m.len() || !g.rho.iter().all(|r| *r > 0.0 && r.is_finite()) {
        return 0.0;
    }
    let dim = phys.dim;
    let mut h: Vec<f64> = (g.m.iter().zip(&g.rho))
        .map(|(&m, &r)| dustsph_device::kernel::h_of_density(m, r, hfact, dim, phys.h))
        .collect();
    if h.is_empty() {
        return 0.0;
    }
    h.sort_by(f64::total_cmp);
    // At most 8× the median's: a stray density (a file's) must not make every particle walk
    // the whole cloud; beyond it the solve's own growth takes over.
    1.1 * SUPPORT * h[h.len() - 1].min(8.0 * h[h.len() / 2])
}

/// The dust's h solve when its density is computed only for an output: converged to
/// round-off (a correction below 1e-8 leaves an error of order 1e-16 after Newton's quadratic
/// step), so that it does not depend on its warm start, i.e. on when the previous output was
/// written (at `H_TOL` the dust density moved with the output cadence by ≈3e-10; a run over MPI
/// ranks, which refreshes it every step, then differed from one process by as much).
const H_TOL_OUTPUT: f64 = 1e-8;

/// Where an engine's first layer (densities, pressures, sound speeds) comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InitialLayer {
    /// Computed from the positions (a run's start, a resume).
    Compute,
    /// The state's own: it was stepped by this code and its densities are exact (a rank's
    /// engine rebuilt on particles their owners stepped).
    FromState,
}

impl From<GpuError> for StepError {
    fn from(e: GpuError) -> Self {
        StepError::Blowup(format!("GPU: {e}"))
    }
}

impl<L: Launcher, R: Float> Engine<L, R> {
    /// Upload the state, sort it, and compute densities and pressures at the initial layer.
    /// The host `state` is then sorted the same way (particle order is the engine's cell order).
    pub fn new(phys: Physics, state: &mut State, launcher: L) -> Result<Engine<L, R>, StepError> {
        Self::with_layer(phys, state, launcher, InitialLayer::Compute)
    }

    /// As [`Engine::new`]; with [`InitialLayer::FromState`] the state's densities, pressures and sound
    /// speeds are its layer's (a rank over MPI builds its engine, at a new halo, on particles that
    /// their owners stepped): the gas's summation density is not redone, and the dust's only
    /// where its drag needs it each step (and then it is the state's too).
    pub fn with_layer(
        phys: Physics,
        state: &mut State,
        launcher: L,
        layer: InitialLayer,
    ) -> Result<Engine<L, R>, StepError> {
        let stages = Stages::from_physics(&phys);
        let nf = state.dust.len();
        if nf > MAX_FRACTIONS {
            return Err(StepError::Unsupported(format!(
                "{nf} dust fractions: the kernels support at most {MAX_FRACTIONS}"
            )));
        }
        let d = Device {
            launcher,
            memory: Default::default(),
        };
        let grid = Grid::build(&phys.domain, phys.cell_size, phys.support(), &[])?;
        let base = step_params(&phys, &stages, nf, &grid);
        let heating = stages.heating;
        let gas = PhaseBuffers::new(&d, &[&state.gas.ph], heating)?;
        let dust_refs: Vec<&Phase> = state.dust.iter().collect();
        let dust = PhaseBuffers::new(&d, &dust_refs, heating)?;
        let ng = gas.n;
        let cap = (gas.n + dust.n).max(1);
        let g = &state.gas;
        // A resumed leapfrog run carries its closing forces: the first step starts from them.
        let rows = g
            .closing_forces
            .as_deref()
            .filter(|r| stages.kdk && r.len() == ng);
        let dedt = rows.map(|r| r.iter().map(|x| x.dedt).collect::<Vec<f64>>());
        let mut eng = Engine {
            pres: d.upload_f64(&fill(&g.p, ng))?,
            cs: d.upload_f64(&fill(&g.c, ng))?,
            e: g.e.as_deref().map(|e| d.upload_f64(e)).transpose()?,
            acc: match rows {
                Some(r) => d.upload_v3(&r.iter().map(|x| x.acc).collect::<Vec<V3>>())?,
                None => d.buf(ng)?,
            },
            zero_acc: d.buf(ng)?,
            dedt: match (stages.energy, dedt) {
                (false, _) => None,
                (true, Some(c)) => Some(d.upload_f64(&c)?),
                (true, None) => Some(d.buf(ng)?),
            },
            cells: CellBuffers::new(&d, cap, nf)?,
            coupling: CouplingBuffers::new(&d, &phys, &stages, ng, dust.n, nf)?,
            sums: d.buf(1)?,
            limits: d.buf(3)?,
            bounds: d.buf(6)?,
            bad: d.buf(1)?,
            chunk_sums: d.buf(1)?,
            resorted: false,
            norms_fresh: false,
            norms_kept: [None, None],
            step: state.step,
            t: state.t,
            force_sparse: false,
            lists: match phys.neighbour_list {
                ListChoice::On => true,
                ListChoice::Off => false,
                ListChoice::Auto => d.launcher.lists_by_default(),
            },
            kdk: LeapfrogBuffers::new(
                &d,
                &phys,
                &stages,
                rows,
                (g.h.as_deref(), g.ph.fixed.as_deref()),
                ng,
                dust.n,
            )?,
            sm: SmoothingBuffers::new(&d, &stages, g, ng, dust.n)?,
            phys,
            stages,
            timers: Timers::synchronised(d.launcher.sync_hook()),
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
        if let Some(f) = &mut eng.kdk.closing {
            // The rows hold no damping rate: the closing layer's, from its positions as the
            // forces kernels take it (the particles not held fixed).
            let pm = &eng.phys.gravity;
            let gas = moving_positions(&state.gas.ph);
            let dust = state.dust.iter().flat_map(moving_positions);
            f.damp_rate_max = gas
                .chain(dust.clone())
                .map(|x| pm.damp_rate(*x))
                .fold(0.0, f64::max);
            // Nor the grains' pull, which the forces pass adds to the force limit (the rows are
            // the gas's): from their positions as its kernel takes them.
            if pm.is_on() {
                let ext = eng.phys.ext_dust;
                let pull = dust.map(|x| dustsph_device::timestep::dust_pull(pm, ext, *x));
                f.acc_max = pull.fold(f.acc_max, f64::max);
            }
        }
        eng.first_layer(state, layer)?;
        Ok(eng)
    }

    /// The first layer: the grid and sort, the gas density (or the state's: see
    /// [`InitialLayer`]) and EOS, the dust densities, the host state brought up to date and
    /// checked.
    fn first_layer(&mut self, state: &mut State, layer: InitialLayer) -> Result<(), StepError> {
        self.regrid()?;
        let given = layer == InitialLayer::FromState;
        if self.stages.variable_h && self.sm.gas_h.is_none() {
            // The first h solve's search radius from the state's densities (a set-up's or a
            // file's): a disc's thin edges and surface need h several times the reference, which
            // the solve otherwise reaches by a dozen failed attempts over a growing radius
            // (method.md §D). Only the reach grows, not the cells: the same keys and order, so
            // the same h to the bit.
            let reach = density_support(state, &self.phys);
            if reach > self.grid.geom.support {
                self.grid = self.grid.with_support(reach);
            }
        }
        if given && !self.stages.variable_h {
            // Summation or continuity density: ρ is the state's; only p and c_s from it.
            self.eos()?;
        } else {
            self.gas_density_eos(None)?;
        }
        // A resumed variable-h run keeps its dust densities too: the next solve starts from
        // them (as the uninterrupted run's does), so the resume stays bit-identical.
        let g = &state.gas;
        let dust_rho_valid = state
            .dust
            .iter()
            .all(|d| d.rho.len() == d.len() && d.rho.iter().all(|r| *r > 0.0 && r.is_finite()));
        self.dust_density_fresh = if given {
            self.stages.dust_density_each_step && dust_rho_valid
        } else {
            self.stages.variable_h && g.h.is_some() && g.omega.is_some() && dust_rho_valid
        };
        if !given || self.stages.dust_density_each_step {
            self.dust_density()?;
        }
        self.sync(state)?;
        self.check(state)
    }

    /// The launcher, and the kernel coupling's pairs at the last layer with the memory their
    /// rows hold (once it has found some).
    pub fn describe(&self) -> String {
        let mut s = self.d.launcher.describe();
        if let Some(p) = self
            .coupling
            .as_ref()
            .map(|c| &c.pairs)
            .filter(|p| p.pairs > 0)
        {
            let bytes = (p.ret_idx.len + p.dep_idx.len + p.ret_cnt.len + 2 * p.dep_off.len) * 4
                + (p.ret_w.len + p.dep_w.len) * std::mem::size_of::<R>();
            s += &format!(
                "; kernel coupling: {} particle–gas pairs at the last layer, {:.1} MB of rows \
                 ({} return slots per particle)",
                p.pairs,
                bytes as f64 / 1e6,
                p.cap
            );
        }
        s
    }

    /// The most device memory the engine's buffers have held at once, in bytes (a buffer
    /// grown counts with the one it replaces).
    pub fn device_bytes(&self) -> usize {
        self.d.memory.peak()
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
    fn params(&self, tau: f64) -> Result<LaunchParams<R>, GpuError> {
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
        Ok(LaunchParams { host, dev })
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

    /// The total momentum and its scale Σ m|v| of every particle, by a reduction on the
    /// launcher, without downloading the particles.
    pub fn momentum(&mut self) -> Result<Momentum, GpuError> {
        let mut m = Momentum {
            p: [0.0; 3],
            scale: 0.0,
            l: [0.0; 3],
            inside: 0,
        };
        for c in self.diagnostic_sums()? {
            for k in 0..3 {
                m.p[k] += c[k];
                m.l[k] += c[4 + k];
            }
            m.scale += c[3];
            m.inside += c[7] as usize;
        }
        Ok(m)
    }

    /// The ball's Lagrange–Jacobi terms (I, 2Σm|v|² + 2dΣm p/ρ) over every particle
    /// (method.md §6.1; `analysis::ball::lagrange_jacobi_terms` on the host), by the same
    /// reduction, without downloading the particles.
    pub fn lagrange_jacobi(&mut self, dim: u32) -> Result<(f64, f64), GpuError> {
        let (mut i, mut ke2, mut pv) = (0.0, 0.0, 0.0);
        for c in self.diagnostic_sums()? {
            i += c[8];
            ke2 += c[9];
            pv += c[10];
        }
        Ok((i, ke2 + 2.0 * dim as f64 * pv))
    }

    /// The momentum kernel's sums per chunk of 256 particles, gas then dust, in particle
    /// order: added in this order, the same on every launcher and thread count.
    fn diagnostic_sums(&mut self) -> Result<Vec<[f64; th::MOMENTUM_SUMS]>, GpuError> {
        /// Particles per thread of the reduction.
        const CHUNK: usize = 256;
        const S: usize = th::MOMENTUM_SUMS;
        let r_acc = self.phys.accretion_radius;
        let mut out = Vec::new();
        for gas in [true, false] {
            let ph = if gas { &self.gas } else { &self.dust };
            if ph.n == 0 {
                continue;
            }
            let threads = ph.n.div_ceil(CHUNK);
            let d = &self.d;
            d.zeroed(&mut self.chunk_sums, S * threads)?;
            let ph = if gas { &self.gas } else { &self.dust };
            let a = th::MomentumArgs {
                ph: ph.bufs(d),
                chunk: CHUNK as u32,
                centre: self.phys.gravity.pos,
                r_acc2: r_acc * r_acc,
                p: if gas {
                    d.ptr(&self.pres).cast_const()
                } else {
                    std::ptr::null()
                },
                out: d.ptr(&self.chunk_sums),
            };
            d.run(R::MOMENTUM, threads, &a)?;
            for c in d.get(&self.chunk_sums, S * threads)?.chunks_exact(S) {
                out.push(c.try_into().expect("S sums"));
            }
        }
        Ok(out)
    }

    /// Copy the particle state back to the host (snapshots, checkpoints, the summary).
    pub fn sync(&self, state: &mut State) -> Result<(), GpuError> {
        let d = &self.d;
        self.gas.download(d, &mut [&mut state.gas.ph])?;
        let ng = self.gas.n;
        // Into the state's vectors, their allocations reused.
        d.get_f64_into(&self.pres, ng, &mut state.gas.p)?;
        d.get_f64_into(&self.cs, ng, &mut state.gas.c)?;
        if let Some(e) = &self.e {
            d.get_f64_into(e, ng, state.gas.e.get_or_insert_with(Vec::new))?;
        }
        if let (Some(h), Some(o)) = (&self.sm.gas_h, &self.sm.gas_omega) {
            d.get_f64_into(h, ng, state.gas.h.get_or_insert_with(Vec::new))?;
            d.get_f64_into(o, ng, state.gas.omega.get_or_insert_with(Vec::new))?;
        }
        if let (Some(_), Some(vsig)) = (self.kdk.closing, &self.kdk.vsig) {
            let acc = d.get_v3(&self.acc, ng)?;
            let dedt = match &self.dedt {
                Some(b) => d.get_f64(b, ng)?,
                None => vec![0.0; ng],
            };
            let vsig = d.get_f64(vsig, ng)?;
            state.gas.closing_forces = Some(
                (0..ng)
                    .map(|i| ClosingForces {
                        acc: acc[i],
                        dedt: dedt[i],
                        vsig: vsig[i],
                    })
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
        self.dust_density_fresh &= self.stages.dust_density_each_step;
    }

    /// Dust densities for output (kept fresh every step only when the drag law needs them).
    /// Over ranks the ghosts' then come from their owners (collective).
    pub fn refresh_dust_density(&mut self, state: &mut State) -> Result<(), StepError> {
        self.dust_density()?;
        self.ghost_sync(&Refresh::OUTPUT_DENSITY)?;
        Ok(self.sync(state)?)
    }

    /// Stop on NaN/Inf or a non-positive density, naming step, phase, particle and field:
    /// the device flags the first bad particle; the host then reads the state back and
    /// words the message with `check_state`.
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

/// The positions of a phase's particles not held fixed.
fn moving_positions(ph: &crate::particles::Phase) -> impl Iterator<Item = &[f64; 3]> + Clone {
    let fixed = ph.fixed.as_deref();
    (ph.x.iter().enumerate())
        .filter(move |(i, _)| !fixed.is_some_and(|f| f[*i]))
        .map(|(_, x)| x)
}
