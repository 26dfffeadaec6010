//! DUSTYBOX (method.md §7.1): uniform periodic box; gas and dust start with different velocities.
use super::*;
use crate::scene::Lattice;

pub(super) fn build(scene: &Scene, b: &crate::scene::BoxCfg) -> Result<Setup, SetupError> {
    let dim = scene.dim();
    let rho = b.background.rho;
    let n_f = (scene.sph.n as f64 * b.length).round().max(2.0);
    super::check_size(
        n_f.powi(dim as i32),
        1 + scene.n_fractions(),
        "sph.n",
        &["dustybox.length"],
    )?;
    let n_axis = n_f as usize;
    let dx = b.length / n_axis as f64;
    let (x, len) = match (b.lattice, dim) {
        (Lattice::Closepacked, 2 | 3) => {
            // Rows Δ√3/2 apart (2D: an even count) or layers Δ√(2/3) apart (3D: a multiple of
            // 6, so that both the row alternation and the ABC stacking are periodic).
            let (row, step) = if dim == 2 {
                (dx * 0.75f64.sqrt(), 2)
            } else {
                (dx * 6f64.sqrt() / 3.0, 6)
            };
            let layers = ((b.length / row / step as f64).round() as usize).max(1) * step;
            dustywave::lattice(dim, Lattice::Closepacked, n_axis, b.length, layers)
        }
        _ => (
            lattice(dim, n_axis, b.length),
            [
                b.length,
                if dim >= 2 { b.length } else { 1.0 },
                if dim >= 3 { b.length } else { 1.0 },
            ],
        ),
    };
    let n = x.len();
    // h = hfact × the mean spacing (V/N)^(1/d); Δx exactly for the cubic lattice.
    let (spacing, vol) = if b.lattice != Lattice::Closepacked || dim == 1 {
        (dx, dx.powi(dim as i32))
    } else {
        let volume: f64 = len[..dim as usize].iter().product();
        let v = volume / n as f64;
        (v.powf(1.0 / dim as f64), v)
    };
    let h = smoothing_length(scene, spacing);
    for l in &len[..dim as usize] {
        check_periodic_fits(*l, h, "dustybox.length")?;
    }
    // Glass or jitter: the gas (phase 0) and each fraction (k + 1) drawn independently.
    let order = (b.lattice, b.jitter, b.seed);
    let mut notes = Vec::new();
    let x0 = x;
    let gas = Phase {
        x: arrange(x0.clone(), dim, &len, dx, h, order, 0, scene, &mut notes)?,
        v: vec![[b.v_gas, 0.0, 0.0]; n],
        m: vec![rho * vol; n],
        rho: vec![rho; n],
        id: (0..n as u64).collect(),
        fixed: None,
    };
    let e = internal_energy(scene, b.background).map(|e| vec![e; n]);
    let mut dust = co_located_dust(scene, &gas, |k| [b.u_dust[k], 0.0, 0.0]);
    // dust_shift: the dust lattice offset by that many spacings along every axis (wrapped).
    for (k, d) in dust.iter_mut().enumerate() {
        let mut x = x0.clone();
        for p in &mut x {
            for (c, l) in p.iter_mut().zip(&len).take(dim as usize) {
                *c = (*c + b.dust_shift * dx).rem_euclid(*l);
            }
        }
        d.x = arrange(x, dim, &len, dx, h, order, k as u64 + 1, scene, &mut notes)?;
    }
    let mut periodic = [None; 3];
    for (p, l) in periodic.iter_mut().zip(len).take(dim as usize) {
        *p = Some((0.0, l));
    }
    let mut su = Setup::at_start(
        gas_phase(gas, e),
        dust,
        h,
        Domain { dim, periodic },
        dx,
        b.length,
    );
    su.notes = notes;
    Ok(su)
}
