//! IDIC (method.md §3): union of occupied cells, the cell step, particle velocities, drag heat,
//! the drift, the energy update and the check.
use super::*;

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
    let base = (t * sc) as u64;
    if sc <= 64 {
        // One bit per IDIC cell of the search cell, set by a walk over its particles: where
        // the cells are small most of them are empty (the 3D box at 0.5 h: 8 cells, 3.4
        // particles a search cell), and a lookup per cell and phase costs more than the walk.
        let mut bits = 0u64;
        let mut mark = |ph: &PhaseBufs<R>, g: usize| {
            let d = ph.dense(&a.p);
            let at = g * a.p.stride() + t;
            let off = (g * a.p.key_stride()) as u64 + base;
            for j in d[at] as usize..d[at + 1] as usize {
                bits |= 1u64 << (*ph.keys.add(j) - off);
            }
        };
        if a.gas.n > 0 {
            mark(&a.gas, 0);
        }
        if a.dust.n > 0 {
            for g in 0..a.dust.groups as usize {
                mark(&a.dust, g);
            }
        }
        let mut i = 0;
        while bits != 0 {
            f(i, base + bits.trailing_zeros() as u64);
            i += 1;
            bits &= bits - 1;
        }
        return;
    }
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
    /// 1 where the cell holds a particle of this rank's own (every cell on one process): the
    /// cell step solves only those; the kicks and the heat leave the others' particles (all
    /// ghosts) as they are, for the halo's refresh after the drift (docs/scaling.md).
    pub mine: *mut u8,
}

/// Whether IDIC cell k holds a particle that is not a ghost (ghost flags per phase, null: no
/// ghosts): a cell of ghosts alone is another rank's to solve.
#[inline(always)]
unsafe fn holds_own<R: Real>(
    gas: &PhaseBufs<R>,
    dust: &PhaseBufs<R>,
    (gas_ghost, dust_ghost): (*const u8, *const u8),
    p: &StepParams<R>,
    k: u64,
) -> bool {
    if gas_ghost.is_null() && dust_ghost.is_null() {
        return true;
    }
    let own = |ph: &PhaseBufs<R>, ghost: *const u8, g: usize| -> bool {
        let (lo, hi) = ph.cell_range(p, g, k);
        (lo..hi).any(|i| ghost.is_null() || *ghost.add(i) == 0)
    };
    let mut any = own(gas, gas_ghost, 0);
    for f in 0..p.nf as usize {
        any |= own(dust, dust_ghost, f);
    }
    any
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CellArgs<R> {
    pub gas: PhaseBufs<R>,
    pub dust: PhaseBufs<R>,
    pub pres: *const R,
    pub acc: *const Vec3<R>,
    pub cells: CellBufs<R>,
    /// Per phase, 1 for a ghost (null: no ghosts, one process).
    pub gas_ghost: *const u8,
    pub dust_ghost: *const u8,
    pub p: Params<R>,
}

/// The IDIC cell step of union cell t: sums (in particle order, as on the CPU), ε, t*, β and
/// the implicit solve; a cell of ghosts alone is left to its owners (`CellBufs::mine`).
pub unsafe fn cell_step<R: Real>(t: usize, a: &CellArgs<R>) {
    let p = &a.p;
    let nu = union_count(&a.cells, p);
    if t >= nu {
        return;
    }
    let k = *a.cells.ukey.add(t);
    let (g, d) = (&a.gas, &a.dust);
    let mine = holds_own(g, d, (a.gas_ghost, a.dust_ghost), p, k);
    *a.cells.mine.add(t) = mine as u8;
    if !mine {
        return;
    }
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
    let k = *a.cells.ukey.add(t);
    if !holds_own(&a.gas, &a.dust, (a.gas_ghost, a.dust_ghost), &a.p, k) {
        return;
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
        let cell = cell_of(g, &a.p, &a.cells, t);
        if *a.cells.mine.add(cell) == 0 {
            return;
        }
        let c = cell * nf;
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
    if *a.cells.mine.add(c) == 0 {
        return;
    }
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
    if t >= union_count(&a.cells, p) || *a.cells.mine.add(t) == 0 {
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
        let c = cell_of(g, &a.p, &a.cells, t);
        if *a.cells.mine.add(c) == 0 {
            // Another rank's cell: this ghost's energy arrives with the refresh.
            return;
        }
        *a.heat.add(c)
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
