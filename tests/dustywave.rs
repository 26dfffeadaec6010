//! DUSTYWAVE (method.md §7.2–7.3): the linear wave against its exact solution, for N = 1 and
//! N = 4 (Benítez-Llambay et al. 2019 modes), its convergence with resolution, and the stiff
//! limit where IDIC must carry the wave at the equilibrium speed without over-damping.
mod common;
use common::*;
use dustsph::particles::Phase;

fn l1_all(s: &dustsph::sim::run::Summary) -> f64 {
    let at_end = s.errors.iter().find(|e| e.t == s.t_final).unwrap();
    at_end.fields.iter().map(|f| f.norms.l1).fold(0.0, f64::max)
}

#[test]
fn four_fraction_eigenmode_matches_the_exact_solution() {
    let (s, _) = run_scene("dustywave", &[]);
    // Measured at n = 256: max L1 4.2e-3 (ρ_g) in units of the amplitude.
    let e = l1_all(&s);
    assert!(e < 1e-2, "max L1 {e:e}");
    assert!(
        s.conservation.momentum_drift_relative < 1e-12,
        "{:e}",
        s.conservation.momentum_drift_relative
    );
}

#[test]
fn one_fraction_eigenmode_matches_the_exact_solution() {
    let (s, _) = run_scene("dustywave", &["dust.fractions=[{eps=2.24, t_stop=0.4}]"]);
    let e = l1_all(&s);
    assert!(e < 1e-2, "max L1 {e:e}");
    assert!(s.conservation.momentum_drift_relative < 1e-12);
}

#[test]
fn error_falls_with_resolution_at_first_order() {
    // h ∝ Δx and τ ∝ h (CFL): the first-order time integration sets the order.
    let e: Vec<f64> = [64, 128, 256]
        .iter()
        .map(|n| {
            let (s, _) = run_scene("dustywave", &[&format!("sph.n={n}")]);
            l1_all(&s)
        })
        .collect();
    let p = order(e[1], e[2], 2.0);
    assert!(e[0] > e[1] && e[1] > e[2], "{e:?}");
    assert!(p > 0.75, "order {p} from {e:?}");
}

/// Complex Fourier amplitude of the density perturbation at wavenumber k (Δx-weighted).
fn density_mode(ph: &Phase, rho0: f64, k: f64) -> (f64, f64) {
    let n = ph.len() as f64;
    let (mut re, mut im) = (0.0, 0.0);
    for (x, r) in ph.x.iter().zip(&ph.rho) {
        re += 2.0 / n * (r - rho0) * (k * x[0]).cos();
        im -= 2.0 / n * (r - rho0) * (k * x[0]).sin();
    }
    (re, im)
}

