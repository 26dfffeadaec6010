//! DUSTYBOX (method.md §7.1): IDIC reproduces the discrete backward-Euler oracle to round-off,
//! converges to the exact solution at first order in τ, and stays exact for τ/t_stop → 10⁶.
mod common;
use common::*;

const FIELDS: [&str; 5] = ["v_g", "u_d0", "u_d1", "u_d2", "u_d3"];

#[test]
fn equals_the_discrete_idic_oracle_to_round_off() {
    let (s, _) = run_scene("dustybox", &[]);
    for f in FIELDS {
        let e = final_error(&s, 1, f);
        // Velocities relative to the initial slip of 1: round-off is ~1e-15 over 100 steps.
        assert!(e.linf < 1e-12, "{f}: L∞ vs oracle {:e}", e.linf);
    }
    assert!(
        s.conservation.momentum_drift_relative < 1e-12,
        "{:e}",
        s.conservation.momentum_drift_relative
    );
}

#[test]
fn converges_to_the_exact_solution_at_first_order_in_tau() {
    let errs: Vec<f64> = [0.02, 0.01, 0.005]
        .iter()
        .map(|dt| {
            let (s, _) = run_scene("dustybox", &[&format!("time.dt={dt}")]);
            FIELDS
                .iter()
                .map(|f| final_error(&s, 0, f).l1)
                .fold(0.0, f64::max)
        })
        .collect();
    for w in errs.windows(2) {
        let p = order(w[0], w[1], 2.0);
        assert!((0.9..1.1).contains(&p), "order {p} from errors {errs:?}");
    }
}

#[test]
fn stays_exact_when_tau_exceeds_t_stop_a_million_times() {
    // τ = 0.01, t_stop = 1e-8 … 1e-7: β = τ/t_stop up to 1e6.
    let fr = "dust.fractions=[{eps=0.1, t_stop=1e-8}, {eps=0.233333, t_stop=2e-8}, {eps=0.366667, t_stop=5e-8}, {eps=0.5, t_stop=1e-7}]";
    let (s, st) = run_scene("dustybox", &[fr, "time.t_end=0.1", "time.output_dt="]);
    let v: Vec<f64> = st.gas.ph.v.iter().map(|v| v[0]).collect();
    let eps = [0.1, 0.233333, 0.366667, 0.5];
    // Barycentric velocity: (0 + Σ ε·1)/(1 + Σ ε), exact and constant.
    let bary = eps.iter().sum::<f64>() / (1.0 + eps.iter().sum::<f64>());
    for (k, d) in st.dust.iter().enumerate() {
        for (u, vg) in d.v.iter().zip(&v) {
            assert!(u[0].is_finite());
            // Relative velocity after 10 steps ≤ (1/β)^10 ≪ round-off.
            assert!(
                (u[0] - vg).abs() < 1e-12,
                "fraction {k}: slip {:e}",
                u[0] - vg
            );
            assert!(
                (u[0] - bary).abs() < 1e-12,
                "fraction {k}: {} vs barycentric {bary}",
                u[0]
            );
        }
    }
    assert_eq!(s.steps, 10, "the stopping time must not shorten the step");
}

#[test]
fn drag_heating_conserves_total_energy_and_without_it_drag_dissipates() {
    let adi = [
        "gas.eos=\"adiabatic\"",
        "gas.cs=",
        "gas.gamma=1.4",
        "gas.p=1.0",
    ];
    let mut with: Vec<&str> = adi.to_vec();
    with.push("dust.heating=true");
    let (s, _) = run_scene("dustybox", &with);
    assert!(
        s.conservation.energy.relative.abs() < 1e-13,
        "with heating: {:e}",
        s.conservation.energy.relative
    );
    let (s, _) = run_scene("dustybox", &adi);
    // Kinetic energy of the slip, ½ Σε(1 − V)² + ½V², is what drag removes.
    assert!(
        s.conservation.energy.relative < -1e-3,
        "without heating: {:e}",
        s.conservation.energy.relative
    );
}

#[test]
fn two_and_three_dimensional_boxes_match_the_oracle() {
    for dim in [2, 3] {
        let (s, _) = run_scene(
            "dustybox",
            &[
                &format!("scene.dim={dim}"),
                "sph.n=16",
                "sph.hfact=2.0",
                "time.t_end=0.1",
                "time.output_dt=",
            ],
        );
        for f in FIELDS {
            let e = final_error(&s, 1, f);
            assert!(e.linf < 1e-12, "dim {dim} {f}: {:e}", e.linf);
        }
        assert!(s.conservation.momentum_drift_relative < 1e-12);
    }
}
