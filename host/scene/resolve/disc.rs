//! `[dustydisc]`: the disc's radii, surface density profile and start.
use super::{err, finite, num, positive, VResult};
use crate::scene::file::*;
use crate::scene::model::*;

/// The disc: 0 < r_in < r_out, Σ > 0; a 2D scene with a point mass and locally isothermal gas.
pub(super) fn disc(d: &DiscSection, f: &SceneFile, eos: GasEos) -> VResult<DiscCfg> {
    if f.scene.dim == 1 {
        return err(
            "scene.dim",
            "the dusty disc is 2D (razor-thin) or 3D (a Gaussian vertical profile)",
        );
    }
    if f.gravity.is_none() {
        return err(
            "gravity",
            "the dusty disc orbits a point mass: give [gravity] central_mass",
        );
    }
    let GasEos::LocallyIsothermal { r_ref, .. } = eos else {
        return err(
            "gas.eos",
            "the dusty disc's gas is locally isothermal: eos = \"locally_isothermal\" with cs0, q, r_ref",
        );
    };
    let r_in = d.r_in.unwrap_or(0.5 * r_ref);
    let r_out = d.r_out.unwrap_or(2.0 * r_ref);
    let p = d.p.unwrap_or(1.0);
    positive("dustydisc.r_in", r_in)?;
    positive("dustydisc.r_out", r_out)?;
    if r_out <= r_in {
        return err(
            "dustydisc.r_out",
            format!(
                "must be beyond dustydisc.r_in = {} (got {})",
                num(r_in),
                num(r_out)
            ),
        );
    }
    finite("dustydisc.p", p)?;
    if let Some(rc) = d.r_c {
        positive("dustydisc.r_c", rc)?;
        if p >= 2.0 {
            return err(
                "dustydisc.r_c",
                format!(
                    "the cut-off e^(−(R/r_c)^(2−p)) needs p < 2 (dustydisc.p = {})",
                    num(p)
                ),
            );
        }
    }
    if let Some(n) = d.particles {
        if n < 100 {
            return err(
                "dustydisc.particles",
                format!("{n} gas particles do not make a disc (at least 100)"),
            );
        }
    }
    if let Some(a) = f.gravity.as_ref().and_then(|g| g.accretion_radius) {
        if a > r_in {
            return err(
                "gravity.accretion_radius",
                format!(
                    "{} reaches beyond the disc's inner edge dustydisc.r_in = {}: the star would \
                     swallow the disc's first rings at the first step",
                    num(a),
                    num(r_in)
                ),
            );
        }
    }
    if r_ref <= r_in {
        return err(
            "gas.r_ref",
            format!(
                "the disc's Σ is set at gas.r_ref = {}, which must be beyond dustydisc.r_in = {}",
                num(r_ref),
                num(r_in)
            ),
        );
    }
    let mut cfg = DiscCfg {
        r_in,
        r_out,
        p,
        sigma_ref: 1.0,
        r_c: d.r_c,
        particles: d.particles,
        dust_velocity: d.dust_velocity.unwrap_or(DustStart::Drift),
        relax: d.relax.unwrap_or(true),
    };
    cfg.sigma_ref = match (d.sigma_ref, d.disc_mass) {
        (Some(_), Some(_)) => {
            return err(
                "dustydisc.disc_mass",
                "give dustydisc.sigma_ref or dustydisc.disc_mass, not both",
            )
        }
        (Some(s), None) => {
            positive("dustydisc.sigma_ref", s)?;
            s
        }
        (None, Some(mass)) => {
            positive("dustydisc.disc_mass", mass)?;
            mass / cfg.mass_between(r_in, r_out, r_ref, 1.0)
        }
        (None, None) => 1e-3,
    };
    finite("dustydisc.disc_mass", cfg.sigma_ref)?;
    Ok(cfg)
}
