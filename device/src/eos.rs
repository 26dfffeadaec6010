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

/// A locally isothermal gas's sound speed (`gas.eos = "locally_isothermal"`): c_s = cs0 (R/r_ref)^(−q)
/// about `centre`, R the cylindrical radius (about the z axis through `centre`) or, with
/// `spherical` = 1, the spherical one (Phantom's ieos = 3). `on` = 0: not in use. Always f64
/// (positions are f64).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LocalSoundSpeed {
    pub cs0: f64,
    pub q: f64,
    pub r_ref: f64,
    pub centre: [f64; 3],
    pub spherical: u32,
    pub on: u32,
}

impl LocalSoundSpeed {
    /// c_s at x (at R = 0 the law's c_s is infinite).
    #[inline(always)]
    pub fn at(&self, x: [f64; 3]) -> f64 {
        let d = crate::sub(x, self.centre);
        let r2 = d[0] * d[0]
            + d[1] * d[1]
            + if self.spherical != 0 {
                d[2] * d[2]
            } else {
                0.0
            };
        // (R/r_ref)^(−q) = exp(−q/2 · ln(R²/r_ref²)): libm's exp and log, not its pow, whose
        // square-root branch pulls a table the PTX cannot hold (build.rs refuses `.extern`).
        self.cs0 * libm::exp(-0.5 * self.q * libm::log(r2 / (self.r_ref * self.r_ref)))
    }
}