#[test]
fn stiff_wave_travels_at_the_equilibrium_speed_without_over_damping() {
    // ε = 1, t_stop = 1e-7 ≪ τ ≈ 5e-3: the exact solution is the equilibrium wave with
    // c_eff = 1/√2 and damping ε k² c² t_stop / (2(1+ε)²) ≈ 5e-7 (negligible).
    let stiff = "dust.fractions=[{eps=1.0, t_stop=1e-7}]";
    let (s, st) = run_scene("dustywave", &[stiff]);
    let (s_loose, _) = run_scene("dustywave", &["dust.fractions=[{eps=1.0, t_stop=0.1}]"]);
    assert_eq!(s.steps, s_loose.steps, "the step must not depend on t_stop");
    let e = l1_all(&s);
    assert!(e < 1.5e-2, "max L1 {e:e} (measured 6.8e-3)");
    // Amplitude and phase of the gas density mode vs the exact equilibrium wave at t = 1.
    let k = 2.0 * std::f64::consts::PI;
    let a = 1e-4;
    let (re, im) = density_mode(&st.gas.ph, 1.0, k);
    let amp = (re * re + im * im).sqrt() / a;
    let w = k / 2f64.sqrt(); // ω = k c_eff; the eigenmode decays by e^{−Re ω t} ≈ 1
    let exact_phase = w * s.t_final;
    let phase = im.atan2(re);
    let dphi = (phase - exact_phase + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
        - std::f64::consts::PI;
    assert!(
        (amp - 1.0).abs() < 0.02,
        "amplitude ratio {amp} (over-damping would be ≪ 1)"
    );
    assert!(dphi.abs() < 0.05, "phase error {dphi} rad");
}

#[test]
fn adiabatic_wave_matches_the_exact_solution() {
    let (s, _) = run_scene(
        "dustywave",
        &[
            "gas.eos=\"adiabatic\"",
            "gas.cs=",
            "gas.gamma=1.4",
            "gas.p=1.0",
        ],
    );
    let e = l1_all(&s);
    assert!(e < 2e-2, "max L1 {e:e} (measured 9.4e-3)");
    assert!(s.conservation.momentum_drift_relative < 1e-12);
}

/// Final gas and dust velocities ordered by particle id.
fn velocities_by_id(st: &dustsph::particles::State) -> Vec<f64> {
    let mut all: Vec<(u64, f64)> = st
        .gas
        .ph
        .id
        .iter()
        .zip(&st.gas.ph.v)
        .map(|(&i, v)| (i, v[0]))
        .collect();
    for d in &st.dust {
        all.extend(d.id.iter().zip(&d.v).map(|(&i, v)| (i, v[0])));
    }
    all.sort_by_key(|p| p.0);
    all.into_iter().map(|p| p.1).collect()
}

#[test]
fn constant_k_and_epstein_laws_reproduce_the_equivalent_constant_stopping_time() {
    // In the linear wave t = ρ_d0/K and t = sρ_s/(ρ_g0 c_s) are constant to O(A), so the three
    // laws must give the same particles: t = 0.4 ⇔ K = 2.24/0.4 = 5.6 ⇔ sρ_s = 0.4 (c_s = 1).
    let a = 1e-4;
    let (_, t) = run_scene("dustywave", &["dust.fractions=[{eps=2.24, t_stop=0.4}]"]);
    let (_, k) = run_scene(
        "dustywave",
        &[
            "dust.law=\"constant_k\"",
            "dust.fractions=[{eps=2.24, k=5.6}]",
        ],
    );
    let (_, e) = run_scene(
        "dustywave",
        &[
            "dust.law=\"epstein\"",
            "dust.fractions=[{eps=2.24, s_rho=0.4}]",
        ],
    );
    let (vt, vk, ve) = (
        velocities_by_id(&t),
        velocities_by_id(&k),
        velocities_by_id(&e),
    );
    let dk = vt
        .iter()
        .zip(&vk)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / a;
    let de = vt
        .iter()
        .zip(&ve)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / a;
    assert!(
        dk < 1e-3,
        "constant K vs constant t: {dk:e} of the amplitude"
    );
    assert!(de < 1e-3, "Epstein vs constant t: {de:e} of the amplitude");
    // A wrong law (t off by 10%) must be visible at this tolerance.
    let (_, w) = run_scene("dustywave", &["dust.fractions=[{eps=2.24, t_stop=0.44}]"]);
    let dw = vt
        .iter()
        .zip(&velocities_by_id(&w))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / a;
    assert!(
        dw > 1e-2,
        "a 10% change of t_stop moves velocities by only {dw:e}"
    );
    // Adiabatic Epstein: c_s = √(γp/ρ) = √1.4, so sρ_s = 0.4√1.4 gives t = 0.4 again.
    let adi = [
        "gas.eos=\"adiabatic\"",
        "gas.cs=",
        "gas.gamma=1.4",
        "gas.p=1.0",
    ];
    let mut st = adi.to_vec();
    st.push("dust.fractions=[{eps=2.24, t_stop=0.4}]");
    let (_, ta) = run_scene("dustywave", &st);
    let s_rho = format!(
        "dust.fractions=[{{eps=2.24, s_rho={}}}]",
        0.4 * 1.4f64.sqrt()
    );
    let mut se = adi.to_vec();
    se.push("dust.law=\"epstein\"");
    se.push(&s_rho);
    let (_, ea) = run_scene("dustywave", &se);
    let da = velocities_by_id(&ta)
        .iter()
        .zip(&velocities_by_id(&ea))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / a;
    assert!(
        da < 1e-3,
        "adiabatic Epstein vs constant t: {da:e} of the amplitude"
    );
}
