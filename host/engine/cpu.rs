//! The CPU backend: rayon loops over the formulas of `dustsph-device`.
//!
//! Step order (method.md §3.6): forces at layer n → IDIC cell sums → cell solve → particle
//! velocities (gas, then dust) → positions and energy → grid rebuild → density and EOS.
use super::timers::Timers;
use super::{Physics, Pipeline};
use crate::grid::{CellIndex, Grid, GridError};
use crate::particles::{Phase, State};
use crate::scene::PositionUpdate;
use dustsph_device::drag;
use dustsph_device::kernels::{self, GasView, Sorted};
use dustsph_device::{dot, kernel, update};
use rayon::prelude::*;

/// Non-drag gas accelerations and energy rates at layer n.
#[derive(Debug, Clone)]
pub struct Forces {
    pub acc: Vec<[f64; 3]>,
    pub dedt: Option<Vec<f64>>,
    /// Largest signal speed (for the CFL limit).
    pub vsig_max: f64,
    /// Largest |A| (for the force limit).
    pub acc_max: f64,
}

impl Forces {
    /// From per-particle rows (A_x, A_y, A_z, ė, v_sig); ė is dropped without an energy
    /// equation.
    pub fn from_rows(rows: &[[f64; 5]], energy: bool) -> Forces {
        let mut f = Forces {
            acc: Vec::with_capacity(rows.len()),
            dedt: energy.then(|| Vec::with_capacity(rows.len())),
            vsig_max: 0.0,
            acc_max: 0.0,
        };
        for r in rows {
            let a = [r[0], r[1], r[2]];
            f.acc_max = f.acc_max.max(dot(a, a).sqrt());
            f.vsig_max = f.vsig_max.max(r[4]);
            f.acc.push(a);
            if let Some(d) = &mut f.dedt {
                d.push(r[3]);
            }
        }
        f
    }
}

/// IDIC cells at one layer: the union of cells occupied by any phase, with per-cell sums
/// and the cell quantities of method.md §3.3–3.4. Arrays indexed `c * nf + k` hold
/// fraction k of cell c.
#[derive(Debug, Clone, Default)]
pub struct CellTable {
    pub nf: usize,
    pub n_cells: usize,
    /// Union cell of each gas cell / dust cell (per fraction).
    gas_map: Vec<u32>,
    dust_map: Vec<Vec<u32>>,
    pub gas_mass: Vec<f64>,
    pub gas_count: Vec<u32>,
    pub dust_mass: Vec<f64>,
    pub dust_count: Vec<u32>,
    /// Σ m (v + τA) over gas; Σ m u over dust (momentum sums).
    gas_mom: Vec<[f64; 3]>,
    dust_mom: Vec<[f64; 3]>,
    pub eps: Vec<f64>,
    /// t_k* (+∞ where the fraction does not couple in that cell).
    pub t_stop: Vec<f64>,
}

pub struct CpuEngine {
    pub phys: Physics,
    pub pipe: Pipeline,
    pub grid: Grid,
    gas_idx: CellIndex,
    dust_idx: Vec<CellIndex>,
    pub timers: Timers,
    /// Whether dust densities are up to date (they are refreshed lazily when not needed by drag).
    dust_density_fresh: bool,
    /// Explicit drag: the cell table of the current layer built for the time-step limit,
    /// reused by the drag pass (only its gas momentum sums depend on τ and are redone).
    limit_table: Option<CellTable>,
    /// Kernel coupling: the normalisers of the gas and of every dust fraction at the current
    /// layer (positions and gas h); cleared whenever either changes.
    kernel_norms: std::sync::Mutex<Option<KernelNorms>>,
}

/// Kernel coupling: S_q = Σ_b W(r_qb, h_b) of every gas particle and every dust particle of
/// each fraction (0 for fixed particles), at one layer.
type KernelNorms = (Vec<f64>, Vec<Vec<f64>>);

#[derive(Debug)]
pub enum StepError {
    Grid(GridError),
    /// A non-finite value or negative density: step, phase, particle id, field.
    Blowup(String),
    /// The scene asks for something this backend does not do.
    Unsupported(String),
}

impl std::fmt::Display for StepError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StepError::Grid(e) => write!(f, "grid: {e}"),
            StepError::Blowup(s) | StepError::Unsupported(s) => f.write_str(s),
        }
    }
}
impl std::error::Error for StepError {}

impl From<GridError> for StepError {
    fn from(e: GridError) -> Self {
        StepError::Grid(e)
    }
}

impl CpuEngine {
    /// Sort the particles, then compute densities and pressures at the initial layer.
    pub fn new(phys: Physics, state: &mut State) -> Result<CpuEngine, StepError> {
        let pipe = Pipeline::from_physics(&phys);
        let grid = Grid::build(&phys.domain, phys.cell_size, phys.support(), &[])?;
        let mut eng = CpuEngine {
            phys,
            pipe,
            grid,
            gas_idx: CellIndex::default(),
            dust_idx: Vec::new(),
            timers: Timers::default(),
            dust_density_fresh: false,
            limit_table: None,
            kernel_norms: std::sync::Mutex::new(None),
        };
        eng.regrid(state)?;
        eng.gas_density_eos(state, None)?;
        eng.refresh_dust_density(state)?;
        eng.check(state)?;
        Ok(eng)
    }

    /// Rebuild the grid over the current positions and sort every phase by cell key.
    /// Returns the permutation applied to the gas (new index → old index).
    fn regrid(&mut self, state: &mut State) -> Result<Vec<u32>, StepError> {
        *self.kernel_norms.get_mut().expect("not poisoned") = None;
        let mut xs: Vec<&[[f64; 3]]> = vec![&state.gas.ph.x];
        xs.extend(state.dust.iter().map(|d| d.x.as_slice()));
        self.grid = Grid::build(
            &self.phys.domain,
            self.phys.cell_size,
            self.search_support(state),
            &xs,
        )?;
        let (perm_gas, idx) = CellIndex::sort(&self.grid, &state.gas.ph.x);
        state.gas.permute(&perm_gas);
        self.gas_idx = idx;
        self.dust_idx.clear();
        for d in &mut state.dust {
            let (perm, idx) = CellIndex::sort(&self.grid, &d.x);
            d.permute(&perm);
            self.dust_idx.push(idx);
        }
        Ok(perm_gas)
    }

