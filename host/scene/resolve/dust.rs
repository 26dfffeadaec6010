//! `[dust]`: the stopping law, the fractions (one by one or by `[dust.sizes]`) and grain sizes.
use super::{err, finite, num, positive, required, VResult};
use crate::scene::file::*;
use crate::scene::model::*;
use dustsph_device::drag::StoppingLaw;

pub(super) fn dust(f: &SceneFile, eos: GasEos, units: Option<&Units>) -> VResult<Option<Dust>> {
    let Some(d) = &f.dust else {
        if f.scene.problem == Problem::Dustybox {
            return err(
                "dust",
                "dustybox needs a [dust] section with at least one fraction",
            );
        }
        return Ok(None);
    };
    let from_sizes;
    let d = match &d.sizes {
        Some(s) => {
            from_sizes = DustSection {
                fractions: size_fractions(s, d)?,
                sizes: None,
                ..d.clone()
            };
            &from_sizes
        }
        None => d,
    };
    if d.fractions.is_empty() {
        return err(
            "dust.fractions",
            "must list at least one fraction ([[dust.fractions]])",
        );
    }
    let max = dustsph_device::kernels::MAX_FRACTIONS;
    if d.fractions.len() > max {
        return err(
            "dust.fractions",
            format!(
                "{} fractions given; at most {max} are supported (the GPU cell kernel keeps them in registers)",
                d.fractions.len()
            ),
        );
    }
    let heating = d.heating.unwrap_or(false);
    if heating && eos.kind() == EosKind::Isothermal {
        return err("dust.heating", "drag heating needs adiabatic gas");
    }
    if let Some(t) = d.t_stop {
        positive("dust.t_stop", t)?;
        if d.law != LawKind::ConstantT {
            return err("dust.t_stop", "only used with law = \"constant_t\"");
        }
    }
    if let Some(rho) = d.grain_density {
        positive("dust.grain_density", rho)?;
        if d.law != LawKind::Epstein {
            return err("dust.grain_density", "only used with law = \"epstein\"");
        }
    }
    if d.epstein.is_some() && d.law != LawKind::Epstein {
        return err("dust.epstein", "only used with law = \"epstein\"");
    }
    let epstein = d.epstein.unwrap_or(EpsteinForm::Report);
    // Phantom's thermal speed √(8/(πγ)) c_s in place of c_s (γ = 1 for isothermal gas).
    let gamma = match eos {
        GasEos::Adiabatic { gamma } => gamma,
        GasEos::Isothermal { .. } | GasEos::LocallyIsothermal { .. } => 1.0,
    };
    let speed_factor = match epstein {
        EpsteinForm::Report => 1.0,
        EpsteinForm::Phantom => (8.0 / (std::f64::consts::PI * gamma)).sqrt(),
    };
    let sized = d.fractions.iter().any(|f| f.size.is_some());
    for (key, v) in [
        ("dust.cross_section", d.cross_section),
        ("dust.mean_molecular_weight", d.mean_molecular_weight),
    ] {
        if let Some(v) = v {
            positive(key, v)?;
            if !sized {
                return err(
                    key,
                    "only used for grains given by size (dust.fractions.N.size, law = \"epstein\")",
                );
            }
        }
    }
    let cross_section = sized.then(|| d.cross_section.unwrap_or(H2_CROSS_SECTION));
    let mean_molecular_weight =
        sized.then(|| d.mean_molecular_weight.unwrap_or(MEAN_MOLECULAR_WEIGHT));
    let grain = Grain {
        units,
        speed_factor,
        density: d.grain_density,
        // λρ_g = μ m_H/σ (g cm⁻²), constant.
        lambda_rho: match (cross_section, mean_molecular_weight) {
            (Some(s), Some(mu)) => mu * HYDROGEN_MASS_G / s,
            _ => f64::INFINITY,
        },
    };
    let fractions = d
        .fractions
        .iter()
        .enumerate()
        .map(|(i, fr)| fraction(i, fr, d, f.scene.problem == Problem::File, &grain))
        .collect::<VResult<Vec<_>>>()?;
    Ok(Some(Dust {
        law: d.law,
        epstein: (d.law == LawKind::Epstein).then_some(epstein),
        cross_section,
        mean_molecular_weight,
        heating,
        fractions,
    }))
}

