//! IDIC: implicit drag in cell (method.md §3), for any number of dust fractions.
//!
//! Convention (method.md §1.1): t_k = ρ_k/K_k; gas drag acceleration Σ_k (ε_k/t_k)(u_k − v),
//! dust drag acceleration −(u_k − v)/t_k.
use crate::{axpy, Real, Vec3};

/// Stopping-time law of one dust fraction (method.md §1.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StoppingLaw<R> {
    /// t_k given.
    ConstantTime { t_stop: R },
    /// Constant drag coefficient K: t_k = ρ_k*/K.
    ConstantK { k: R },
    /// Epstein (the authors' form): t_k = s ρ_s /(ρ_g* c_s*), with `s_rho` = s·ρ_s; with
    /// `stokes` = 4s/(9 λρ_g) > 0 (λ the gas's mean free path, λρ_g = μ m_H/σ a constant),
    /// grains larger than 9λ/4 take the Stokes law t = t_Epstein · 4s/(9λ) (Re < 1), which
    /// meets Epstein's at s = 9λ/4: t_k = s ρ_s /(ρ_g* c_s*) · max(1, `stokes` ρ_g*).
    Epstein { s_rho: R, stokes: R },
}

/// Cell means that a stopping-time law may need.
#[derive(Clone, Copy, Debug)]
pub struct CellMeans<R> {
    /// Mean SPH density of the fraction's particles in the cell.
    pub rho_dust: R,
    /// Mean SPH gas density in the cell.
    pub rho_gas: R,
    /// Cell gas sound speed c_s* = g · mean sqrt(p/ρ) (method.md §3.4).
    pub cs_gas: R,
}

impl<R: Real> StoppingLaw<R> {
    /// The law's stopping time t_k at a gas density, a dust density (the fraction's own) and
    /// a gas sound speed: t_stop; ρ_d/K; s ρ_s/(ρ_g c_s). The one formula of each law, for
    /// the drag's cell means ([`Self::cell_time`]) and the exact solutions alike. Not checked:
    /// no dust (constant K) gives 0, no gas (Epstein) +∞ or less than 0.
    #[inline(always)]
    pub fn stopping_time(&self, rho_gas: R, rho_dust: R, cs_gas: R) -> R {
        match *self {
            StoppingLaw::ConstantTime { t_stop } => t_stop,
            StoppingLaw::ConstantK { k } => rho_dust / k,
            StoppingLaw::Epstein { s_rho, stokes } => {
                let regime = stokes * rho_gas;
                let epstein = s_rho / (rho_gas * cs_gas);
                if regime > R::ONE {
                    epstein * regime
                } else {
                    epstein
                }
            }
        }
    }

    /// Cell stopping time t_k*. Returns +∞-like `None` when the law cannot couple
    /// (no dust density under constant K, no gas under Epstein: a time that is not finite and
    /// positive): the caller then skips drag.
    #[inline(always)]
    pub fn cell_time(&self, m: &CellMeans<R>) -> Option<R> {
        let t = self.stopping_time(m.rho_gas, m.rho_dust, m.cs_gas);
        if t > R::ZERO && t.is_finite() {
            Some(t)
        } else {
            None
        }
    }

    /// Whether the law needs the fraction's own SPH density every step.
    pub fn needs_dust_density(&self) -> bool {
        matches!(self, StoppingLaw::ConstantK { .. })
    }

    /// Whether the law needs gas density and sound speed cell means.
    pub fn needs_gas_state(&self) -> bool {
        matches!(self, StoppingLaw::Epstein { .. })
    }
}

/// Closed-form IDIC cell solve (method.md §3.3), O(N) per cell.
///
/// Inputs: `v_tilde` = gas cell mean of v^n + τA^n; `u_tilde[k]` = fraction-k cell mean of
/// u^n + τB^n; `eps[k]` = ε_k (0 where the fraction is absent); `beta[k]` = τ/t_k* (0 where no
/// drag). Writes u_k*^{n+1} into `u_new[k]` and returns v*^{n+1}.
///
/// Momentum (per unit gas mass) y = ṽ + Σ ε_k ũ_k is conserved exactly: the result is the
/// backward-Euler solution of the linear drag ODE for the cell means.
#[inline]
pub fn cell_solve<R: Real>(
    v_tilde: Vec3<R>,
    u_tilde: &[Vec3<R>],
    eps: &[R],
    beta: &[R],
    u_new: &mut [Vec3<R>],
) -> Vec3<R> {
    let mut num = v_tilde;
    let mut den = R::ONE;
    let n = u_tilde
        .len()
        .min(eps.len())
        .min(beta.len())
        .min(u_new.len());
    for k in 0..n {
        let w = eps[k] * beta[k] / (R::ONE + beta[k]);
        num = axpy(num, w, u_tilde[k]);
        den += w;
    }
    let inv = R::ONE / den;
    let v_new = [num[0] * inv, num[1] * inv, num[2] * inv];
    for k in 0..n {
        u_new[k] = dust_update(u_tilde[k], beta[k], v_new);
    }
    v_new
}

/// Gas particle update (method.md §3.3): v_a^{n+1} = [ṽ_a + Σ ε_k β_k u_k*^{n+1}]/[1 + Σ ε_k β_k],
/// with ṽ_a = v_a^n + τA_a^n.
#[inline]
pub fn gas_update<R: Real>(
    v_tilde_a: Vec3<R>,
    eps: &[R],
    beta: &[R],
    u_new: &[Vec3<R>],
) -> Vec3<R> {
    let mut num = v_tilde_a;
    let mut den = R::ONE;
    let n = u_new.len().min(eps.len()).min(beta.len());
    for k in 0..n {
        let w = eps[k] * beta[k];
        num = axpy(num, w, u_new[k]);
        den += w;
    }
    let inv = R::ONE / den;
    [num[0] * inv, num[1] * inv, num[2] * inv]
}