    /// Search radius of the grid: the kernel support 2h; with variable h, 2 max h_a plus 0.1% for
    /// the growth of h within a step (the density solve widens it further if needed).
    fn search_support(&self, state: &State) -> f64 {
        let base = self.phys.support();
        match (&state.gas.h, self.pipe.variable_h) {
            (Some(h), true) => {
                let hmax = h.par_iter().copied().reduce(|| 0.0, f64::max);
                base.max(kernel::SUPPORT * hmax * (1.0 + 1e-3))
            }
            _ => base,
        }
    }

    /// Variable h: solve h_a, ρ_a, Ω_a of every gas particle by Newton–Raphson from the
    /// current h (the reference h at the start).
    fn solve_gas_h(&mut self, state: &mut State, hfact: f64) -> Result<(), StepError> {
        let n = state.gas.ph.len();
        let h0 = state.gas.h.take().unwrap_or_else(|| vec![self.phys.h; n]);
        let out = self.solve_h(&state.gas.ph, None, &h0, hfact, state.step, "gas")?;
        let g = &mut state.gas;
        g.ph.rho = out.iter().map(|o| o.rho).collect();
        g.h = Some(out.iter().map(|o| o.h).collect());
        g.omega = Some(out.iter().map(|o| o.omega).collect());
        Ok(())
    }

    /// h, ρ and Ω of every particle of one phase (`dust` = its fraction; `None`: the gas) from
    /// the guesses `h0` (Newton–Raphson, [`kernels::solve_h_at`]). A particle whose h would
    /// outgrow the search radius widens the grid's reach (same cells and order) and the solve
    /// is repeated.
    fn solve_h(
        &mut self,
        ph: &Phase,
        dust: Option<usize>,
        h0: &[f64],
        hfact: f64,
        step: u64,
        what: &str,
    ) -> Result<Vec<kernels::HSolve<f64>>, StepError> {
        const TOL: f64 = 1e-4; // Phantom's tolh
        let dim = self.phys.dim;
        for _attempt in 0..40 {
            let idx = dust.map_or(&self.gas_idx, |k| &self.dust_idx[k]);
            let s = self.sorted(idx, &ph.x);
            let fixed = ph.fixed.as_deref().unwrap_or(&[]);
            let h_max = self.grid.geom.support / kernel::SUPPORT;
            let out: Vec<kernels::HSolve<f64>> = (0..ph.len())
                .into_par_iter()
                .map(|i| {
                    kernels::solve_h_at(
                        &s, &ph.m, fixed, ph.rho[i], i, h0[i], hfact, h_max, TOL, dim,
                    )
                })
                .collect();
            if let Some(i) = out.iter().position(|o| !o.ok) {
                if out[i].iterations < 30 && self.grid.geom.support < 1e300 {
                    // h ran into the search radius: widen it and solve again.
                    self.grid = self.grid.with_support(1.02 * self.grid.geom.support);
                    continue;
                }
                return Err(StepError::Blowup(format!(
                    "step {step}: variable h did not converge for {what} particle id {} (h = {:e})",
                    ph.id[i], out[i].h
                )));
            }
            return Ok(out);
        }
        Err(StepError::Blowup(format!(
            "step {step}: variable h of the {what} outgrew every search radius"
        )))
    }

    /// Visit same-phase neighbours j of particle i within the kernel support; `f(j, dx, r2)`.
    #[inline(always)]
    fn for_neighbours(
        &self,
        idx: &CellIndex,
        x: &[[f64; 3]],
        i: usize,
        f: impl FnMut(usize, [f64; 3], f64),
    ) {
        dustsph_device::grid::for_neighbours(&self.grid.geom, &idx.lookup(), x, x[i], f);
    }

