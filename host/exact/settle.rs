//! Dust settling in an isothermal gas column (docs/method.md §S).
//!
//! Gas at rest in hydrostatic equilibrium under a constant acceleration −g along x, carrying
//! dust fractions of uniform dust-to-gas ratio ε_k that fall at their terminal velocity. Each
//! fraction's terminal relative velocity solves 0 = −g − (u_k − v)/t_k (the dust feels gravity
//! and drag only), so u_k − v = −g t_k; the gas carries the dust's weight through the drag,
//! 0 = −∂p/∂x/ρ_g − g − Σ_k ε_k g, hence ρ_g(x) = ρ_0 exp(−x/H) with H = c_s²/((1 + Σε) g).
//! Valid while t_k is short against the settling time (the ε_k stay uniform).
use dustsph_device::drag::StoppingLaw;

/// The column: base density, isothermal sound speed, gravity and the dust-to-gas ratios.
#[derive(Debug, Clone)]
pub struct SettleColumn {
    pub rho0: f64,
    pub cs: f64,
    pub g: f64,
    pub eps: Vec<f64>,
}

impl SettleColumn {
    /// Scale height c_s²/((1 + Σε) g).
    pub fn scale_height(&self) -> f64 {
        self.cs * self.cs / ((1.0 + self.eps.iter().sum::<f64>()) * self.g)
    }

    pub fn rho_gas(&self, x: f64) -> f64 {
        self.rho0 * (-x / self.scale_height()).exp()
    }

    /// Cumulative gas mass per unit area from x = 0 (negative below).
    pub fn mass_below(&self, x: f64) -> f64 {
        let h = self.scale_height();
        self.rho0 * h * (1.0 - (-x / h).exp())
    }

    /// Inverse of [`Self::mass_below`] (`m` < ρ_0 H).
    pub fn height_of_mass(&self, m: f64) -> f64 {
        let h = self.scale_height();
        -h * (1.0 - m / (self.rho0 * h)).ln()
    }

    /// Stopping time of fraction k at height x: the law ([`StoppingLaw::stopping_time`]) at
    /// the gas density there, the fraction's density ε_k ρ_g and c_s.
    pub fn t_stop(&self, k: usize, law: StoppingLaw<f64>, x: f64) -> f64 {
        let rho = self.rho_gas(x);
        law.stopping_time(rho, self.eps[k] * rho, self.cs)
    }

    /// Terminal velocity of fraction k at height x (the gas is at rest): −g t_k(x).
    pub fn u_terminal(&self, k: usize, law: StoppingLaw<f64>, x: f64) -> f64 {
        -self.g * self.t_stop(k, law, x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mass_coordinate_round_trips_and_profile_is_hydrostatic() {
        let c = SettleColumn {
            rho0: 2.0,
            cs: 0.7,
            g: 1.5,
            eps: vec![0.01, 0.03],
        };
        for x in [-0.3, 0.0, 0.4, 1.7] {
            assert!((c.height_of_mass(c.mass_below(x)) - x).abs() < 1e-12);
        }
        // dp/dx = c_s² dρ/dx = −(1 + Σε) ρ g, by finite differences.
        let (x, d) = (0.6, 1e-6);
        let dpdx = c.cs * c.cs * (c.rho_gas(x + d) - c.rho_gas(x - d)) / (2.0 * d);
        let want = -(1.04) * c.rho_gas(x) * c.g;
        assert!((dpdx / want - 1.0).abs() < 1e-8, "{dpdx} vs {want}");
        // Epstein: t ∝ 1/ρ_g, so the fall speeds up with height by e^{x/H}.
        let law = StoppingLaw::Epstein {
            s_rho: 1e-3,
            stokes: 0.0,
        };
        let r = c.u_terminal(0, law, 1.0) / c.u_terminal(0, law, 0.0);
        assert!((r - (1.0 / c.scale_height()).exp()).abs() < 1e-12);
    }
}
