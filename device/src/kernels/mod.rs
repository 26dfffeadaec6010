//! Kernel bodies: what one GPU thread computes, as a safe function of an index and slices.
//!
//! The CPU backend calls these from rayon loops and the PTX entry points of [`crate::ptx`] call
//! them from one thread each, so the two backends share not only the formulas but the loops
//! around them (neighbour walk, summation order, cell couplings). Fixed particles (walls) are
//! marked in a `fixed` slice; an empty slice means none is fixed.
use crate::drag::{self, CellMeans, StoppingLaw};
use crate::eos::Eos;
use crate::grid::{for_neighbours, for_neighbours_within, CellLookup, GridGeom};
use crate::kernel::KernelAt;
use crate::sph::{self, GasPair, GasState, Viscosity};
use crate::{add, axpy, scale, sub, update, Real, Vec3};
use core::sync::atomic::{AtomicU32, Ordering::Relaxed};

mod coupling;
pub use coupling::*;

/// Largest number of dust fractions a scene may have (the GPU cell kernel keeps per-fraction
/// sums in registers / local memory).
pub const MAX_FRACTIONS: usize = 32;

#[inline(always)]
pub fn is_fixed(fixed: &[bool], i: usize) -> bool {
    !fixed.is_empty() && fixed[i]
}

/// One phase sorted by cell key, as the neighbour walk sees it. Positions and the grid are f64
/// in every precision: separations are formed in f64 and only then rounded to R, so f32 keeps
/// its relative precision on r_ab however far the particles sit from the origin
/// (docs/accuracy.md, "f32 against f64").
#[derive(Clone, Copy)]
pub struct Sorted<'a, R> {
    pub geom: &'a GridGeom<f64>,
    pub look: CellLookup<'a>,
    pub x: &'a [Vec3<f64>],
    /// The phase's neighbour list ([`NeighbourList`]), or empty: then every walk scans cells.
    pub list: NeighbourList<'a>,
    pub _r: core::marker::PhantomData<R>,
}

/// Each particle's neighbours within the search radius, in the order the cell walk visits them:
/// `stride` slots per particle and, in `count`, 1 + the number found (0: not recorded yet).
/// The first pass of a layer over a particle ([`Sorted::walk_own`]) scans the cells and
/// records; later passes replay (same pairs, same order, same arithmetic: results are
/// bit-identical with and without lists). A particle with more than `stride` neighbours keeps
/// scanning; `max` collects the largest count so that the host can widen the stride
/// (docs/performance.md, "Neighbour lists").
/// Atomics only so that this stays safe code: each row and count is touched by one thread
/// (relaxed loads and stores are plain ones on x86 and in PTX).
#[derive(Clone, Copy, Default)]
pub struct NeighbourList<'a> {
    pub index: &'a [AtomicU32],
    pub count: &'a [AtomicU32],
    pub max: Option<&'a AtomicU32>,
    pub stride: usize,
}

/// Where a walk is centred: on particle i of the walked phase itself (its neighbour list, where
/// there is one, replays the walk: same pairs, same order, same bits), or at any point.
#[derive(Clone, Copy, Debug)]
pub enum Centre {
    Own(usize),
    Point(Vec3<f64>),
}

