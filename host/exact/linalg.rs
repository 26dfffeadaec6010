//! Small dense linear algebra for the exact oracles.
//!
//! The matrix functions work internally in double-double arithmetic (~32 significant digits).
//! Scaling-and-squaring of a stiff matrix (norm·t ≫ 1) needs s ≈ log2(norm·t) squarings, and
//! each one doubles the relative rounding error of the slow modes: in plain f64 the slow
//! (acoustic) modes of a stiff dusty wave would lose up to 2^s·1e-16 ≈ 1e-8. With ~1e-32 per
//! operation the same loss stays far below f64 resolution, so the f64 results are accurate to
//! round-off even for norm·t ~ 1e9. The same argument covers (I + τM)^{-n} for n ~ 1e6.
use super::complex::C;
use std::ops::{Add, Mul, Neg, Sub};

/// Solves a·x = b (nalgebra's LU with partial pivoting; plain f64 suffices for the set-up
/// solves that use it). Returns `None` when the system is singular or the result not finite.
pub fn solve_real(a: &[Vec<f64>], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    assert_eq!(a.len(), n, "solve_real: matrix rows != rhs length");
    let m = nalgebra::DMatrix::from_fn(n, n, |i, j| a[i][j]);
    let x = m.lu().solve(&nalgebra::DVector::from_column_slice(b))?;
    x.iter()
        .all(|v| v.is_finite())
        .then(|| x.iter().copied().collect())
}

/// m·x for a complex matrix.
pub fn matvec(m: &[Vec<C>], x: &[C]) -> Vec<C> {
    m.iter()
        .map(|row| {
            assert_eq!(row.len(), x.len(), "matvec: dimension mismatch");
            row.iter()
                .zip(x)
                .fold(C::new(0.0, 0.0), |s, (&a, &b)| s + a * b)
        })
        .collect()
}

/// m·x for a real matrix.
pub fn matvec_real(m: &[Vec<f64>], x: &[f64]) -> Vec<f64> {
    m.iter()
        .map(|row| row.iter().zip(x).map(|(a, b)| a * b).sum())
        .collect()
}

/// exp(m·t) for a complex square matrix (scaling-and-squaring with a Taylor approximant,
/// in double-double; see the module note).
pub fn expm_complex(m: &[Vec<C>], t: f64) -> Vec<Vec<C>> {
    let a: Vec<Vec<Cdd>> = m
        .iter()
        .map(|row| row.iter().map(|z| Cdd::from_c(*z).scale(t)).collect())
        .collect();
    expm_generic(&a)
        .iter()
        .map(|row| row.iter().map(|z| z.to_c()).collect())
        .collect()
}

/// exp(m·t) for a real square matrix (same algorithm as [`expm_complex`]).
pub fn expm_real(m: &[Vec<f64>], t: f64) -> Vec<Vec<f64>> {
    let a: Vec<Vec<Dd>> = m
        .iter()
        .map(|row| row.iter().map(|&x| Dd::prod(x, t)).collect())
        .collect();
    expm_generic(&a)
        .iter()
        .map(|row| row.iter().map(|x| x.to_f64()).collect())
        .collect()
}

/// (I + τ·m)^{-n}·x for a real matrix: the n-step backward-Euler propagator of dx/dt = −m·x.
/// The inverse is formed once and raised to the n-th power by binary powering, all in
/// double-double, so n up to ~1e9 costs ~30 products and loses no accuracy.
/// Returns `None` if I + τm is singular.
pub fn implicit_euler_power(m: &[Vec<f64>], tau: f64, n: usize, x: &[f64]) -> Option<Vec<f64>> {
    let dim = x.len();
    let mut b: Vec<Vec<Dd>> = m
        .iter()
        .enumerate()
        .map(|(i, row)| {
            row.iter()
                .enumerate()
                .map(|(j, &mij)| {
                    let d = if i == j { Dd::from(1.0) } else { Dd::ZERO };
                    d + Dd::prod(mij, tau)
                })
                .collect()
        })
        .collect();
    let mut p = invert_dd(&mut b)?;
    let mut r: Vec<Dd> = x.iter().map(|&v| Dd::from(v)).collect();
    let mut k = n;
    while k > 0 {
        if k & 1 == 1 {
            r = (0..dim)
                .map(|i| (0..dim).fold(Dd::ZERO, |s, j| s + p[i][j] * r[j]))
                .collect();
        }
        k >>= 1;
        if k > 0 {
            p = matmul(&p, &p);
        }
    }
    Some(r.iter().map(|v| v.to_f64()).collect())
}

