//! DUSTYWAVE (method.md §7.2, §7.3): a linear sound wave in gas + N dust fractions in a
//! periodic 1D domain, isothermal or adiabatic, any initial amplitudes.
//!
//! Every field is f(x,t) = f0 + A·Re[f̂(t) e^{ikx}]; the amplitudes obey the linear ODE
//! dŷ/dt = 𝕄ŷ of method.md §7.2, solved exactly as ŷ(t) = exp(𝕄t)ŷ(0) (double-double matrix
//! exponential, so stiff t_k ≪ 1/(kc) are exact too). Eigenmodes use the BL2019 convention
//! exp(ikx − ωt) (Re ω = damping rate).
use super::complex::C;
use super::dustybox::DustyBox;
use super::linalg::{expm_complex, matvec};

/// Gas thermodynamics of the linear wave.
#[derive(Clone, Copy, Debug)]
pub enum WaveGas {
    /// p = cs² ρ.
    Isothermal { cs: f64 },
    /// p = (γ − 1) ρ e about the background pressure p0 (no drag heating: it is second order).
    Adiabatic { gamma: f64, p0: f64 },
}

/// Uniform background (ρg0, ρk0, zero velocities) and wavenumber k.
/// `t_stop[k]` = ρk0/K_k (method.md §1.1), ε_k = ρk0/ρg0.
#[derive(Clone, Debug)]
pub struct LinearWave {
    pub rho_g0: f64,
    pub gas: WaveGas,
    pub rho_d0: Vec<f64>,
    pub t_stop: Vec<f64>,
    pub k: f64,
}

/// Complex amplitudes: the physical field is f(x,t) = f0 + A·Re[f̂(t) e^{ikx}].
/// `e` (specific internal energy) is `Some` exactly for an adiabatic gas.
#[derive(Clone, Debug)]
pub struct WaveAmplitudes {
    pub rho_g: C,
    pub v_g: C,
    pub e: Option<C>,
    pub rho_d: Vec<C>,
    pub v_d: Vec<C>,
}

/// Re[f̂ e^{ikx}]: the real perturbation shape of one amplitude at position x.
pub fn real_field(amp: C, k: f64, x: f64) -> f64 {
    amp.re * (k * x).cos() - amp.im * (k * x).sin()
}

impl WaveAmplitudes {
    /// Every amplitude multiplied by z (e.g. z = e^{−ωt} for an eigenmode).
    pub fn scale(&self, z: C) -> Self {
        WaveAmplitudes {
            rho_g: self.rho_g * z,
            v_g: self.v_g * z,
            e: self.e.map(|e| e * z),
            rho_d: self.rho_d.iter().map(|&a| a * z).collect(),
            v_d: self.v_d.iter().map(|&a| a * z).collect(),
        }
    }

    /// Largest modulus of the difference over all amplitudes (a missing `e` counts as 0).
    pub fn max_abs_diff(&self, o: &WaveAmplitudes) -> f64 {
        let e = match (self.e, o.e) {
            (None, None) => 0.0,
            (a, b) => (a.unwrap_or(C::ZERO) - b.unwrap_or(C::ZERO)).norm(),
        };
        let pairs = self
            .rho_d
            .iter()
            .zip(&o.rho_d)
            .chain(self.v_d.iter().zip(&o.v_d));
        pairs
            .map(|(a, b)| (*a - *b).norm())
            .fold(e, f64::max)
            .max((self.rho_g - o.rho_g).norm())
            .max((self.v_g - o.v_g).norm())
    }
}

impl LinearWave {
    /// Isothermal sound speed cs, or the adiabatic sqrt(γ p0/ρg0).
    pub fn sound_speed(&self) -> f64 {
        match self.gas {
            WaveGas::Isothermal { cs } => cs,
            WaveGas::Adiabatic { gamma, p0 } => (gamma * p0 / self.rho_g0).sqrt(),
        }
    }

    fn n(&self) -> usize {
        self.rho_d0.len()
    }

    fn adiabatic(&self) -> bool {
        matches!(self.gas, WaveGas::Adiabatic { .. })
    }

