//! `[gravity]` and `[external]`: the point mass and the uniform accelerations.
use super::{err, finite, non_negative, positive, VResult};
use crate::scene::file::*;
use crate::scene::model::*;

/// `[gravity]`: M > 0, a position in the scene's dimensions, ε ≥ 0, an accretion radius ≥ 0.
pub(super) fn gravity(g: Option<&GravitySection>, dim: u32) -> VResult<Option<Gravity>> {
    let Some(g) = g else { return Ok(None) };
    positive("gravity.central_mass", g.central_mass)?;
    let position = g.position.unwrap_or([0.0; 3]);
    for (i, v) in position.iter().enumerate() {
        finite(&format!("gravity.position.{i}"), *v)?;
    }
    if position[dim as usize..].iter().any(|v| *v != 0.0) {
        return err(
            "gravity.position",
            format!("has a component along an axis a {dim}D scene does not have"),
        );
    }
    let softening = g.softening.unwrap_or(0.0);
    non_negative("gravity.softening", softening)?;
    let accretion_radius = g.accretion_radius.unwrap_or(0.0);
    non_negative("gravity.accretion_radius", accretion_radius)?;
    let zone = |key: &str, z: Option<[f64; 2]>| -> VResult<Option<[f64; 2]>> {
        let Some([a, b]) = z else { return Ok(None) };
        if !(a.is_finite() && b.is_finite() && a >= 0.0 && a < b) {
            return err(
                key,
                format!("[{a}, {b}] must be two radii, 0 ≤ the first < the second"),
            );
        }
        Ok(Some([a, b]))
    };
    let damp_inner = zone("gravity.damp_inner", g.damp_inner)?;
    let damp_outer = zone("gravity.damp_outer", g.damp_outer)?;
    if let (Some(i), Some(o)) = (damp_inner, damp_outer) {
        if i[1] > o[0] {
            return err(
                "gravity.damp_inner",
                format!(
                    "the inner zone (to R = {}) reaches into the outer one (from R = {})",
                    i[1], o[0]
                ),
            );
        }
    }
    let zones = damp_inner.is_some() || damp_outer.is_some();
    let damp_time = match (zones, g.damp_time) {
        (false, Some(_)) => {
            return err(
                "gravity.damp_time",
                "used only with gravity.damp_inner or gravity.damp_outer (remove it: --set \
                 gravity.damp_time=)"
                    .to_string(),
            )
        }
        (false, None) => 0.0,
        (true, t) => {
            // Faster than grid codes' tenth of an orbit (de Val-Borro et al. 2006): on the SPH
            // disc 0.1 let the edges stir it within an orbit, 0.02 held them (method.md §D).
            let t = t.unwrap_or(0.02);
            if !(t.is_finite() && t > 0.0) {
                return err("gravity.damp_time", format!("{t} must be positive"));
            }
            t
        }
    };
    Ok(Some(Gravity {
        central_mass: g.central_mass,
        position,
        softening,
        accretion_radius,
        damp_inner,
        damp_outer,
        damp_time,
    }))
}

pub(super) fn external(e: Option<&ExternalSection>, dim: u32) -> VResult<External> {
    let ext = External {
        gas: e.and_then(|e| e.gas).unwrap_or([0.0; 3]),
        dust: e.and_then(|e| e.dust).unwrap_or([0.0; 3]),
    };
    for (name, a) in [("gas", ext.gas), ("dust", ext.dust)] {
        for (i, v) in a.iter().enumerate() {
            finite(&format!("external.{name}.{i}"), *v)?;
        }
        if (dim as usize) < 3 && a[dim as usize..].iter().any(|v| *v != 0.0) {
            return err(
                format!("external.{name}"),
                format!("has a component along an axis a {dim}D scene does not have"),
            );
        }
    }
    Ok(ext)
}