impl<R: Real> Sorted<'_, R> {
    /// The neighbour walk around `c`: [`Self::walk_own`] or [`Self::walk`].
    #[inline(always)]
    pub fn walk_at(&self, c: Centre, f: impl FnMut(usize, Vec3<R>, R)) {
        match c {
            Centre::Own(i) => self.walk_own(i, f),
            Centre::Point(x) => self.walk(x, f),
        }
    }

    /// The neighbour walk around `xi`: `f(j, xi − x_j, r²)` in R.
    #[inline(always)]
    pub fn walk(&self, xi: Vec3<f64>, mut f: impl FnMut(usize, Vec3<R>, R)) {
        for_neighbours(self.geom, &self.look, self.x, xi, |j, dx, r2| {
            f(j, dx.map(R::from_f64), R::from_f64(r2))
        });
    }

    /// The neighbour walk around particle i of this phase: replayed from its list when it has
    /// one, recorded into it on the layer's first pass ([`NeighbourList`]), else over the cells.
    #[inline(always)]
    pub fn walk_own(&self, i: usize, mut f: impl FnMut(usize, Vec3<R>, R)) {
        // The GPU kernels are built without lists: their recording and replaying copies of
        // `f` cost the forces kernel 26 registers and 350 B of stack (ptxas, sm_90) even when
        // no list is passed, and lists are unmeasured on a GPU (docs/performance.md).
        #[cfg(not(target_arch = "nvptx64"))]
        if self.walk_list(i, &mut f) {
            return;
        }
        self.walk(self.x[i], f)
    }

    /// [`Self::walk_own`] within `radius` of particle i ([`for_neighbours_within`]): a gather
    /// over its own support. A list, where the particle has one, replays (or records) the whole
    /// walk, which the later passes of the layer need.
    #[inline(always)]
    pub fn walk_own_within(&self, i: usize, radius: f64, mut f: impl FnMut(usize, Vec3<R>, R)) {
        #[cfg(not(target_arch = "nvptx64"))]
        if self.walk_list(i, &mut f) {
            return;
        }
        for_neighbours_within(
            self.geom,
            &self.look,
            self.x,
            self.x[i],
            radius,
            |j, dx, r2| f(j, dx.map(R::from_f64), R::from_f64(r2)),
        );
    }

    /// [`Self::walk_own`] through the list: false when particle i has none (no list, or more
    /// neighbours than its slots), and nothing was visited.
    #[cfg(not(target_arch = "nvptx64"))]
    #[inline(always)]
    fn walk_list(&self, i: usize, f: &mut impl FnMut(usize, Vec3<R>, R)) -> bool {
        let l = self.list;
        let (Some(cnt), Some(max)) = (l.count.get(i), l.max) else {
            return false;
        };
        let xi = self.x[i];
        let row = &l.index[i * l.stride..(i + 1) * l.stride];
        let c = cnt.load(Relaxed) as usize;
        if c == 0 {
            let mut k = 0usize;
            self.walk(xi, |j, dx, r2| {
                if let Some(slot) = row.get(k) {
                    slot.store(j as u32, Relaxed);
                }
                k += 1;
                f(j, dx, r2);
            });
            cnt.store(k as u32 + 1, Relaxed);
            // A plain load first: the read-modify-write only when it raises the max.
            if k as u32 > max.load(Relaxed) {
                max.fetch_max(k as u32, Relaxed);
            }
            return true;
        }
        let Some(js) = row.get(..c - 1) else {
            return false;
        };
        for j in js {
            let j = j.load(Relaxed) as usize;
            let dx = self.geom.separation(xi, self.x[j]);
            let r2 = crate::dot(dx, dx);
            f(j, dx.map(R::from_f64), R::from_f64(r2));
        }
        true
    }
}

/// SPH density of particle i by summation over its own phase (self-contribution included);
/// fixed particles keep `rho_fixed`.
#[inline(always)]
pub fn density_at<R: Real>(
    s: &Sorted<'_, R>,
    m: &[R],
    fixed: &[bool],
    rho_fixed: R,
    i: usize,
    h: R,
    dim: u32,
) -> R {
    if is_fixed(fixed, i) {
        return rho_fixed;
    }
    let k = KernelAt::new(h, dim);
    let mut rho = R::ZERO;
    s.walk_own(i, |j, _, r2| {
        rho += m[j] * k.w(r2.sqrt());
    });
    rho
}

