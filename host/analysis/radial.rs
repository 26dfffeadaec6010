//! Radial profiles on increasing r: the SPH bins of a snapshot and the 1D reference solution
//! share this type, so figures and error norms treat them alike.

/// Fields against radius (mass-weighted means for SPH bins; zone values for the reference).
/// `v` is the radial gas velocity (for SPH bins: mean |v| of gas), `u` the dust one.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RadialCurve {
    pub r: Vec<f64>,
    pub rho_g: Vec<f64>,
    pub rho_d: Vec<f64>,
    pub p: Vec<f64>,
    pub e: Vec<f64>,
    pub v: Vec<f64>,
    pub u: Vec<f64>,
}

/// The state at one radius.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RadialState {
    pub rho_g: f64,
    pub rho_d: f64,
    pub p: f64,
    pub e: f64,
    pub v: f64,
    pub u: f64,
}

impl RadialCurve {
    pub fn len(&self) -> usize {
        self.r.len()
    }

    pub fn is_empty(&self) -> bool {
        self.r.is_empty()
    }

    /// Linear interpolation in r; the first point's state holds inside it; beyond the last
    /// point is vacuum (all zero).
    pub fn sample(&self, r: f64) -> RadialState {
        let n = self.r.len();
        if n == 0 || r > self.r[n - 1] {
            return RadialState::default();
        }
        let at = |i: usize| RadialState {
            rho_g: self.rho_g[i],
            rho_d: self.rho_d[i],
            p: self.p[i],
            e: self.e[i],
            v: self.v[i],
            u: self.u[i],
        };
        if r <= self.r[0] {
            return at(0);
        }
        let j = self.r.partition_point(|&x| x < r).min(n - 1);
        let (a, b) = (at(j - 1), at(j));
        let w = (r - self.r[j - 1]) / (self.r[j] - self.r[j - 1]);
        let l = |x: f64, y: f64| x + w * (y - x);
        RadialState {
            rho_g: l(a.rho_g, b.rho_g),
            rho_d: l(a.rho_d, b.rho_d),
            p: l(a.p, b.p),
            e: l(a.e, b.e),
            v: l(a.v, b.v),
            u: l(a.u, b.u),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_and_is_vacuum_outside() {
        let c = RadialCurve {
            r: vec![0.0, 1.0],
            rho_g: vec![1.0, 3.0],
            rho_d: vec![0.5, 0.5],
            p: vec![1.0, 0.0],
            e: vec![2.5, 2.5],
            v: vec![0.0, 2.0],
            u: vec![0.0, 2.0],
        };
        let s = c.sample(0.25);
        assert!((s.rho_g - 1.5).abs() < 1e-15 && (s.v - 0.5).abs() < 1e-15);
        assert_eq!(c.sample(1.5), RadialState::default());
    }
}
