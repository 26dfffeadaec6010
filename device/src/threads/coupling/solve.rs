//! The implicit solve of each gas particle from the deposits gathered on it.
use super::*;

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CoupleArgs<R> {
    pub gas: PhaseBufs<R>,
    pub dust: PhaseBufs<R>,
    /// A^n of the gas (ṽ = v + τ(A + ext_gas)).
    pub acc: *const Vec3<R>,
    pub pres: *const R,
    pub cb: CouplingBufs<R>,
    pub p: Params<R>,
}

/// Gas particle t: the deposits of the gas and of every fraction on it (summed over its deposit
/// rows), the implicit solve, and the increments of its means (and its t_k*).
pub unsafe fn coupling_solve<R: Real>(t: usize, a: &CoupleArgs<R>) {
    let g = &a.gas;
    if t >= g.len() {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let mut dust_dep = [kernels::Deposit::default(); MAX_FRACTIONS];
    if kernels::is_fixed(g.fixed(), t) || gas_skipped(&a.cb, t) {
        store_gradient(t, &a.cb, &[[R::ZERO; 3]; 3]);
        return coupling_finish(t, a, &kernels::Deposit::default(), &dust_dep);
    }
    let pr = &a.cb.pairs;
    let (idx, w) = pr.dep(t, 0, 1 + nf);
    let mut gas_dep = kernels::deposit_rows(
        idx,
        w,
        g.m(),
        g.rho(),
        |b| gas_base_velocity(a, b),
        |b| gas_sound(a, b),
    );
    let d = &a.dust;
    let u = d.v();
    for (f, dep) in dust_dep.iter_mut().enumerate().take(nf) {
        let (idx, w) = pr.dep(t, 1 + f, 1 + nf);
        *dep = kernels::deposit_rows(idx, w, d.m(), d.rho(), |j| u[j], |_| R::ZERO);
    }
    if p.linear_sampling != 0 {
        read_at_particle(t, a, &mut gas_dep, &mut dust_dep);
    }
    coupling_finish(t, a, &gas_dep, &dust_dep);
}

/// Every deposit on gas particle t read at x_t, not at its particles' mass-weighted centroid:
/// corrected by the gas's velocity gradient fitted over t's gas row (method.md §K, "Sampling
/// offsets"). Gas and dust centroids about a gas particle differ by a fraction of h wherever
/// the two lattices differ, and in a Keplerian shear that offset alone reads as a relative
/// velocity of the order of the drift; unchanged where the row does not span the dimensions.
#[inline(always)]
unsafe fn read_at_particle<R: Real>(
    t: usize,
    a: &CoupleArgs<R>,
    gas_dep: &mut kernels::Deposit<R>,
    dust_dep: &mut [kernels::Deposit<R>; MAX_FRACTIONS],
) {
    let (g, d, p) = (&a.gas, &a.dust, &a.p);
    let nf = p.nf as usize;
    let pr = &a.cb.pairs;
    let xt = g.x()[t];
    let dx = |x: Vec3<f64>| p.geom.separation(x, xt).map(R::from_f64);
    let vt = gas_base_velocity(a, t);
    let (idx, w) = pr.dep(t, 0, 1 + nf);
    let Some((grad, first)) = kernels::row_gradient(
        idx,
        w,
        g.m(),
        |b| dx(g.x()[b]),
        |b| crate::sub(gas_base_velocity(a, b), vt),
        p.dim as usize,
    ) else {
        return store_gradient(t, &a.cb, &[[R::ZERO; 3]; 3]);
    };
    store_gradient(t, &a.cb, &grad);
    kernels::read_at_centre(gas_dep, &grad, first);
    for (f, dep) in dust_dep.iter_mut().enumerate().take(nf) {
        let (idx, w) = pr.dep(t, 1 + f, 1 + nf);
        let first = kernels::row_moment(idx, w, d.m(), |j| dx(d.x()[j]));
        kernels::read_at_centre(dep, &grad, first);
    }
}

/// Keep gas particle t's fitted gradient for the damping ([`CouplingBufs::grad`]), if kept.
#[inline(always)]
unsafe fn store_gradient<R: Real>(t: usize, cb: &CouplingBufs<R>, g: &[Vec3<R>; 3]) {
    if !cb.grad.is_null() {
        for (i, gi) in g.iter().enumerate() {
            *cb.grad.add(3 * t + i) = *gi;
        }
    }
}

/// ṽ_b = v_b + τ(A_b + ext_gas) of gas particle b.
#[inline(always)]
pub(super) unsafe fn gas_base_velocity<R: Real>(a: &CoupleArgs<R>, b: usize) -> Vec3<R> {
    crate::axpy(
        *a.gas.v.add(b),
        a.p.tau,
        crate::add(*a.acc.add(b), a.p.ext_gas),
    )
}

/// sqrt(p/ρ) of gas particle b where a stopping-time law needs it, else 0.
#[inline(always)]
pub(super) unsafe fn gas_sound<R: Real>(a: &CoupleArgs<R>, b: usize) -> R {
    if a.p.needs_gas_state != 0 {
        let rho = *a.gas.rho.add(b);
        a.p.eos().isothermal_speed(rho, *a.pres.add(b))
    } else {
        R::ZERO
    }
}

/// The implicit solve of gas particle t from its deposits; writes the increments of its means
/// and its t_k* (zeros and +∞ for a fixed particle, whose deposits are empty).
#[inline(always)]
pub(super) unsafe fn coupling_finish<R: Real>(
    t: usize,
    a: &CoupleArgs<R>,
    gas_dep: &kernels::Deposit<R>,
    dust_dep: &[kernels::Deposit<R>; MAX_FRACTIONS],
) {
    let p = &a.p;
    let nf = p.nf as usize;
    let laws = p.stopping_laws();
    let inc = kernels::kernel_increments(
        gas_dep,
        &dust_dep[..nf],
        &laws[..nf],
        p.tau,
        p.eos().gamma_root(),
    );
    *a.cb.dv.add(t) = inc.dv;
    for f in 0..nf {
        *a.cb.du.add(t * nf + f) = inc.du[f];
        *a.cb.t_stop.add(t * nf + f) = inc.t_stop[f];
    }
    if p.damp_dispersion != 0 {
        let mean = |d: &kernels::Deposit<R>| {
            if d.mass > R::ZERO {
                crate::scale(R::ONE / d.mass, d.mom)
            } else {
                [R::ZERO; 3]
            }
        };
        *a.cb.v_new.add(t) = crate::add(mean(gas_dep), inc.dv);
        for (f, dep) in dust_dep.iter().enumerate().take(nf) {
            *a.cb.u_new.add(t * nf + f) = crate::add(mean(dep), inc.du[f]);
        }
    }
}
