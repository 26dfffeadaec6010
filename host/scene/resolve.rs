//! The scene file → the [`Scene`] model: every check of a scene's values, made while the model
//! is built from them, and every default (what a key left out of the file means), applied here
//! and nowhere else. The first failure is returned as (key, message); the checks run in the
//! order of the file's sections (scene, the problem's section, gas, dust, sph, idic, external,
//! drag, time, then the problem's own parameters); each section's checks are in a submodule.
mod disc;
mod dust;
mod forces;
mod gas;
mod method;
mod problem;
mod time;
mod units;

use super::file::*;
use super::model::*;
use dust::dust;
use forces::{external, gravity};
use gas::gas_eos;
use method::{coupling, sph};
use problem::{problem, Section};
use time::time;
use units::units;

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

/// The ball given by its particle count (`dustyball.particles`): `[sph]` with the lattice's
/// particles per unit length n that put about that many gas particles in the ball, N ≈ V_d(R)
/// n^d (V_d(R) the ball's volume, length or area); `None` without the key.
fn ball_lattice(f: &SceneFile) -> VResult<Option<SphSection>> {
    let Some(b) = f
        .dustyball
        .as_ref()
        .filter(|_| f.scene.problem == Problem::Dustyball)
    else {
        return Ok(None);
    };
    let Some(count) = b.particles else {
        return Ok(None);
    };
    if f.sph.n.is_some() {
        return err(
            "dustyball.particles",
            "the ball's resolution is given twice: keep dustyball.particles or sph.n",
        );
    }
    if count < 100 {
        return err(
            "dustyball.particles",
            format!("{count} gas particles do not make a ball (at least 100)"),
        );
    }
    let r = b.radius.unwrap_or(1.0);
    let volume = match f.scene.dim {
        1 => 2.0 * r,
        2 => std::f64::consts::PI * r * r,
        _ => 4.0 / 3.0 * std::f64::consts::PI * r * r * r,
    };
    let n = (count as f64 / volume)
        .powf(1.0 / f.scene.dim as f64)
        .round() as usize;
    Ok(Some(SphSection {
        n: Some(n.max(2)),
        ..f.sph.clone()
    }))
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
        let sph_file = ball_lattice(f)?;
        let sph = sph(
            sph_file.as_ref().unwrap_or(&f.sph),
            f.scene.problem == Problem::File,
            counted,
        )?;
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
        if let Some(r) = numerics.and_then(|n| n.rebalance_at) {
            if r.is_nan() || r < 0.0 {
                return err(
                    "numerics.rebalance_at",
                    format!("must be a number ≥ 0, or inf for never (got {})", num(r)),
                );
            }
        }
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
                rebalance_at: numerics
                    .and_then(|n| n.rebalance_at)
                    .unwrap_or(crate::dist::ranks::REBALANCE_AT),
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
