//! DUSTYBOX (method.md §7.1): uniform periodic box; gas and dust start with different velocities.
use super::*;
use crate::scene::Lattice;

/// The box's particles, of those `keep` says are this process's (every one alone): each
/// phase's positions are laid out whole, one phase at a time, and only this process's
/// particles are made of them.
pub(super) fn build(
    scene: &Scene,
    b: &crate::scene::BoxCfg,
    keep: Keep,
) -> Result<Setup, SetupError> {
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
    let m = rho * vol;
    let gas = phase_kept(
        arrange(x0.clone(), dim, &len, dx, h, order, 0, scene, &mut notes)?,
        (0, 0),
        keep,
        |_, _| ([b.v_gas, 0.0, 0.0], m, rho),
    );
    let e = internal_energy(scene, b.background).map(|e| vec![e; gas.len()]);
    // Each fraction k on the lattice (offset by dust_shift spacings along every axis,
    // wrapped) with ε_k of the gas's mass and density, ids after the gas's and the earlier
    // fractions' ([`co_located_dust`]).
    let mut dust = Vec::new();
    for (k, f) in scene.fractions().iter().enumerate() {
        let mut x = x0.clone();
        for p in &mut x {
            for (c, l) in p.iter_mut().zip(&len).take(dim as usize) {
                *c = (*c + b.dust_shift * dx).rem_euclid(*l);
            }
        }
        let x = arrange(x, dim, &len, dx, h, order, k as u64 + 1, scene, &mut notes)?;
        let at = |_, _| ([b.u_dust[k], 0.0, 0.0], f.eps * m, f.eps * rho);
        dust.push(phase_kept(
            x,
            (k as u64 + 1, (k as u64 + 1) * n as u64),
            keep,
            at,
        ));
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
    su.share = keep.shared();
    Ok(su)
}