/// `[dust.sizes]`: `count` Epstein fractions at the log-centres of log-spaced size bins, each
/// with the bin's share of `dust_to_gas` for dn/ds ∝ s^(−index), the mass per bin ∝
/// ∫ s^(3−index) ds.
fn size_fractions(s: &SizesSection, d: &DustSection) -> VResult<Vec<FractionSection>> {
    if !d.fractions.is_empty() {
        return err(
            "dust.sizes",
            "give the grains by dust.sizes or one by one in [[dust.fractions]], not both",
        );
    }
    if d.law != LawKind::Epstein {
        return err(
            "dust.sizes",
            "grains by size follow the Epstein/Stokes law: set dust.law = \"epstein\"",
        );
    }
    positive("dust.sizes.min", s.min)?;
    positive("dust.sizes.max", s.max)?;
    positive("dust.sizes.dust_to_gas", s.dust_to_gas)?;
    let max = dustsph_device::kernels::MAX_FRACTIONS;
    if s.count == 0 || s.count > max {
        return err(
            "dust.sizes.count",
            format!("must be 1 to {max} fractions (got {})", s.count),
        );
    }
    if s.max < s.min || (s.max == s.min && s.count > 1) {
        return err(
            "dust.sizes.max",
            format!(
                "must be beyond dust.sizes.min = {} for {} sizes (got {})",
                num(s.min),
                s.count,
                num(s.max)
            ),
        );
    }
    let index = s.index.unwrap_or(3.5);
    finite("dust.sizes.index", index)?;
    let n = s.count as f64;
    let edge = |i: usize| s.min * (s.max / s.min).powf(i as f64 / n);
    // ∫ s^(3−index) ds between two edges (the logarithm at index 4).
    let mass = |a: f64, b: f64| {
        let k = 4.0 - index;
        if k.abs() < 1e-12 {
            (b / a).ln()
        } else {
            (b.powf(k) - a.powf(k)) / k
        }
    };
    let shares: Vec<f64> = (0..s.count)
        .map(|i| {
            if s.count == 1 {
                1.0
            } else {
                mass(edge(i), edge(i + 1))
            }
        })
        .collect();
    let total: f64 = shares.iter().sum();
    Ok(shares
        .iter()
        .enumerate()
        .map(|(i, w)| FractionSection {
            eps: Some(s.dust_to_gas * w / total),
            size: Some((edge(i) * edge(i + 1)).sqrt()),
            grain_density: None,
            t_stop: None,
            k: None,
            s_rho: None,
        })
        .collect())
}

/// Fraction `i`: its ε and the law's one parameter (the constant-t law falls back on
/// `dust.t_stop`). Initial conditions from a file (`from_file`) give ε by their masses.
/// What an Epstein fraction's `size` needs: the units, the law's speed factor, the default
/// grain density.
struct Grain<'a> {
    units: Option<&'a Units>,
    speed_factor: f64,
    density: Option<f64>,
    /// λρ_g = μ m_H/σ in g cm⁻² (∞ without sized grains).
    lambda_rho: f64,
}

/// The H₂ molecule's collision cross-section (cm²), the usual value for the mean free path
/// in discs (e.g. Chapman & Cowling; 2e-15 cm² is a round form of it).
const H2_CROSS_SECTION: f64 = 2e-15;
/// Mean molecular weight of solar-composition molecular gas.
const MEAN_MOLECULAR_WEIGHT: f64 = 2.353;
/// The hydrogen atom's mass, g.
const HYDROGEN_MASS_G: f64 = 1.673_557_5e-24;

