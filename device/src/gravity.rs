//! A central point mass (`[gravity]`, docs/scenes.md): its acceleration on every gas and dust
//! particle, with G = 1 (the code units of `[units]`) and Plummer softening, and the discs'
//! edge damping zones about it.
use crate::Vec3;

/// A point mass M at `pos`, softened over `softening` (ε): g(x) = −M (x − pos)/(|x − pos|² +
/// ε²)^{3/2}. Always f64 (positions are f64 in every precision); `gm` = 0: no point mass.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PointMass {
    pub gm: f64,
    pub pos: Vec3<f64>,
    /// ε².
    pub soft2: f64,
    /// Edge damping zones (method.md §D, "The discs' edges"), in cylindrical R about `pos`:
    /// full at R ≤ `damp_inner[0]`, none from `damp_inner[1]` on; none up to `damp_outer[0]`,
    /// full from `damp_outer[1]` on; a quadratic ramp between. [0, 0]: no such zone.
    pub damp_inner: [f64; 2],
    pub damp_outer: [f64; 2],
    /// The damping rate at full weight over the local Kepler Ω: 1/(2π t_d), t_d the damping
    /// time in local orbits. 0: no zones.
    pub damp_per_omega: f64,
}

impl PointMass {
    pub fn is_on(&self) -> bool {
        self.gm != 0.0
    }

    /// The acceleration at x (0 without a point mass, or at its very centre unsoftened).
    #[inline(always)]
    pub fn accel(&self, x: Vec3<f64>) -> Vec3<f64> {
        if self.gm == 0.0 {
            return [0.0; 3];
        }
        let d = crate::sub(x, self.pos);
        let r2 = crate::dot(d, d) + self.soft2;
        if r2 <= 0.0 {
            return [0.0; 3];
        }
        let f = -self.gm / (r2 * crate::Real::sqrt(r2));
        [f * d[0], f * d[1], f * d[2]]
    }

    /// The zones' weight at cylindrical radius `r`: 1 where the damping is full, 0 outside
    /// both zones, (distance into the ramp / its width)² between (de Val-Borro et al. 2006,
    /// MNRAS 370, 529, use the same quadratic ramp).
    #[inline(always)]
    pub fn damp_weight(&self, r: f64) -> f64 {
        let [a, b] = self.damp_inner;
        let [c, e] = self.damp_outer;
        let ramp = |s: f64| {
            let s = if s > 1.0 { 1.0 } else { s };
            s * s
        };
        if b > 0.0 && r < b {
            ramp((b - r) / (b - a))
        } else if e > 0.0 && r > c {
            ramp((r - c) / (e - c))
        } else {
            0.0
        }
    }

    /// The zones' damping rate at x, w(R) Ω_K(R)/(2π t_d) (0 outside the zones or without
    /// them). The step keeps τ ≤ 1/rate, so the explicit decay is monotone.
    #[inline(always)]
    pub fn damp_rate(&self, x: Vec3<f64>) -> f64 {
        if self.damp_per_omega == 0.0 || self.gm == 0.0 {
            return 0.0;
        }
        let d = crate::sub(x, self.pos);
        let r2 = d[0] * d[0] + d[1] * d[1];
        if r2 <= 0.0 {
            return 0.0;
        }
        let r = crate::Real::sqrt(r2);
        let w = self.damp_weight(r);
        if w == 0.0 {
            return 0.0;
        }
        w * self.damp_per_omega * crate::Real::sqrt(self.gm / (r2 * r))
    }

    /// The zones' damping acceleration of a particle at x moving at v: −rate (v_R R̂ + v_z ẑ).
    /// Only the radial and vertical motion is damped, toward zero: a force along R̂ or ẑ exerts
    /// no torque about the star's axis, so the zones keep the angular momentum L_z to
    /// round-off and never force a rotation on the edge rings, whose pressure support there an
    /// SPH kernel sets over h (a prescribed rotation, as grid codes relax toward, would move
    /// the edges' mass: method.md §D). What it removes are the edge rings' epicycles, which grow there (Rayleigh-unstable
    /// rings) and stir the disc. Zero outside the zones.
    #[inline(always)]
    pub fn damping(&self, x: Vec3<f64>, v: Vec3<f64>) -> Vec3<f64> {
        let rate = self.damp_rate(x);
        if rate == 0.0 {
            return [0.0; 3];
        }
        let d = crate::sub(x, self.pos);
        let r2 = d[0] * d[0] + d[1] * d[1];
        let vr_over_r = (v[0] * d[0] + v[1] * d[1]) / r2;
        [
            -rate * vr_over_r * d[0],
            -rate * vr_over_r * d[1],
            -rate * v[2],
        ]
    }
}
