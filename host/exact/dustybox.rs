//! DUSTYBOX (method.md §7.1): a uniform gas + N dust fractions whose relative velocities relax
//! by linear drag. Exact solution and the exact discrete (IDIC / backward-Euler) oracle.
//!
//! Relative velocities w_k = u_k − v obey dw/dt = −M w with M_jk = δ_jk/t_j + ε_k/t_k; the
//! barycentric velocity V = (v + Σ ε_k u_k)/(1 + Σ ε_k) is constant, and
//! v = V − Σ ε_k w_k/(1 + Σ ε_k), u_k = v + w_k.
use super::linalg::{expm_real, implicit_euler_power};

/// Constant accelerations along the velocity component: `gas` on the gas, `dust` on every
/// fraction (the `[external]` section's).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Forcing {
    pub gas: f64,
    pub dust: f64,
}

/// Uniform box: ε_k = ρ_k/ρ_g and t_k = ρ_k/K_k (method.md §1.1 convention).
#[derive(Clone, Debug, PartialEq)]
pub struct DustyBox {
    pub eps: Vec<f64>,
    pub t_stop: Vec<f64>,
}

impl DustyBox {
    /// Checked constructor (equal lengths, ε_k ≥ 0, t_k > 0).
    pub fn new(eps: Vec<f64>, t_stop: Vec<f64>) -> Self {
        let b = DustyBox { eps, t_stop };
        b.validate();
        b
    }

    fn validate(&self) {
        assert_eq!(
            self.eps.len(),
            self.t_stop.len(),
            "DustyBox: eps and t_stop lengths differ"
        );
        assert!(
            self.eps.iter().all(|e| e.is_finite() && *e >= 0.0),
            "DustyBox: eps must be finite and >= 0"
        );
        assert!(
            self.t_stop.iter().all(|t| t.is_finite() && *t > 0.0),
            "DustyBox: t_stop must be finite and > 0"
        );
    }

    /// Total dust-to-gas ratio Σ ε_k.
    pub fn eps_total(&self) -> f64 {
        self.eps.iter().sum()
    }

    /// The drag matrix M_jk = δ_jk/t_j + ε_k/t_k acting on w = u − v.
    pub fn drag_matrix(&self) -> Vec<Vec<f64>> {
        let n = self.eps.len();
        (0..n)
            .map(|j| {
                (0..n)
                    .map(|k| {
                        let d = if j == k { 1.0 / self.t_stop[j] } else { 0.0 };
                        d + self.eps[k] / self.t_stop[k]
                    })
                    .collect()
            })
            .collect()
    }

    /// V = (v + Σ ε_k u_k)/(1 + Σ ε_k), conserved by drag.
    pub fn barycentric_velocity(&self, v: f64, u: &[f64]) -> f64 {
        assert_eq!(
            u.len(),
            self.eps.len(),
            "DustyBox: wrong number of dust velocities"
        );
        let mom: f64 = self.eps.iter().zip(u).map(|(e, uk)| e * uk).sum();
        (v + mom) / (1.0 + self.eps_total())
    }

