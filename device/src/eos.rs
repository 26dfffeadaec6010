//! Equations of state (method.md §1, §2).
use crate::Real;

/// The gas equation of state. Isothermal gas carries no energy equation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Eos<R> {
    /// p = cs² ρ
    Isothermal { cs: R },
    /// p = (γ − 1) ρ e
    Adiabatic { gamma: R },
}

impl<R: Real> Eos<R> {
    /// Pressure from density and (for adiabatic gas) specific internal energy.
    #[inline(always)]
    pub fn pressure(&self, rho: R, e: R) -> R {
        match *self {
            Eos::Isothermal { cs } => cs * cs * rho,
            Eos::Adiabatic { gamma } => (gamma - R::ONE) * rho * e,
        }
    }

    /// Sound speed: cs, or sqrt(γ p / ρ).
    #[inline(always)]
    pub fn sound_speed(&self, rho: R, p: R) -> R {
        match *self {
            Eos::Isothermal { cs } => cs,
            Eos::Adiabatic { gamma } => {
                if rho > R::ZERO && p > R::ZERO {
                    (gamma * p / rho).sqrt()
                } else {
                    R::ZERO
                }
            }
        }
    }

    /// sqrt(p/ρ), the per-particle quantity whose cell mean gives cs* (method.md §3.4).
    #[inline(always)]
    pub fn isothermal_speed(&self, rho: R, p: R) -> R {
        if rho > R::ZERO && p > R::ZERO {
            (p / rho).sqrt()
        } else {
            R::ZERO
        }
    }

    /// The factor g with cs = g · sqrt(p/ρ): sqrt(γ) for adiabatic gas, 1 for isothermal.
    #[inline(always)]
    pub fn gamma_root(&self) -> R {
        match *self {
            Eos::Isothermal { .. } => R::ONE,
            Eos::Adiabatic { gamma } => gamma.sqrt(),
        }
    }
}