    fn validate(&self) {
        assert!(
            self.rho_g0 > 0.0 && self.rho_g0.is_finite(),
            "LinearWave: rho_g0 > 0"
        );
        assert!(self.k.is_finite(), "LinearWave: k must be finite");
        assert_eq!(
            self.rho_d0.len(),
            self.t_stop.len(),
            "LinearWave: rho_d0/t_stop lengths"
        );
        assert!(
            self.rho_d0.iter().all(|r| *r >= 0.0 && r.is_finite()),
            "LinearWave: rho_d0 >= 0"
        );
        assert!(
            self.t_stop.iter().all(|t| *t > 0.0 && t.is_finite()),
            "LinearWave: t_stop > 0"
        );
        match self.gas {
            WaveGas::Isothermal { cs } => assert!(cs > 0.0, "LinearWave: cs > 0"),
            WaveGas::Adiabatic { gamma, p0 } => {
                assert!(gamma > 1.0 && p0 > 0.0, "LinearWave: gamma > 1, p0 > 0")
            }
        }
    }

    /// Dust-to-gas ratios ε_k = ρk0/ρg0.
    pub fn eps(&self) -> Vec<f64> {
        self.rho_d0.iter().map(|r| r / self.rho_g0).collect()
    }

    /// The ODE matrix 𝕄 on ŷ = (ρ̂g, v̂, ρ̂1, û1, …, ρ̂N, ûN[, ê]).
    pub fn matrix(&self) -> Vec<Vec<C>> {
        self.validate();
        let n = self.n();
        let dim = 2 * n + 2 + usize::from(self.adiabatic());
        let mut m = vec![vec![C::ZERO; dim]; dim];
        let ik = C::new(0.0, self.k);
        m[0][1] = -ik * self.rho_g0;
        match self.gas {
            WaveGas::Isothermal { cs } => m[1][0] = -ik * (cs * cs / self.rho_g0),
            WaveGas::Adiabatic { gamma, p0 } => {
                // p̂ = (γ−1)(e0 ρ̂g + ρg0 ê) with e0 = p0/((γ−1)ρg0); dê/dt = −(p0/ρg0) ik v̂.
                let e0 = p0 / ((gamma - 1.0) * self.rho_g0);
                let ie = dim - 1;
                m[1][0] = -ik * ((gamma - 1.0) * e0 / self.rho_g0);
                m[1][ie] = -ik * (gamma - 1.0);
                m[ie][1] = -ik * (p0 / self.rho_g0);
            }
        }
        for (j, (&rho, &t)) in self.rho_d0.iter().zip(&self.t_stop).enumerate() {
            let (ir, iu) = (2 + 2 * j, 3 + 2 * j);
            let a = rho / self.rho_g0 / t;
            m[1][1] -= C::from(a);
            m[1][iu] += C::from(a);
            m[ir][iu] = -ik * rho;
            m[iu][iu] = C::from(-1.0 / t);
            m[iu][1] = C::from(1.0 / t);
        }
        m
    }

    fn pack(&self, y: &WaveAmplitudes) -> Vec<C> {
        let n = self.n();
        assert!(
            y.rho_d.len() == n && y.v_d.len() == n,
            "WaveAmplitudes: wrong number of dust fractions"
        );
        let mut v = vec![y.rho_g, y.v_g];
        for j in 0..n {
            v.push(y.rho_d[j]);
            v.push(y.v_d[j]);
        }
        if self.adiabatic() {
            v.push(y.e.expect("adiabatic LinearWave needs the internal-energy amplitude `e`"));
        }
        v
    }

    fn unpack(&self, v: &[C]) -> WaveAmplitudes {
        let n = self.n();
        WaveAmplitudes {
            rho_g: v[0],
            v_g: v[1],
            e: self.adiabatic().then(|| v[2 * n + 2]),
            rho_d: (0..n).map(|j| v[2 + 2 * j]).collect(),
            v_d: (0..n).map(|j| v[3 + 2 * j]).collect(),
        }
    }

    /// Exact amplitudes at time t: ŷ(t) = exp(𝕄t) ŷ(0).
    ///
    /// # Panics
    /// If the dust vectors have the wrong length, or the gas is adiabatic and `y0.e` is `None`
    /// (for an isothermal gas `y0.e` is ignored and the result has `e = None`).
    pub fn evolve(&self, y0: &WaveAmplitudes, t: f64) -> WaveAmplitudes {
        let e = expm_complex(&self.matrix(), t);
        self.unpack(&matvec(&e, &self.pack(y0)))
    }