/// Gauss–Jordan inverse with partial pivoting in double-double.
fn invert_dd(a: &mut [Vec<Dd>]) -> Option<Vec<Vec<Dd>>> {
    let n = a.len();
    let mut inv: Vec<Vec<Dd>> = (0..n)
        .map(|i| {
            (0..n)
                .map(|j| if i == j { Dd::from(1.0) } else { Dd::ZERO })
                .collect()
        })
        .collect();
    for col in 0..n {
        let piv = (col..n).max_by(|&i, &j| a[i][col].hi.abs().total_cmp(&a[j][col].hi.abs()))?;
        if a[piv][col].hi == 0.0 || !a[piv][col].hi.is_finite() {
            return None;
        }
        a.swap(col, piv);
        inv.swap(col, piv);
        let pinv = Dd::from(1.0) / a[col][col];
        for c in 0..n {
            a[col][c] = a[col][c] * pinv;
            inv[col][c] = inv[col][c] * pinv;
        }
        for row in 0..n {
            if row == col {
                continue;
            }
            let f = a[row][col];
            if f.hi == 0.0 {
                continue;
            }
            for c in 0..n {
                let ac = a[col][c];
                let ic = inv[col][c];
                a[row][c] = a[row][c] - f * ac;
                inv[row][c] = inv[row][c] - f * ic;
            }
        }
    }
    Some(inv)
}

/// Arithmetic needed by the generic matrix exponential.
trait Field:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Neg<Output = Self>
{
    const ZERO: Self;
    const ONE: Self;
    /// A magnitude (for norms and stopping tests only, so f64 is enough).
    fn mag(self) -> f64;
    /// Multiplication by a double-double real.
    fn mul_dd(self, r: Dd) -> Self;
    /// Exact multiplication by 2^k.
    fn ldexp(self, k: i32) -> Self;
}

fn matmul<F: Field>(a: &[Vec<F>], b: &[Vec<F>]) -> Vec<Vec<F>> {
    let n = a.len();
    let mut c = vec![vec![F::ZERO; n]; n];
    for i in 0..n {
        for k in 0..n {
            let aik = a[i][k];
            if aik.mag() == 0.0 {
                continue;
            }
            for j in 0..n {
                c[i][j] = c[i][j] + aik * b[k][j];
            }
        }
    }
    c
}

fn norm1<F: Field>(a: &[Vec<F>]) -> f64 {
    let n = a.len();
    (0..n)
        .map(|j| (0..n).map(|i| a[i][j].mag()).sum::<f64>())
        .fold(0.0, f64::max)
}

