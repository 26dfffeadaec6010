//! After the solve: each particle's return, the damped dispersion, the dust's stopping times
//! and the drag heat.
use super::*;

/// Gas particle g's field `f` read at x (its gradient times x − x_g added where kept).
#[inline(always)]
unsafe fn field_at<R: Real>(a: &ReturnArgs<R>, g: usize, f: Vec3<R>, x: Vec3<f64>) -> Vec3<R> {
    if a.cb.grad.is_null() {
        return f;
    }
    let d = a.p.geom.separation(x, a.gas.x()[g]).map(R::from_f64);
    let gr = a.cb.grad.add(3 * g);
    [
        f[0] + crate::dot(*gr, d),
        f[1] + crate::dot(*gr.add(1), d),
        f[2] + crate::dot(*gr.add(2), d),
    ]
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct ReturnArgs<R> {
    pub gas: PhaseBufs<R>,
    /// The phase that receives its increments (the gas itself, or the dust).
    pub ph: PhaseBufs<R>,
    /// A^n for the gas (its base velocity is ṽ = v + τ(A + ext_gas)); null for the dust (ũ).
    pub acc: *const Vec3<R>,
    /// 1: `ph` is the gas.
    pub is_gas: u32,
    pub cb: CouplingBufs<R>,
    /// For [`coupling_tstop`]: the stopping time of every particle of `ph`.
    pub out: *mut R,
    /// Drag heating: the kinetic energy each particle of `ph` loses; null without heating.
    pub loss: *mut R,
    pub p: Params<R>,
}

/// Return row of particle t of `a.ph` (gas t, or n_gas + dust t).
#[inline(always)]
unsafe fn ret_row<R: Real>(t: usize, a: &ReturnArgs<R>) -> (&[u32], &[R]) {
    let row = if a.is_gas != 0 { t } else { a.gas.len() + t };
    a.cb.pairs.ret(row)
}

/// Particle t of `ph` gets its base velocity plus Σ_a w_ta Δ_a.
pub unsafe fn coupling_return<R: Real>(t: usize, a: &ReturnArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() || kernels::is_fixed(ph.fixed(), t) {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let v = *ph.v.add(t);
    let is_gas = a.is_gas != 0;
    let (base, s, f) = if is_gas {
        let acc = crate::add(*a.acc.add(t), p.ext_gas);
        (crate::axpy(v, p.tau, acc), *a.cb.s_gas.add(t), 0)
    } else {
        (v, *a.cb.s_dust.add(t), ph.group_of(t))
    };
    let (idx, w) = ret_row(t, a);
    let inc = kernels::gather_rows(idx, w, s, |g| {
        if is_gas {
            *a.cb.dv.add(g)
        } else {
            *a.cb.du.add(g * nf + f)
        }
    });
    let new = crate::add(base, inc);
    if !a.loss.is_null() {
        *a.loss.add(t) = drag::kinetic_loss(*ph.m.add(t), base, new);
    }
    *ph.v.add(t) = new;
}

/// `idic.dispersion = "damped"` (method.md §K, "The unresolved dispersion"), after the return
/// of both phases. A gas particle records its deviation from its smoothed new field,
/// d_a = v_a − Σ_c w_ac V_c^{n+1}; then (a second launch, once every d_a is there) a dust
/// particle j relaxes its own deviation from the smoothed field it should follow,
/// δ_j = u_j − Σ_a w_ja (U_a^{n+1} + d_a), by β/(1 + β), β = τ/t_j (backward Euler, t_j =
/// Σ_a w_ja t_k,a), and records what it lost for [`coupling_react`]. For a smooth field carried
/// alike by gas and dust the gas's deviation equals the dust's to high order, so only what the
/// kernel does not resolve is damped. A kernel of its own: the return stays as lean as without.
pub unsafe fn coupling_damp<R: Real>(t: usize, a: &ReturnArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() || kernels::is_fixed(ph.fixed(), t) {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let is_gas = a.is_gas != 0;
    let (s, f) = if is_gas {
        (*a.cb.s_gas.add(t), 0)
    } else {
        (*a.cb.s_dust.add(t), ph.group_of(t))
    };
    let v = ph.v.add(t);
    if s <= R::ZERO {
        if is_gas {
            *a.cb.gas_dev.add(t) = [R::ZERO; 3];
        } else {
            *a.cb.react.add(t) = [R::ZERO; 3];
        }
        return;
    }
    let (idx, ws) = ret_row(t, a);
    if is_gas {
        let x = ph.x()[t];
        let smooth = kernels::gather_rows(idx, ws, s, |c| field_at(a, c, *a.cb.v_new.add(c), x));
        *a.cb.gas_dev.add(t) = crate::sub(*v, smooth);
        return;
    }
    // One sweep for the target and the stopping time the particle feels.
    let (mut target, mut t_stop) = ([R::ZERO; 3], R::ZERO);
    let x = ph.x()[t];
    for (&g, &w) in idx.iter().zip(ws) {
        let (g, w) = (g as usize, w / s);
        let u = field_at(a, g, *a.cb.u_new.add(g * nf + f), x);
        let aim = crate::add(u, *a.cb.gas_dev.add(g));
        target = crate::axpy(target, w, aim);
        t_stop += w * *a.cb.t_stop.add(g * nf + f);
    }
    let beta = p.tau / t_stop;
    let share = if beta.is_finite() && beta > R::ZERO {
        beta / (R::ONE + beta)
    } else {
        R::ZERO
    };
    let lost = crate::scale(share, crate::sub(*v, target));
    *a.cb.react.add(t) = lost;
    *v = crate::sub(*v, lost);
}

/// `idic.dispersion = "damped"`: gas particle t takes the momentum the damping took from the
/// dust around it, with the deposit's weights (Σ_j w_jt m_j Δu_j / m_t): Σ_a w_ja = 1, so the
/// total momentum is exact.
pub unsafe fn coupling_react<R: Real>(t: usize, a: &CoupleArgs<R>) {
    let g = &a.gas;
    if t >= g.len() || kernels::is_fixed(g.fixed(), t) {
        return;
    }
    let p = &a.p;
    let nf = p.nf as usize;
    let d = &a.dust;
    let mut gained = [R::ZERO; 3];
    for f in 0..nf {
        let (idx, w) = a.cb.pairs.dep(t, 1 + f, 1 + nf);
        let dep =
            kernels::deposit_rows(idx, w, d.m(), d.rho(), |j| *a.cb.react.add(j), |_| R::ZERO);
        gained = crate::add(gained, dep.mom);
    }
    let v = g.v.add(t);
    *v = crate::axpy(*v, R::ONE / *g.m.add(t), gained);
}

/// The stopping time dust particle t feels: Σ_a w_ta t_k,a (+∞ without gas within reach).
pub unsafe fn coupling_tstop<R: Real>(t: usize, a: &ReturnArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let nf = a.p.nf as usize;
    let s = *a.cb.s_dust.add(t);
    let out = if s <= R::ZERO {
        R::from_f64(f64::INFINITY)
    } else {
        let f = ph.group_of(t);
        let (idx, w) = ret_row(t, a);
        kernels::gather_rows(idx, w, s, |g| {
            [*a.cb.t_stop.add(g * nf + f), R::ZERO, R::ZERO]
        })[0]
    };
    *a.out.add(t) = out;
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CouplingHeatArgs<R> {
    pub couple: CoupleArgs<R>,
    /// Kinetic energy lost per gas / dust particle in this drag pass ([`coupling_return`]).
    pub loss_gas: *const R,
    pub loss_dust: *const R,
    /// Out: drag heat per unit mass of every gas particle.
    pub heat: *mut R,
}

/// Drag heat of gas particle t under the kernel coupling: Σ_q w_qt ΔE_q / m_t, every particle's
/// loss spread with its own weights (Σ_a w_qa = 1: the gas gains what the particles lose), as
/// the deposit of the losses as masses (method.md §K).
pub unsafe fn coupling_heat<R: Real>(t: usize, a: &CouplingHeatArgs<R>) {
    let c = &a.couple;
    let g = &c.gas;
    if t >= g.len() {
        return;
    }
    let p = &c.p;
    if kernels::is_fixed(g.fixed(), t) || gas_skipped(&c.cb, t) {
        *a.heat.add(t) = R::ZERO;
        return;
    }
    let stride = 1 + p.nf as usize;
    let zero = [R::ZERO; 3];
    let pr = &c.cb.pairs;
    let (idx, w) = pr.dep(t, 0, stride);
    let loss_gas = sl(a.loss_gas, g.len());
    let mut q = kernels::deposit_rows(idx, w, loss_gas, g.rho(), |_| zero, |_| R::ZERO).mass;
    let d = &c.dust;
    let loss_dust = sl(a.loss_dust, d.len());
    for f in 0..p.nf as usize {
        let (idx, w) = pr.dep(t, 1 + f, stride);
        q += kernels::deposit_rows(idx, w, loss_dust, d.rho(), |_| zero, |_| R::ZERO).mass;
    }
    *a.heat.add(t) = q / *g.m.add(t);
}