fn fraction(
    i: usize,
    f: &FractionSection,
    d: &DustSection,
    from_file: bool,
    grain: &Grain,
) -> VResult<Fraction> {
    let key = |k: &str| format!("dust.fractions.{i}.{k}");
    let eps = match (f.eps, from_file) {
        (Some(_), true) => {
            return err(
                key("eps"),
                "initial conditions from a file take each fraction's dust-to-gas ratio from \
                 the file's masses; remove it",
            )
        }
        (None, true) => Fraction::EPS_FROM_FILE,
        (eps, false) => {
            let eps = required(
                &key("eps"),
                eps,
                "required (the fraction's dust-to-gas ratio)",
            )?;
            positive(&key("eps"), eps)?;
            eps
        }
    };
    let (want, other): (&str, [(&str, Option<f64>); 2]) = match d.law {
        LawKind::ConstantT => ("t_stop", [("k", f.k), ("s_rho", f.s_rho)]),
        LawKind::ConstantK => ("k", [("t_stop", f.t_stop), ("s_rho", f.s_rho)]),
        LawKind::Epstein => ("s_rho", [("t_stop", f.t_stop), ("k", f.k)]),
    };
    for (name, v) in other {
        if v.is_some() {
            return err(
                key(name),
                format!("not used by law `{}` (expects `{want}`)", d.law.name()),
            );
        }
    }
    for (name, v) in [("size", f.size), ("grain_density", f.grain_density)] {
        if v.is_some() && d.law != LawKind::Epstein {
            return err(key(name), "only used with law = \"epstein\"");
        }
    }
    let v = match d.law {
        LawKind::ConstantT => f.t_stop.or(d.t_stop),
        LawKind::ConstantK => f.k,
        LawKind::Epstein => match (f.s_rho, f.size) {
            (Some(_), Some(_)) => {
                return err(
                    key("size"),
                    "give s_rho (code units) or size (cm, with grain_density), not both",
                )
            }
            (None, Some(size)) => Some(grain_s_rho(&key, size, f, grain)?),
            (s_rho, None) => s_rho,
        },
    };
    // Sized grains: the Stokes regime's 4s/(9λρ_g), in code units (s / surface density).
    let stokes = match (f.size, grain.units) {
        (Some(size), Some(u)) => {
            4.0 * (size / u.length_cm) / (9.0 * grain.lambda_rho / u.surface_density_g_cm2())
        }
        _ => 0.0,
    };
    let v = required(
        &key(want),
        v,
        if d.law == LawKind::Epstein {
            "required by dust.law (or size in cm with grain_density and [units])"
        } else {
            "required by dust.law"
        },
    )?;
    positive(&key(want), v)?;
    let law = match d.law {
        LawKind::ConstantT => StoppingLaw::ConstantTime { t_stop: v },
        LawKind::ConstantK => StoppingLaw::ConstantK { k: v },
        // The law divides by ρ_g c_s; Phantom's form divides by ρ_g v_th instead.
        LawKind::Epstein => StoppingLaw::Epstein {
            s_rho: v / grain.speed_factor,
            stokes,
        },
    };
    Ok(Fraction { eps, law })
}

/// `from_file`: initial conditions from a file, which has its own particles (no `sph.n`)
/// and may give h by its `SmoothingLength` (no `sph.h`/`sph.hfact`).
/// s ρ_s in code units from a grain radius in cm and a material density in g cm⁻³.
fn grain_s_rho(
    key: &impl Fn(&str) -> String,
    size: f64,
    f: &FractionSection,
    grain: &Grain,
) -> VResult<f64> {
    positive(&key("size"), size)?;
    let Some(units) = grain.units else {
        return err(
            key("size"),
            "a grain size in cm needs [units] (length and mass) to become code units",
        );
    };
    let rho = f.grain_density.or(grain.density).ok_or_else(|| {
        (
            key("grain_density"),
            "required with size (g cm⁻³; or dust.grain_density for every fraction)".to_string(),
        )
    })?;
    positive(&key("grain_density"), rho)?;
    Ok(size * rho / units.surface_density_g_cm2())
}
