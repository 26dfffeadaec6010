//! The problem's section (`scene.problem` picks it) and the built-in problems' own parameters.
use super::disc::disc;
use super::{err, finite, num, positive, required, VResult};
use crate::scene::file::*;
use crate::scene::model::*;

/// The problem's section of a file, with what it is resolved with so far (`B`: nothing yet,
/// then the background gas state; the shock tube has none).
pub(super) enum Section<'a, B> {
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
    pub(super) fn of(f: &'a SceneFile) -> VResult<Section<'a, ()>> {
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
    pub(super) fn with_background(
        self,
        g: &GasSection,
        eos: GasEos,
    ) -> VResult<Section<'a, GasState>> {
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

/// The problem's own parameters, checked last.
pub(super) fn problem(
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
            ProblemCfg::Dustyball(BallCfg {
                background,
                radius,
                particles: b.particles,
            })
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