/// exp(a): scale by 2^{-s} so that ‖a‖₁/2^s ≤ 1/4, sum the Taylor series to double-double
/// round-off (~22 terms), then square s times.
fn expm_generic<F: Field>(a: &[Vec<F>]) -> Vec<Vec<F>> {
    let n = a.len();
    assert!(
        a.iter().all(|r| r.len() == n),
        "expm: matrix must be square"
    );
    let identity: Vec<Vec<F>> = (0..n)
        .map(|i| {
            (0..n)
                .map(|j| if i == j { F::ONE } else { F::ZERO })
                .collect()
        })
        .collect();
    let nrm = norm1(a);
    assert!(nrm.is_finite(), "expm: matrix has non-finite entries");
    if nrm == 0.0 {
        return identity;
    }
    let s = if nrm > 0.25 {
        (nrm / 0.25).log2().ceil() as i32
    } else {
        0
    };
    let x: Vec<Vec<F>> = a
        .iter()
        .map(|r| r.iter().map(|v| v.ldexp(-s)).collect())
        .collect();
    let mut sum = identity.clone();
    let mut term = identity;
    for j in 1..=60 {
        let inv_j = Dd::from(1.0) / Dd::from(j as f64);
        term = matmul(&term, &x);
        for row in term.iter_mut() {
            for v in row.iter_mut() {
                *v = v.mul_dd(inv_j);
            }
        }
        for (srow, trow) in sum.iter_mut().zip(&term) {
            for (sv, &tv) in srow.iter_mut().zip(trow) {
                *sv = *sv + tv;
            }
        }
        // ‖sum‖ ≥ 1 − 1/4·e^{1/4} > 0.6, so an absolute test is a relative one.
        if norm1(&term) < 1e-34 {
            break;
        }
    }
    for _ in 0..s {
        sum = matmul(&sum, &sum);
    }
    sum
}

/// Double-double real: the unevaluated sum hi + lo with |lo| ≤ ulp(hi)/2.
#[derive(Clone, Copy, Debug)]
struct Dd {
    hi: f64,
    lo: f64,
}

#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

#[inline]
fn quick_two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    (s, b - (s - a))
}

impl Dd {
    const ZERO: Dd = Dd { hi: 0.0, lo: 0.0 };

    /// Exact product of two f64 (error-free transformation with FMA).
    #[inline]
    fn prod(a: f64, b: f64) -> Dd {
        let p = a * b;
        if !p.is_finite() || p == 0.0 {
            return Dd { hi: p, lo: 0.0 };
        }
        Dd {
            hi: p,
            lo: a.mul_add(b, -p),
        }
    }

    #[inline]
    fn to_f64(self) -> f64 {
        self.hi + self.lo
    }

    #[inline]
    fn norm(hi: f64, lo: f64) -> Dd {
        let (h, l) = quick_two_sum(hi, lo);
        Dd { hi: h, lo: l }
    }
}

impl From<f64> for Dd {
    #[inline]
    fn from(x: f64) -> Dd {
        Dd { hi: x, lo: 0.0 }
    }
}

impl Add for Dd {
    type Output = Dd;
    #[inline]
    fn add(self, o: Dd) -> Dd {
        let (s, e) = two_sum(self.hi, o.hi);
        let (t, f) = two_sum(self.lo, o.lo);
        let (s, e) = quick_two_sum(s, e + t);
        Dd::norm(s, e + f)
    }
}

impl Neg for Dd {
    type Output = Dd;
    #[inline]
    fn neg(self) -> Dd {
        Dd {
            hi: -self.hi,
            lo: -self.lo,
        }
    }
}

impl Sub for Dd {
    type Output = Dd;
    #[inline]
    fn sub(self, o: Dd) -> Dd {
        self + (-o)
    }
}

impl Mul for Dd {
    type Output = Dd;
    #[inline]
    fn mul(self, o: Dd) -> Dd {
        let p = Dd::prod(self.hi, o.hi);
        if p.hi == 0.0 || !p.hi.is_finite() {
            return Dd::from(p.hi);
        }
        Dd::norm(p.hi, p.lo + (self.hi * o.lo + self.lo * o.hi))
    }
}

impl std::ops::Div for Dd {
    type Output = Dd;
    /// Long division with three f64 quotient digits.
    fn div(self, o: Dd) -> Dd {
        let q1 = self.hi / o.hi;
        let r = self - o * Dd::from(q1);
        let q2 = r.hi / o.hi;
        let r = r - o * Dd::from(q2);
        let q3 = r.hi / o.hi;
        Dd::norm(q1, q2) + Dd::from(q3)
    }
}

impl Field for Dd {
    const ZERO: Dd = Dd::ZERO;
    const ONE: Dd = Dd { hi: 1.0, lo: 0.0 };
    #[inline]
    fn mag(self) -> f64 {
        self.hi.abs()
    }
    #[inline]
    fn mul_dd(self, r: Dd) -> Dd {
        self * r
    }
    #[inline]
    fn ldexp(self, k: i32) -> Dd {
        let f = 2f64.powi(k);
        Dd {
            hi: self.hi * f,
            lo: self.lo * f,
        }
    }
}