    /// The N decay rates λ (ascending): eigenvalues of M, i.e. roots of
    /// 1 + Σ ε_k/(1 − λ t_k) = 0, by bisection between consecutive poles 1/t_k.
    ///
    /// Fractions with identical t_k are merged first (a group of m with total ε_G > 0
    /// contributes one pole of weight ε_G plus the eigenvalue 1/t with multiplicity m − 1:
    /// in-group velocity differences with Σ ε_k w_k = 0 decay at exactly 1/t). A fraction with
    /// ε_k = 0 is a test particle: its eigenvalue is 1/t_k.
    pub fn eigenvalues(&self) -> Vec<f64> {
        self.validate();
        let mut idx: Vec<usize> = (0..self.eps.len()).collect();
        // Descending t = ascending pole 1/t.
        idx.sort_by(|&a, &b| self.t_stop[b].total_cmp(&self.t_stop[a]));
        let mut lambdas = Vec::with_capacity(idx.len());
        let mut poles: Vec<(f64, f64)> = Vec::new(); // (t, ε_G)
        let mut i = 0;
        while i < idx.len() {
            let t = self.t_stop[idx[i]];
            let mut j = i;
            let mut eg = 0.0;
            while j < idx.len() && self.t_stop[idx[j]] == t {
                eg += self.eps[idx[j]];
                j += 1;
            }
            let m = j - i;
            if eg > 0.0 {
                lambdas.extend(std::iter::repeat_n(1.0 / t, m - 1));
                poles.push((t, eg));
            } else {
                lambdas.extend(std::iter::repeat_n(1.0 / t, m));
            }
            i = j;
        }
        let secular = |lam: f64| 1.0 + poles.iter().map(|&(t, e)| e / (1.0 - lam * t)).sum::<f64>();
        let eps_poles: f64 = poles.iter().map(|p| p.1).sum();
        for (p, &(t, _)) in poles.iter().enumerate() {
            // The secular function increases from −∞ (right of pole p) to +∞ (left of the next
            // pole), or to 1 above the last pole, where it is > 0 for λ > (1 + ε)/t_min.
            let mut lo = 1.0 / t;
            let mut hi = match poles.get(p + 1) {
                Some(&(tn, _)) => 1.0 / tn,
                None => 2.0 * (1.0 + eps_poles) / t,
            };
            for _ in 0..2200 {
                let mid = 0.5 * (lo + hi);
                if mid <= lo || mid >= hi {
                    break;
                }
                if secular(mid) > 0.0 {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            lambdas.push(0.5 * (lo + hi));
        }
        lambdas.sort_by(f64::total_cmp);
        lambdas
    }

    /// The steady relative velocities under constant accelerations (`a_gas` on the gas,
    /// `a_dust` on every fraction): M w* = (a_dust − a_gas) 1 gives
    /// w*_k = t_k (a_dust − a_gas)/(1 + Σε), the terminal drift of each fraction.
    pub fn terminal_drift(&self, a: Forcing) -> Vec<f64> {
        let c = (a.dust - a.gas) / (1.0 + self.eps_total());
        self.t_stop.iter().map(|t| t * c).collect()
    }

    /// The barycentric acceleration (a_gas + Σ ε_k a_dust)/(1 + Σε).
    fn barycentric_acceleration(&self, a: Forcing) -> f64 {
        (a.gas + self.eps_total() * a.dust) / (1.0 + self.eps_total())
    }

    /// [`Self::exact`] under constant accelerations: w(t) = w* + exp(−Mt)(w(0) − w*), the
    /// barycentric velocity grows at the barycentric acceleration.
    pub fn exact_forced(&self, v0: f64, u0: &[f64], a: Forcing, t: f64) -> (f64, Vec<f64>) {
        self.forced(v0, u0, a, t, |v, u| self.exact(v, u, t))
    }

    /// [`Self::implicit_euler`] under constant accelerations, as IDIC applies them (the kick
    /// τa before the implicit drag): w^n = w* + (I + τM)^{−n}(w^0 − w*), exact for the discrete
    /// scheme since w^{n+1} − w* = (I + τM)^{−1}(w^n − w*).
    pub fn implicit_euler_forced(
        &self,
        v0: f64,
        u0: &[f64],
        a: Forcing,
        tau: f64,
        n: usize,
    ) -> (f64, Vec<f64>) {
        let t = tau * n as f64;
        self.forced(v0, u0, a, t, |v, u| self.implicit_euler(v, u, tau, n))
    }

    /// The unforced solution `decay` of the deviation from the terminal drift, shifted back and
    /// carried by the barycentric acceleration over time t.
    fn forced(
        &self,
        v0: f64,
        u0: &[f64],
        a: Forcing,
        t: f64,
        decay: impl Fn(f64, &[f64]) -> (f64, Vec<f64>),
    ) -> (f64, Vec<f64>) {
        if a.gas == 0.0 && a.dust == 0.0 {
            return decay(v0, u0);
        }
        let ws = self.terminal_drift(a);
        // The same barycentric velocity with the relative velocities w(0) − w*.
        let vbar = self.barycentric_velocity(v0, u0);
        let (v, u) = self.assemble(
            vbar,
            &u0.iter()
                .zip(&ws)
                .map(|(u, w)| u - v0 - w)
                .collect::<Vec<_>>(),
        );
        let (v, u) = decay(v, &u);
        let shift = self.barycentric_acceleration(a) * t;
        let (vd, _) = self.assemble(0.0, &ws);
        let v_new = v + vd + shift;
        (
            v_new,
            u.iter()
                .zip(&ws)
                .map(|(uk, w)| uk - v + v_new + w)
                .collect(),
        )
    }

    /// Exact velocities at time t for one velocity component: (v_gas, u_k for each k).
    ///
    /// w(t) = exp(−M t) w(0) by the double-double matrix exponential: robust for equal or
    /// nearly equal t_k (where an eigenvector basis degenerates) and for stiff t_k ≪ t
    /// (decaying modes underflow to 0, nothing overflows).
    pub fn exact(&self, v0: f64, u0: &[f64], t: f64) -> (f64, Vec<f64>) {
        self.validate();
        let vbar = self.barycentric_velocity(v0, u0);
        let w0: Vec<f64> = u0.iter().map(|u| u - v0).collect();
        let minus_m: Vec<Vec<f64>> = self
            .drag_matrix()
            .into_iter()
            .map(|r| r.into_iter().map(|x| -x).collect())
            .collect();
        let e = expm_real(&minus_m, t);
        let w: Vec<f64> = e
            .iter()
            .map(|row| row.iter().zip(&w0).map(|(a, b)| a * b).sum())
            .collect();
        self.assemble(vbar, &w)
    }

    /// The discrete IDIC / backward-Euler oracle after n steps of size tau:
    /// w^n = (I + τM)^{-n} w^0 with V conserved. Computed as one double-double inverse raised
    /// to the n-th power by binary powering, so n ~ 1e6 and τ/t ~ 1e8 lose no accuracy.
    pub fn implicit_euler(&self, v0: f64, u0: &[f64], tau: f64, n: usize) -> (f64, Vec<f64>) {
        self.validate();
        assert!(tau >= 0.0 && tau.is_finite(), "DustyBox: tau must be >= 0");
        let vbar = self.barycentric_velocity(v0, u0);
        let w0: Vec<f64> = u0.iter().map(|u| u - v0).collect();
        // I + τM has eigenvalues 1 + τλ ≥ 1, so it is never singular.
        let w = implicit_euler_power(&self.drag_matrix(), tau, n, &w0)
            .expect("I + tau*M is nonsingular for tau >= 0");
        self.assemble(vbar, &w)
    }

    fn assemble(&self, vbar: f64, w: &[f64]) -> (f64, Vec<f64>) {
        let ew: f64 = self.eps.iter().zip(w).map(|(e, wk)| e * wk).sum();
        let v = vbar - ew / (1.0 + self.eps_total());
        (v, w.iter().map(|wk| v + wk).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::super::linalg::solve_real;
    use super::*;

    /// The N = 4 parameter set of method.md §7.1/§7.3.
    fn box4() -> DustyBox {
        DustyBox::new(
            vec![0.1, 0.233333, 0.366667, 0.5],
            vec![0.1, 0.215443, 0.464159, 1.0],
        )
    }

    /// Classical RK4 on the full (v, u_k) system, an independent reference.
    fn rk4(b: &DustyBox, v0: f64, u0: &[f64], t: f64, steps: usize) -> (f64, Vec<f64>) {
        let n = u0.len();
        let rhs = |y: &[f64]| -> Vec<f64> {
            let mut d = vec![0.0; n + 1];
            for k in 0..n {
                let r = (y[k + 1] - y[0]) / b.t_stop[k];
                d[0] += b.eps[k] * r;
                d[k + 1] = -r;
            }
            d
        };
        let mut y: Vec<f64> = std::iter::once(v0).chain(u0.iter().copied()).collect();
        let h = t / steps as f64;
        let axpy = |y: &[f64], k: &[f64], a: f64| -> Vec<f64> {
            y.iter().zip(k).map(|(yi, ki)| yi + a * ki).collect()
        };
        for _ in 0..steps {
            let k1 = rhs(&y);
            let k2 = rhs(&axpy(&y, &k1, 0.5 * h));
            let k3 = rhs(&axpy(&y, &k2, 0.5 * h));
            let k4 = rhs(&axpy(&y, &k3, h));
            for i in 0..=n {
                y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        }
        (y[0], y[1..].to_vec())
    }

    /// Eigen-form w = Σ c_m g(λ_m) φ_m with φ_m,j = t_j/(λ_m t_j − 1) (distinct t_k only);
    /// g = e^{−λt} for the exact solution, (1 + τλ)^{-n} for the discrete one.
    fn eigen_form(b: &DustyBox, v0: f64, u0: &[f64], g: impl Fn(f64) -> f64) -> (f64, Vec<f64>) {
        let lam = b.eigenvalues();
        let n = lam.len();
        let phi: Vec<Vec<f64>> = (0..n)
            .map(|j| {
                (0..n)
                    .map(|m| b.t_stop[j] / (lam[m] * b.t_stop[j] - 1.0))
                    .collect()
            })
            .collect();
        let w0: Vec<f64> = u0.iter().map(|u| u - v0).collect();
        let c = solve_real(&phi, &w0).unwrap();
        let w: Vec<f64> = (0..n)
            .map(|j| (0..n).map(|m| c[m] * g(lam[m]) * phi[j][m]).sum())
            .collect();
        b.assemble(b.barycentric_velocity(v0, u0), &w)
    }

    fn max_diff(a: &(f64, Vec<f64>), b: &(f64, Vec<f64>)) -> f64 {
        a.1.iter()
            .zip(&b.1)
            .map(|(x, y)| (x - y).abs())
            .fold((a.0 - b.0).abs(), f64::max)
    }

    #[test]
    fn forced_box_matches_direct_integration_and_the_discrete_scheme() {
        let b = box4();
        let (v0, u0) = (0.3, [1.0, -0.5, 0.2, 0.0]);
        let (ag, ad) = (10.0, -2.0);
        // Exact: RK4 on v' = ag + Σ ε_k (u_k − v)/t_k, u_k' = ad − (u_k − v)/t_k.
        let (t, steps) = (0.7, 20_000);
        let mut y: Vec<f64> = std::iter::once(v0).chain(u0).collect();
        let rhs = |y: &[f64]| -> Vec<f64> {
            let mut d = vec![ag; 5];
            for k in 0..4 {
                let r = (y[k + 1] - y[0]) / b.t_stop[k];
                d[0] += b.eps[k] * r;
                d[k + 1] = ad - r;
            }
            d
        };
        let h = t / steps as f64;
        for _ in 0..steps {
            let k1 = rhs(&y);
            let y2: Vec<f64> = y.iter().zip(&k1).map(|(a, k)| a + 0.5 * h * k).collect();
            let k2 = rhs(&y2);
            let y3: Vec<f64> = y.iter().zip(&k2).map(|(a, k)| a + 0.5 * h * k).collect();
            let k3 = rhs(&y3);
            let y4: Vec<f64> = y.iter().zip(&k3).map(|(a, k)| a + h * k).collect();
            let k4 = rhs(&y4);
            for i in 0..5 {
                y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        }
        let f = Forcing { gas: ag, dust: ad };
        let e = b.exact_forced(v0, &u0, f, t);
        assert!(max_diff(&e, &(y[0], y[1..].to_vec())) < 1e-11);
        // Discrete: kick by τa, then solve (I + τM) w^{n+1} = w̃ with V carried exactly.
        let (tau, n) = (0.05, 14);
        let mut w: Vec<f64> = u0.iter().map(|u| u - v0).collect();
        let mut vbar = b.barycentric_velocity(v0, &u0);
        let m = b.drag_matrix();
        let a: Vec<Vec<f64>> = (0..4)
            .map(|i| {
                (0..4)
                    .map(|j| tau * m[i][j] + if i == j { 1.0 } else { 0.0 })
                    .collect()
            })
            .collect();
        for _ in 0..n {
            let kicked: Vec<f64> = w.iter().map(|x| x + tau * (ad - ag)).collect();
            w = solve_real(&a, &kicked).unwrap();
            vbar += tau * (ag + b.eps_total() * ad) / (1.0 + b.eps_total());
        }
        let d = b.implicit_euler_forced(v0, &u0, f, tau, n);
        assert!(max_diff(&d, &b.assemble(vbar, &w)) < 1e-12);
        // Long after: the terminal drift t_k Δa/(1 + Σε).
        let late = b.exact_forced(v0, &u0, f, 50.0);
        for (k, w) in b.terminal_drift(f).iter().enumerate() {
            assert!((late.1[k] - late.0 - w).abs() < 1e-12);
            assert!((w - b.t_stop[k] * (ad - ag) / (1.0 + b.eps_total())).abs() < 1e-15);
        }
    }

    #[test]
    fn single_fraction_rate() {
        let b = DustyBox::new(vec![0.7], vec![0.3]);
        let lam = b.eigenvalues();
        let expect = 1.7 / 0.3;
        assert_eq!(lam.len(), 1);
        assert!((lam[0] - expect).abs() < 1e-14 * expect, "{lam:?}");
        // w(t) = w0 e^{−λt}, V fixed.
        let (v, u) = b.exact(0.2, &[1.0], 0.4);
        let w = 0.8 * (-expect * 0.4).exp();
        let vbar = (0.2 + 0.7) / 1.7;
        assert!((u[0] - v - w).abs() < 1e-15);
        assert!((v - (vbar - 0.7 * w / 1.7)).abs() < 1e-15);
    }

    #[test]
    fn four_fraction_eigenvalues() {
        let b = box4();
        let lam = b.eigenvalues();
        // Interlacing with the poles 1/t_k.
        let mut poles: Vec<f64> = b.t_stop.iter().map(|t| 1.0 / t).collect();
        poles.sort_by(f64::total_cmp);
        for m in 0..4 {
            assert!(lam[m] > poles[m]);
            if m < 3 {
                assert!(lam[m] < poles[m + 1]);
            }
        }
        // trace(M) = Σ(1+ε_k)/t_k, det(M) = (1+Σε)/Πt_k (matrix determinant lemma).
        let tr: f64 = b
            .eps
            .iter()
            .zip(&b.t_stop)
            .map(|(e, t)| (1.0 + e) / t)
            .sum();
        let det = (1.0 + b.eps_total()) / b.t_stop.iter().product::<f64>();
        let s: f64 = lam.iter().sum();
        let p: f64 = lam.iter().product();
        assert!((s - tr).abs() < 1e-13 * tr, "{s} {tr}");
        assert!((p - det).abs() < 1e-13 * det, "{p} {det}");
    }

    #[test]
    fn four_fraction_exact_vs_rk4_and_eigen_form() {
        let b = box4();
        let u0 = [1.0; 4];
        for t in [0.05, 0.3, 1.0, 3.0] {
            let ex = b.exact(0.0, &u0, t);
            let rk = rk4(&b, 0.0, &u0, t, (t * 1e4) as usize);
            let ef = eigen_form(&b, 0.0, &u0, |l| (-l * t).exp());
            assert!(
                max_diff(&ex, &rk) < 1e-10,
                "t={t}: {:e}",
                max_diff(&ex, &rk)
            );
            assert!(
                max_diff(&ex, &ef) < 1e-13,
                "t={t}: {:e}",
                max_diff(&ex, &ef)
            );
            let v = b.barycentric_velocity(ex.0, &ex.1);
            assert!((v - b.barycentric_velocity(0.0, &u0)).abs() < 1e-15);
        }
    }

    #[test]
    fn degenerate_and_test_particle_fractions() {
        // Two equal stopping times and one ε = 0 fraction.
        let b = DustyBox::new(vec![0.2, 0.5, 0.4, 0.0], vec![0.3, 0.3, 1.0, 0.05]);
        let lam = b.eigenvalues();
        assert_eq!(lam.len(), 4);
        for want in [1.0 / 0.3, 1.0 / 0.05] {
            assert!(
                lam.iter().any(|l| (l - want).abs() < 1e-12 * want),
                "{lam:?}"
            );
        }
        let m = b.drag_matrix();
        let tr: f64 = (0..4).map(|i| m[i][i]).sum();
        assert!((lam.iter().sum::<f64>() - tr).abs() < 1e-12 * tr);
        let det = (1.0 + b.eps_total()) / b.t_stop.iter().product::<f64>();
        assert!((lam.iter().product::<f64>() - det).abs() < 1e-12 * det);
        let u0 = [1.0, -0.5, 2.0, 3.0];
        for t in [0.1, 1.0] {
            let ex = b.exact(0.25, &u0, t);
            let rk = rk4(&b, 0.25, &u0, t, (t * 2e4) as usize);
            assert!(
                max_diff(&ex, &rk) < 1e-10,
                "t={t}: {:e}",
                max_diff(&ex, &rk)
            );
        }
    }

    #[test]
    fn stiff_exact_is_finite_and_matches_eigen_form() {
        let b = DustyBox::new(vec![0.5, 1.0, 0.25], vec![1e-8, 1e-3, 1.0]);
        let u0 = [1.0, -2.0, 0.5];
        for t in [1e-9, 1e-6, 1e-2, 1.0] {
            let ex = b.exact(0.3, &u0, t);
            assert!(ex.0.is_finite() && ex.1.iter().all(|x| x.is_finite()));
            let ef = eigen_form(&b, 0.3, &u0, |l| (-l * t).exp());
            assert!(
                max_diff(&ex, &ef) < 1e-12,
                "t={t}: {:e}",
                max_diff(&ex, &ef)
            );
        }
        // All fractions stiff: at t = 1 every w_k has decayed (e^{-1e8}) and v = u_k = V.
        let s = DustyBox::new(vec![1.0, 0.5], vec![1e-8, 3e-8]);
        let (v, u) = s.exact(0.0, &[1.0, 2.0], 1.0);
        let vbar = 2.0 / 2.5;
        assert!((v - vbar).abs() < 1e-15 && u.iter().all(|x| (x - vbar).abs() < 1e-15));
    }

    /// Backward Euler converges at first order; measured order between n = 1000…8000.
    #[test]
    fn implicit_euler_first_order() {
        let b = box4();
        let u0 = [1.0; 4];
        let t = 1.0;
        let ex = b.exact(0.0, &u0, t);
        let errs: Vec<f64> = [1000, 2000, 4000, 8000]
            .iter()
            .map(|&n| max_diff(&b.implicit_euler(0.0, &u0, t / n as f64, n), &ex))
            .collect();
        for w in errs.windows(2) {
            let order = (w[0] / w[1]).log2();
            assert!((order - 1.0).abs() < 0.01, "order {order} from {errs:?}");
        }
    }

    /// Three ways to (I + τM)^{-n}: double-double powering (the oracle), n repeated f64
    /// solves, and the eigen-form (1 + τλ)^{-n}; V conserved.
    #[test]
    fn implicit_euler_cross_checks() {
        let b = box4();
        let u0 = [1.0, 0.5, -0.25, 2.0];
        let v0 = -0.3;
        for (tau, n) in [(1e-6, 1_000_000), (2e-3, 500), (10.0, 3)] {
            let ie = b.implicit_euler(v0, &u0, tau, n);
            let ef = eigen_form(&b, v0, &u0, |l| (-(n as f64) * (tau * l).ln_1p()).exp());
            assert!(
                max_diff(&ie, &ef) < 1e-13,
                "{tau} {n}: {:e}",
                max_diff(&ie, &ef)
            );
            let m = b.drag_matrix();
            let mut w: Vec<f64> = u0.iter().map(|u| u - v0).collect();
            for _ in 0..n {
                let a: Vec<Vec<f64>> = (0..4)
                    .map(|i| {
                        (0..4)
                            .map(|j| f64::from(u8::from(i == j)) + tau * m[i][j])
                            .collect()
                    })
                    .collect();
                w = solve_real(&a, &w).unwrap();
            }
            let rs = b.assemble(b.barycentric_velocity(v0, &u0), &w);
            // Repeated f64 solves accumulate ~n·1e-16.
            let tol = 1e-14 + 1e-15 * n as f64;
            assert!(
                max_diff(&ie, &rs) < tol,
                "{tau} {n}: {:e}",
                max_diff(&ie, &rs)
            );
            let vb = b.barycentric_velocity(ie.0, &ie.1);
            assert!((vb - b.barycentric_velocity(v0, &u0)).abs() < 1e-15);
        }
    }

    /// τ/t = 1e8 (up to 1e9): one step kills w to O(t/τ), values stay finite, V exact.
    #[test]
    fn implicit_euler_stiff() {
        let b = DustyBox::new(
            vec![0.1, 0.233333, 0.366667, 0.5],
            vec![1e-9, 2.15443e-9, 4.64159e-9, 1e-8],
        );
        let u0 = [1.0; 4];
        let vbar = b.barycentric_velocity(0.0, &u0);
        for n in [1, 2, 10, 1_000_000] {
            let (v, u) = b.implicit_euler(0.0, &u0, 1.0, n);
            assert!(v.is_finite() && u.iter().all(|x| x.is_finite()));
            assert!((v - vbar).abs() < 1e-8, "n={n} v={v}");
            assert!(u.iter().all(|x| (x - v).abs() < 1e-8), "n={n} {u:?}");
            assert!((b.barycentric_velocity(v, &u) - vbar).abs() < 1e-15);
        }
        let one = b.implicit_euler(0.0, &u0, 1.0, 1);
        let ef = eigen_form(&b, 0.0, &u0, |l| 1.0 / (1.0 + l));
        assert!(max_diff(&one, &ef) < 1e-15, "{:e}", max_diff(&one, &ef));
    }
}
