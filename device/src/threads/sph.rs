//! SPH: density, EOS, forces.
use super::*;

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
    /// The positions, for a locally isothermal gas (null otherwise).
    pub x: *const Vec3<f64>,
    pub p: Params<R>,
}

pub unsafe fn eos<R: Real>(t: usize, a: &EosArgs<R>) {
    if t >= a.n as usize {
        return;
    }
    let e = if a.e.is_null() { R::ZERO } else { *a.e.add(t) };
    // Locally isothermal gas: isothermal at the sound speed of its place.
    let eos = if a.p.local_cs.on != 0 && !a.x.is_null() {
        crate::eos::Eos::Isothermal {
            cs: R::from_f64(a.p.local_cs.at(*a.x.add(t))),
        }
    } else {
        a.p.eos()
    };
    let (p, c) = kernels::eos_at(&eos, *a.rho.add(t), e);
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
    /// 1: the step's limits with each particle's own h from `kernel_at` (variable h).
    pub own_h: u32,
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
    // A^n includes the central point mass and its edge zones' damping (fixed particles are
    // never kicked).
    let mut rate = 0.0;
    let acc = if a.p.gravity.is_on() {
        let x = g.x()[t];
        let pm = &a.p.gravity;
        rate = pm.damp_rate(x);
        let damp = pm.damping(x, view.v[t].map(|c| c.to_f64()));
        crate::add(r.acc, crate::add(pm.accel(x), damp).map(R::from_f64))
    } else {
        r.acc
    };
    *a.acc.add(t) = acc;
    if !a.dedt.is_null() {
        *a.dedt.add(t) = r.dedt;
    }
    if !a.vsig.is_null() {
        *a.vsig.add(t) = r.vsig;
    }
    // Fixed particles (walls; over ranks the ghosts, whose kernels this rank does not solve)
    // stay out of the step's maxima: their owners count them.
    if kernels::is_fixed(view.fixed, t) {
        return;
    }
    let am = Real::sqrt(dot(acc, acc));
    // Variable h: the limits with each particle's own h (method.md §T), as maxima scaled by
    // h_ref/h_a, so that h_ref / max = min h_a/v_sig,a (and the same for the force limit).
    let scale = if a.own_h != 0 {
        a.p.h / sl(a.kernel_at, n)[t].h
    } else {
        R::ONE
    };
    atomic_max_u64(a.limits, kernels::ordered_bits(r.vsig * scale));
    atomic_max_u64(a.limits.add(1), kernels::ordered_bits(am * scale));
    if rate > 0.0 {
        atomic_max_u64(a.limits.add(2), kernels::ordered_bits(R::from_f64(rate)));
    }
}
