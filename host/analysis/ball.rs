//! Exact checks of the gas–dust ball into vacuum (method.md §6.1) that need no reference
//! solution: the undisturbed core and the Lagrange–Jacobi identity.
use crate::particles::State;
use serde::{Deserialize, Serialize};

/// Deviation of the core from the initial state, at one output time.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct CoreCheck {
    pub t: f64,
    /// Core radius: R0 − c_s t − 2h (c_s the frozen gas sound speed, 2h the kernel support).
    pub r_core: f64,
    pub particles: usize,
    /// max |ρ_g/ρ0 − 1|, max |p/p0 − 1|, max |v|/c_s over gas in the core; max |ρ_d/ρ_d0 − 1|, |u|/c_s over dust.
    pub rho_g: f64,
    pub p: f64,
    pub v: f64,
    pub rho_d: f64,
    pub u: f64,
}

/// The core check of the particles every process of `c` holds a share of (`state`: this
/// process's; collective: the counts summed, the largest deviations over the processes);
/// `None` once the core has shrunk to nothing.
pub fn core_check(
    c: &dyn crate::dist::Comm,
    state: &State,
    ball: (f64, f64, f64, f64, f64, f64),
) -> Option<CoreCheck> {
    let check = core_check_here(state, ball)?;
    let mut n = [check.particles as u64];
    c.sum_u64(&mut n);
    let mut most = [check.rho_g, check.p, check.v, check.rho_d, check.u];
    c.max_f64(&mut most);
    let [rho_g, p, v, rho_d, u] = most;
    Some(CoreCheck {
        particles: n[0] as usize,
        rho_g,
        p,
        v,
        rho_d,
        u,
        ..check
    })
}

/// [`core_check`] of this process's particles: (r0, ρ0, ρ_d0, p0, c_s, h) the ball's radius,
/// background gas and dust densities, pressure, sound speed and smoothing length.
fn core_check_here(
    state: &State,
    (r0, rho0, rho_d0, p0, cs, h): (f64, f64, f64, f64, f64, f64),
) -> Option<CoreCheck> {
    let r_core = r0 - cs * state.t - 2.0 * h;
    if r_core <= 0.0 {
        return None;
    }
    let inside = |x: &[f64; 3]| x[0] * x[0] + x[1] * x[1] + x[2] * x[2] < r_core * r_core;
    let speed = |v: &[f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let g = &state.gas;
    let mut c = CoreCheck {
        t: state.t,
        r_core,
        particles: 0,
        rho_g: 0.0,
        p: 0.0,
        v: 0.0,
        rho_d: 0.0,
        u: 0.0,
    };
    for i in (0..g.ph.len()).filter(|&i| inside(&g.ph.x[i])) {
        c.particles += 1;
        c.rho_g = c.rho_g.max((g.ph.rho[i] / rho0 - 1.0).abs());
        c.p = c.p.max((g.p[i] / p0 - 1.0).abs());
        c.v = c.v.max(speed(&g.ph.v[i]) / cs);
    }
    for d in &state.dust {
        for j in (0..d.len()).filter(|&j| inside(&d.x[j])) {
            c.rho_d = c.rho_d.max((d.rho[j] / rho_d0 - 1.0).abs());
            c.u = c.u.max(speed(&d.v[j]) / cs);
        }
    }
    Some(c)
}

/// I = Σ m r² over all particles, and the right side of the Lagrange–Jacobi identity
/// d²I/dt² = 2 Σ m|v|² + 6 Σ_gas m p/ρ (valid in 3D; in d dimensions 2d replaces 6).
pub fn lagrange_jacobi_terms(state: &State, dim: u32) -> (f64, f64) {
    lagrange_jacobi_terms_where(state, dim, |_| true)
}

/// [`lagrange_jacobi_terms`] over the particles `keep(n)` keeps, n counting every particle,
/// the gas first, then each dust fraction (a rank's own particles beside its ghosts).
pub fn lagrange_jacobi_terms_where(
    state: &State,
    dim: u32,
    keep: impl Fn(usize) -> bool,
) -> (f64, f64) {
    let mut i = 0.0;
    let mut ke2 = 0.0;
    let mut n = 0;
    let mut add = |ph: &crate::particles::Phase| {
        for (m, (x, v)) in ph.m.iter().zip(ph.x.iter().zip(&ph.v)) {
            if keep(n) {
                i += m * (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
                ke2 += 2.0 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            }
            n += 1;
        }
    };
    add(&state.gas.ph);
    for d in &state.dust {
        add(d);
    }
    let g = &state.gas;
    let pv: f64 = (0..g.ph.len())
        .filter(|&k| keep(k))
        .map(|k| g.ph.m[k] * g.p[k] / g.ph.rho[k])
        .sum();
    (i, ke2 + 2.0 * dim as f64 * pv)
}

/// The identity checked on a series (t, I, rhs) with a constant step: the largest
/// |d²I/dt² − rhs| / rhs over interior points (central second differences).
pub fn lagrange_jacobi_deviation(series: &[(f64, f64, f64)]) -> Option<f64> {
    if series.len() < 3 {
        return None;
    }
    let mut worst: f64 = 0.0;
    for w in series.windows(3) {
        let (t0, i0, _) = w[0];
        let (t1, i1, r1) = w[1];
        let (t2, i2, _) = w[2];
        let (a, b) = (t1 - t0, t2 - t1);
        // Non-uniform central second difference.
        let d2 = 2.0 * (a * i2 - (a + b) * i1 + b * i0) / (a * b * (a + b));
        worst = worst.max((d2 - r1).abs() / r1.abs().max(1e-300));
    }
    Some(worst)
}