/// Double-double complex.
#[derive(Clone, Copy, Debug)]
struct Cdd {
    re: Dd,
    im: Dd,
}

impl Cdd {
    #[inline]
    fn from_c(z: C) -> Cdd {
        Cdd {
            re: Dd::from(z.re),
            im: Dd::from(z.im),
        }
    }

    /// Exact scaling of an f64 complex by an f64 real.
    #[inline]
    fn scale(self, t: f64) -> Cdd {
        Cdd {
            re: Dd::prod(self.re.hi, t),
            im: Dd::prod(self.im.hi, t),
        }
    }

    #[inline]
    fn to_c(self) -> C {
        C::new(self.re.to_f64(), self.im.to_f64())
    }
}

impl Add for Cdd {
    type Output = Cdd;
    #[inline]
    fn add(self, o: Cdd) -> Cdd {
        Cdd {
            re: self.re + o.re,
            im: self.im + o.im,
        }
    }
}

impl Sub for Cdd {
    type Output = Cdd;
    #[inline]
    fn sub(self, o: Cdd) -> Cdd {
        Cdd {
            re: self.re - o.re,
            im: self.im - o.im,
        }
    }
}

impl Neg for Cdd {
    type Output = Cdd;
    #[inline]
    fn neg(self) -> Cdd {
        Cdd {
            re: -self.re,
            im: -self.im,
        }
    }
}

impl Mul for Cdd {
    type Output = Cdd;
    #[inline]
    fn mul(self, o: Cdd) -> Cdd {
        Cdd {
            re: self.re * o.re - self.im * o.im,
            im: self.re * o.im + self.im * o.re,
        }
    }
}

