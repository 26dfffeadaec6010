//! `[gas]`: the equation of state and its parameters.
use super::{err, finite, positive, required, VResult};
use crate::scene::file::*;
use crate::scene::model::*;

pub(super) fn gas_eos(g: &GasSection) -> VResult<GasEos> {
    if g.eos != EosKind::LocallyIsothermal {
        for (key, v) in [("gas.cs0", g.cs0), ("gas.q", g.q), ("gas.r_ref", g.r_ref)] {
            if v.is_some() {
                return err(key, "only used by eos = \"locally_isothermal\"");
            }
        }
        if g.radius.is_some() {
            return err("gas.radius", "only used by eos = \"locally_isothermal\"");
        }
    }
    match g.eos {
        EosKind::LocallyIsothermal => {
            let cs0 = required("gas.cs0", g.cs0, "required for locally isothermal gas")?;
            positive("gas.cs0", cs0)?;
            let q = g.q.unwrap_or(0.25);
            finite("gas.q", q)?;
            let r_ref = g.r_ref.unwrap_or(1.0);
            positive("gas.r_ref", r_ref)?;
            for (key, v, why) in [
                (
                    "gas.cs",
                    g.cs.is_some(),
                    "locally isothermal gas takes gas.cs0 at gas.r_ref",
                ),
                (
                    "gas.gamma",
                    g.gamma.is_some(),
                    "not used by locally isothermal gas",
                ),
                (
                    "gas.p",
                    g.p.is_some(),
                    "locally isothermal pressure is c_s(x)²ρ",
                ),
            ] {
                if v {
                    return err(key, format!("{why} (remove it)"));
                }
            }
            Ok(GasEos::LocallyIsothermal {
                cs0,
                q,
                r_ref,
                radius: g.radius.unwrap_or(RadiusKind::Cylindrical),
            })
        }
        EosKind::Isothermal => {
            let cs = required("gas.cs", g.cs, "required for isothermal gas")?;
            positive("gas.cs", cs)?;
            if g.gamma.is_some() {
                return err("gas.gamma", "not used by isothermal gas (remove it)");
            }
            if g.p.is_some() {
                return err("gas.p", "isothermal pressure is cs²ρ (remove it)");
            }
            Ok(GasEos::Isothermal { cs })
        }
        EosKind::Adiabatic => {
            let gamma = required("gas.gamma", g.gamma, "required for adiabatic gas")?;
            if !(gamma.is_finite() && gamma > 1.0) {
                return err("gas.gamma", format!("must be > 1 (got {gamma})"));
            }
            if g.cs.is_some() {
                return err(
                    "gas.cs",
                    "adiabatic sound speed follows from γ, p, ρ (remove it)",
                );
            }
            Ok(GasEos::Adiabatic { gamma })
        }
    }
}
