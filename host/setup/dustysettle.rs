//! DUSTYSETTLE (docs/method.md §S): an isothermal gas column in hydrostatic equilibrium under
//! the constant `[external]` gravity, with dust at uniform ε_k that settles at its terminal
//! velocity. Equal-mass gas particles placed on the exact profile by their mass coordinate;
//! fixed gas particles continue the profile beyond both ends (walls); the dust starts at rest,
//! `dustysettle.dust_shift` gas spacings above the gas in mass coordinate, inside the column.
use super::*;
use crate::exact::settle::SettleColumn;
use crate::scene::SettleCfg;

/// The exact column of a settle scene.
pub fn column(scene: &Scene, c: &SettleCfg) -> SettleColumn {
    SettleColumn {
        rho0: c.background.rho,
        cs: c.cs,
        g: -scene.external.gas[0],
        eps: scene.fractions().iter().map(|f| f.eps).collect(),
    }
}

/// The column's smoothing length and its top spacing: h refers to the coarsest spacing inside
/// the column (the top), so every particle has enough neighbours.
pub fn smoothing(scene: &Scene, c: &SettleCfg) -> (f64, f64) {
    let col = column(scene, c);
    let len = c.height;
    let top_spacing = col.rho0 / (scene.sph.n as f64 * col.rho_gas(len));
    (smoothing_length(scene, top_spacing), top_spacing)
}

pub(super) fn build(scene: &Scene, c: &SettleCfg) -> Result<Setup, SetupError> {
    let col = column(scene, c);
    let len = c.height;
    // Equal masses: sph.n particles per unit length at the base.
    let dx0 = 1.0 / scene.sph.n as f64;
    let m = col.rho0 * dx0;
    // The walls reach one support beyond both ends.
    let (h, top_spacing) = smoothing(scene, c);
    if len < 8.0 * h {
        return Err(SetupError {
            key: "dustysettle.height".into(),
            msg: format!(
                "column height {len} must exceed 8h = {} (raise sph.n or lower sph.hfact)",
                8.0 * h
            ),
        });
    }
    let wall = dustsph_device::kernel::SUPPORT * h + top_spacing;
    let (m_lo, m_hi) = (col.mass_below(-wall), col.mass_below(len + wall));
    if m_hi.is_nan() || m_hi >= col.rho0 * col.scale_height() || !m_lo.is_finite() {
        return Err(SetupError {
            key: "dustysettle.height".into(),
            msg: "the column is too tall for its scale height".into(),
        });
    }
    super::check_size(
        (m_hi - m_lo) / m + 1.0,
        1 + scene.n_fractions(),
        "sph.n",
        &["dustysettle.height"],
    )?;
    let i_lo = (m_lo / m).floor() as i64;
    let i_hi = (m_hi / m).ceil() as i64;
    let x: Vec<[f64; 3]> = (i_lo..i_hi)
        .map(|i| [col.height_of_mass((i as f64 + 0.5) * m), 0.0, 0.0])
        .collect();
    let n = x.len();
    let fixed: Vec<bool> = x.iter().map(|p| p[0] < 0.0 || p[0] > len).collect();
    let gas = Phase {
        rho: x.iter().map(|p| col.rho_gas(p[0])).collect(),
        x,
        v: vec![[0.0; 3]; n],
        m: vec![m; n],
        id: (0..n as u64).collect(),
        fixed: Some(fixed),
    };
    let xd: Vec<[f64; 3]> = (i_lo..i_hi)
        .map(|i| {
            [
                col.height_of_mass((i as f64 + 0.5 + c.dust_shift) * m),
                0.0,
                0.0,
            ]
        })
        .filter(|p| p[0] > 0.0 && p[0] < len)
        .collect();
    let nd = xd.len();
    let dust = scene
        .fractions()
        .iter()
        .enumerate()
        .map(|(k, f)| Phase {
            rho: xd.iter().map(|p| f.eps * col.rho_gas(p[0])).collect(),
            x: xd.clone(),
            v: vec![[0.0; 3]; nd],
            m: vec![f.eps * m; nd],
            id: (n as u64 + (k * nd) as u64..n as u64 + ((k + 1) * nd) as u64).collect(),
            fixed: None,
        })
        .collect();
    Ok(Setup::at_start(
        gas_phase(gas, None),
        dust,
        h,
        Domain {
            dim: 1,
            periodic: [None; 3],
        },
        top_spacing,
        len,
    ))
}