/// Continuity-equation density rate of particle i within its own phase:
/// dρ_i/dt = Σ_j m_j (v_i − v_j)·∇_i W_ij (zero for fixed particles).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn density_rate_at<R: Real>(
    s: &Sorted<'_, R>,
    v: &[Vec3<R>],
    m: &[R],
    fixed: &[bool],
    i: usize,
    h: R,
    dim: u32,
) -> R {
    if is_fixed(fixed, i) {
        return R::ZERO;
    }
    let vi = v[i];
    let k = KernelAt::new(h, dim);
    let mut rate = R::ZERO;
    s.walk_own(i, |j, dx, r2| {
        rate += sph::density_rate_term(m[j], vi, v[j], dx, r2.sqrt(), &k);
    });
    rate
}

/// Variable smoothing length (Price 2012; Phantom): h_i solves Σ_j m_j W(r_ij, h_i) =
/// m_i (hfact/h_i)^d. Result of [`solve_h_at`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HSolve<R> {
    pub h: R,
    /// ρ_i = m_i (hfact/h_i)^d at the accepted h.
    pub rho: R,
    /// The grad-h term Ω_i = 1 + (h_i/(d ρ_i)) Σ_j m_j ∂W_ij/∂h_i.
    pub omega: R,
    /// Newton iterations used (neighbour passes).
    pub iterations: u32,
    /// False if h would leave (0, h_max] or the iteration did not settle.
    pub ok: bool,
}

/// Newton–Raphson for h_i from the guess `h0` (the previous step's h): one neighbour pass per
/// iteration; stops when the relative correction is below `tol`, and accepts the corrected h.
/// `h_max` is half the search radius of the grid: h must stay below it. Fixed particles keep
/// `h0` and `rho_fixed`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn solve_h_at<R: Real>(
    s: &Sorted<'_, R>,
    m: &[R],
    fixed: &[bool],
    rho_fixed: R,
    i: usize,
    h0: R,
    hfact: R,
    h_max: R,
    tol: R,
    dim: u32,
) -> HSolve<R> {
    if is_fixed(fixed, i) {
        return HSolve {
            h: h0,
            rho: rho_fixed,
            omega: R::ONE,
            iterations: 0,
            ok: true,
        };
    }
    let d = R::from_f64(dim as f64);
    let mhd = m[i] * crate::kernel::h_pow_dim(hfact, dim);
    let mut h = h0;
    let mut it = 0;
    loop {
        let k = KernelAt::new(h, dim);
        let (mut sum, mut dsum) = (R::ZERO, R::ZERO);
        // Within 2h (and a thousandth: what lies beyond adds W = ∂W/∂h = 0, so the sums are
        // those of the whole walk to the bit).
        s.walk_own_within(i, 2.002 * h.to_f64(), |j, _, r2| {
            let r = r2.sqrt();
            sum += m[j] * k.w(r);
            dsum += m[j] * k.dw_dh(r);
        });
        it += 1;
        let rho_h = mhd / crate::kernel::h_pow_dim(h, dim);
        // f(h) = Σ m W(h) − m (hfact/h)^d;  f'(h) = Σ m ∂W/∂h + d ρ_h / h.
        let f = sum - rho_h;
        let df = dsum + d * rho_h / h;
        // A Newton step is kept within [h/2, 2h]: from a guess far off (the reference h on the
        // dense side of a shock tube, 8× too large) the plain step lands at h < 0. Steps that
        // small never change a converging solve.
        let h_new = if df > R::ZERO {
            (h - f / df)
                .max(h * R::from_f64(0.5))
                .min(h * R::from_f64(2.0))
        } else if f > R::ZERO {
            // f'(h) ≤ 0 (across a density jump, widening h takes in much thinner gas): no
            // Newton step; halve h while the kernel sum exceeds ρ(h), double it otherwise, until
            // the Newton step applies again (no libm root: the GPU build links none).
            h * R::from_f64(0.5)
        } else {
            h + h
        };
        let done = (h_new - h).abs() < tol * h;
        let bad = !(h_new > R::ZERO && h_new <= h_max) || it >= 30;
        if done || bad {
            let hh = if bad { h } else { h_new };
            let rho = mhd / crate::kernel::h_pow_dim(hh, dim);
            return HSolve {
                h: hh,
                rho,
                omega: R::ONE + h / (d * rho_h) * dsum,
                iterations: it,
                ok: done && !bad,
            };
        }
        h = h_new;
    }
}

