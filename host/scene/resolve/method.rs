//! `[sph]`, `[idic]` and `[drag]`: the numerical method's settings and which of them go together.
use super::{err, non_negative, positive, VResult};
use crate::scene::file::*;
use crate::scene::model::*;

pub(super) fn sph(s: &SphSection, from_file: bool, counted: bool) -> VResult<Sph> {
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

/// The drag's method, coupling and deposit go together.
pub(super) fn coupling(idic: &Idic, drag: &Drag, has_dust: bool) -> VResult {
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