    /// The phase as the shared neighbour walk sees it.
    fn sorted<'a>(&'a self, idx: &'a CellIndex, x: &'a [[f64; 3]]) -> Sorted<'a, f64> {
        Sorted {
            geom: &self.grid.geom,
            look: idx.lookup(),
            x,
        }
    }

    /// SPH density by summation within one phase (self-contribution included).
    fn density(&self, idx: &CellIndex, ph: &Phase) -> Vec<f64> {
        let (h, dim) = (self.phys.h, self.phys.dim);
        let s = self.sorted(idx, &ph.x);
        let fixed = ph.fixed.as_deref().unwrap_or(&[]);
        (0..ph.len())
            .into_par_iter()
            .map(|i| {
                let rho_fixed = if kernels::is_fixed(fixed, i) {
                    ph.rho[i]
                } else {
                    0.0
                };
                kernels::density_at(&s, &ph.m, fixed, rho_fixed, i, h, dim)
            })
            .collect()
    }

    /// Gas density at the current (new) positions, then the EOS. Summation; or, for the
    /// continuity equation, ρ += τ dρ/dt with the current velocities and positions (`tau`
    /// `None` at start-up and on resume: the state's density is kept as it is).
    fn gas_density_eos(&mut self, state: &mut State, tau: Option<f64>) -> Result<(), StepError> {
        *self.kernel_norms.get_mut().expect("not poisoned") = None;
        if let Some(hfact) = self.phys.variable_h {
            // On resume the state carries h, Ω and ρ of the last step: keep them as they are.
            let resumed = tau.is_none() && state.gas.h.is_some() && state.gas.omega.is_some();
            if !resumed {
                self.solve_gas_h(state, hfact)?;
            }
        } else if !self.pipe.continuity_density {
            let rho = self.density(&self.gas_idx, &state.gas.ph);
            state.gas.ph.rho = rho;
        } else if let Some(tau) = tau {
            let (h, dim) = (self.phys.h, self.phys.dim);
            let ph = &state.gas.ph;
            let s = self.sorted(&self.gas_idx, &ph.x);
            let fixed = ph.fixed.as_deref().unwrap_or(&[]);
            let rho: Vec<f64> = (0..ph.len())
                .into_par_iter()
                .map(|i| {
                    ph.rho[i] + tau * kernels::density_rate_at(&s, &ph.v, &ph.m, fixed, i, h, dim)
                })
                .collect();
            state.gas.ph.rho = rho;
        }
        self.eos(state);
        Ok(())
    }

    /// Pressure and sound speed of every gas particle from its density and energy.
    fn eos(&self, state: &mut State) {
        let eos = self.phys.eos;
        let g = &mut state.gas;
        let e = g.e.as_deref();
        let out: Vec<(f64, f64)> = (0..g.ph.len())
            .into_par_iter()
            .map(|i| {
                let rho = g.ph.rho[i];
                let p = eos.pressure(rho, e.map_or(0.0, |e| e[i]));
                (p, eos.sound_speed(rho, p))
            })
            .collect();
        (g.p, g.c) = out.into_iter().unzip();
    }

    /// Dust densities for output (and for constant-K drag, which refreshes them every step).
    /// With variable h (`sph.variable_h`) every dust particle gets its own h as the gas does,
    /// ρ = m (hfact/h)^d, solved afresh from the reference h (so a resumed run is bit-identical).
    pub fn refresh_dust_density(&mut self, state: &mut State) -> Result<(), StepError> {
        if self.dust_density_fresh {
            return Ok(());
        }
        for k in 0..state.dust.len() {
            let rho = match self.phys.variable_h {
                Some(hfact) => {
                    let d = &state.dust[k];
                    let h0 = vec![self.phys.h; d.len()];
                    let what = format!("dust fraction {k}");
                    self.solve_h(d, Some(k), &h0, hfact, state.step, &what)?
                        .iter()
                        .map(|o| o.rho)
                        .collect()
                }
                None => self.density(&self.dust_idx[k], &state.dust[k]),
            };
            state.dust[k].rho = rho;
        }
        self.dust_density_fresh = true;
        Ok(())
    }

    /// Mean number of gas neighbours within the support (self excluded), for benchmarks.
    pub fn mean_gas_neighbours(&self, state: &State) -> f64 {
        let ph = &state.gas.ph;
        let total: usize = (0..ph.len())
            .into_par_iter()
            .map(|i| {
                let mut n = 0usize;
                self.for_neighbours(&self.gas_idx, &ph.x, i, |j, _, _| n += (j != i) as usize);
                n
            })
            .sum();
        total as f64 / ph.len().max(1) as f64
    }

    /// Non-drag gas accelerations A^n (pressure + AV) and de/dt^n.
    pub fn forces(&self, state: &State) -> Forces {
        match (&state.gas.next_forces, self.pipe.kdk) {
            (Some(rows), true) => Forces::from_rows(rows, self.pipe.energy),
            _ => Forces::from_rows(&self.force_rows(state), self.pipe.energy),
        }
    }

    /// The forces at the state as it is, per particle: (A_x, A_y, A_z, ė, v_sig).
    fn force_rows(&self, state: &State) -> Vec<[f64; 5]> {
        let g = &state.gas;
        let (h, dim) = (self.phys.h, self.phys.dim);
        let av = self.phys.av.as_ref();
        let s = self.sorted(&self.gas_idx, &g.ph.x);
        let view = GasView {
            v: &g.ph.v,
            m: &g.ph.m,
            rho: &g.ph.rho,
            p: &g.p,
            c: &g.c,
            fixed: g.ph.fixed.as_deref().unwrap_or(&[]),
        };
        // Variable h: each particle's kernel constants and p/(Ω ρ²), once per step.
        let kernels_at = |hv: &[f64]| -> Vec<kernel::KernelAt<f64>> {
            hv.par_iter()
                .map(|&h| kernel::KernelAt::new(h, dim))
                .collect()
        };
        let out: Vec<[f64; 5]> = if self.pipe.iad {
            // IAD: per-particle kernels (all at h for a fixed h), p/ρ², the matrices C_a.
            let k = match g.h.as_deref() {
                Some(hv) => kernels_at(hv),
                None => vec![kernel::KernelAt::new(h, dim); g.ph.len()],
            };
            let pt: Vec<f64> = (0..g.ph.len())
                .into_par_iter()
                .map(|i| g.p[i] / (g.ph.rho[i] * g.ph.rho[i]))
                .collect();
            let c: Vec<_> = (0..g.ph.len())
                .into_par_iter()
                .map(|i| kernels::iad_matrix_at(&s, &g.ph.m, &g.ph.rho, &k, i))
                .collect();
            (0..g.ph.len())
                .into_par_iter()
                .map(|i| {
                    let r = kernels::forces_iad_at(&s, &view, &k, &pt, &c, i, av);
                    [r.acc[0], r.acc[1], r.acc[2], r.dedt, r.vsig]
                })
                .collect()
        } else {
            let vh: Option<(Vec<kernel::KernelAt<f64>>, Vec<f64>)> =
                g.h.as_deref().zip(g.omega.as_deref()).map(|(hv, om)| {
                    let pt = (0..hv.len())
                        .into_par_iter()
                        .map(|i| g.p[i] / (om[i] * g.ph.rho[i] * g.ph.rho[i]))
                        .collect();
                    (kernels_at(hv), pt)
                });
            (0..g.ph.len())
                .into_par_iter()
                .map(|i| {
                    let r = match &vh {
                        Some((k, pt)) => kernels::forces_vh_at(&s, &view, k, pt, i, av),
                        None => kernels::forces_at(&s, &view, i, h, dim, av),
                    };
                    [r.acc[0], r.acc[1], r.acc[2], r.dedt, r.vsig]
                })
                .collect()
        };
        out
    }

    /// Per-cell sums and cell stopping times at the current layer. `v_tilde` is the gas
    /// velocity v^n + τA^n (or v^n for diagnostics).
    pub fn cell_table(&self, state: &State, v_tilde: &[[f64; 3]]) -> CellTable {
        let nf = state.dust.len();
        // Union of occupied cells over all phases (all share one grid).
        let mut keys: Vec<u64> = self.gas_idx.keys.clone();
        for d in &self.dust_idx {
            keys.extend_from_slice(&d.keys);
        }
        keys.par_sort_unstable();
        keys.dedup();
        let n = keys.len();
        let map = |idx: &CellIndex| -> Vec<u32> {
            idx.keys
                .par_iter()
                .map(|k| keys.binary_search(k).unwrap_or(0) as u32)
                .collect()
        };
        let mut t = CellTable {
            nf,
            n_cells: n,
            gas_map: map(&self.gas_idx),
            dust_map: self.dust_idx.iter().map(map).collect(),
            gas_mass: vec![0.0; n],
            gas_count: vec![0; n],
            dust_mass: vec![0.0; n * nf],
            dust_count: vec![0; n * nf],
            gas_mom: vec![[0.0; 3]; n],
            dust_mom: vec![[0.0; 3]; n * nf],
            eps: vec![0.0; n * nf],
            t_stop: vec![f64::INFINITY; n * nf],
        };
        let g = &state.gas;
        let needs_gas_state = self.phys.laws.iter().any(|l| l.needs_gas_state());
        let gamma_root = self.phys.eos.gamma_root();
        // Gas sums of every union cell (what the stopping-time laws read).
        let mut gas_u = vec![kernels::GasSums::default(); n];
        // Gas sums per gas cell (contiguous particle ranges), scattered to union cells.
        let eos = self.phys.eos;
        let gfixed = g.ph.fixed.as_deref().unwrap_or(&[]);
        let gsum: Vec<kernels::GasSums<f64>> = (0..self.gas_idx.n_cells())
            .into_par_iter()
            .map(|c| {
                let r = self.gas_idx.cell_range(c);
                kernels::gas_cell_sums(
                    r.start,
                    r.end,
                    &g.ph.m,
                    &g.ph.rho,
                    &g.p,
                    gfixed,
                    &eos,
                    needs_gas_state,
                    |i| v_tilde[i],
                )
            })
            .collect();
        for (c, gs) in gsum.into_iter().enumerate() {
            let u = t.gas_map[c] as usize;
            t.gas_mass[u] = gs.mass;
            t.gas_count[u] = gs.count;
            t.gas_mom[u] = gs.mom;
            gas_u[u] = gs;
        }
        for (k, d) in state.dust.iter().enumerate() {
            let idx = &self.dust_idx[k];
            let needs_rho = self.phys.laws[k].needs_dust_density();
            let dfixed = d.fixed.as_deref().unwrap_or(&[]);
            let dsum: Vec<kernels::DustSums<f64>> = (0..idx.n_cells())
                .into_par_iter()
                .map(|c| {
                    let r = idx.cell_range(c);
                    kernels::dust_cell_sums(r.start, r.end, &d.m, &d.v, &d.rho, dfixed, needs_rho)
                })
                .collect();
            for (c, ds) in dsum.into_iter().enumerate() {
                let u = t.dust_map[k][c] as usize;
                let s = u * nf + k;
                t.dust_mass[s] = ds.mass;
                t.dust_count[s] = ds.count;
                t.dust_mom[s] = ds.mom;
                let law = &self.phys.laws[k];
                if let Some((eps, ts)) = kernels::fraction_coupling(&gas_u[u], &ds, law, gamma_root)
                {
                    t.eps[s] = eps;
                    if let Some(ts) = ts {
                        t.t_stop[s] = ts;
                    }
                }
            }
        }
        t
    }

    /// Stopping time of every dust particle (its cell's t_k*; +∞ where uncoupled), for output.
    pub fn dust_stopping_times(&mut self, state: &mut State) -> Result<Vec<Vec<f64>>, StepError> {
        if state.dust.is_empty() {
            return Ok(Vec::new());
        }
        self.refresh_dust_density(state)?;
        if self.pipe.kernel_coupling {
            return Ok(self.kernel_stopping_times(state));
        }
        let t = self.cell_table(state, &state.gas.ph.v);
        Ok((0..state.dust.len())
            .map(|k| {
                let idx = &self.dust_idx[k];
                (0..state.dust[k].len())
                    .map(|j| t.t_stop[t.dust_map[k][idx.cell_of[j] as usize] as usize * t.nf + k])
                    .collect()
            })
            .collect())
    }

    /// Explicit drag only: the largest step the drag allows at the current layer,
    /// [`drag::EXPLICIT_SAFETY`]/Λ with Λ the fastest drag rate of any cell
    /// ([`drag::explicit_rate`]); +∞ with IDIC (the drag never limits its step) or no coupling.
    /// The table is kept for the drag pass of the step that follows.
    pub fn drag_dt_limit(&mut self, state: &State) -> f64 {
        if !self.pipe.explicit_drag {
            return f64::INFINITY;
        }
        // ε_k and t_k* do not depend on the velocities handed to the cell sums.
        let t = self.cell_table(state, &state.gas.ph.v);
        let nf = t.nf;
        let rate = (0..t.n_cells)
            .into_par_iter()
            .map_init(
                || vec![0.0; nf],
                |inv_t, c| {
                    for (k, r) in inv_t.iter_mut().enumerate() {
                        let ts = t.t_stop[c * nf + k];
                        *r = if ts.is_finite() { 1.0 / ts } else { 0.0 };
                    }
                    drag::explicit_rate(&t.eps[c * nf..(c + 1) * nf], inv_t)
                },
            )
            .reduce(|| 0.0, f64::max);
        self.limit_table = Some(t);
        if rate > 0.0 {
            drag::EXPLICIT_SAFETY / rate
        } else {
            f64::INFINITY
        }
    }

    /// Redo the gas momentum sums Σ m ṽ of a cell table of this layer for another ṽ.
    fn redo_gas_momentum(&self, state: &State, v_tilde: &[[f64; 3]], t: &mut CellTable) {
        let g = &state.gas.ph;
        let sums: Vec<[f64; 3]> = (0..self.gas_idx.n_cells())
            .into_par_iter()
            .map(|c| {
                let mut mom = [0.0; 3];
                for i in self.gas_idx.cell_range(c) {
                    if !g.is_fixed(i) {
                        mom = dustsph_device::axpy(mom, g.m[i], v_tilde[i]);
                    }
                }
                mom
            })
            .collect();
        for (c, mom) in sums.into_iter().enumerate() {
            t.gas_mom[t.gas_map[c] as usize] = mom;
        }
    }

    /// The drag pass: new gas and dust velocities from ṽ = v^n + τA^n. IDIC (method.md §3.3)
    /// solves each cell implicitly; the explicit baseline applies the same particle equations
    /// with the drag at the known velocities (`drag::explicit_*_update`), from the same cell
    /// sums. Returns the drag heat per unit gas mass of every gas particle when heating is on.
    /// `table`: this layer's cell table if one was built already (explicit drag's limit).
    fn idic(
        &self,
        state: &mut State,
        v_tilde: &[[f64; 3]],
        tau: f64,
        table: Option<CellTable>,
    ) -> Option<Vec<f64>> {
        let t = match table {
            Some(mut t) => {
                self.redo_gas_momentum(state, v_tilde, &mut t);
                t
            }
            None => self.cell_table(state, v_tilde),
        };
        let nf = t.nf;
        let explicit = self.pipe.explicit_drag;
        type GasUpd = fn([f64; 3], &[f64], &[f64], &[[f64; 3]]) -> [f64; 3];
        type DustUpd = fn([f64; 3], f64, [f64; 3]) -> [f64; 3];
        let (gas_update, dust_update): (GasUpd, DustUpd) = if explicit {
            (drag::explicit_gas_update, drag::explicit_dust_update)
        } else {
            (drag::gas_update, drag::dust_update)
        };
        // Cell solve: independent per cell, written into flat arrays (cell c, fraction k at c*nf+k).
        // IDIC: v*^{n+1}, u_k*^{n+1}; explicit: the known means ṽ*, ũ_k*.
        let mut v_cell = vec![[0.0; 3]; t.n_cells];
        let mut u_cell = vec![[0.0; 3]; t.n_cells * nf];
        let mut beta_cell = vec![0.0; t.n_cells * nf];
        v_cell
            .par_iter_mut()
            .zip(u_cell.par_chunks_mut(nf.max(1)))
            .zip(beta_cell.par_chunks_mut(nf.max(1)))
            .enumerate()
            .for_each_init(
                || vec![[0.0; 3]; nf],
                |ut, (c, ((vnew, unew), beta))| {
                    let vt = if t.gas_mass[c] > 0.0 {
                        dustsph_device::scale(1.0 / t.gas_mass[c], t.gas_mom[c])
                    } else {
                        [0.0; 3]
                    };
                    for k in 0..nf {
                        let s = c * nf + k;
                        ut[k] = if t.dust_mass[s] > 0.0 {
                            dustsph_device::scale(1.0 / t.dust_mass[s], t.dust_mom[s])
                        } else {
                            [0.0; 3]
                        };
                        let ts = t.t_stop[s];
                        beta[k] = drag::cell_beta(tau, ts.is_finite().then_some(ts));
                    }
                    *vnew = if explicit {
                        unew.copy_from_slice(ut);
                        vt
                    } else {
                        drag::cell_solve(vt, ut, &t.eps[c * nf..(c + 1) * nf], beta, unew)
                    };
                },
            );
        let gas_map = &t.gas_map;
        let gas_cell = &self.gas_idx.cell_of;
        let g = &mut state.gas.ph;
        let fixed = g.fixed.as_deref();
        let v_new: Vec<[f64; 3]> = (0..g.len())
            .into_par_iter()
            .map(|i| {
                if fixed.is_some_and(|f| f[i]) {
                    return g.v[i];
                }
                let c = gas_map[gas_cell[i] as usize] as usize;
                let r = c * nf..(c + 1) * nf;
                gas_update(
                    v_tilde[i],
                    &t.eps[r.clone()],
                    &beta_cell[r.clone()],
                    &u_cell[r],
                )
            })
            .collect();
        let mut heat_cell = if self.pipe.heating {
            vec![0.0; t.n_cells]
        } else {
            Vec::new()
        };
        if self.pipe.heating {
            for (i, vn) in v_new.iter().enumerate() {
                if !g.is_fixed(i) {
                    let c = gas_map[gas_cell[i] as usize] as usize;
                    heat_cell[c] += drag::kinetic_loss(g.m[i], v_tilde[i], *vn);
                }
            }
        }
        g.v = v_new;
        for (k, d) in state.dust.iter_mut().enumerate() {
            let idx = &self.dust_idx[k];
            let map = &t.dust_map[k];
            let fixed = d.fixed.as_deref();
            let u_new: Vec<[f64; 3]> = (0..d.len())
                .into_par_iter()
                .map(|j| {
                    if fixed.is_some_and(|f| f[j]) {
                        return d.v[j];
                    }
                    let c = map[idx.cell_of[j] as usize] as usize;
                    dust_update(d.v[j], beta_cell[c * nf + k], v_cell[c])
                })
                .collect();
            if self.pipe.heating {
                for (j, un) in u_new.iter().enumerate() {
                    if !d.is_fixed(j) {
                        let c = map[idx.cell_of[j] as usize] as usize;
                        heat_cell[c] += drag::kinetic_loss(d.m[j], d.v[j], *un);
                    }
                }
            }
            d.v = u_new;
        }
        self.pipe.heating.then(|| {
            (0..g.len())
                .map(|i| {
                    let c = gas_map[gas_cell[i] as usize] as usize;
                    if g.is_fixed(i) || t.gas_mass[c] <= 0.0 {
                        0.0
                    } else {
                        heat_cell[c] / t.gas_mass[c]
                    }
                })
                .collect()
        })
    }

    /// The gas kernels of the weights: one per gas particle with variable h, else one shared.
    fn gas_kernels(&self, state: &State) -> Vec<kernel::KernelAt<f64>> {
        match state.gas.h.as_deref() {
            Some(hv) if self.pipe.variable_h => hv
                .par_iter()
                .map(|&h| kernel::KernelAt::new(h, self.phys.dim))
                .collect(),
            _ => vec![kernel::KernelAt::new(self.phys.h, self.phys.dim)],
        }
    }

    /// The deposits of every dust fraction (u, ρ) on the gas particle at `xa` with kernel `ka`.
    fn dust_deposits(
        state: &State,
        ds: &[Sorted<'_, f64>],
        s_dust: &[Vec<f64>],
        xa: [f64; 3],
        ka: &kernel::KernelAt<f64>,
    ) -> [kernels::Deposit<f64>; kernels::MAX_FRACTIONS] {
        let mut dep = [kernels::Deposit::default(); kernels::MAX_FRACTIONS];
        for (f, d) in state.dust.iter().enumerate() {
            let dfixed = d.fixed.as_deref().unwrap_or(&[]);
            dep[f] = kernels::deposit_at(
                &ds[f],
                &s_dust[f],
                &d.m,
                &d.rho,
                dfixed,
                xa,
                ka,
                |j| d.v[j],
                |_| 0.0,
            );
        }
        dep
    }

    /// S of every free particle of a phase over the gas (0 for fixed ones, which do not couple).
    fn coupling_norms(
        gs: &Sorted<'_, f64>,
        k: &[kernel::KernelAt<f64>],
        gfixed: &[bool],
        ph: &Phase,
    ) -> Vec<f64> {
        (0..ph.len())
            .into_par_iter()
            .map(|i| {
                if ph.is_fixed(i) {
                    0.0
                } else {
                    kernels::gas_weight_sum_at(gs, k, gfixed, ph.x[i])
                }
            })
            .collect()
    }

    /// The drag pass with the kernel coupling (docs/method.md §K): every particle spreads its
    /// mass and ṽ (gas) or ũ (dust) over the gas particles within reach with the weights
    /// w_qa = W(r_qa, h_a)/S_q; each gas particle solves the closed form of method.md §3.3 on
    /// those means; each particle gets Σ_a w_qa (new − old mean). Σ_a w_qa = 1, so momentum is
    /// exchanged exactly and a uniform flow stays uniform. Returns the drag heat per unit gas
    /// mass when heating is on (each particle's kinetic-energy loss spread with its weights).
    /// The same per-particle functions, in the same order, as the GPU kernels
    /// (`threads::coupling_solve`, `coupling_return`): the two agree bit for bit. The
    /// normalisers S are kept while the positions and h do not change.
    fn idic_kernel(&self, state: &mut State, v_tilde: &[[f64; 3]], tau: f64) -> Option<Vec<f64>> {
        let nf = state.dust.len();
        let k = self.gas_kernels(state);
        let eos = self.phys.eos;
        let gamma_root = eos.gamma_root();
        let needs_gas_state = self.phys.laws.iter().any(|l| l.needs_gas_state());
        let g = &state.gas;
        let ng = g.ph.len();
        let gfixed = g.ph.fixed.as_deref().unwrap_or(&[]);
        let gs = self.sorted(&self.gas_idx, &g.ph.x);
        let mut cache = self.kernel_norms.lock().expect("not poisoned");
        let (s_gas, s_dust) = &*cache.get_or_insert_with(|| {
            (
                Self::coupling_norms(&gs, &k, gfixed, &g.ph),
                state
                    .dust
                    .iter()
                    .map(|d| Self::coupling_norms(&gs, &k, gfixed, d))
                    .collect(),
            )
        });
        let ds: Vec<Sorted<'_, f64>> = state
            .dust
            .iter()
            .zip(&self.dust_idx)
            .map(|(d, idx)| self.sorted(idx, &d.x))
            .collect();
        let zero = [0.0; 3];
        // Deposits and the solve on every free gas particle: the increments of its means.
        type Incs = ([f64; 3], [[f64; 3]; kernels::MAX_FRACTIONS]);
        let incs: Vec<Incs> = (0..ng)
            .into_par_iter()
            .map(|a| {
                if kernels::is_fixed(gfixed, a) {
                    return (zero, [zero; kernels::MAX_FRACTIONS]);
                }
                let xa = g.ph.x[a];
                let ka = kernels::kernel_of(&k, a);
                let gas_dep = kernels::deposit_at(
                    &gs,
                    s_gas,
                    &g.ph.m,
                    &g.ph.rho,
                    gfixed,
                    xa,
                    &ka,
                    |b| v_tilde[b],
                    |b| {
                        if needs_gas_state {
                            eos.isothermal_speed(g.ph.rho[b], g.p[b])
                        } else {
                            0.0
                        }
                    },
                );
                let dust_dep = Self::dust_deposits(state, &ds, s_dust, xa, &ka);
                let inc = kernels::kernel_increments(
                    &gas_dep,
                    &dust_dep[..nf],
                    &self.phys.laws,
                    tau,
                    gamma_root,
                );
                (inc.dv, inc.du)
            })
            .collect();
        let v_new: Vec<[f64; 3]> = (0..ng)
            .into_par_iter()
            .map(|b| {
                if kernels::is_fixed(gfixed, b) {
                    return g.ph.v[b];
                }
                let inc = kernels::gather_increment_at(&gs, &k, gfixed, g.ph.x[b], s_gas[b], |a| {
                    incs[a].0
                });
                dustsph_device::add(v_tilde[b], inc)
            })
            .collect();
        let u_new_all: Vec<Vec<[f64; 3]>> = state
            .dust
            .iter()
            .enumerate()
            .map(|(f, d)| {
                (0..d.len())
                    .into_par_iter()
                    .map(|j| {
                        if d.is_fixed(j) {
                            return d.v[j];
                        }
                        let inc = kernels::gather_increment_at(
                            &gs,
                            &k,
                            gfixed,
                            d.x[j],
                            s_dust[f][j],
                            |a| incs[a].1[f],
                        );
                        dustsph_device::add(d.v[j], inc)
                    })
                    .collect()
            })
            .collect();
        let heat = self.pipe.heating.then(|| {
            // Kinetic energy lost by each particle, spread over the gas with its own weights
            // (Σ_a w_qa = 1: the gas gains exactly what the particles lose).
            let loss_gas: Vec<f64> = (0..ng)
                .into_par_iter()
                .map(|b| {
                    if kernels::is_fixed(gfixed, b) {
                        0.0
                    } else {
                        drag::kinetic_loss(g.ph.m[b], v_tilde[b], v_new[b])
                    }
                })
                .collect();
            let loss_dust: Vec<Vec<f64>> = state
                .dust
                .iter()
                .zip(&u_new_all)
                .map(|(d, un)| {
                    (0..d.len())
                        .into_par_iter()
                        .map(|j| {
                            if d.is_fixed(j) {
                                0.0
                            } else {
                                drag::kinetic_loss(d.m[j], d.v[j], un[j])
                            }
                        })
                        .collect()
                })
                .collect();
            let big = ng.max(state.dust.iter().map(|d| d.len()).max().unwrap_or(0));
            let unused = vec![0.0; big];
            (0..ng)
                .into_par_iter()
                .map(|a| {
                    if kernels::is_fixed(gfixed, a) {
                        return 0.0;
                    }
                    let ka = kernels::kernel_of(&k, a);
                    let xa = g.ph.x[a];
                    // Σ_q w_qa ΔE_q: the deposit's "mass" slot with the losses as masses.
                    let mut q = kernels::deposit_at(
                        &gs,
                        s_gas,
                        &loss_gas,
                        &unused,
                        gfixed,
                        xa,
                        &ka,
                        |_| zero,
                        |_| 0.0,
                    )
                    .mass;
                    for (f, d) in state.dust.iter().enumerate() {
                        let dfixed = d.fixed.as_deref().unwrap_or(&[]);
                        q += kernels::deposit_at(
                            &ds[f],
                            &s_dust[f],
                            &loss_dust[f],
                            &unused,
                            dfixed,
                            xa,
                            &ka,
                            |_| zero,
                            |_| 0.0,
                        )
                        .mass;
                    }
                    q / g.ph.m[a]
                })
                .collect()
        });
        drop(cache);
        state.gas.ph.v = v_new;
        for (d, u) in state.dust.iter_mut().zip(u_new_all) {
            d.v = u;
        }
        heat
    }

    /// Kernel coupling: the stopping time each dust particle feels, Σ_a w_ja t_k,a over the
    /// gas particles it couples to (+∞ without gas within reach), for output. The same
    /// functions as the GPU's `coupling_solve` / `coupling_tstop` kernels.
    fn kernel_stopping_times(&self, state: &State) -> Vec<Vec<f64>> {
        let k = self.gas_kernels(state);
        let eos = self.phys.eos;
        let gamma_root = eos.gamma_root();
        let g = &state.gas;
        let gfixed = g.ph.fixed.as_deref().unwrap_or(&[]);
        let gs = self.sorted(&self.gas_idx, &g.ph.x);
        let s_gas = Self::coupling_norms(&gs, &k, gfixed, &g.ph);
        let s_dust: Vec<Vec<f64>> = state
            .dust
            .iter()
            .map(|d| Self::coupling_norms(&gs, &k, gfixed, d))
            .collect();
        let ds: Vec<Sorted<'_, f64>> = state
            .dust
            .iter()
            .zip(&self.dust_idx)
            .map(|(d, idx)| self.sorted(idx, &d.x))
            .collect();
        let nf = state.dust.len();
        let t_gas: Vec<[f64; kernels::MAX_FRACTIONS]> = (0..g.ph.len())
            .into_par_iter()
            .map(|a| {
                let inf = [f64::INFINITY; kernels::MAX_FRACTIONS];
                if kernels::is_fixed(gfixed, a) {
                    return inf;
                }
                let ka = kernels::kernel_of(&k, a);
                let xa = g.ph.x[a];
                let gd = kernels::deposit_at(
                    &gs,
                    &s_gas,
                    &g.ph.m,
                    &g.ph.rho,
                    gfixed,
                    xa,
                    &ka,
                    |b| g.ph.v[b],
                    |b| eos.isothermal_speed(g.ph.rho[b], g.p[b]),
                );
                let dd = Self::dust_deposits(state, &ds, &s_dust, xa, &ka);
                kernels::kernel_increments(&gd, &dd[..nf], &self.phys.laws, 0.0, gamma_root).t_stop
            })
            .collect();
        state
            .dust
            .iter()
            .enumerate()
            .map(|(f, d)| {
                (0..d.len())
                    .into_par_iter()
                    .map(|j| {
                        if s_dust[f][j] <= 0.0 {
                            return f64::INFINITY;
                        }
                        kernels::gather_increment_at(&gs, &k, gfixed, d.x[j], s_dust[f][j], |a| {
                            [t_gas[a][f], 0.0, 0.0]
                        })[0]
                    })
                    .collect()
            })
            .collect()
    }

    /// Advance one step of size τ from layer n (forces already computed at layer n).
    pub fn advance(&mut self, state: &mut State, f: &Forces, tau: f64) -> Result<(), StepError> {
        if self.pipe.kdk {
            return self.advance_kdk(state, f, tau);
        }
        let old_gas_v =
            (self.phys.position_update == PositionUpdate::Old).then(|| state.gas.ph.v.clone());
        let old_dust_v: Option<Vec<Vec<[f64; 3]>>> = (self.phys.position_update
            == PositionUpdate::Old)
            .then(|| state.dust.iter().map(|d| d.v.clone()).collect());
        let table = self.limit_table.take();
        let heat = self.kick(state, &f.acc, tau, table);
        let mut timers = std::mem::take(&mut self.timers);
        timers.time("positions + energy", || {
            self.drift(state, tau, old_gas_v.as_ref(), old_dust_v.as_ref());
            if let Some(dedt) = &f.dedt {
                Self::energy_step(state, dedt, tau, heat.as_deref());
            }
        });
        self.timers = timers;
        self.new_layer(state, tau, |_, _| {})?;
        state.t += tau;
        state.step += 1;
        self.check(state)
    }

    /// The layer after the drift: grid rebuild and sort, then `before_density(state, perm)`
    /// (perm: the gas permutation of the sort, new index → old index), the gas density and EOS,
    /// and the dust densities where the drag needs them every step.
    fn new_layer(
        &mut self,
        state: &mut State,
        tau: f64,
        before_density: impl FnOnce(&mut State, &[u32]),
    ) -> Result<(), StepError> {
        let mut timers = std::mem::take(&mut self.timers);
        let res = (|| {
            let perm = timers.time("grid rebuild + sort", || self.regrid(state))?;
            before_density(state, &perm);
            timers.time("gas density + EOS", || {
                self.gas_density_eos(state, Some(tau))
            })?;
            self.dust_density_fresh = false;
            if self.pipe.dust_density_each_step {
                timers.time("dust density", || self.refresh_dust_density(state))?;
            }
            Ok(())
        })();
        self.timers = timers;
        res
    }

    /// Kick–drift–kick leapfrog ([`crate::scene::Integrator::Kdk`]): from layer n with its
    /// forces `f`, half kick (forces + drag over τ/2), drift with v^{n+1/2}, forces at n+1 from
    /// predicted v*, e* (a τ/2 kick of v^{n+1/2} with the old forces and the drag at the new
    /// layer), closing half kick with the new forces. The new forces are kept for the next
    /// step, so a step costs one force evaluation.
    fn advance_kdk(&mut self, state: &mut State, f: &Forces, tau: f64) -> Result<(), StepError> {
        let half = 0.5 * tau;
        let table = self.limit_table.take();
        let heat = self.kick(state, &f.acc, half, table);
        let mut timers = std::mem::take(&mut self.timers);
        timers.time("positions + energy", || {
            if let Some(dedt) = &f.dedt {
                Self::energy_step(state, dedt, half, heat.as_deref());
            }
            self.drift(state, tau, None, None);
        });
        self.timers = timers;
        // The sort reorders the gas: the opening forces follow it for the predictor.
        let mut acc_n = Vec::new();
        let mut e_half = None;
        self.new_layer(state, tau, |st, perm| {
            acc_n = perm.iter().map(|&p| f.acc[p as usize]).collect();
            // Predicted energy e* = e^{n+1/2} + τ/2 ė^n sets the pressure of the new layer.
            e_half = st.gas.e.clone();
            if let Some(dedt) = &f.dedt {
                let dedt: Vec<f64> = perm.iter().map(|&p| dedt[p as usize]).collect();
                Self::energy_step(st, &dedt, half, None);
            }
        })?;
        // Predicted velocities v* (drag included: for stiff drag the undragged prediction would
        // be off by O(1)), for the energy rate and the viscosity of the new layer.
        let v_half = state.gas.ph.v.clone();
        let u_half: Vec<Vec<[f64; 3]>> = state.dust.iter().map(|d| d.v.clone()).collect();
        self.kick(state, &acc_n, half, None);
        let mut timers = std::mem::take(&mut self.timers);
        let rows = timers.time("gas forces", || self.force_rows(state));
        let f1 = Forces::from_rows(&rows, self.pipe.energy);
        self.timers = timers;
        state.gas.ph.v = v_half;
        for (d, u) in state.dust.iter_mut().zip(u_half) {
            d.v = u;
        }
        state.gas.e = e_half;
        let heat = self.kick(state, &f1.acc, half, None);
        let mut timers = std::mem::take(&mut self.timers);
        timers.time("positions + energy", || {
            if let Some(dedt) = &f1.dedt {
                Self::energy_step(state, dedt, half, heat.as_deref());
                self.eos(state);
            }
        });
        self.timers = timers;
        state.t += tau;
        state.step += 1;
        state.gas.next_forces = Some(rows);
        self.check(state)
    }

    /// Velocity kick over `dt`: ṽ = v + dt·A, then the drag pass over `dt` (gas and dust) or,
    /// without dust, v = ṽ. Fixed particles keep their velocity. Returns the drag heat per unit
    /// gas mass when heating is on.
    fn kick(
        &mut self,
        state: &mut State,
        acc: &[[f64; 3]],
        dt: f64,
        table: Option<CellTable>,
    ) -> Option<Vec<f64>> {
        let g = &state.gas.ph;
        let (eg, ed) = (self.phys.ext_gas, self.phys.ext_dust);
        let v_tilde: Vec<[f64; 3]> = (0..g.len())
            .into_par_iter()
            .map(|i| dustsph_device::axpy(g.v[i], dt, dustsph_device::add(acc[i], eg)))
            .collect();
        if ed.iter().any(|a| *a != 0.0) {
            // ũ = u^n + τB^n (method.md §3.3): the drag pass reads the dust velocities as ũ.
            for d in &mut state.dust {
                let fixed = d.fixed.clone();
                d.v.par_iter_mut().enumerate().for_each(|(j, u)| {
                    if !fixed.as_ref().is_some_and(|f| f[j]) {
                        *u = dustsph_device::axpy(*u, dt, ed);
                    }
                });
            }
        }
        if self.pipe.drag {
            let mut timers = std::mem::take(&mut self.timers);
            let name = if self.pipe.explicit_drag {
                "explicit drag"
            } else if self.pipe.kernel_coupling {
                "idic (kernel coupling)"
            } else {
                "idic"
            };
            let h = timers.time(name, || {
                if self.pipe.kernel_coupling {
                    self.idic_kernel(state, &v_tilde, dt)
                } else {
                    self.idic(state, &v_tilde, dt, table)
                }
            });
            self.timers = timers;
            h
        } else {
            let g = &mut state.gas.ph;
            let v_new: Vec<[f64; 3]> = v_tilde
                .into_iter()
                .enumerate()
                .map(|(i, v)| if g.is_fixed(i) { g.v[i] } else { v })
                .collect();
            g.v = v_new;
            None
        }
    }

    /// x += τ w for every phase, w = the phase's velocity or the given old one.
    fn drift(
        &self,
        state: &mut State,
        tau: f64,
        old_gas_v: Option<&Vec<[f64; 3]>>,
        old_dust_v: Option<&Vec<Vec<[f64; 3]>>>,
    ) {
        let geom = self.grid.geom;
        let drift = |ph: &mut Phase, w: Option<&Vec<[f64; 3]>>| {
            let fixed = ph.fixed.as_deref();
            let w = w.unwrap_or(&ph.v);
            let x: Vec<[f64; 3]> =
                ph.x.par_iter()
                    .enumerate()
                    .map(|(i, &x)| {
                        if fixed.is_some_and(|f| f[i]) {
                            x
                        } else {
                            geom.wrap(update::drift(x, w[i], tau))
                        }
                    })
                    .collect();
            ph.x = x;
        };
        drift(&mut state.gas.ph, old_gas_v);
        for (k, d) in state.dust.iter_mut().enumerate() {
            drift(d, old_dust_v.map(|o| &o[k]));
        }
    }

    /// e += dt ė (+ drag heat) for every free gas particle.
    fn energy_step(state: &mut State, dedt: &[f64], dt: f64, heat: Option<&[f64]>) {
        if let Some(e) = &mut state.gas.e {
            let fixed = state.gas.ph.fixed.as_deref();
            e.par_iter_mut().enumerate().for_each(|(i, e)| {
                if !fixed.is_some_and(|f| f[i]) {
                    *e = update::energy(*e, dedt[i], dt) + heat.map_or(0.0, |h| h[i]);
                }
            });
        }
    }

    /// Full step: forces, then advance. Returns the forces used (for diagnostics).
    pub fn step(&mut self, state: &mut State, tau: f64) -> Result<Forces, StepError> {
        let mut timers = std::mem::take(&mut self.timers);
        let f = timers.time("gas forces", || self.forces(state));
        self.timers = timers;
        self.advance(state, &f, tau)?;
        Ok(f)
    }

    fn check(&self, state: &State) -> Result<(), StepError> {
        check_state(state, self.dust_density_fresh)
    }
}