    /// Fractions merged by equal t_k, as (t, Σε), dropping groups with Σε = 0. Only these
    /// enter the dispersion relation: the extra roots ω = 1/t_k of equal-t fractions (in-group
    /// relaxation with Σ ε_k û_k = 0) and of ε_k = 0 test fractions carry no gas motion.
    fn drag_groups(&self) -> Vec<(f64, f64)> {
        let mut g: Vec<(f64, f64)> = Vec::new();
        for (&r, &t) in self.rho_d0.iter().zip(&self.t_stop) {
            match g.iter_mut().find(|(tg, _)| *tg == t) {
                Some(entry) => entry.1 += r / self.rho_g0,
                None => g.push((t, r / self.rho_g0)),
            }
        }
        g.retain(|&(_, e)| e > 0.0);
        g
    }

    /// Coefficients (ascending powers of ω) of the dispersion polynomial
    /// ω² [Π(1−ωt_k) + Σ ε_k Π_{j≠k}(1−ωt_j)] + k²c² Π(1−ωt_k), of degree G+2 where G is the
    /// number of distinct t_k with ε > 0 (N+2 when all t_k differ; see `drag_groups`).
    pub fn dispersion_polynomial(&self) -> Vec<f64> {
        self.validate();
        let groups = self.drag_groups();
        let prod_except = |skip: Option<usize>| {
            groups
                .iter()
                .enumerate()
                .filter(|(j, _)| Some(*j) != skip)
                .fold(vec![1.0], |acc, (_, &(t, _))| poly_mul(&acc, &[1.0, -t]))
        };
        let b = prod_except(None);
        let mut a = b.clone();
        for (k, &(_, e)) in groups.iter().enumerate() {
            for (ai, pi) in a.iter_mut().zip(prod_except(Some(k))) {
                *ai += e * pi;
            }
        }
        let kc2 = (self.k * self.sound_speed()).powi(2);
        let mut p = vec![0.0; groups.len() + 3];
        for (i, ai) in a.iter().enumerate() {
            p[i + 2] += ai;
        }
        for (i, bi) in b.iter().enumerate() {
            p[i] += kc2 * bi;
        }
        p
    }

    /// The rational form F(ω) = ω²[1 + Σ ε_k/(1−ωt_k)] + k²c² and dF/dω.
    fn dispersion_rational(&self, w: C) -> (C, C) {
        let mut s = C::ONE;
        let mut ds = C::ZERO;
        for (&r, &t) in self.rho_d0.iter().zip(&self.t_stop) {
            let e = r / self.rho_g0;
            let d = 1.0 - w * t;
            s += e / d;
            ds += (e * t) / (d * d);
        }
        let kc2 = (self.k * self.sound_speed()).powi(2);
        (w * w * s + kc2, w * 2.0 * s + w * w * ds)
    }

    /// All roots ω of [`Self::dispersion_polynomial`] (modes ∝ exp(ikx − ωt)), sorted by Re ω
    /// then Im ω. Aberth–Ehrlich iteration started from the k → 0 limits (the DUSTYBOX decay
    /// rates and ±i k c_eff), then Newton polishing on the better-conditioned rational form
    /// away from its poles. For k = 0 the two acoustic roots are 0.
    pub fn dispersion_roots(&self) -> Vec<C> {
        let coef = self.dispersion_polynomial();
        let (t_g, eps_g): (Vec<f64>, Vec<f64>) = self.drag_groups().into_iter().unzip();
        let kc = (self.k * self.sound_speed()).abs();
        let eps_tot: f64 = eps_g.iter().sum();
        let rates = DustyBox::new(eps_g, t_g).eigenvalues();
        let mut z: Vec<C> = rates
            .iter()
            .enumerate()
            .map(|(j, &l)| C::new(l * (1.0 + 0.013 * (j + 1) as f64), 0.01 * l))
            .collect();
        let ca = 0.5 * kc * (1.0 + 1.0 / (1.0 + eps_tot).sqrt());
        let scale = ca.max(1e-300);
        z.push(C::new(0.05 * scale, -scale));
        z.push(C::new(0.07 * scale, 1.01 * scale));
        let mut roots = aberth(&coef, z);
        for w in roots.iter_mut() {
            let near_pole = self.t_stop.iter().any(|&t| (1.0 - *w * t).norm() < 1e-6);
            if !near_pole && w.norm() > 0.0 {
                *w = self.polish(*w);
            }
        }
        roots.sort_by(|a, b| a.re.total_cmp(&b.re).then(a.im.total_cmp(&b.im)));
        roots
    }

