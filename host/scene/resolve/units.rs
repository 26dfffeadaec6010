//! `[units]`: the code units in cm and g, by name or number.
use super::{positive, VResult};
use crate::scene::file::*;
use crate::scene::model::*;

/// Named units (IAU 2012 au, IAU 2015 nominal solar mass GM/G with CODATA 2018 G).
const LENGTHS: [(&str, f64); 6] = [
    ("cm", 1.0),
    ("m", 100.0),
    ("km", 1e5),
    ("au", 1.495_978_707e13),
    ("pc", 3.085_677_581_491_367e18),
    ("rsun", 6.957e10),
];
const MASSES: [(&str, f64); 5] = [
    ("g", 1.0),
    ("kg", 1000.0),
    ("msun", 1.988_409_870_698_051e33),
    ("mjup", 1.898_124_6e30),
    ("mearth", 5.972_167_87e27),
];

/// `[units]`: each of length and mass by name or as a number of cm / g (both required).
pub(super) fn units(u: Option<&UnitsSection>) -> VResult<Option<Units>> {
    let Some(u) = u else { return Ok(None) };
    let one = |key: &str, v: Option<&UnitValue>, table: &[(&str, f64)], cgs: &str| {
        let names = table
            .iter()
            .map(|(n, _)| format!("\"{n}\""))
            .collect::<Vec<_>>();
        let v = v.ok_or_else(|| {
            (
                key.to_string(),
                format!(
                    "required in [units]: {} or a number of {cgs}",
                    names.join(", ")
                ),
            )
        })?;
        match v {
            UnitValue::Cgs(x) => positive(key, *x).map(|_| *x),
            UnitValue::Name(n) => table
                .iter()
                .find(|(name, _)| name.eq_ignore_ascii_case(n.trim()))
                .map(|(_, x)| *x)
                .ok_or_else(|| {
                    (
                        key.to_string(),
                        format!(
                            "unknown unit {n:?}: give {} or a number of {cgs}",
                            names.join(", ")
                        ),
                    )
                }),
        }
    };
    Ok(Some(Units {
        length_cm: one("units.length", u.length.as_ref(), &LENGTHS, "cm")?,
        mass_g: one("units.mass", u.mass.as_ref(), &MASSES, "g")?,
    }))
}
