//! DUSTYBOX (method.md §7.1): uniform periodic box; gas and dust start with different velocities.
use super::*;

pub(super) fn build(scene: &Scene) -> Result<Setup, SetupError> {
    let b = scene.dustybox.as_ref().expect("validated");
    let dim = scene.dim();
    let rho = scene.gas.rho.expect("validated");
    let n_axis = ((scene.sph.n as f64 * b.length).round() as usize).max(2);
    let dx = b.length / n_axis as f64;
    let h = smoothing_length(scene, dx);
    check_periodic_fits(b.length, h, "dustybox.length")?;
    let x = lattice(dim, n_axis, b.length);
    let vol = dx.powi(dim as i32);
    let n = x.len();
    let gas = Phase {
        x,
        v: vec![[b.v_gas, 0.0, 0.0]; n],
        m: vec![rho * vol; n],
        rho: vec![rho; n],
        id: (0..n as u64).collect(),
        fixed: None,
    };
    let e = internal_energy(scene, rho, scene.gas.p.unwrap_or(0.0)).map(|e| vec![e; n]);
    let mut dust = co_located_dust(scene, &gas, |k| [b.u_dust[k], 0.0, 0.0]);
    // dust_shift: the dust lattice offset by that many spacings along every axis (wrapped).
    for d in &mut dust {
        for p in &mut d.x {
            for c in p.iter_mut().take(dim as usize) {
                *c = (*c + b.dust_shift * dx).rem_euclid(b.length);
            }
        }
    }
    let mut periodic = [None; 3];
    for p in periodic.iter_mut().take(dim as usize) {
        *p = Some((0.0, b.length));
    }
    Ok(Setup::at_start(
        gas_phase(gas, e),
        dust,
        h,
        Domain { dim, periodic },
        dx,
        b.length,
    ))
}