impl Field for Cdd {
    const ZERO: Cdd = Cdd {
        re: Dd::ZERO,
        im: Dd::ZERO,
    };
    const ONE: Cdd = Cdd {
        re: Dd { hi: 1.0, lo: 0.0 },
        im: Dd::ZERO,
    };
    #[inline]
    fn mag(self) -> f64 {
        self.re.hi.abs() + self.im.hi.abs()
    }
    #[inline]
    fn mul_dd(self, r: Dd) -> Cdd {
        Cdd {
            re: self.re * r,
            im: self.im * r,
        }
    }
    #[inline]
    fn ldexp(self, k: i32) -> Cdd {
        Cdd {
            re: self.re.ldexp(k),
            im: self.im.ldexp(k),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solve_real_with_pivoting() {
        // The zero leading pivot forces a row swap.
        let a = vec![
            vec![0.0, 2.0, 1.0],
            vec![1.0, 1.0, 1.0],
            vec![2.0, 1.0, -1.0],
        ];
        let x_true = [1.0, -2.0, 3.0];
        let a0 = a.clone();
        let b = matvec_real(&a, &x_true);
        let x = solve_real(&a, &b).unwrap();
        for (xi, ti) in x.iter().zip(x_true) {
            assert!((xi - ti).abs() < 1e-14);
        }
        let r = matvec_real(&a0, &x);
        let b0 = matvec_real(&a0, &x_true);
        assert!(r.iter().zip(&b0).all(|(p, q)| (p - q).abs() < 1e-14));
        let sing = vec![vec![1.0, 2.0], vec![2.0, 4.0]];
        assert!(solve_real(&sing, &[1.0, 1.0]).is_none());
    }

    #[test]
    fn dd_arithmetic_beats_f64() {
        let third = Dd::from(1.0) / Dd::from(3.0);
        let back = third * Dd::from(3.0) - Dd::from(1.0);
        assert!(back.to_f64().abs() < 1e-31, "{back:?}");
        // 1 + 2^-70 survives in double-double.
        let tiny = 2f64.powi(-70);
        let s = (Dd::from(1.0) + Dd::from(tiny)) - Dd::from(1.0);
        assert_eq!(s.to_f64(), tiny);
    }

    /// Rotation generator: exp(t·[[0, −w], [w, 0]]) is a rotation by w·t.
    #[test]
    fn expm_rotation() {
        let w = 4.442882938158366;
        let m = vec![
            vec![C::new(0.0, 0.0), C::new(-w, 0.0)],
            vec![C::new(w, 0.0), C::new(0.0, 0.0)],
        ];
        for t in [0.0, 1e-3, 0.7, 10.0, 1000.0] {
            let e = expm_complex(&m, t);
            let (c, s) = ((w * t).cos(), (w * t).sin());
            let expect = [[c, -s], [s, c]];
            for i in 0..2 {
                for j in 0..2 {
                    let err = (e[i][j] - C::new(expect[i][j], 0.0)).norm();
                    // The f64 reference cos(w·t) itself carries ~ulp(w·t) argument rounding.
                    assert!(err < 1e-15 * (1.0 + w * t), "t={t} err={err:e}");
                }
            }
        }
    }

    /// Stiff, non-normal test with a known answer: m = V diag(λ) V⁻¹ with V = [[1, 1], [0, 1]]
    /// (V⁻¹ = [[1, −1], [0, 1]] exactly), λ₁ = −1e9 (stiff, decays to 0), λ₂ = iω (undamped).
    /// exp(m t) = [[e₁, e₂ − e₁], [0, e₂]].
    #[test]
    fn expm_stiff_nonnormal() {
        let l1 = C::new(-1e9, 0.0);
        let l2 = C::new(-0.3, 4.4);
        let m = vec![vec![l1, l2 - l1], vec![C::new(0.0, 0.0), l2]];
        for t in [1e-9, 1e-6, 0.37, 1.0] {
            let e = expm_complex(&m, t);
            let e1 = (l1 * t).exp();
            let e2 = (l2 * t).exp();
            let expect = [[e1, e2 - e1], [C::new(0.0, 0.0), e2]];
            let mut err: f64 = 0.0;
            for i in 0..2 {
                for j in 0..2 {
                    err = err.max((e[i][j] - expect[i][j]).norm());
                }
            }
            assert!(err < 1e-12, "t={t} err={err:e}");
        }
    }

    /// Real path: a 3×3 upper-triangular matrix with distinct eigenvalues has a closed form;
    /// compare with the divided-difference formula for exp of a triangular matrix.
    #[test]
    fn expm_real_triangular() {
        let (a, b, c) = (-2.0, -5e8, 0.5);
        let (x, y, z) = (1.5, -0.25, 3.0);
        let m = vec![vec![a, x, y], vec![0.0, b, z], vec![0.0, 0.0, c]];
        let t = 0.9;
        let e = expm_real(&m, t);
        let (ea, eb, ec) = ((a * t).exp(), (b * t).exp(), (c * t).exp());
        let dd = |p: f64, q: f64, ep: f64, eq: f64| (ep - eq) / (p - q);
        let f_ab = dd(a, b, ea, eb);
        let f_bc = dd(b, c, eb, ec);
        let f_ac = dd(a, c, ea, ec);
        let f_abc = (f_ab - f_bc) / (a - c);
        let expect = [
            [ea, x * f_ab, y * f_ac + x * z * f_abc],
            [0.0, eb, z * f_bc],
            [0.0, 0.0, ec],
        ];
        for i in 0..3 {
            for j in 0..3 {
                let err = (e[i][j] - expect[i][j]).abs();
                assert!(
                    err < 1e-12 * (1.0 + expect[i][j].abs()),
                    "({i},{j}) {err:e}"
                );
            }
        }
    }

    /// (I + τm)^{-n} by binary powering equals n repeated f64 solves (n = 1000) and the
    /// scalar formula (1 + τλ)^{-n} on a diagonal matrix with n = 1e6.
    #[test]
    fn implicit_euler_power_matches_repeated_solves() {
        let m = vec![vec![3.0, 1.0], vec![0.5, 2.0]];
        let x0 = [1.0, -1.0];
        let (tau, n) = (1e-3, 1000);
        let fast = implicit_euler_power(&m, tau, n, &x0).unwrap();
        let mut x = x0.to_vec();
        for _ in 0..n {
            let a = vec![vec![1.0 + tau * 3.0, tau], vec![tau * 0.5, 1.0 + tau * 2.0]];
            x = solve_real(&a, &x).unwrap();
        }
        for (p, q) in fast.iter().zip(&x) {
            assert!((p - q).abs() < 1e-13, "{p} {q}");
        }
        let d = vec![vec![7.0, 0.0], vec![0.0, 1e-2]];
        let n = 1_000_000;
        let tau = 1e-6;
        let r = implicit_euler_power(&d, tau, n, &[1.0, 1.0]).unwrap();
        let expect = [
            (-(n as f64) * (7.0 * tau).ln_1p()).exp(),
            (-(n as f64) * (1e-2 * tau).ln_1p()).exp(),
        ];
        for (p, q) in r.iter().zip(expect) {
            assert!(((p - q) / q).abs() < 1e-13, "{p} {q}");
        }
    }
}

#[cfg(test)]
mod double_double_need {
    use super::*;
    use nalgebra::{DMatrix, DVector};

    /// Why the matrix exponential stays in double-double (the module note), measured against
    /// nalgebra's f64 `exp` (Padé with scaling and squaring): for a stiff symmetric matrix
    /// M = Q diag(λ) Qᵀ (λ = −1e6, −1e4, −1e2, −1; Q a Householder reflection), whose
    /// exponential Q diag(e^{λt}) Qᵀ is known, the errors relative to the largest entry are
    /// (measured): t = 1e-3: nalgebra 2.6e-14, double-double 1.5e-14; t = 0.1: 7.2e-13 /
    /// 3.2e-13; t = 1 (norm·t = 1e6): 6.0e-11 / 3.2e-12. The double-double one is at the floor
    /// set by M's own f64 rounding (entries of 1e6 carry 1e-10 absolute); nalgebra's grows with
    /// its squarings, 19× above it at t = 1. Held with a margin: if nalgebra ever matches it,
    /// switch.
    #[test]
    fn nalgebra_expm_loses_digits_on_stiff_matrices_where_double_double_does_not() {
        let n = 4;
        let v = DVector::<f64>::from_vec(vec![1.0, 2.0, 3.0, 4.0]);
        let q = DMatrix::<f64>::identity(n, n) - &v * v.transpose() * (2.0 / v.norm_squared());
        let lam: [f64; 4] = [-1e6, -1e4, -1e2, -1.0];
        let m = &q * DMatrix::from_diagonal(&DVector::from_vec(lam.to_vec())) * q.transpose();
        let rows: Vec<Vec<f64>> = (0..n)
            .map(|i| (0..n).map(|j| m[(i, j)]).collect())
            .collect();
        let mut worst = [0.0f64; 2];
        for t in [1e-5, 1e-3, 1e-1, 1.0] {
            let exact =
                &q * DMatrix::from_diagonal(&DVector::from_iterator(
                    n,
                    lam.iter().map(|l| (l * t).exp()),
                )) * q.transpose();
            let scale = exact.abs().max();
            let na = (&m * t).exp();
            let dd = expm_real(&rows, t);
            let dd = DMatrix::from_fn(n, n, |i, j| dd[i][j]);
            let (a, b) = (
                (&na - &exact).abs().max() / scale,
                (&dd - &exact).abs().max() / scale,
            );
            eprintln!("t = {t:e}: error / max entry: nalgebra {a:.2e}, double-double {b:.2e}");
            worst = [worst[0].max(a), worst[1].max(b)];
        }
        assert!(worst[1] < 1e-11, "double-double: {:.2e}", worst[1]);
        assert!(
            worst[0] > 5.0 * worst[1],
            "nalgebra is as good here: {worst:?}"
        );
    }
}