    /// Newton on the rational form; a step is kept only if it lowers |F|.
    fn polish(&self, mut w: C) -> C {
        let mut f = self.dispersion_rational(w).0.norm();
        for _ in 0..50 {
            let (fv, df) = self.dispersion_rational(w);
            if df.norm() == 0.0 {
                break;
            }
            let step = fv / df;
            let wn = w - step;
            let fnew = self.dispersion_rational(wn).0.norm();
            if fnew.is_nan() || fnew >= f {
                break;
            }
            w = wn;
            f = fnew;
            if step.norm() <= 1e-16 * w.norm() {
                break;
            }
        }
        w
    }

    /// Amplitudes of the mode with root ω, normalised to δρ̂g = 1:
    /// δv̂g = −iω/(kρg0), δv̂k = δv̂g/(1−ωt_k), δρ̂k = (ρk0/ρg0)/(1−ωt_k),
    /// and for an adiabatic gas the isentropic ê = (p0/ρg0²)·δρ̂g.
    pub fn mode_amplitudes(&self, w: C) -> WaveAmplitudes {
        let v_g = C::new(0.0, -1.0) * w / (self.k * self.rho_g0);
        let e = match self.gas {
            WaveGas::Isothermal { .. } => None,
            WaveGas::Adiabatic { p0, .. } => Some(C::from(p0 / (self.rho_g0 * self.rho_g0))),
        };
        let (rho_d, v_d) = self
            .rho_d0
            .iter()
            .zip(&self.t_stop)
            .map(|(&r, &t)| {
                let d = 1.0 - w * t;
                ((r / self.rho_g0) / d, v_g / d)
            })
            .unzip();
        WaveAmplitudes {
            rho_g: C::ONE,
            v_g,
            e,
            rho_d,
            v_d,
        }
    }

    /// Least-damped acoustic eigenmode, BL2019 convention exp(ikx − ωt): returns ω (the root
    /// with Im ω < 0 and the smallest Re ω) and its amplitudes with δρ̂g = 1. If no root is
    /// complex (an overdamped regime), the least-damped non-zero root is used instead.
    pub fn eigenmode(&self) -> (C, WaveAmplitudes) {
        assert!(self.k != 0.0, "LinearWave::eigenmode needs k != 0");
        let roots = self.dispersion_roots();
        let pick = |pred: &dyn Fn(&C) -> bool| {
            roots
                .iter()
                .copied()
                .filter(|w| pred(w))
                .min_by(|a, b| a.re.total_cmp(&b.re))
        };
        let w = pick(&|w| w.im < -1e-10 * w.norm())
            .or_else(|| pick(&|w| w.norm() > 0.0))
            .expect("dispersion relation has a non-zero root");
        (w, self.mode_amplitudes(w))
    }
}

fn poly_mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut c = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            c[i + j] += x * y;
        }
    }
    c
}

/// p(z) and p'(z) by Horner, coefficients in ascending order.
fn horner(coef: &[f64], z: C) -> (C, C) {
    let mut p = C::ZERO;
    let mut dp = C::ZERO;
    for &c in coef.iter().rev() {
        dp = dp * z + p;
        p = p * z + c;
    }
    (p, dp)
}

