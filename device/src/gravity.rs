//! A central point mass (`[gravity]`, docs/scenes.md): its acceleration on every gas and dust
//! particle, with G = 1 (the code units of `[units]`) and Plummer softening.
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
}
