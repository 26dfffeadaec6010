//! The steady radial and azimuthal drift of gas and N dust species in a disc (local, steady,
//! axisymmetric, inviscid): Nakagawa, Sekiya & Hayashi (1986) for one species, Tanaka et al.
//! (2005) and Bai & Stone (2010) for N (docs/method.md §D).
//!
//! Velocities relative to Keplerian rotation, in units of η v_K, η v_K = −(R/(2ρ_g v_K))
//! ∂P/∂R the gas's pressure support. Stokes numbers St_j = Ω t_j, t_j in the convention of
//! method.md §1.1 (dust acceleration −(u_j − v)/t_j, gas Σ_j ε_j (u_j − v)/t_j). With
//! x = (v_R, δv_φ, u_R,1, δu_φ,1, …) the balances (units Ω = η v_K = 1) are
//!   gas R:     0 = 2 δv_φ + 2 + Σ_j ε_j (u_R,j − v_R)/St_j
//!   gas φ:     0 = −v_R/2 + Σ_j ε_j (δu_φ,j − δv_φ)/St_j
//!   species R: 0 = 2 δu_φ,j − (u_R,j − v_R)/St_j
//!   species φ: 0 = −u_R,j/2 − (δu_φ,j − δv_φ)/St_j
//! a linear system of 2N + 2 unknowns, solved directly (for the drag accelerations
//! (u_j − v)/St_j rather than the velocities, see `steady_drift`). A viscous gas
//! (`steady_drift_viscous`) adds the torque that alone would drive the inflow v_visc: the gas φ
//! balance becomes 0 = −v_R/2 + Σ_j ε_j (δu_φ,j − δv_φ)/St_j + v_visc/2 (Dipierro et al. 2018).
use super::linalg::solve_real;

/// The steady velocities, relative to Keplerian, in units of η v_K.
#[derive(Debug, Clone, PartialEq)]
pub struct SteadyDrift {
    /// Gas (v_R, v_φ − v_K).
    pub gas: (f64, f64),
    /// Each species' (u_R, u_φ − v_K).
    pub dust: Vec<(f64, f64)>,
}

/// The steady drift for dust-to-gas ratios `eps` and Stokes numbers `st` (each > 0); `None`
/// when the inputs are not positive and finite.
pub fn steady_drift(eps: &[f64], st: &[f64]) -> Option<SteadyDrift> {
    steady_drift_viscous(eps, st, 0.0)
}

