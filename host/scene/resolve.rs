//! The scene file → the [`Scene`] model: every check of a scene's values, made while the model
//! is built from them, and every default (what a key left out of the file means), applied here
//! and nowhere else. The first failure is returned as (key, message); the checks run in the
//! order of the file's sections (scene, the problem's section, gas, dust, sph, idic, external,
//! drag, time, then the problem's own parameters).
use super::file::*;
use super::model::*;
use dustsph_device::drag::StoppingLaw;

type VError = (String, String);
type VResult<T = ()> = Result<T, VError>;

/// A number as a person would write it: plain in a friendly range, else in e-notation.
pub fn num(v: f64) -> String {
    if v == 0.0 || (1e-4..1e6).contains(&v.abs()) || !v.is_finite() {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Magnitudes a scene value may have: products of a few of them (masses × velocities², sums
/// over 1e9 particles) must stay finite in f64, so that every number of a summary is a number.
const MAX_MAGNITUDE: f64 = 1e100;

/// The most steps a fixed `time.dt` may ask for (1e9: days of a small run).
pub const MAX_FIXED_STEPS: f64 = 1e9;

fn err<T>(key: impl Into<String>, msg: impl Into<String>) -> VResult<T> {
    Err((key.into(), msg.into()))
}

fn positive(key: &str, v: f64) -> VResult {
    if !(v.is_finite() && v > 0.0) {
        return err(key, format!("must be a finite number > 0 (got {})", num(v)));
    }
    in_range(key, v)
}

/// |v| within [1/MAX_MAGNITUDE, MAX_MAGNITUDE] (or 0).
fn in_range(key: &str, v: f64) -> VResult {
    let a = v.abs();
    if a != 0.0 && !(1.0 / MAX_MAGNITUDE..=MAX_MAGNITUDE).contains(&a) {
        return err(
            key,
            format!(
                "{} is outside [1e-100, 1e100] in magnitude: the run's derived quantities \
                 (masses, momenta, energies) would overflow; change the units",
                num(v)
            ),
        );
    }
    Ok(())
}

fn non_negative(key: &str, v: f64) -> VResult {
    if !(v.is_finite() && v >= 0.0) {
        return err(key, format!("must be a finite number ≥ 0 (got {})", num(v)));
    }
    in_range(key, v)
}

fn finite(key: &str, v: f64) -> VResult {
    if !v.is_finite() {
        return err(key, format!("must be finite (got {})", num(v)));
    }
    in_range(key, v)
}

/// A required key's value, or the error naming it.
fn required(key: &str, v: Option<f64>, why: &str) -> VResult<f64> {
    v.ok_or_else(|| (key.to_string(), why.to_string()))
}

/// The problem's section of a file, with what it is resolved with so far (`B`: nothing yet,
/// then the background gas state; the shock tube has none).
enum Section<'a, B> {
    Box(&'a BoxSection, B),
    Wave(&'a WaveSection, B),
    Shock(&'a ShockSection),
    Ball(&'a BallSection, B),
    Settle(&'a SettleSection, B),
    File(&'a FileSection),
    Disc(&'a DiscSection),
}

impl<'a> Section<'a, ()> {
    /// The section `scene.problem` names; every other problem's section must be absent (the
    /// first section, in the order of the problems, that is wrong is reported).
    fn of(f: &'a SceneFile) -> VResult<Section<'a, ()>> {
        let problem = f.scene.problem;
        let chosen = match problem {
            Problem::Dustybox => f.dustybox.as_ref().map(|s| Section::Box(s, ())),
            Problem::Dustywave => f.dustywave.as_ref().map(|s| Section::Wave(s, ())),
            Problem::Dustyshock => f.dustyshock.as_ref().map(Section::Shock),
            Problem::Dustyball => f.dustyball.as_ref().map(|s| Section::Ball(s, ())),
            Problem::Dustysettle => f.dustysettle.as_ref().map(|s| Section::Settle(s, ())),
            Problem::File => f.file.as_ref().map(Section::File),
            Problem::Dustydisc => f.dustydisc.as_ref().map(Section::Disc),
        };
        let missing = |p: Problem| {
            err(
                p.name(),
                format!("section [{}] is required by scene.problem", p.name()),
            )
        };
        let present = [
            (Problem::Dustybox, f.dustybox.is_some()),
            (Problem::Dustywave, f.dustywave.is_some()),
            (Problem::Dustyshock, f.dustyshock.is_some()),
            (Problem::Dustyball, f.dustyball.is_some()),
            (Problem::Dustysettle, f.dustysettle.is_some()),
            (Problem::File, f.file.is_some()),
            (Problem::Dustydisc, f.dustydisc.is_some()),
        ];
        for (p, there) in present {
            if p == problem && chosen.is_none() {
                return missing(p);
            }
            if p != problem && there {
                return err(
                    p.name(),
                    format!(
                        "section [{}] does not belong to problem `{}`",
                        p.name(),
                        problem.name()
                    ),
                );
            }
        }
        chosen.map_or_else(|| missing(problem), Ok)
    }

    /// The background gas state (`gas.rho`, and `gas.p` for adiabatic gas) of every problem
    /// but the shock tube, which must not give one.
    fn with_background(self, g: &GasSection, eos: GasEos) -> VResult<Section<'a, GasState>> {
        let bg = || -> VResult<GasState> {
            let rho = required("gas.rho", g.rho, "required")?;
            positive("gas.rho", rho)?;
            let p = match eos {
                GasEos::Adiabatic { .. } => {
                    let p = required("gas.p", g.p, "required for adiabatic gas")?;
                    positive("gas.p", p)?;
                    p
                }
                GasEos::Isothermal { cs } => cs * cs * rho,
                GasEos::LocallyIsothermal { .. } => {
                    return err(
                        "gas.eos",
                        "\"locally_isothermal\" gas needs its own particles (scene.problem = \"file\"); \
                         the built-in problems start from a uniform state",
                    )
                }
            };
            Ok(GasState { rho, p })
        };
        Ok(match self {
            Section::Shock(s) => {
                for (key, v) in [("gas.rho", g.rho), ("gas.p", g.p)] {
                    if v.is_some() {
                        return err(key, "the shock tube takes dustyshock.left/right instead");
                    }
                }
                Section::Shock(s)
            }
            Section::File(s) => {
                for (key, v) in [("gas.rho", g.rho), ("gas.p", g.p)] {
                    if v.is_some() {
                        return err(
                            key,
                            "initial conditions from a file take the gas state from the file \
                             (Density, InternalEnergy); remove it",
                        );
                    }
                }
                Section::File(s)
            }
            Section::Disc(s) => {
                for (key, v) in [("gas.rho", g.rho), ("gas.p", g.p)] {
                    if v.is_some() {
                        return err(
                            key,
                            "the disc's gas state is its Σ profile (dustydisc.sigma_ref) and \
                             its locally isothermal c_s; remove it",
                        );
                    }
                }
                Section::Disc(s)
            }
            Section::Box(s, ()) => Section::Box(s, bg()?),
            Section::Wave(s, ()) => Section::Wave(s, bg()?),
            Section::Ball(s, ()) => Section::Ball(s, bg()?),
            Section::Settle(s, ()) => Section::Settle(s, bg()?),
        })
    }
}

impl Scene {
    /// The scene a file describes, or the first thing wrong with it as (key, message).
    pub fn from_file(f: &SceneFile) -> VResult<Scene> {
        meta(&f.scene)?;
        let section = Section::of(f)?;
        let eos = gas_eos(&f.gas)?;
        let section = section.with_background(&f.gas, eos)?;
        let units = units(f.units.as_ref())?;
        let gravity = gravity(f.gravity.as_ref(), f.scene.dim)?;
        if f.sph.alpha_ss.is_some() && gravity.is_none() {
            return err(
                "sph.alpha_ss",
                "the disc viscosity takes Ω from a point mass: it needs [gravity]",
            );
        }
        let dust = dust(f, eos, units.as_ref())?;
        // A disc given by its particle count has no `sph.n`.
        let counted = f.scene.problem == Problem::Dustydisc
            && f.dustydisc.as_ref().is_some_and(|d| d.particles.is_some());
        let sph = sph(&f.sph, f.scene.problem == Problem::File, counted)?;
        let idic_file = f.idic.as_ref();
        let cell = idic_file.and_then(|i| i.cell).unwrap_or(0.5);
        positive("idic.cell", cell)?;
        // Below 0.05h the neighbour reach (2h/Δc rows per axis) explodes; above 4h a cell
        // averages over several kernel supports.
        if !(0.05..=4.0).contains(&cell) {
            return err(
                "idic.cell",
                format!(
                    "must be between 0.05 and 4 (cell size in units of h; got {})",
                    num(cell)
                ),
            );
        }
        let external = external(f.external.as_ref(), f.scene.dim)?;
        let drag = Drag {
            method: f
                .drag
                .as_ref()
                .and_then(|d| d.method)
                .unwrap_or(DragMethod::Idic),
        };
        // The kernel coupling is right wherever the dust sits (method.md §K); the explicit
        // baseline is defined on the source report's cells.
        let default_coupling = if drag.method == DragMethod::Explicit {
            Coupling::Cell
        } else {
            Coupling::Kernel
        };
        let coupling_kind = idic_file
            .and_then(|i| i.coupling)
            .unwrap_or(default_coupling);
        let deposit = idic_file
            .and_then(|i| i.deposit)
            .unwrap_or(DepositForm::Gather);
        // The deposits read at their gas particle about a point mass, where the shear makes
        // the lattices' offsets read as a drift (method.md §K, "Sampling offsets"); elsewhere
        // the plain means, whose stiff-limit bias on strongly disordered gas is half as large.
        // The scatter form sums no rows to fit.
        let default_sampling = if coupling_kind == Coupling::Kernel
            && deposit == DepositForm::Gather
            && gravity.is_some()
        {
            Sampling::Linear
        } else {
            Sampling::Mean
        };
        let idic = Idic {
            cell,
            coupling: coupling_kind,
            deposit,
            dispersion: idic_file
                .and_then(|i| i.dispersion)
                .unwrap_or(Dispersion::Kept),
            sampling: idic_file
                .and_then(|i| i.sampling)
                .unwrap_or(default_sampling),
        };
        coupling(&idic, &drag, dust.is_some())?;
        if idic.dispersion == Dispersion::Damped && dust.as_ref().is_some_and(|d| d.heating) {
            return err(
                "idic.dispersion",
                "\"damped\" does not yet hand the kinetic energy it takes to the gas's heat: \
                 use it without dust.heating",
            );
        }
        let time = time(&f.time)?;
        let numerics = f.numerics.as_ref();
        let problem = problem(section, f, eos, dust.as_ref(), &external)?;
        Ok(Scene {
            name: f.scene.name.clone(),
            dim: f.scene.dim,
            gas: Gas { eos },
            dust,
            sph,
            idic,
            drag,
            external,
            time,
            units,
            gravity,
            numerics: Numerics {
                precision: numerics.and_then(|n| n.precision).unwrap_or(Precision::F64),
                neighbour_list: numerics
                    .and_then(|n| n.neighbour_list)
                    .unwrap_or(ListChoice::Auto),
                deposit_rows: numerics
                    .and_then(|n| n.deposit_rows)
                    .unwrap_or(DepositRows::Auto),
            },
            problem,
        })
    }
}

fn meta(s: &MetaSection) -> VResult {
    if s.name.trim().is_empty() {
        return err("scene.name", "must not be empty");
    }
    // The default output folder is output/<name>: a name must not lead anywhere else.
    if s.name.contains(['/', '\\', '\0']) || s.name == "." || s.name.contains("..") {
        return err(
            "scene.name",
            format!(
                "{:?} is not a plain name: no path separators or \"..\" (it names the \
                 output folder output/<name>; use --out for another place)",
                s.name
            ),
        );
    }
    if !(1..=3).contains(&s.dim) {
        return err("scene.dim", format!("must be 1, 2 or 3 (got {})", s.dim));
    }
    match s.problem {
        Problem::Dustyshock | Problem::Dustysettle if s.dim != 1 => err(
            "scene.dim",
            format!(
                "problem `{}` is one-dimensional: dim must be 1",
                s.problem.name()
            ),
        ),
        _ => Ok(()),
    }
}

fn gas_eos(g: &GasSection) -> VResult<GasEos> {
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

/// `[gravity]`: M > 0, a position in the scene's dimensions, ε ≥ 0, an accretion radius ≥ 0.
fn gravity(g: Option<&GravitySection>, dim: u32) -> VResult<Option<Gravity>> {
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
fn units(u: Option<&UnitsSection>) -> VResult<Option<Units>> {
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

fn dust(f: &SceneFile, eos: GasEos, units: Option<&Units>) -> VResult<Option<Dust>> {
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

fn sph(s: &SphSection, from_file: bool, counted: bool) -> VResult<Sph> {
    if counted && s.n.is_some() {
        return err(
            "dustydisc.particles",
            "the disc's resolution is given twice: keep dustydisc.particles or sph.n",
        );
    }
    let n = match (s.n, from_file || counted) {
        (Some(_), true) => {
            return err(
                "sph.n",
                "initial conditions from a file have their own particles; remove it",
            )
        }
        (None, true) => 0,
        (None, false) => return err("sph.n", "required (particles per unit length)"),
        (Some(n), false) if n < 2 => {
            return err(
                "sph.n",
                format!("must be ≥ 2 particles per unit length (got {n})"),
            )
        }
        (Some(n), false) => n,
    };
    let variable_h = s.variable_h.unwrap_or(false);
    let density = s.density.unwrap_or(DensityMethod::Summation);
    let smoothing = match (s.h, s.hfact) {
        (Some(_), Some(_)) => return err("sph.h", "give either sph.h or sph.hfact, not both"),
        (None, None) if from_file => {
            if variable_h {
                return err(
                    "sph.variable_h",
                    "needs sph.hfact (h = hfact (m/ρ)^(1/d)); the file's SmoothingLength is \
                     then each particle's first guess",
                );
            }
            SmoothingLength::FromFile {}
        }
        (None, None) => {
            return err(
                "sph.hfact",
                "give sph.hfact (h in units of the particle spacing) or sph.h",
            )
        }
        (Some(h), None) => {
            positive("sph.h", h)?;
            if variable_h {
                return err(
                    "sph.variable_h",
                    "needs sph.hfact (h = hfact (m/ρ)^(1/d)), not sph.h",
                );
            }
            SmoothingLength::Absolute { h }
        }
        (None, Some(hfact)) => {
            positive("sph.hfact", hfact)?;
            SmoothingLength::Hfact { hfact, variable_h }
        }
    };
    if variable_h && density == DensityMethod::Continuity {
        return err(
            "sph.variable_h",
            "variable h defines the density by summation (sph.density = \"continuity\" excludes it)",
        );
    }
    if let Some(a) = s.alpha_ss {
        positive("sph.alpha_ss", a)?;
        if s.alpha.is_some() {
            return err(
                "sph.alpha",
                "the disc viscosity sets α per pair from sph.alpha_ss: give one of the two",
            );
        }
        if s.viscosity == Some(false) {
            return err(
                "sph.alpha_ss",
                "is the disc viscosity, and sph.viscosity = false turns it off: remove one",
            );
        }
    }
    let (alpha, beta) = (s.alpha.unwrap_or(1.0), s.beta.unwrap_or(2.0));
    non_negative("sph.alpha", alpha)?;
    non_negative("sph.beta", beta)?;
    Ok(Sph {
        n,
        smoothing,
        density,
        gradient: s.gradient.unwrap_or(GradientMethod::Standard),
        viscosity: s
            .viscosity
            .unwrap_or(s.alpha_ss.is_some())
            .then_some(ArtificialViscosity {
                alpha,
                beta,
                alpha_ss: s.alpha_ss,
            }),
    })
}

fn external(e: Option<&ExternalSection>, dim: u32) -> VResult<External> {
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

/// The drag's method, coupling and deposit go together.
fn coupling(idic: &Idic, drag: &Drag, has_dust: bool) -> VResult {
    if idic.deposit == DepositForm::Scatter && idic.coupling != Coupling::Kernel {
        return err(
            "idic.deposit",
            "\"scatter\" sums the kernel coupling's deposits; it needs idic.coupling = \"kernel\"",
        );
    }
    if idic.dispersion == Dispersion::Damped && idic.coupling != Coupling::Kernel {
        return err(
            "idic.dispersion",
            "\"damped\" acts on the kernel coupling's return; it needs idic.coupling = \"kernel\"",
        );
    }
    if idic.sampling == Sampling::Linear
        && (idic.coupling != Coupling::Kernel || idic.deposit != DepositForm::Gather)
    {
        return err(
            "idic.sampling",
            "\"linear\" fits the gas over the kernel coupling's gathered rows; it needs \
             idic.coupling = \"kernel\" with idic.deposit = \"gather\" (or set \"mean\")",
        );
    }
    if idic.coupling == Coupling::Kernel && drag.method == DragMethod::Explicit {
        return err(
            "idic.coupling",
            "\"kernel\" is an implicit coupling; the explicit baseline uses \"cell\"",
        );
    }
    if drag.method == DragMethod::Explicit && !has_dust {
        return err(
            "drag.method",
            "\"explicit\" drag needs a [dust] section (without dust there is no drag)",
        );
    }
    Ok(())
}

/// (`MAX_FIXED_STEPS` bounds a fixed step's count: `time.dt = 1e-300` would never end.)
fn time(t: &TimeSection) -> VResult<Time> {
    positive("time.t_end", t.t_end)?;
    let integrator = t.integrator.unwrap_or(Integrator::FirstOrder);
    let position_update = t.position_update.unwrap_or(PositionUpdate::New);
    if integrator == Integrator::Kdk && position_update == PositionUpdate::Old {
        return err(
            "time.position_update",
            "\"old\" belongs to the first-order step; time.integrator = \"kdk\" drifts with v^{n+1/2}",
        );
    }
    let step = match (t.dt, t.cfl) {
        (Some(_), Some(_)) => {
            return err(
                "time.dt",
                "give either time.dt (fixed) or time.cfl, not both",
            )
        }
        (None, None) => return err("time.dt", "give time.dt (fixed step) or time.cfl"),
        (Some(dt), None) => {
            positive("time.dt", dt)?;
            let steps = (t.t_end / dt).ceil();
            if steps.is_nan() || steps > MAX_FIXED_STEPS {
                return err(
                    "time.dt",
                    format!(
                        "{steps:e} steps of {dt:e} to time.t_end = {}: more than {MAX_FIXED_STEPS:e}; \
                         a larger time.dt or time.cfl",
                        t.t_end
                    ),
                );
            }
            StepRule::Fixed { dt }
        }
        (None, Some(c)) => {
            positive("time.cfl", c)?;
            if c > 1.0 {
                return err("time.cfl", format!("must be ≤ 1 (got {c})"));
            }
            if let Some(m) = t.dt_max {
                positive("time.dt_max", m)?;
            }
            StepRule::Cfl {
                cfl: c,
                dt_max: t.dt_max,
            }
        }
    };
    if t.dt.is_some() && t.dt_max.is_some() {
        return err(
            "time.dt_max",
            "caps the CFL step (time.cfl); with a fixed time.dt there is nothing to cap",
        );
    }
    Ok(Time {
        t_end: t.t_end,
        step,
        output: output_schedule(t)?,
        position_update,
        integrator,
    })
}

fn output_schedule(t: &TimeSection) -> VResult<OutputSchedule> {
    match (&t.output_dt, &t.output_times) {
        (Some(_), Some(_)) => err("time.output_dt", "give output_dt or output_times, not both"),
        (Some(d), None) => {
            positive("time.output_dt", *d)?;
            if t.t_end / d > 100_000.0 {
                return err(
                    "time.output_dt",
                    format!(
                        "{} snapshots would be written (limit 100000)",
                        (t.t_end / d).floor()
                    ),
                );
            }
            Ok(OutputSchedule::Every { output_dt: *d })
        }
        (None, Some(ts)) => {
            if ts.len() > 100_000 {
                return err(
                    "time.output_times",
                    format!("{} snapshots would be written (limit 100000)", ts.len()),
                );
            }
            for (i, &x) in ts.iter().enumerate() {
                let key = format!("time.output_times.{i}");
                non_negative(&key, x)?;
                if x > t.t_end {
                    return err(key, format!("{x} is after time.t_end = {}", t.t_end));
                }
            }
            Ok(OutputSchedule::At {
                output_times: ts.clone(),
            })
        }
        (None, None) => Ok(OutputSchedule::EndOnly),
    }
}

/// The problem's own parameters, checked last.
fn problem(
    section: Section<'_, GasState>,
    f: &SceneFile,
    eos: GasEos,
    dust: Option<&Dust>,
    external: &External,
) -> VResult<ProblemCfg> {
    Ok(match section {
        Section::Box(b, background) => ProblemCfg::Dustybox(dustybox(
            b,
            background,
            dust.map_or(0, |d| d.fractions.len()),
        )?),
        Section::Settle(c, background) => {
            let height = c.height.unwrap_or(1.0);
            let dust_shift = c.dust_shift.unwrap_or(0.0);
            positive("dustysettle.height", height)?;
            finite("dustysettle.dust_shift", dust_shift)?;
            if !(0.0..1.0).contains(&dust_shift) {
                return err(
                    "dustysettle.dust_shift",
                    format!("must be in [0, 1) gas spacings (got {})", num(dust_shift)),
                );
            }
            let GasEos::Isothermal { cs } = eos else {
                return err(
                    "gas.eos",
                    "dustysettle is an isothermal column: eos must be \"isothermal\"",
                );
            };
            settle_forces(dust.is_some(), external)?;
            ProblemCfg::Dustysettle(SettleCfg {
                background,
                cs,
                height,
                dust_shift,
            })
        }
        Section::Wave(w, background) => {
            ProblemCfg::Dustywave(dustywave(w, background, f.scene.dim)?)
        }
        Section::Ball(b, background) => {
            let radius = b.radius.unwrap_or(1.0);
            positive("dustyball.radius", radius)?;
            ProblemCfg::Dustyball(BallCfg { background, radius })
        }
        Section::Disc(d) => ProblemCfg::Dustydisc(disc(d, f, eos)?),
        Section::File(s) => ProblemCfg::File(FileCfg {
            path: {
                if s.path.trim().is_empty() {
                    return err("file.path", "must name the initial conditions' HDF5 file");
                }
                s.path.clone()
            },
            resolved: s.path.clone().into(),
            periodic: {
                let p = s.periodic.unwrap_or([false; 3]);
                if let Some(k) = (f.scene.dim as usize..3).find(|&k| p[k]) {
                    return err(
                        format!("file.periodic.{k}"),
                        format!("a {}D scene has no axis {k}", f.scene.dim),
                    );
                }
                p
            },
        }),
        Section::Shock(s) => {
            let length = s.length.unwrap_or(1.0);
            positive("dustyshock.length", length)?;
            ProblemCfg::Dustyshock(ShockCfg {
                length,
                left: shock_side("left", s.left, eos)?,
                right: shock_side("right", s.right, eos)?,
            })
        }
    })
}

/// The disc: 0 < r_in < r_out, Σ > 0; a 2D scene with a point mass and locally isothermal gas.
fn disc(d: &DiscSection, f: &SceneFile, eos: GasEos) -> VResult<DiscCfg> {
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

fn dustybox(b: &BoxSection, background: GasState, nf: usize) -> VResult<BoxCfg> {
    let length = b.length.unwrap_or(1.0);
    let v_gas = b.v_gas.unwrap_or(0.0);
    let dust_shift = b.dust_shift.unwrap_or(0.0);
    positive("dustybox.length", length)?;
    finite("dustybox.v_gas", v_gas)?;
    if b.u_dust.len() != nf {
        return err(
            "dustybox.u_dust",
            format!(
                "needs one velocity per dust fraction ({nf}), got {}",
                b.u_dust.len()
            ),
        );
    }
    for (i, &u) in b.u_dust.iter().enumerate() {
        finite(&format!("dustybox.u_dust.{i}"), u)?;
    }
    finite("dustybox.dust_shift", dust_shift)?;
    let jitter = disorder("dustybox.jitter", b.jitter)?;
    Ok(BoxCfg {
        background,
        length,
        v_gas,
        u_dust: b.u_dust.clone(),
        dust_shift,
        lattice: b.lattice.unwrap_or(Lattice::Cubic),
        jitter,
        seed: b.seed.unwrap_or(DEFAULT_SEED),
    })
}

/// The seed of the disordered set-ups when the scene names none.
const DEFAULT_SEED: u64 = 20_181_001;

/// `jitter`: 0 (the lattice) up to one spacing.
fn disorder(key: &str, jitter: Option<f64>) -> VResult<f64> {
    let f = jitter.unwrap_or(0.0);
    if !(0.0..=1.0).contains(&f) {
        return err(
            key,
            format!("must be in [0, 1] lattice spacings (got {})", num(f)),
        );
    }
    Ok(f)
}

/// The settling column needs dust, and gravity along −x on gas and dust alike.
fn settle_forces(has_dust: bool, external: &External) -> VResult {
    if !has_dust {
        return err(
            "dust",
            "dustysettle needs a [dust] section with at least one fraction",
        );
    }
    let g = -external.gas[0];
    if g.is_nan() || g <= 0.0 {
        return err(
            "external.gas",
            "dustysettle needs gravity along −x: external.gas = [-g, 0, 0] with g > 0",
        );
    }
    if external.dust != external.gas {
        return err(
            "external.dust",
            "dustysettle: gas and dust fall under the same gravity (external.dust = external.gas)",
        );
    }
    Ok(())
}

fn dustywave(w: &WaveSection, background: GasState, dim: u32) -> VResult<WaveCfg> {
    let length = w.length.unwrap_or(1.0);
    let dust_shift = w.dust_shift.unwrap_or(0.0);
    let lattice = w.lattice.unwrap_or(Lattice::Closepacked);
    let layers = w.layers.unwrap_or(12);
    positive("dustywave.length", length)?;
    positive("dustywave.amplitude", w.amplitude)?;
    finite("dustywave.dust_shift", dust_shift)?;
    let jitter = disorder("dustywave.jitter", w.jitter)?;
    if dim > 1 {
        let need = match (lattice, dim) {
            // Hexagonal rows alternate (period 2); fcc layers repeat every 3.
            (Lattice::Closepacked, 2) => 2,
            (Lattice::Closepacked, _) => 6,
            (Lattice::Cubic | Lattice::Glass, _) => 1,
        };
        if layers == 0 || layers % need != 0 {
            return err(
                "dustywave.layers",
                format!(
                    "must be a positive multiple of {need} for a periodic {} lattice in {dim}D (got {layers})",
                    lattice.name()
                ),
            );
        }
    }
    if w.amplitude > 0.1 {
        return err(
            "dustywave.amplitude",
            format!(
                "a linear wave needs a small amplitude (≤ 0.1, got {})",
                w.amplitude
            ),
        );
    }
    Ok(WaveCfg {
        background,
        length,
        amplitude: w.amplitude,
        mode: w.mode,
        lattice,
        layers,
        dust_shift,
        jitter,
        seed: w.seed.unwrap_or(DEFAULT_SEED),
    })
}

/// One side of the shock tube: ρ, and p for adiabatic gas (isothermal: p = c_s² ρ).
fn shock_side(side: &str, st: ShockSideSection, eos: GasEos) -> VResult<GasState> {
    positive(&format!("dustyshock.{side}.rho"), st.rho)?;
    let key = format!("dustyshock.{side}.p");
    let p = match (eos, st.p) {
        (GasEos::Adiabatic { .. }, None) => return err(key, "required for adiabatic gas"),
        (GasEos::Adiabatic { .. }, Some(p)) => {
            positive(&key, p)?;
            p
        }
        (GasEos::Isothermal { .. }, Some(_)) => {
            return err(key, "isothermal pressure is cs²ρ (remove it)")
        }
        (GasEos::Isothermal { cs }, None) => cs * cs * st.rho,
        (GasEos::LocallyIsothermal { .. }, _) => {
            return err(
                "gas.eos",
                "the shock tube starts from two uniform states: locally isothermal gas needs \
                 scene.problem = \"file\"",
            )
        }
    };
    Ok(GasState { rho: st.rho, p })
}