/// IAD matrix C_a = τ_a⁻¹ of gas particle i ([`sph::iad_inverse`]), from the neighbours within
/// its own support 2h_i (`k[i]`); volumes V_b = m_b/ρ_b. Fixed particles get the same matrix
/// (their neighbours read it).
#[inline(always)]
pub fn iad_matrix_at<R: Real>(
    s: &Sorted<'_, R>,
    m: &[R],
    rho: &[R],
    k: &[KernelAt<R>],
    i: usize,
) -> sph::Sym3<R> {
    let ki = k[i];
    let mut t = [R::ZERO; 6];
    // W(h_i) = 0 beyond 2h_i and r_ab = 0 for b = a: no test needed.
    s.walk_own(i, |j, dx, r2| {
        let c = sph::iad_moment_term(m[j] / rho[j], dx, ki.w(r2.sqrt()));
        for (a, b) in t.iter_mut().zip(c) {
            *a += b;
        }
    });
    sph::iad_inverse(t, ki.dim)
}

/// Forces on gas particle i with the IAD gradient ([`sph::gas_pair_iad`]): per-particle
/// kernels `k` (all equal for a fixed h), `pt` = p/ρ², IAD matrices `c`.
#[inline(always)]
pub fn forces_iad_at<R: Real>(
    s: &Sorted<'_, R>,
    g: &GasView<'_, R>,
    k: &[KernelAt<R>],
    pt: &[R],
    c: &[sph::Sym3<R>],
    i: usize,
    av: Option<&Viscosity<R>>,
) -> GasPair<R> {
    forces_two_sided_at(s, g, k, i, |a, b, j, dx, r2| {
        sph::gas_pair_iad(a, b, pt[i], pt[j], dx, r2, &k[i], &k[j], &c[i], &c[j], av)
    })
}

/// The force loop of the per-particle-h forms: neighbours j within either support (the result
/// must not depend on the search radius), `pair(a, b, j, r_ab, r²)` per pair.
#[inline(always)]
fn forces_two_sided_at<R: Real>(
    s: &Sorted<'_, R>,
    g: &GasView<'_, R>,
    k: &[KernelAt<R>],
    i: usize,
    pair: impl Fn(&GasState<R>, &GasState<R>, usize, Vec3<R>, R) -> GasPair<R>,
) -> GasPair<R> {
    let mut out = GasPair {
        acc: [R::ZERO; 3],
        dedt: R::ZERO,
        vsig: R::ZERO,
    };
    if is_fixed(g.fixed, i) {
        return out;
    }
    let a = g.state(s.x[i], i);
    out.vsig = a.c;
    let s2 = R::from_f64(crate::kernel::SUPPORT * crate::kernel::SUPPORT);
    s.walk_own(i, |j, dx, r2| {
        let hm = k[i].h.max(k[j].h);
        if j == i || r2 >= s2 * hm * hm {
            return;
        }
        let pr = pair(&a, &g.state(s.x[j], j), j, dx, r2);
        out.acc = add(out.acc, pr.acc);
        out.dedt += pr.dedt;
        out.vsig = out.vsig.max(pr.vsig);
    });
    out
}

/// The gas fields the force loop reads.
#[derive(Clone, Copy)]
pub struct GasView<'a, R> {
    pub v: &'a [Vec3<R>],
    pub m: &'a [R],
    pub rho: &'a [R],
    pub p: &'a [R],
    pub c: &'a [R],
    pub fixed: &'a [bool],
}

impl<R: Real> GasView<'_, R> {
    #[inline(always)]
    fn state(&self, x: Vec3<f64>, i: usize) -> GasState<R> {
        GasState {
            x,
            v: self.v[i],
            m: self.m[i],
            rho: self.rho[i],
            p: self.p[i],
            c: self.c[i],
        }
    }
}