/// [`steady_drift`] with the gas's viscous inflow `v_visc` (in η v_K: the radial velocity the
/// viscous torque would give the gas alone, −3/(Σ√R) ∂(νΣ√R)/∂R); `None` also when it is not
/// finite.
pub fn steady_drift_viscous(eps: &[f64], st: &[f64], v_visc: f64) -> Option<SteadyDrift> {
    let n = eps.len();
    if !v_visc.is_finite() {
        return None;
    }
    if st.len() != n || eps.iter().chain(st).any(|v| !(v.is_finite() && *v > 0.0)) {
        return None;
    }
    // Unknowns (v_R, δv_φ, a_R,1, a_φ,1, …) with a_j = (u_j − v)/St_j, the drag per unit
    // dust mass: every coefficient is O(1), O(ε) or O(St), so small grains (St → 0, where
    // u − v is a difference of O(1) velocities) keep their relative accuracy.
    let m = 2 * n + 2;
    let mut a = vec![vec![0.0; m]; m];
    let mut b = vec![0.0; m];
    // Gas R: 2 δv_φ + Σ ε a_R = −2.
    a[0][1] = 2.0;
    b[0] = -2.0;
    // Gas φ: −v_R/2 + Σ ε a_φ = −v_visc/2.
    a[1][0] = -0.5;
    b[1] = -0.5 * v_visc;
    for j in 0..n {
        let (ar, ap) = (2 + 2 * j, 3 + 2 * j);
        a[0][ar] = eps[j];
        a[1][ap] = eps[j];
        // Species R: 2 (δv_φ + St a_φ) − a_R = 0.
        a[ar][1] = 2.0;
        a[ar][ap] = 2.0 * st[j];
        a[ar][ar] = -1.0;
        // Species φ: −(v_R + St a_R)/2 − a_φ = 0.
        a[ap][0] = -0.5;
        a[ap][ar] = -0.5 * st[j];
        a[ap][ap] = -1.0;
    }
    let x = solve_real(&a, &b)?;
    let gas = (x[0], x[1]);
    Some(SteadyDrift {
        gas,
        dust: (0..n)
            .map(|j| (gas.0 + st[j] * x[2 + 2 * j], gas.1 + st[j] * x[3 + 2 * j]))
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One species: Nakagawa, Sekiya & Hayashi (1986), D = (1 + ε)² + St²: dust
    /// u_R = −2 St/D, δu_φ = −(1 + ε)/D; gas v_R = 2 ε St/D, δv_φ = −(1 + ε + St²)/D.
    #[test]
    fn one_species_is_nakagawa_sekiya_hayashi() {
        for &eps in &[1e-3, 0.01, 1.0, 3.0, 100.0] {
            for &st in &[1e-4, 1e-2, 0.3, 1.0, 10.0, 1e3] {
                let d = steady_drift(&[eps], &[st]).unwrap();
                let den = (1.0 + eps) * (1.0 + eps) + st * st;
                let want = [
                    -2.0 * st / den,
                    -(1.0 + eps) / den,
                    2.0 * eps * st / den,
                    -(1.0 + eps + st * st) / den,
                ];
                let got = [d.dust[0].0, d.dust[0].1, d.gas.0, d.gas.1];
                for (g, w) in got.iter().zip(want) {
                    // Relative 1e-12, or 1e-15 η v_K where a value is a near-cancellation.
                    assert!(
                        (g - w).abs() <= 1e-12 * w.abs() + 1e-15,
                        "ε {eps} St {st}: {got:?} vs {want:?}"
                    );
                }
            }
        }
    }

    /// N species, radial velocities: the closed form of Dipierro et al. (2018, eqs. 11 and
    /// 13) with and without the gas's viscous inflow v_visc, λ0 = Σ ε_j/(1 + St_j²),
    /// λ1 = Σ ε_j St_j/(1 + St_j²), D = (1 + λ0)² + λ1², v_P = −2 (in η v_K):
    /// v_g,R = [−λ1 v_P + (1 + λ0) v_visc]/D, u_R,j = [v_P ((1 + λ0) St_j − λ1) + v_visc
    /// (1 + λ0 + St_j λ1)]/[D (1 + St_j²)]. The net radial mass flux is ρ_g v_visc (the drag
    /// only moves momentum between the phases; the torque on the gas moves the whole), and
    /// dust-free gas flows in at v_visc.
    #[test]
    fn radial_drift_is_dipierro_et_al_with_and_without_the_viscous_inflow() {
        let eps = [0.01, 0.3, 1.5, 0.05];
        let st = [1e-3, 0.1, 1.0, 30.0];
        let l0: f64 = eps.iter().zip(&st).map(|(e, s)| e / (1.0 + s * s)).sum();
        let l1: f64 = eps
            .iter()
            .zip(&st)
            .map(|(e, s)| e * s / (1.0 + s * s))
            .sum();
        let den = (1.0 + l0).powi(2) + l1 * l1;
        let vp = -2.0;
        for vv in [0.0, -0.37] {
            let d = steady_drift_viscous(&eps, &st, vv).unwrap();
            let want_g = (-l1 * vp + (1.0 + l0) * vv) / den;
            assert!((d.gas.0 - want_g).abs() < 1e-13, "{:?} vs {want_g}", d.gas);
            for (j, (s, u)) in st.iter().zip(&d.dust).enumerate() {
                let want =
                    (vp * ((1.0 + l0) * s - l1) + vv * (1.0 + l0 + s * l1)) / (den * (1.0 + s * s));
                assert!((u.0 - want).abs() < 1e-13, "{j}: {} vs {want}", u.0);
            }
            let flux = d.gas.0 + eps.iter().zip(&d.dust).map(|(e, u)| e * u.0).sum::<f64>();
            assert!((flux - vv).abs() < 1e-13, "net radial mass flux {flux}");
            let alone = steady_drift_viscous(&[1e-300], &[1.0], vv).unwrap();
            assert!((alone.gas.0 - vv).abs() < 1e-13);
        }
        assert_eq!(
            steady_drift(&eps, &st),
            steady_drift_viscous(&eps, &st, 0.0)
        );
        assert!(steady_drift_viscous(&eps, &st, f64::NAN).is_none());
        assert!(steady_drift(&[0.1], &[0.0]).is_none());
        assert!(steady_drift(&[0.1, 0.2], &[1.0]).is_none());
    }
}
