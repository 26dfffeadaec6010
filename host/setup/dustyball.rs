//! The seed's gas–dust ball (method.md §4, §6.1): gas and dust at rest on one Cartesian lattice
//! (points i·Δ, centred on the origin) inside a ball, vacuum outside. Gas and dust sit at the
//! same points, so every IDIC cell starts with the ball's ε.
use super::*;

pub(super) fn build(scene: &Scene, b: &crate::scene::BallCfg) -> Result<Setup, SetupError> {
    let dim = scene.dim();
    let rho = b.background.rho;
    let dx = 1.0 / scene.sph.n as f64;
    let h = smoothing_length(scene, dx);
    let nmax_f = (b.radius / dx).floor();
    // The ball fills π/6 of its bounding cube (π/4 of the square in 2D).
    let fill = [
        1.0,
        1.0,
        std::f64::consts::FRAC_PI_4,
        std::f64::consts::PI / 6.0,
    ][dim as usize];
    let per_phase = fill * (2.0 * nmax_f + 1.0).powi(dim as i32);
    super::check_size(
        per_phase,
        1 + scene.n_fractions(),
        "sph.n",
        &["dustyball.radius"],
    )?;
    let nmax = nmax_f as i64;
    let r2 = b.radius * b.radius;
    let span = |used: bool| if used { -nmax..=nmax } else { 0..=0 };
    let mut x = Vec::new();
    for k in span(dim >= 3) {
        for j in span(dim >= 2) {
            for i in span(true) {
                let q = [i as f64 * dx, j as f64 * dx, k as f64 * dx];
                if q[0] * q[0] + q[1] * q[1] + q[2] * q[2] <= r2 {
                    x.push(q);
                }
            }
        }
    }
    let n = x.len();
    // m = ρΔ^d makes the interior SPH density exactly ρ on the lattice; the total mass then
    // differs from ρ·V_ball by the lattice's volume error (0.02% at the seed's Δ = 2/78).
    let vol = dx.powi(dim as i32);
    let gas = Phase {
        x,
        v: vec![[0.0; 3]; n],
        m: vec![rho * vol; n],
        rho: vec![rho; n],
        id: (0..n as u64).collect(),
        fixed: None,
    };
    let e = internal_energy(scene, b.background).map(|e| vec![e; n]);
    let dust = co_located_dust(scene, &gas, |_| [0.0; 3]);
    Ok(Setup::at_start(
        gas_phase(gas, e),
        dust,
        h,
        Domain {
            dim,
            periodic: [None; 3],
        },
        dx,
        2.0 * b.radius,
    ))
}