/// Non-drag acceleration A_i, de_i/dt and the largest signal speed of gas particle i (all zero
/// for fixed particles).
#[inline(always)]
pub fn forces_at<R: Real>(
    s: &Sorted<'_, R>,
    g: &GasView<'_, R>,
    i: usize,
    h: R,
    dim: u32,
    av: Option<&Viscosity<R>>,
) -> GasPair<R> {
    let mut out = GasPair {
        acc: [R::ZERO; 3],
        dedt: R::ZERO,
        vsig: R::ZERO,
    };
    if is_fixed(g.fixed, i) {
        return out;
    }
    let a = g.state(s.x[i], i);
    let k = KernelAt::new(h, dim);
    let pa = a.p / (a.rho * a.rho);
    out.vsig = a.c;
    s.walk_own(i, |j, dx, r2| {
        if j == i {
            return;
        }
        let b = g.state(s.x[j], j);
        let pb = b.p / (b.rho * b.rho);
        let pr = sph::gas_pair(&a, &b, pa, pb, dx, r2, &k, av);
        out.acc = add(out.acc, pr.acc);
        out.dedt += pr.dedt;
        out.vsig = out.vsig.max(pr.vsig);
    });
    out
}

/// [`forces_at`] for variable smoothing lengths, with per-particle kernels `k` (at h_j) and
/// pressure terms `pt` = p_j/(Ω_j ρ_j²) (grad-h, Price 2012):
/// A_i = −Σ_j m_j [pt_i ∇W_ij(h_i) + pt_j ∇W_ij(h_j) + Π_ij ∇̄W_ij],
/// de_i/dt = pt_i Σ_j m_j v_ij·∇W_ij(h_i) + ½ Σ_j m_j Π_ij v_ij·∇̄W_ij, with ∇̄W the mean of the
/// two gradients. The grid's search radius must cover 2 max h.
#[inline(always)]
pub fn forces_vh_at<R: Real>(
    s: &Sorted<'_, R>,
    g: &GasView<'_, R>,
    k: &[KernelAt<R>],
    pt: &[R],
    i: usize,
    av: Option<&Viscosity<R>>,
) -> GasPair<R> {
    forces_two_sided_at(s, g, k, i, |a, b, j, dx, r2| {
        sph::gas_pair_vh(a, b, pt[i], pt[j], dx, r2, &k[i], &k[j], av)
    })
}

/// Pressure and sound speed of a gas particle from its density (and energy).
#[inline(always)]
pub fn eos_at<R: Real>(eos: &Eos<R>, rho: R, e: R) -> (R, R) {
    let p = eos.pressure(rho, e);
    (p, eos.sound_speed(rho, p))
}

/// Gas sums over one cell's particle range [a, b).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GasSums<R> {
    pub mass: R,
    pub count: u32,
    /// Σ m ṽ with ṽ = v + τA.
    pub mom: Vec3<R>,
    /// Σ ρ and Σ sqrt(p/ρ) (for laws that need the gas state).
    pub rho: R,
    pub cs: R,
}

/// Dust sums of one fraction over one cell's particle range.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DustSums<R> {
    pub mass: R,
    pub count: u32,
    pub mom: Vec3<R>,
    pub rho: R,
}

/// Gas sums over particles [a, b) of a sorted phase; `v_tilde(i)` gives ṽ_i.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn gas_cell_sums<R: Real>(
    a: usize,
    b: usize,
    m: &[R],
    rho: &[R],
    p: &[R],
    fixed: &[bool],
    eos: &Eos<R>,
    needs_state: bool,
    v_tilde: impl Fn(usize) -> Vec3<R>,
) -> GasSums<R> {
    let mut s = GasSums {
        mass: R::ZERO,
        count: 0,
        mom: [R::ZERO; 3],
        rho: R::ZERO,
        cs: R::ZERO,
    };
    for i in a..b {
        if is_fixed(fixed, i) {
            continue;
        }
        s.mass += m[i];
        s.count += 1;
        s.mom = axpy(s.mom, m[i], v_tilde(i));
        if needs_state {
            s.rho += rho[i];
            s.cs += eos.isothermal_speed(rho[i], p[i]);
        }
    }
    s
}

