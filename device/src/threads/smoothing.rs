//! Variable smoothing lengths and the IAD gradient (docs/method.md; Price 2012, Garcia-Senz et
//! al. 2012).
use super::*;

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
