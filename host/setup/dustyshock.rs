//! DUSTYSHOCK (method.md §7.4): Sod-like tube with dust of uniform ε per fraction, fixed wall
//! particles beyond both ends, equal-mass particles (spacing ∝ 1/ρ).
use super::*;

pub(super) fn build(scene: &Scene, s: &crate::scene::ShockCfg) -> Result<Setup, SetupError> {
    let len = s.length;
    let x0 = 0.5 * len;
    // Equal masses: sph.n particles per unit length on the denser side.
    let dx_dense = 1.0 / scene.sph.n as f64;
    let rho_dense = s.left.rho.max(s.right.rho);
    let dx_l = dx_dense * rho_dense / s.left.rho;
    let dx_r = dx_dense * rho_dense / s.right.rho;
    // h refers to the coarser spacing, so every particle has enough neighbours.
    let spacing = dx_l.max(dx_r);
    let h = smoothing_length(scene, spacing);
    let wall = dustsph_device::kernel::SUPPORT * h + spacing;
    if x0 < 4.0 * h {
        return Err(SetupError {
            key: "dustyshock.length".into(),
            msg: format!(
                "tube half-length {x0} must exceed 4h = {} (raise sph.n or lower sph.hfact)",
                4.0 * h
            ),
        });
    }
    // Both sides and the walls, at the finer spacing: an upper bound.
    let per_phase = (len + 2.0 * wall) / dx_l.min(dx_r);
    super::check_size(
        per_phase,
        1 + scene.n_fractions(),
        "sph.n",
        &["dustyshock.length"],
    )?;
    let m = s.left.rho * dx_l;
    let mut x = Vec::new();
    let mut rho = Vec::new();
    let mut side_left = Vec::new();
    let mut xi = x0 - 0.5 * dx_l;
    while xi > -wall {
        x.push([xi, 0.0, 0.0]);
        rho.push(s.left.rho);
        side_left.push(true);
        xi -= dx_l;
    }
    x.reverse();
    rho.reverse();
    side_left.reverse();
    let mut xi = x0 + 0.5 * dx_r;
    while xi < len + wall {
        x.push([xi, 0.0, 0.0]);
        rho.push(s.right.rho);
        side_left.push(false);
        xi += dx_r;
    }
    let n = x.len();
    let fixed: Vec<bool> = x.iter().map(|p| p[0] < 0.0 || p[0] > len).collect();
    let gas = Phase {
        x,
        v: vec![[0.0; 3]; n],
        m: vec![m; n],
        rho,
        id: (0..n as u64).collect(),
        fixed: Some(fixed),
    };
    let e = internal_energy(scene, s.left)
        .zip(internal_energy(scene, s.right))
        .map(|(e_l, e_r)| {
            side_left
                .iter()
                .map(|&l| if l { e_l } else { e_r })
                .collect()
        });
    let dust = co_located_dust(scene, &gas, |_| [0.0; 3]);
    Ok(Setup::at_start(
        gas_phase(gas, e),
        dust,
        h,
        Domain {
            dim: 1,
            periodic: [None; 3],
        },
        spacing,
        len,
    ))
}