/// Dust sums over particles [a, b) of one fraction.
#[inline(always)]
pub fn dust_cell_sums<R: Real>(
    a: usize,
    b: usize,
    m: &[R],
    u: &[Vec3<R>],
    rho: &[R],
    fixed: &[bool],
    needs_rho: bool,
) -> DustSums<R> {
    let mut s = DustSums {
        mass: R::ZERO,
        count: 0,
        mom: [R::ZERO; 3],
        rho: R::ZERO,
    };
    for j in a..b {
        if is_fixed(fixed, j) {
            continue;
        }
        s.mass += m[j];
        s.count += 1;
        s.mom = axpy(s.mom, m[j], u[j]);
        if needs_rho {
            s.rho += rho[j];
        }
    }
    s
}

/// What the drag update of a cell hands to its particles: per fraction ε_k, β_k = τ/t_k*,
/// u_k*^{n+1}, and the gas v*^{n+1}.
#[derive(Clone, Copy, Debug)]
pub struct CellCoupling<R> {
    pub eps: [R; MAX_FRACTIONS],
    pub beta: [R; MAX_FRACTIONS],
    pub t_stop: [R; MAX_FRACTIONS],
    pub u_new: [Vec3<R>; MAX_FRACTIONS],
    pub v_new: Vec3<R>,
}

/// How one dust fraction couples in a cell, from the cell's sums: `None` without both phases
/// in the cell (no drag), else ε_k and the cell stopping time t_k* (method.md §3.4; `None` when
/// the law cannot couple). `gamma_root` turns the mean sqrt(p/ρ) into c_s*.
#[inline(always)]
pub fn fraction_coupling<R: Real>(
    gas: &GasSums<R>,
    d: &DustSums<R>,
    law: &StoppingLaw<R>,
    gamma_root: R,
) -> Option<(R, Option<R>)> {
    if d.count == 0 || gas.count == 0 {
        return None;
    }
    let count = R::from_f64(gas.count as f64);
    let means = CellMeans {
        rho_dust: d.rho / R::from_f64(d.count as f64),
        rho_gas: gas.rho / count,
        cs_gas: gamma_root * gas.cs / count,
    };
    Some((drag::cell_eps(d.mass, gas.mass), law.cell_time(&means)))
}

/// The IDIC cell step from a cell's sums (method.md §3.3–3.4): cell ε_k, stopping times t_k*
/// from each fraction's law (+∞ when it does not couple: no gas or no dust in the cell), and the
/// closed-form implicit solve. `gamma_root` turns the mean sqrt(p/ρ) into c_s*. With
/// `explicit` (the forward-Euler baseline, [`drag::explicit_gas_update`]) there is no solve:
/// the new means handed to the particles are the known means ṽ*, ũ_k*.
#[inline(always)]
pub fn cell_couple<R: Real>(
    gas: &GasSums<R>,
    dust: &[DustSums<R>],
    laws: &[StoppingLaw<R>],
    tau: R,
    gamma_root: R,
    explicit: bool,
) -> CellCoupling<R> {
    let nf = dust.len().min(laws.len()).min(MAX_FRACTIONS);
    let mut u_tilde = [[R::ZERO; 3]; MAX_FRACTIONS];
    for k in 0..nf {
        if dust[k].mass > R::ZERO {
            u_tilde[k] = scale(R::ONE / dust[k].mass, dust[k].mom);
        }
    }
    let v_tilde = if gas.mass > R::ZERO {
        scale(R::ONE / gas.mass, gas.mom)
    } else {
        [R::ZERO; 3]
    };
    let mut c = solve_coupling(v_tilde, &u_tilde[..nf], tau, |k| {
        fraction_coupling(gas, &dust[k], &laws[k], gamma_root)
    });
    if explicit {
        c.v_new = v_tilde;
        c.u_new[..nf].copy_from_slice(&u_tilde[..nf]);
    }
    c
}