/// Stop on NaN/Inf or a non-positive density, naming step, phase, particle and field (dust
/// densities are checked when `dust_density_fresh`).
pub fn check_state(state: &State, dust_density_fresh: bool) -> Result<(), StepError> {
    let bad = |phase: &str,
               ph: &Phase,
               check_rho: bool,
               extra: Option<(&str, &[f64])>|
     -> Option<String> {
        let rho_ok = |i: usize| !check_rho || (ph.rho[i].is_finite() && ph.rho[i] > 0.0);
        let i = (0..ph.len()).into_par_iter().find_first(|&i| {
            !(ph.x[i].iter().all(|v| v.is_finite())
                && ph.v[i].iter().all(|v| v.is_finite())
                && rho_ok(i)
                && extra.is_none_or(|(_, e)| e[i].is_finite() && e[i] >= 0.0))
        })?;
        let field = if !ph.x[i].iter().all(|v| v.is_finite()) {
            "position"
        } else if !ph.v[i].iter().all(|v| v.is_finite()) {
            "velocity"
        } else if !rho_ok(i) {
            "density"
        } else {
            extra.map_or("?", |e| e.0)
        };
        Some(format!(
                "step {}, t = {:.6e}: {phase} particle id {} has a bad {field} (x = {:?}, v = {:?}, rho = {:?})",
                state.step,
                state.t,
                ph.id[i],
                ph.x[i],
                ph.v[i],
                ph.rho.get(i)
            ))
    };
    let g = &state.gas;
    if let Some(m) = bad(
        "gas",
        &g.ph,
        true,
        g.e.as_deref().map(|e| ("internal energy", e)),
    ) {
        return Err(StepError::Blowup(m));
    }
    for (k, d) in state.dust.iter().enumerate() {
        if let Some(m) = bad(&format!("dust fraction {k}"), d, dust_density_fresh, None) {
            return Err(StepError::Blowup(m));
        }
    }
    Ok(())
}

/// The kernel support in units of h (re-exported for set-ups).
pub const SUPPORT: f64 = kernel::SUPPORT;
