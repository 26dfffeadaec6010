//! The seed's gas–dust ball (method.md §4, §6.1): gas and dust at rest on one Cartesian lattice
//! (points i·Δ, centred on the origin) inside a ball, vacuum outside. Gas and dust sit at the
//! same points, so every IDIC cell starts with the ball's ε.
use super::*;

/// The ball's particles, of those `keep` says this process's (every one alone): the lattice's
/// sites are enumerated twice (counted, then set up), so that no process holds more than its
/// share; one process's ids and order are those of a set-up alone.
pub(super) fn build(
    scene: &Scene,
    b: &crate::scene::BallCfg,
    keep: Keep,
) -> Result<Setup, SetupError> {
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
    let span = move |used: bool| if used { -nmax..=nmax } else { 0..=0 };
    let sites = || {
        (span(dim >= 3).flat_map(move |k| {
            span(dim >= 2).flat_map(move |j| {
                span(true).map(move |i| [i as f64 * dx, j as f64 * dx, k as f64 * dx])
            })
        }))
        .filter(move |q| q[0] * q[0] + q[1] * q[1] + q[2] * q[2] <= r2)
    };
    let n = sites().count() as u64;
    if let Some(asked) = b.particles {
        eprintln!(
            "dustsph: ball: {asked} gas particles asked for: {} per unit length (spacing \
             {dx:.4e}, h = {h:.4e}), {n} placed (and as many per dust fraction)",
            scene.sph.n
        );
    }
    // m = ρΔ^d makes the interior SPH density exactly ρ on the lattice; the total mass then
    // differs from ρ·V_ball by the lattice's volume error (0.02% at the seed's Δ = 2/78).
    // Each fraction k sits on the gas's sites with ε_k of its mass and density, ids after the
    // gas's and the earlier fractions' ([`co_located_dust`]).
    let m = rho * (dx.powi(dim as i32));
    let eps: Vec<f64> = std::iter::once(1.0)
        .chain(scene.fractions().iter().map(|f| f.eps))
        .collect();
    let mut phases: Vec<Phase> = eps.iter().map(|_| Phase::default()).collect();
    for (i, q) in sites().enumerate() {
        for (p, ph) in phases.iter_mut().enumerate() {
            let id = p as u64 * n + i as u64;
            if keep.mine(p as u64, id) {
                let (mp, rp) = match p {
                    0 => (m, rho),
                    _ => (eps[p] * m, eps[p] * rho),
                };
                ph.x.push(q);
                ph.v.push([0.0; 3]);
                ph.m.push(mp);
                ph.rho.push(rp);
                ph.id.push(id);
            }
        }
    }
    phases.iter_mut().for_each(Phase::shrink_to_fit);
    let mut phases = phases.into_iter();
    let gas = phases.next().expect("the gas");
    let e = internal_energy(scene, b.background).map(|e| vec![e; gas.len()]);
    let mut su = Setup::at_start(
        gas_phase(gas, e),
        phases.collect(),
        h,
        Domain {
            dim,
            periodic: [None; 3],
        },
        dx,
        2.0 * b.radius,
    );
    su.share = keep.shared();
    Ok(su)
}