/// The implicit solve of one cell (or gas particle) from its means ṽ, ũ_k and, per fraction,
/// `coupling(k)` = (ε_k, t_k*) (`None`: the fraction does not couple there; t `None`: the law
/// cannot couple): fills ε, β = τ/t*, t* (+∞ where uncoupled) and the new means.
#[inline(always)]
fn solve_coupling<R: Real>(
    v_tilde: Vec3<R>,
    u_tilde: &[Vec3<R>],
    tau: R,
    coupling: impl Fn(usize) -> Option<(R, Option<R>)>,
) -> CellCoupling<R> {
    let nf = u_tilde.len().min(MAX_FRACTIONS);
    let inf = R::from_f64(f64::INFINITY);
    let mut c = CellCoupling {
        eps: [R::ZERO; MAX_FRACTIONS],
        beta: [R::ZERO; MAX_FRACTIONS],
        t_stop: [inf; MAX_FRACTIONS],
        u_new: [[R::ZERO; 3]; MAX_FRACTIONS],
        v_new: [R::ZERO; 3],
    };
    for k in 0..nf {
        if let Some((eps, t)) = coupling(k) {
            c.eps[k] = eps;
            if let Some(t) = t {
                c.t_stop[k] = t;
                c.beta[k] = drag::cell_beta(tau, Some(t));
            }
        }
    }
    c.v_new = drag::cell_solve(
        v_tilde,
        &u_tilde[..nf],
        &c.eps[..nf],
        &c.beta[..nf],
        &mut c.u_new[..nf],
    );
    c
}

/// New position of a particle: drift with `w` (v^{n+1}, or v^n for the authors' update) and
/// wrap on periodic axes; fixed particles stay.
#[inline(always)]
pub fn drift_at<R: Real>(
    geom: &GridGeom<f64>,
    x: Vec3<f64>,
    w: Vec3<R>,
    tau: R,
    fixed: bool,
) -> Vec3<f64> {
    if fixed {
        x
    } else {
        // Positions advance in f64 whatever R is (see `Sorted`).
        geom.wrap(update::drift(x, w.map(R::to_f64), tau.to_f64()))
    }
}

/// Order-preserving map of a float to an unsigned integer (for atomic min/max of bounds and
/// time-step limits on the GPU): a < b ⇔ key(a) < key(b) for all non-NaN values.
#[inline(always)]
pub fn ordered_bits<R: Real>(x: R) -> u64 {
    // Widening f32 → f64 is exact and keeps the order (and a NaN's sign).
    let b = x.to_f64().to_bits();
    if b >> 63 == 1 {
        !b
    } else {
        b | (1 << 63)
    }
}

/// Inverse of [`ordered_bits`].
#[inline(always)]
pub fn from_ordered_bits(k: u64) -> f64 {
    if k >> 63 == 1 {
        f64::from_bits(k & !(1 << 63))
    } else {
        f64::from_bits(!k)
    }
}

/// Insertion sort of one search cell's particles (old indices) by (combined key, old index):
/// the stable sort order by cell, restored after the counting sort by search cell.
#[inline(always)]
pub fn sort_segment_by_key(perm: &mut [u32], keys: &[u64]) {
    let at = |p: u32| (keys[p as usize], p);
    for i in 1..perm.len() {
        let v = perm[i];
        let mut j = i;
        while j > 0 && at(perm[j - 1]) > at(v) {
            perm[j] = perm[j - 1];
            j -= 1;
        }
        perm[j] = v;
    }
}

/// Exclusive prefix sum of `chunk` in place, starting from `offset`; returns the running total.
/// The GPU scan runs this per chunk after one thread has scanned the chunk totals.
#[inline(always)]
pub fn scan_exclusive(chunk: &mut [u32], mut offset: u32) -> u32 {
    for v in chunk.iter_mut() {
        let c = *v;
        *v = offset;
        offset += c;
    }
    offset
}
