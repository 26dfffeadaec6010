//! DUSTYSETTLE (docs/method.md §S): dust settling through a hydrostatic isothermal column at
//! its terminal velocity u − v = −g t(x), with the dust half a gas spacing off the gas.
mod common;
use common::*;

#[test]
fn dust_settles_at_its_terminal_velocity_with_the_kernel_coupling() {
    let (s, st) = run_scene("dustysettle", &[]);
    let e = |f: &str| final_error(&s, 0, f);
    // Two Epstein fractions, t = 1e-3 and 1e-4 at the base (τ/t ≈ 1…30): the drift relative
    // to the local gas within 2% everywhere in the middle of the column (measured 0.3% / 1.0%).
    for f in ["drift_d0", "drift_d1"] {
        assert!(e(f).linf < 2e-2, "{f}: {:?}", e(f));
    }
    // The column stays hydrostatic (IAD gradient): ρ_g within 1e-3, the gas nearly at rest.
    assert!(e("rho_g").l1 < 1e-3, "{:?}", e("rho_g"));
    assert!(e("v_g").l1 < 2e-2, "{:?}", e("v_g"));
    // Nothing settles out of the column or gets lost.
    assert!(st
        .dust
        .iter()
        .all(|d| d.x.iter().all(|x| x[0] > 0.0 && x[0] < 1.0)));
}

#[test]
fn the_nearest_cell_misses_the_terminal_velocity_of_offset_dust() {
    let (s, _) = run_scene("dustysettle", &["idic.coupling=\"cell\""]);
    let e = final_error(&s, 0, "drift_d0");
    assert!(e.l1 > 0.1, "nearest cell: {e:?}");
}