/// Dust particle update: u^{n+1} = (ũ + β v*^{n+1})/(1 + β), with ũ = u^n + τB^n.
/// β = 0 (no gas in the cell) leaves the particle ballistic.
#[inline(always)]
pub fn dust_update<R: Real>(u_tilde: Vec3<R>, beta: R, v_star_new: Vec3<R>) -> Vec3<R> {
    let inv = R::ONE / (R::ONE + beta);
    [
        (u_tilde[0] + beta * v_star_new[0]) * inv,
        (u_tilde[1] + beta * v_star_new[1]) * inv,
        (u_tilde[2] + beta * v_star_new[2]) * inv,
    ]
}

/// Safety factor of the explicit drag's time-step limit: τ ≤ 0.9 t_s, as Phantom's explicit
/// two-fluid drag (there t_s is the relative-velocity decay time, see [`explicit_rate`]).
pub const EXPLICIT_SAFETY: f64 = 0.9;

/// Explicit (forward-Euler) drag, gas particle: the particle equation of method.md §3.3 with the
/// drag evaluated at the known velocities instead of the new ones,
/// v_a^{n+1} = ṽ_a + Σ_k ε_k β_k (ũ_k* − ṽ_a), with ũ_k* the fraction-k cell mean of u^n (+τB^n).
///
/// Paired with [`explicit_dust_update`] it conserves momentum exactly in every cell: the gas
/// gains Σ_k β_k Σm_k (ũ_k* − ṽ*) (because m_g N_g ε_k = Σm_k), which is what the dust loses.
/// Same arguments as [`gas_update`] (`u_cell[k]` = ũ_k*), so the two methods are interchangeable.
#[inline]
pub fn explicit_gas_update<R: Real>(
    v_tilde_a: Vec3<R>,
    eps: &[R],
    beta: &[R],
    u_cell: &[Vec3<R>],
) -> Vec3<R> {
    let mut v = v_tilde_a;
    let n = u_cell.len().min(eps.len()).min(beta.len());
    for k in 0..n {
        v = axpy(v, eps[k] * beta[k], crate::sub(u_cell[k], v_tilde_a));
    }
    v
}

/// Explicit drag, dust particle: u_j^{n+1} = ũ_j + β_k (ṽ* − ũ_j), with ṽ* the gas cell mean of
/// v^n + τA^n. β = 0 (no gas in the cell) leaves the particle ballistic, as in IDIC.
/// Same arguments as [`dust_update`] (`v_cell` = ṽ*).
#[inline(always)]
pub fn explicit_dust_update<R: Real>(u_tilde: Vec3<R>, beta: R, v_cell: Vec3<R>) -> Vec3<R> {
    axpy(u_tilde, beta, crate::sub(v_cell, u_tilde))
}

/// Upper bound of the fastest drag rate in a cell, Λ = max_k 1/t_k + Σ_k ε_k/t_k (the row-sum
/// norm of the relative-velocity matrix diag(1/t_k) + 1·cᵀ, c_k = ε_k/t_k, of method.md §3.3;
/// for one fraction it is exactly (1+ε)/t, the inverse of the Laibe & Price / Phantom stopping
/// time t_s = t/(1+ε)). `inv_t[k]` = 1/t_k* (0 where the fraction does not couple).
///
/// Forward Euler is stable for τΛ < 2 on the cell means and for β_k, Σε_kβ_k < 2 on particle
/// deviations; the explicit method uses τ ≤ [`EXPLICIT_SAFETY`]/Λ, which keeps all of them
/// ≤ 0.9 (monotone decay). Note that τ ≤ 0.9 t_k alone is unstable once ε > 1.2.
#[inline]
pub fn explicit_rate<R: Real>(eps: &[R], inv_t: &[R]) -> R {
    let mut max = R::ZERO;
    let mut sum = R::ZERO;
    for (e, r) in eps.iter().zip(inv_t) {
        if *r > max {
            max = *r;
        }
        sum += *e * *r;
    }
    max + sum
}

/// Dust-to-gas ratio of a fraction in a cell: ε = Σm_dust / Σm_gas (0 without gas).
#[inline(always)]
pub fn cell_eps<R: Real>(mass_dust: R, mass_gas: R) -> R {
    if mass_gas > R::ZERO {
        mass_dust / mass_gas
    } else {
        R::ZERO
    }
}

/// β = τ/t (0 when there is no coupling).
#[inline(always)]
pub fn cell_beta<R: Real>(tau: R, t_stop: Option<R>) -> R {
    match t_stop {
        Some(t) => tau / t,
        None => R::ZERO,
    }
}

/// Kinetic energy a particle of mass m loses in the drag update (½m|v_before|² − ½m|v_after|²).
/// Summed over a cell and handed to the gas, it makes the drag step conserve total energy
/// exactly (the optional frictional heating of method.md §1.3).
#[inline(always)]
pub fn kinetic_loss<R: Real>(m: R, before: Vec3<R>, after: Vec3<R>) -> R {
    R::from_f64(0.5) * m * (crate::dot(before, before) - crate::dot(after, after))
}
