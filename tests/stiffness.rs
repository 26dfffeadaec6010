//! The stiffness and extremes matrix (host/commands/stiffness/): the reduced grid in CI, the full grid
//! on demand (`cargo test --release --test stiffness -- --ignored`, or `dustsph stiffness --full`).
//! Each case asserts: finite, momentum drift ≤ 1e-12 relative to max Σ m|v|, densities > 0,
//! waves carry the exact amplitude (no over-damping), boxes equal IDIC's discrete solution.
use dustsph::commands::stiffness;

fn check(full: bool) {
    let reports = stiffness::run(full, |_| {});
    let failed: Vec<String> = reports
        .iter()
        .filter(|r| !r.passed())
        .map(|r| format!("{} — {}: {}", r.group, r.name, r.failures.join("; ")))
        .collect();
    assert!(failed.is_empty(), "failed cases:\n{}", failed.join("\n"));
    // The matrix must actually be stiff where it says so, and the explicit baseline would need
    // orders of magnitude more steps there.
    let stiffest = reports
        .iter()
        .map(|r| r.max_beta)
        .filter(|b| b.is_finite())
        .fold(0.0, f64::max);
    assert!(stiffest >= 1e6, "largest τ/t_stop met {stiffest:e}");
    assert!(reports
        .iter()
        .any(|r| r.explicit_steps >= 1e5 * r.steps as f64));
    assert!(reports.iter().any(|r| r.wave_amplitude.is_some()));
    assert!(reports.iter().any(|r| r.box_oracle.is_some()));
}

#[test]
fn reduced_matrix_passes() {
    check(false);
}

#[test]
#[ignore = "the full matrix (about a minute in release): cargo test --release --test stiffness -- --ignored"]
fn full_matrix_passes() {
    check(true);
}
