//! The run's time series (`DIR/evolution.csv`, Phantom's `.ev` in spirit): at every output the
//! masses (the star's accretion included), total momentum, angular momentum about the point
//! mass (with the star's share), and kinetic + thermal energy. Rewritten whole at each output
//! from the record a checkpoint keeps, so a resumed run's file has each output once.
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The file's name in the output directory.
pub const EVOLUTION_NAME: &str = "evolution.csv";

/// One output's sums.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Row {
    pub t: f64,
    pub step: u64,
    pub mass_gas: f64,
    /// Per dust fraction.
    pub mass_dust: Vec<f64>,
    /// Accreted by the point mass so far: gas, then per fraction.
    pub accreted_gas: f64,
    pub accreted_dust: Vec<f64>,
    pub momentum: [f64; 3],
    /// L of the particles about the point mass, and of what it accreted (`None`: no point
    /// mass).
    pub angular_momentum: Option<([f64; 3], [f64; 3])>,
    /// Kinetic + thermal.
    pub energy: f64,
}

impl Row {
    /// The sums of a (synced) state at an output: `totals` reduced over the ranks, the
    /// diagnostics' last angular momentum and accretion record.
    pub fn of(
        (t, step): (f64, u64),
        totals: &super::diagnostics::Totals,
        d: &super::diagnostics::Diagnostics,
        point_mass: bool,
    ) -> Row {
        let a = &d.accreted;
        let nf = totals.mass_dust.len();
        Row {
            t,
            step,
            mass_gas: totals.mass_gas,
            mass_dust: totals.mass_dust.clone(),
            accreted_gas: a.gas_mass,
            accreted_dust: (0..nf)
                .map(|k| a.dust_mass.get(k).copied().unwrap_or(0.0))
                .collect(),
            momentum: totals.momentum,
            angular_momentum: point_mass.then_some((d.angular_momentum, a.angular_momentum)),
            energy: totals.energy,
        }
    }
}

/// The CSV of `rows` (one header; columns for each dust fraction and, with a point mass, the
/// angular momentum).
pub fn csv(rows: &[Row]) -> String {
    let Some(first) = rows.first() else {
        return String::new();
    };
    let nf = first.mass_dust.len();
    let mut head = vec!["t".to_string(), "step".into(), "mass_gas".into()];
    head.extend((0..nf).map(|k| format!("mass_dust_{k}")));
    head.push("accreted_gas".into());
    head.extend((0..nf).map(|k| format!("accreted_dust_{k}")));
    head.extend(["momentum_x", "momentum_y", "momentum_z"].map(String::from));
    if first.angular_momentum.is_some() {
        head.extend(
            [
                "L_x",
                "L_y",
                "L_z",
                "L_accreted_x",
                "L_accreted_y",
                "L_accreted_z",
            ]
            .map(String::from),
        );
    }
    head.push("energy".into());
    let mut out = head.join(",") + "\n";
    for r in rows {
        let mut v: Vec<String> = vec![format!("{:e}", r.t), r.step.to_string()];
        let num = |x: &f64| format!("{x:e}");
        v.push(num(&r.mass_gas));
        v.extend(r.mass_dust.iter().map(num));
        v.push(num(&r.accreted_gas));
        v.extend(r.accreted_dust.iter().map(num));
        v.extend(r.momentum.iter().map(num));
        if let Some((l, la)) = &r.angular_momentum {
            v.extend(l.iter().chain(la).map(num));
        }
        v.push(num(&r.energy));
        out += &(v.join(",") + "\n");
    }
    out
}

/// Write `rows` to `DIR/evolution.csv` (atomically: never a torn file).
pub fn write(dir: &Path, rows: &[Row]) -> Result<(), crate::io::IoError> {
    crate::io::write_bytes_atomic(&dir.join(EVOLUTION_NAME), csv(rows).as_bytes())
}
