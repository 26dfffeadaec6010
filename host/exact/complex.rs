//! Minimal complex number type for the linear-wave oracles (std only, no external crate).
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// Complex number `re + i·im` in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct C {
    pub re: f64,
    pub im: f64,
}

/// The imaginary unit.
pub const I: C = C { re: 0.0, im: 1.0 };
/// Zero.
pub const ZERO: C = C { re: 0.0, im: 0.0 };
/// One.
pub const ONE: C = C { re: 1.0, im: 0.0 };

impl C {
    pub const I: C = I;
    pub const ZERO: C = ZERO;
    pub const ONE: C = ONE;

    /// re + i·im.
    #[inline]
    pub const fn new(re: f64, im: f64) -> Self {
        C { re, im }
    }

    /// Modulus, via `hypot` so that large or tiny parts neither overflow nor underflow.
    #[inline]
    pub fn abs(self) -> f64 {
        self.re.hypot(self.im)
    }

    /// |z|².
    #[inline]
    pub fn norm_sqr(self) -> f64 {
        self.re * self.re + self.im * self.im
    }

    /// Complex conjugate.
    #[inline]
    pub fn conj(self) -> Self {
        C::new(self.re, -self.im)
    }

    /// Argument in (−π, π].
    #[inline]
    pub fn arg(self) -> f64 {
        self.im.atan2(self.re)
    }

    /// e^z.
    #[inline]
    pub fn exp(self) -> Self {
        let m = self.re.exp();
        C::new(m * self.im.cos(), m * self.im.sin())
    }

    /// Principal square root (branch cut on the negative real axis), computed without cancellation.
    pub fn sqrt(self) -> Self {
        if self.re == 0.0 && self.im == 0.0 {
            return ZERO;
        }
        let r = self.abs();
        if self.re >= 0.0 {
            let s = (0.5 * (r + self.re)).sqrt();
            C::new(s, 0.5 * self.im / s)
        } else {
            let s = (0.5 * (r - self.re)).sqrt();
            C::new(0.5 * self.im.abs() / s, s.copysign(self.im))
        }
    }

    /// 1/z.
    #[inline]
    pub fn recip(self) -> Self {
        ONE / self
    }
}

impl From<f64> for C {
    #[inline]
    fn from(re: f64) -> Self {
        C::new(re, 0.0)
    }
}

impl Add for C {
    type Output = C;
    #[inline]
    fn add(self, o: C) -> C {
        C::new(self.re + o.re, self.im + o.im)
    }
}

impl Sub for C {
    type Output = C;
    #[inline]
    fn sub(self, o: C) -> C {
        C::new(self.re - o.re, self.im - o.im)
    }
}

impl Mul for C {
    type Output = C;
    #[inline]
    fn mul(self, o: C) -> C {
        C::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
}

impl Div for C {
    type Output = C;
    /// Smith's algorithm: avoids the overflow of forming |o|² directly.
    #[inline]
    fn div(self, o: C) -> C {
        if o.re.abs() >= o.im.abs() {
            let r = o.im / o.re;
            let d = o.re + o.im * r;
            C::new((self.re + self.im * r) / d, (self.im - self.re * r) / d)
        } else {
            let r = o.re / o.im;
            let d = o.re * r + o.im;
            C::new((self.re * r + self.im) / d, (self.im * r - self.re) / d)
        }
    }
}

impl Neg for C {
    type Output = C;
    #[inline]
    fn neg(self) -> C {
        C::new(-self.re, -self.im)
    }
}

impl Add<f64> for C {
    type Output = C;
    #[inline]
    fn add(self, o: f64) -> C {
        C::new(self.re + o, self.im)
    }
}

impl Sub<f64> for C {
    type Output = C;
    #[inline]
    fn sub(self, o: f64) -> C {
        C::new(self.re - o, self.im)
    }
}

impl Mul<f64> for C {
    type Output = C;
    #[inline]
    fn mul(self, o: f64) -> C {
        C::new(self.re * o, self.im * o)
    }
}

impl Div<f64> for C {
    type Output = C;
    #[inline]
    fn div(self, o: f64) -> C {
        C::new(self.re / o, self.im / o)
    }
}

impl Add<C> for f64 {
    type Output = C;
    #[inline]
    fn add(self, o: C) -> C {
        o + self
    }
}

impl Sub<C> for f64 {
    type Output = C;
    #[inline]
    fn sub(self, o: C) -> C {
        C::new(self - o.re, -o.im)
    }
}

impl Mul<C> for f64 {
    type Output = C;
    #[inline]
    fn mul(self, o: C) -> C {
        o * self
    }
}

impl Div<C> for f64 {
    type Output = C;
    #[inline]
    fn div(self, o: C) -> C {
        C::from(self) / o
    }
}

impl AddAssign for C {
    #[inline]
    fn add_assign(&mut self, o: C) {
        *self = *self + o;
    }
}

impl SubAssign for C {
    #[inline]
    fn sub_assign(&mut self, o: C) {
        *self = *self - o;
    }
}

impl MulAssign for C {
    #[inline]
    fn mul_assign(&mut self, o: C) {
        *self = *self * o;
    }
}

impl MulAssign<f64> for C {
    #[inline]
    fn mul_assign(&mut self, o: f64) {
        *self = *self * o;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: C, b: C, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn field_identities() {
        let a = C::new(1.5, -2.0);
        let b = C::new(-0.25, 3.0);
        assert!(close(a * b, C::new(-0.375 + 6.0, 4.5 + 0.5), 1e-15));
        assert!(close((a / b) * b, a, 1e-14));
        assert!(close(a * a.recip(), ONE, 1e-15));
        assert!(close(I * I, -ONE, 0.0));
        assert_eq!(a.conj(), C::new(1.5, 2.0));
        assert!((a * a.conj()).im.abs() < 1e-15);
        assert!((C::new(3.0, 4.0).abs() - 5.0).abs() < 1e-15);
        assert!(close(2.0 - a, C::new(0.5, 2.0), 0.0));
        assert!(close(2.0 / C::new(0.0, 2.0), -I, 1e-16));
    }

    #[test]
    fn exp_and_sqrt() {
        // Euler: e^{iπ} = −1.
        assert!(close((I * std::f64::consts::PI).exp(), -ONE, 1e-15));
        let z = C::new(0.3, -1.7);
        assert!(close(z.exp() * (-z).exp(), ONE, 1e-15));
        for z in [C::new(-4.0, 0.0), C::new(-3.0, -4.0), C::new(2.0, 1e-20), z] {
            let s = z.sqrt();
            assert!(close(s * s, z, 1e-14 * z.abs()), "{z:?}");
            assert!(s.re >= 0.0);
        }
        assert!(close(C::new(-4.0, 0.0).sqrt(), C::new(0.0, 2.0), 0.0));
    }

    #[test]
    fn smith_division_avoids_overflow() {
        let big = C::new(1e300, 1e300);
        let q = big / big;
        assert!(close(q, ONE, 1e-15), "{q:?}");
    }
}