/// Aberth–Ehrlich simultaneous root iteration (Gauss–Seidel updates) from distinct guesses.
fn aberth(coef: &[f64], mut z: Vec<C>) -> Vec<C> {
    let n = z.len();
    debug_assert_eq!(n + 1, coef.len());
    for _ in 0..2000 {
        let mut moved: f64 = 0.0;
        for i in 0..n {
            let (p, dp) = horner(coef, z[i]);
            if p.norm() == 0.0 {
                continue;
            }
            let s = (0..n)
                .filter(|&j| j != i)
                .fold(C::ZERO, |s, j| s + (z[i] - z[j]).inv());
            let ratio = p / dp;
            let corr = ratio / (1.0 - ratio * s);
            if !(corr.re.is_finite() && corr.im.is_finite()) {
                // Zero derivative or coincident guesses: nudge and retry next sweep.
                z[i] = z[i] * C::new(1.0 + 1e-7, 1e-7) + C::new(1e-300, 0.0);
                moved = f64::INFINITY;
                continue;
            }
            z[i] -= corr;
            moved = moved.max(corr.norm() / z[i].norm().max(f64::MIN_POSITIVE));
        }
        if moved < 1e-15 {
            break;
        }
    }
    z
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn iso(rho_d0: Vec<f64>, t_stop: Vec<f64>) -> LinearWave {
        LinearWave {
            rho_g0: 1.0,
            gas: WaveGas::Isothermal { cs: 1.0 },
            rho_d0,
            t_stop,
            k: 2.0 * PI,
        }
    }

    fn bl4() -> LinearWave {
        iso(
            vec![0.1, 0.233333, 0.366667, 0.5],
            vec![0.1, 0.215443, 0.464159, 1.0],
        )
    }

    fn close(a: C, re: f64, im: f64, tol: f64) -> bool {
        (a - C::new(re, im)).norm() < tol
    }

    /// BL2019 N = 1 (method.md §7.3): ω and the eigenvector to the tabulated digits.
    #[test]
    fn bl2019_single_species() {
        let wave = iso(vec![2.24], vec![0.4]);
        let (w, m) = wave.eigenmode();
        assert!(close(w, 1.915896034, -4.410541315, 1e-9), "{w:?}");
        assert!(close(m.v_g, -0.701960, -0.304924, 1e-6), "{:?}", m.v_g);
        assert!(close(m.rho_d[0], 0.165251, -1.247801, 1e-6));
        assert!(close(m.v_d[0], -0.221645, 0.368534, 1e-6));
        assert!(m.e.is_none());
    }

    /// BL2019 N = 4 (method.md §7.3).
    #[test]
    fn bl2019_four_species() {
        let (w, m) = bl4().eigenmode();
        assert!(close(w, 0.912413245, -5.493799325, 1e-9), "{w:?}");
        assert_eq!(m.rho_g, C::ONE);
        assert!(close(m.v_g, -0.874365, -0.145215, 1e-6));
        let rho = [
            (0.080588, -0.048719),
            (0.091607, -0.134955),
            (0.030927, -0.136799),
            (0.001451, -0.090989),
        ];
        let vel = [
            (-0.775380, 0.308952),
            (-0.427268, 0.448704),
            (-0.127928, 0.313967),
            (-0.028963, 0.158693),
        ];
        for j in 0..4 {
            assert!(close(m.rho_d[j], rho[j].0, rho[j].1, 1e-6), "{j}");
            assert!(close(m.v_d[j], vel[j].0, vel[j].1, 1e-6), "{j}");
        }
    }

    /// The matrix exponential propagates an eigenmode as e^{−ωt} (ties 𝕄 to the dispersion
    /// relation and the eigenvector formulas).
    #[test]
    fn evolve_eigenmode_bl() {
        for wave in [iso(vec![2.24], vec![0.4]), bl4()] {
            let (w, m) = wave.eigenmode();
            for t in [0.1, 0.5, 2.0] {
                let y = wave.evolve(&m, t);
                let err = y.max_abs_diff(&m.scale((-w * t).exp()));
                assert!(err < 1e-10, "t={t}: {err:e}");
            }
        }
    }

    /// Laibe & Price spot roots (method.md §7.2 table, y = −ω, 6 decimals).
    #[test]
    fn laibe_price_spot_roots() {
        // (ρg, ρd, K, Re y_ac, |Im y_ac|, y_3)
        let table = [
            (1.0, 1.0, 0.01, -0.005000, 6.283175, -0.010000),
            (1.0, 1.0, 1.0, -0.487015, 6.184004, -1.025971),
            (1.0, 1.0, 100.0, -0.049348, 4.443706, -199.901304),
            (1.0, 1.0, 1000.0, -0.004935, 4.442891, -1999.990130),
            (1.0, 0.01, 1.0, -0.001928, 6.252122, -100.996145),
            (1.0, 0.01, 100.0, -0.000019, 6.252003, -10099.999961),
        ];
        for (rg, rd, kd, yr, yi, y3) in table {
            let wave = LinearWave {
                rho_g0: rg,
                gas: WaveGas::Isothermal { cs: 1.0 },
                rho_d0: vec![rd],
                t_stop: vec![rd / kd],
                k: 2.0 * PI,
            };
            let y: Vec<C> = wave.dispersion_roots().iter().map(|&w| -w).collect();
            assert_eq!(y.len(), 3);
            let tol = 1e-6;
            assert!(y.iter().any(|r| close(*r, yr, yi, tol)), "K={kd}: {y:?}");
            assert!(y.iter().any(|r| close(*r, yr, -yi, tol)), "K={kd}: {y:?}");
            assert!(y.iter().any(|r| close(*r, y3, 0.0, tol)), "K={kd}: {y:?}");
        }
    }

    /// Stiff coupling t = 1e-7, ε = 1: the wave travels at c_eff = cs/√2 and the damping is
    /// the asymptotic ε k²c² t/(2(1+ε)²) ≈ 4.93e-7, negligible over t = 1.
    #[test]
    fn stiff_limit_isothermal() {
        let wave = iso(vec![1.0], vec![1e-7]);
        let (w, m) = wave.eigenmode();
        let k = 2.0 * PI;
        let speed = -w.im / k;
        assert!((speed - 1.0 / 2f64.sqrt()).abs() < 1e-10, "{speed}");
        let damp = k * k * 1e-7 / 8.0;
        assert!((w.re - damp).abs() < 1e-5 * damp, "{} vs {damp}", w.re);
        let decay = (-w).exp().norm();
        assert!(decay > 1.0 - 1e-6 && decay <= 1.0);
        let y = wave.evolve(&m, 1.0);
        let err = y.max_abs_diff(&m.scale((-w).exp()));
        assert!(err < 1e-10, "{err:e}");
    }

    fn adiabatic(rho_d0: Vec<f64>, t_stop: Vec<f64>, gamma: f64, p0: f64) -> LinearWave {
        LinearWave {
            rho_g0: 1.0,
            gas: WaveGas::Adiabatic { gamma, p0 },
            rho_d0,
            t_stop,
            k: 2.0 * PI,
        }
    }

    /// Adiabatic gas: with γp0/ρg0 = cs² the roots equal the isothermal ones; the matrix
    /// propagates the isentropic eigenmode; the stiff phase speed is sqrt(γp0/ρ)/sqrt(1+ε).
    #[test]
    fn adiabatic_consistency() {
        let a = adiabatic(vec![2.24], vec![0.4], 5.0 / 3.0, 0.6);
        assert!((a.sound_speed() - 1.0).abs() < 1e-15);
        let (wa, ma) = a.eigenmode();
        let (wi, _) = iso(vec![2.24], vec![0.4]).eigenmode();
        assert!((wa - wi).norm() < 1e-12);
        assert!(close(ma.e.unwrap(), 0.6, 0.0, 1e-15));
        for t in [0.3, 2.0] {
            let err = a.evolve(&ma, t).max_abs_diff(&ma.scale((-wa * t).exp()));
            assert!(err < 1e-10, "{err:e}");
        }
        let s = adiabatic(vec![1.0], vec![1e-7], 1.4, 2.5);
        let c = (1.4f64 * 2.5).sqrt();
        let (ws, ms) = s.eigenmode();
        let speed = -ws.im / s.k;
        assert!((speed - c / 2f64.sqrt()).abs() < 1e-10 * c, "{speed}");
        let err = s.evolve(&ms, 1.0).max_abs_diff(&ms.scale((-ws).exp()));
        assert!(err < 1e-10, "{err:e}");
    }

    /// Arbitrary (non-eigenmode) initial data: exp(𝕄t) against a fine RK4 integration.
    #[test]
    fn evolve_matches_rk4() {
        let waves = [bl4(), {
            let mut w = bl4();
            w.gas = WaveGas::Adiabatic {
                gamma: 1.4,
                p0: 0.8,
            };
            w
        }];
        for wave in waves {
            let n = wave.n();
            let y0 = WaveAmplitudes {
                rho_g: C::new(1.0, 0.0),
                v_g: C::new(0.0, 0.3),
                e: wave.adiabatic().then_some(C::new(0.2, -0.1)),
                rho_d: wave.rho_d0.iter().map(|&r| C::new(r, 0.0)).collect(),
                v_d: (0..n).map(|j| C::new(0.1 * j as f64, 0.0)).collect(),
            };
            let t = 1.0;
            let m = wave.matrix();
            let mut y = wave.pack(&y0);
            let steps = 20_000;
            let h = t / steps as f64;
            let f = |y: &[C]| matvec(&m, y);
            let axpy = |y: &[C], k: &[C], a: f64| -> Vec<C> {
                y.iter().zip(k).map(|(&p, &q)| p + q * a).collect()
            };
            for _ in 0..steps {
                let k1 = f(&y);
                let k2 = f(&axpy(&y, &k1, 0.5 * h));
                let k3 = f(&axpy(&y, &k2, 0.5 * h));
                let k4 = f(&axpy(&y, &k3, h));
                for i in 0..y.len() {
                    y[i] += (k1[i] + k2[i] * 2.0 + k3[i] * 2.0 + k4[i]) * (h / 6.0);
                }
            }
            let rk = wave.unpack(&y);
            let ex = wave.evolve(&y0, t);
            let err = ex.max_abs_diff(&rk);
            assert!(err < 1e-10, "{err:e}");
            // Semigroup: evolving in two pieces gives the same state.
            let two = wave.evolve(&wave.evolve(&y0, 0.37), t - 0.37);
            assert!(two.max_abs_diff(&ex) < 1e-13);
        }
    }

    /// Awkward parameter sets: equal t_k, an ε = 0 fraction, stiff and slow fractions mixed,
    /// eight species, heavy dust. The chosen root must be a genuine acoustic mode, i.e. the
    /// matrix exponential must propagate it as e^{−ωt}.
    #[test]
    fn eigenmode_robustness() {
        let cases = [
            iso(vec![0.2, 0.5, 0.4], vec![0.3, 0.3, 0.3]),
            iso(vec![0.2, 0.5, 0.4, 1.0], vec![1e-8, 1e-3, 1.0, 10.0]),
            iso(
                (0..8).map(|i| 0.1 + 0.05 * i as f64).collect(),
                (0..8).map(|i| 10f64.powf(-3.0 + 0.5 * i as f64)).collect(),
            ),
            iso(vec![100.0], vec![0.01]),
            iso(vec![0.01, 0.0], vec![100.0, 1.0]),
            iso(vec![], vec![]),
        ];
        for wave in cases {
            let (w, m) = wave.eigenmode();
            assert!(w.im < 0.0 && w.re >= 0.0, "{w:?}");
            for t in [0.2, 1.0] {
                let err = wave.evolve(&m, t).max_abs_diff(&m.scale((-w * t).exp()));
                assert!(err < 1e-10, "{:?}: {err:e}", wave.t_stop);
            }
        }
        // Equal stopping times act as one fraction with the summed density.
        let (w3, _) = iso(vec![0.2, 0.5, 0.4], vec![0.3, 0.3, 0.3]).eigenmode();
        let (w1, _) = iso(vec![1.1], vec![0.3]).eigenmode();
        assert!((w3 - w1).norm() < 1e-13);
        // k = 0: a double root at 0 and the DUSTYBOX decay rates (method.md §7.1).
        let mut flat = bl4();
        flat.k = 0.0;
        let roots = flat.dispersion_roots();
        let rates = DustyBox::new(flat.eps(), flat.t_stop.clone()).eigenvalues();
        assert!(
            roots[0].norm() < 1e-200 && roots[1].norm() < 1e-200,
            "{roots:?}"
        );
        for (r, l) in roots[2..].iter().zip(&rates) {
            assert!((*r - *l).norm() < 1e-13 * l, "{r:?} vs {l}");
        }
        // Pure gas: ω = −ikc exactly.
        let (w0, _) = iso(vec![], vec![]).eigenmode();
        assert!(close(w0, 0.0, -2.0 * PI, 1e-14));
    }

    /// A pure dust-density perturbation with no velocity is a zero-frequency mode.
    #[test]
    fn static_dust_density_mode() {
        let wave = bl4();
        let y0 = WaveAmplitudes {
            rho_g: C::ZERO,
            v_g: C::ZERO,
            e: None,
            rho_d: vec![C::new(0.3, -0.2); 4],
            v_d: vec![C::ZERO; 4],
        };
        assert!(wave.evolve(&y0, 5.0).max_abs_diff(&y0) < 1e-15);
        assert!((real_field(C::new(0.0, -1.0), 2.0 * PI, 0.25) - 1.0).abs() < 1e-15);
    }
}
