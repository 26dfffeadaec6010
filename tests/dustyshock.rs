//! DUSTYSHOCK (method.md §7.4): the Sod tube with dust in the stiff limit converges to the
//! equilibrium (mixture) Riemann solution.
mod common;
use common::*;

#[test]
fn l1_error_falls_with_resolution() {
    let e: Vec<(f64, f64)> = [200, 400, 800]
        .iter()
        .map(|n| {
            let (s, _) = run_scene("dustyshock", &[&format!("sph.n={n}")]);
            (
                final_error(&s, 0, "rho_g").l1,
                final_error(&s, 0, "rho_d0").l1,
            )
        })
        .collect();
    // Measured: ρ_g 2.26e-2, 1.42e-2, 7.8e-3 (order ≈ 0.7–0.9).
    for w in e.windows(2) {
        assert!(order(w[0].0, w[1].0, 2.0) > 0.5, "gas {e:?}");
        assert!(order(w[0].1, w[1].1, 2.0) > 0.5, "dust {e:?}");
    }
    assert!(e[2].0 < 1.2e-2, "{e:?}");
}

#[test]
fn wall_force_sets_the_momentum_the_exact_solution_predicts() {
    // With fixed walls, d(total momentum)/dt = p_left − p_right until waves reach the walls.
    let (s, _) = run_scene("dustyshock", &[]);
    let expect = (1.0 - 0.1) * s.t_final;
    let got = s.conservation.momentum_final[0];
    assert!(
        (got - expect).abs() < 2e-3 * expect,
        "momentum {got} vs {expect}"
    );
}
