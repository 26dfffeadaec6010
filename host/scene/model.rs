//! The resolved scene: what a run is made of, every default applied and every choice an enum
//! whose variants carry exactly the numbers they need. A [`Scene`] comes only from a scene
//! file that passed every check (`resolve.rs`); it cannot express a half-specified scene
//! (an isothermal gas without its sound speed, a fraction without its stopping-time
//! parameter, both a fixed step and a CFL factor), so nothing downstream re-checks it.
//!
//! [`Scene::to_toml`] writes the model as TOML (the summary's `scene_model`, the snapshots'
//! `SceneModel` attribute), with the scene file's key names where the file has the key.
use super::file::{
    Coupling, DensityMethod, DepositForm, DepositRows, Dispersion, DragMethod, DustStart, EosKind,
    EpsteinForm, GradientMethod, Integrator, Lattice, LawKind, ListChoice, PositionUpdate,
    Precision, Problem, RadiusKind, Sampling, WaveMode,
};
use dustsph_device::drag::StoppingLaw;
use dustsph_device::eos::Eos;
use serde::ser::SerializeStruct;
use serde::{Serialize, Serializer};

/// A validated scene with its defaults applied.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// `scene.name` (also the default output folder).
    pub name: String,
    pub dim: u32,
    pub gas: Gas,
    /// `None`: no dust section (a dust-free run; never for the box or the settling column).
    pub dust: Option<Dust>,
    pub sph: Sph,
    pub idic: Idic,
    pub drag: Drag,
    pub external: External,
    pub time: Time,
    pub numerics: Numerics,
    /// `[units]`: what the scene's numbers are in (`None`: no unit system).
    pub units: Option<Units>,
    /// `[gravity]`: a central point mass.
    pub gravity: Option<Gravity>,
    /// The problem's own parameters, with the gas state it starts from.
    pub problem: ProblemCfg,
}

impl Scene {
    pub fn dim(&self) -> u32 {
        self.dim
    }

    /// Which problem this is (`scene.problem`).
    pub fn kind(&self) -> Problem {
        self.problem.kind()
    }

    /// The dust fractions (none without dust).
    pub fn fractions(&self) -> &[Fraction] {
        self.dust.as_ref().map_or(&[], |d| d.fractions.as_slice())
    }

    pub fn n_fractions(&self) -> usize {
        self.fractions().len()
    }

    /// The ball's section, if this is the ball.
    pub fn ball(&self) -> Option<&BallCfg> {
        match &self.problem {
            ProblemCfg::Dustyball(b) => Some(b),
            _ => None,
        }
    }

    /// The model as TOML: the scene as it runs, every default written out (what was left to
    /// a default in the file is not told apart from what was given).
    pub fn to_toml(&self) -> String {
        let view = ModelToml {
            scene: MetaToml {
                name: &self.name,
                problem: self.kind(),
                dim: self.dim,
            },
            gas: GasToml {
                eos: self.gas.eos,
                background: self.problem.background(),
            },
            dust: self.dust.as_ref(),
            sph: &self.sph,
            idic: &self.idic,
            drag: &self.drag,
            external: &self.external,
            time: &self.time,
            numerics: &self.numerics,
            units: self.units.as_ref(),
            gravity: self.gravity.as_ref(),
            problem: &self.problem,
        };
        // Every value of a model is a finite number, a string, a bool or a table of them:
        // TOML holds all of them.
        toml::to_string(&view)
            .unwrap_or_else(|e| format!("# the scene model cannot be written as TOML: {e}\n"))
    }
}

/// `[gas]`: the equation of state. The state the gas starts in is the problem's (the
/// background of [`ProblemCfg`], or the shock tube's two sides).
#[derive(Debug, Clone, PartialEq)]
pub struct Gas {
    pub eos: GasEos,
}

/// The gas equation of state with its constant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "eos", rename_all = "snake_case")]
pub enum GasEos {
    /// p = c_s² ρ.
    Isothermal { cs: f64 },
    /// p = (γ − 1) ρ e.
    Adiabatic { gamma: f64 },
    /// p = c_s(x)² ρ, c_s = cs0 (R/r_ref)^(−q).
    LocallyIsothermal {
        cs0: f64,
        q: f64,
        r_ref: f64,
        radius: RadiusKind,
    },
}

impl GasEos {
    pub fn kind(self) -> EosKind {
        match self {
            GasEos::Isothermal { .. } => EosKind::Isothermal,
            GasEos::Adiabatic { .. } => EosKind::Adiabatic,
            GasEos::LocallyIsothermal { .. } => EosKind::LocallyIsothermal,
        }
    }

    /// The step's equation of state (locally isothermal gas: isothermal, its c_s set per
    /// particle by [`Self::local_sound_speed`]; cs0 stands for it here).
    pub fn eos(self) -> Eos<f64> {
        match self {
            GasEos::Isothermal { cs } => Eos::Isothermal { cs },
            GasEos::Adiabatic { gamma } => Eos::Adiabatic { gamma },
            GasEos::LocallyIsothermal { cs0, .. } => Eos::Isothermal { cs: cs0 },
        }
    }

    /// The step's position-dependent sound speed about `centre` (the origin without one).
    pub fn local_sound_speed(
        self,
        centre: Option<[f64; 3]>,
    ) -> dustsph_device::eos::LocalSoundSpeed {
        match self {
            GasEos::LocallyIsothermal {
                cs0,
                q,
                r_ref,
                radius,
            } => dustsph_device::eos::LocalSoundSpeed {
                cs0,
                q,
                r_ref,
                centre: centre.unwrap_or([0.0; 3]),
                spherical: u32::from(radius == RadiusKind::Spherical),
                on: 1,
            },
            _ => Default::default(),
        }
    }

    /// Sound speed of the gas state `s`: c_s, or sqrt(γ p / ρ).
    pub fn sound_speed(self, s: GasState) -> f64 {
        match self {
            GasEos::Isothermal { cs } => cs,
            GasEos::Adiabatic { gamma } => (gamma * s.p / s.rho).sqrt(),
            GasEos::LocallyIsothermal { .. } => (s.p / s.rho).sqrt(),
        }
    }

    /// Specific internal energy of adiabatic gas in state `s` (`None`: isothermal gas has no
    /// energy equation).
    pub fn internal_energy(self, s: GasState) -> Option<f64> {
        match self {
            GasEos::Isothermal { .. } | GasEos::LocallyIsothermal { .. } => None,
            GasEos::Adiabatic { gamma } => Some(s.p / ((gamma - 1.0) * s.rho)),
        }
    }
}

/// A uniform gas state: density and pressure (isothermal gas: p = c_s² ρ).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GasState {
    pub rho: f64,
    pub p: f64,
}

/// `[dust]`: the fractions, each with its resolved stopping-time law.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Dust {
    /// The law of every fraction (`dust.law`), for names and messages.
    pub law: LawKind,
    /// Frictional heating of the gas by the drag (adiabatic gas only).
    pub heating: bool,
    /// The Epstein law's form (its `s_rho` below already holds the factor); `None` for the
    /// other laws.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub epstein: Option<EpsteinForm>,
    /// Grains given by size: the cross-section σ (cm²) and mean molecular weight μ of the
    /// mean free path λ = μ m_H/(ρ_g σ) that starts the Stokes regime (each fraction's
    /// `stokes_regime_coefficient` holds 4s/(9λρ_g) in code units).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cross_section: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_molecular_weight: Option<f64>,
    pub fractions: Vec<Fraction>,
}

/// One dust fraction: its dust-to-gas ratio in the background state and its stopping-time
/// law with the law's parameter (`dust.t_stop` applied where the fraction gives none).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fraction {
    pub eps: f64,
    pub law: StoppingLaw<f64>,
}

impl Fraction {
    /// Initial conditions from a file: ε comes from the file's masses, not the scene.
    pub const EPS_FROM_FILE: f64 = f64::NAN;
}

impl Serialize for Fraction {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("Fraction", 2)?;
        // A file's fractions have no ε in the scene (their masses are in the file).
        if !self.eps.is_nan() {
            st.serialize_field("eps", &self.eps)?;
        }
        match self.law {
            StoppingLaw::ConstantTime { t_stop } => st.serialize_field("t_stop", &t_stop)?,
            StoppingLaw::ConstantK { k } => st.serialize_field("k", &k)?,
            StoppingLaw::Epstein { s_rho, stokes } => {
                st.serialize_field("s_rho", &s_rho)?;
                // Not a Stokes number: the Stokes drag regime's onset, t_k's factor
                // max(1, coefficient × ρ_g) (method.md §1.2).
                if stokes > 0.0 {
                    st.serialize_field("stokes_regime_coefficient", &stokes)?;
                }
            }
        }
        st.end()
    }
}

/// `[sph]`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Sph {
    /// Gas particles per unit length (see the file's `sph.n` for what each problem counts);
    /// 0 for initial conditions from a file, whose particles are the resolution.
    #[serde(skip_serializing_if = "is_zero")]
    pub n: usize,
    #[serde(flatten)]
    pub smoothing: SmoothingLength,
    pub density: DensityMethod,
    pub gradient: GradientMethod,
    /// Artificial viscosity, if on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub viscosity: Option<ArtificialViscosity>,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// The smoothing length rule.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(untagged)]
pub enum SmoothingLength {
    /// Initial conditions from a file without `sph.h` or `sph.hfact`: its `SmoothingLength`
    /// column (one value for every gas particle; host/setup/file.rs).
    FromFile {},
    /// `sph.h`: one absolute smoothing length.
    Absolute { h: f64 },
    /// `sph.hfact`: h = hfact × the problem's reference gas spacing; with `variable_h`, the
    /// gas's own h_a = hfact (m_a/ρ_a)^(1/d) (h is then the reference h).
    Hfact { hfact: f64, variable_h: bool },
}

impl SmoothingLength {
    /// The (reference) smoothing length for a reference gas spacing.
    /// `FromFile` has no rule: the file's column is read by its set-up (NaN here).
    pub fn h(self, spacing: f64) -> f64 {
        match self {
            SmoothingLength::FromFile {} => f64::NAN,
            SmoothingLength::Absolute { h } => h,
            SmoothingLength::Hfact { hfact, .. } => hfact * spacing,
        }
    }

    /// Variable h: `Some(hfact)`.
    pub fn variable_hfact(self) -> Option<f64> {
        match self {
            SmoothingLength::Hfact {
                hfact,
                variable_h: true,
            } => Some(hfact),
            _ => None,
        }
    }
}

/// Monaghan's artificial viscosity (`sph.viscosity = true`, `sph.alpha`, `sph.beta`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ArtificialViscosity {
    /// The shock form's α (unused by the disc form).
    pub alpha: f64,
    pub beta: f64,
    /// The disc form's target Shakura–Sunyaev α (`None`: the shock form).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alpha_ss: Option<f64>,
}

/// `[idic]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Idic {
    /// Cell size in units of h.
    pub cell: f64,
    pub coupling: Coupling,
    /// Kernel coupling: how the deposits are summed (`gather` with the cell coupling).
    pub deposit: DepositForm,
    /// Kernel coupling: the dust's unresolved velocity deviation (`kept` with the cell one).
    pub dispersion: Dispersion,
    /// Kernel coupling: where the deposits are read (`mean` with the cell coupling).
    pub sampling: Sampling,
}

/// `[drag]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Drag {
    pub method: DragMethod,
}

/// `[external]`: constant accelerations of the gas and of every dust particle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct External {
    pub gas: [f64; 3],
    pub dust: [f64; 3],
}

impl External {
    pub fn is_zero(&self) -> bool {
        self.gas.iter().chain(&self.dust).all(|a| *a == 0.0)
    }
}

/// `[time]`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Time {
    pub t_end: f64,
    #[serde(flatten)]
    pub step: StepRule,
    #[serde(flatten)]
    pub output: OutputSchedule,
    pub position_update: PositionUpdate,
    pub integrator: Integrator,
}

impl Time {
    /// The fixed step, if the step is fixed.
    pub fn fixed_dt(&self) -> Option<f64> {
        match self.step {
            StepRule::Fixed { dt } => Some(dt),
            StepRule::Cfl { .. } => None,
        }
    }
}

/// How each step's size is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(untagged)]
pub enum StepRule {
    /// `time.dt`: every step τ = dt.
    Fixed { dt: f64 },
    /// `time.cfl`: τ = cfl × min(CFL limit, force limit), and at most `time.dt_max` (a cap
    /// such as Phantom's dt ≤ 90 t_s for its implicit two-fluid drag, for comparisons).
    Cfl {
        cfl: f64,
        #[serde(skip_serializing_if = "Option::is_none")]
        dt_max: Option<f64>,
    },
}

/// When snapshots are written besides t = 0 and t_end.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum OutputSchedule {
    /// `time.output_dt`: every output_dt.
    Every { output_dt: f64 },
    /// `time.output_times`: at these times.
    At { output_times: Vec<f64> },
    /// At t = 0 and t_end only.
    EndOnly,
}

/// `[numerics]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Numerics {
    pub precision: Precision,
    pub neighbour_list: ListChoice,
    pub deposit_rows: DepositRows,
    /// Over MPI ranks: the work imbalance above which the cut follows the measured cost
    /// (`numerics.rebalance_at`; infinite: never).
    pub rebalance_at: f64,
}

/// The problem's own parameters (`[dustybox]`, `[dustywave]`, …), selected by `scene.problem`.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ProblemCfg {
    Dustybox(BoxCfg),
    Dustywave(WaveCfg),
    Dustyshock(ShockCfg),
    Dustyball(BallCfg),
    Dustysettle(SettleCfg),
    File(FileCfg),
    Dustydisc(DiscCfg),
}

impl ProblemCfg {
    pub fn kind(&self) -> Problem {
        match self {
            ProblemCfg::Dustybox(_) => Problem::Dustybox,
            ProblemCfg::Dustywave(_) => Problem::Dustywave,
            ProblemCfg::Dustyshock(_) => Problem::Dustyshock,
            ProblemCfg::Dustyball(_) => Problem::Dustyball,
            ProblemCfg::Dustysettle(_) => Problem::Dustysettle,
            ProblemCfg::File(_) => Problem::File,
            ProblemCfg::Dustydisc(_) => Problem::Dustydisc,
        }
    }

    /// The uniform gas state the problem starts from (`gas.rho`, `gas.p`); the shock tube
    /// has two (its sides) instead.
    pub fn background(&self) -> Option<GasState> {
        match self {
            ProblemCfg::Dustybox(b) => Some(b.background),
            ProblemCfg::Dustywave(w) => Some(w.background),
            ProblemCfg::Dustyshock(_) => None,
            ProblemCfg::Dustyball(b) => Some(b.background),
            ProblemCfg::Dustysettle(c) => Some(c.background),
            ProblemCfg::File(_) | ProblemCfg::Dustydisc(_) => None,
        }
    }
}

/// DUSTYBOX.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoxCfg {
    /// `gas.rho`, `gas.p` (written under `[gas]`).
    #[serde(skip)]
    pub background: GasState,
    pub length: f64,
    pub v_gas: f64,
    /// One initial dust velocity per fraction.
    pub u_dust: Vec<f64>,
    pub dust_shift: f64,
    pub lattice: Lattice,
    /// Random displacements of up to ±`jitter` spacings per axis (setup/disorder.rs).
    pub jitter: f64,
    pub seed: u64,
}

/// DUSTYWAVE.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WaveCfg {
    /// `gas.rho`, `gas.p` (written under `[gas]`).
    #[serde(skip)]
    pub background: GasState,
    pub length: f64,
    pub amplitude: f64,
    pub mode: WaveMode,
    /// 2D/3D only.
    pub lattice: Lattice,
    /// 2D/3D only.
    pub layers: usize,
    pub dust_shift: f64,
    /// Random displacements of up to ±`jitter` spacings per axis (setup/disorder.rs).
    pub jitter: f64,
    pub seed: u64,
}

/// DUSTYSHOCK: the two sides' gas states (isothermal gas: p = c_s² ρ).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ShockCfg {
    pub length: f64,
    pub left: GasState,
    pub right: GasState,
}

/// The ball.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BallCfg {
    /// `gas.rho`, `gas.p` (written under `[gas]`).
    #[serde(skip)]
    pub background: GasState,
    pub radius: f64,
    /// The gas particles asked for (`sph.n` then follows from them).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub particles: Option<u64>,
}

/// DUSTYSETTLE: an isothermal column (its gas's c_s here, the same as the scene's
/// [`GasEos::Isothermal`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SettleCfg {
    /// The base of the column: `gas.rho` and p = c_s² ρ (written under `[gas]`).
    #[serde(skip)]
    pub background: GasState,
    #[serde(skip)]
    pub cs: f64,
    pub height: f64,
    pub dust_shift: f64,
}

/// `[gravity]`: a point mass M at `position`, softened over `softening` (G = 1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Gravity {
    pub central_mass: f64,
    pub position: [f64; 3],
    pub softening: f64,
    /// Particles closer than this to the point mass are removed at the end of a step, their
    /// mass, momentum and angular momentum added to the star's record (0: none).
    pub accretion_radius: f64,
    /// Edge damping zones (method.md §D, "The discs' edges"): radial and vertical velocities
    /// damped, fully at R ≤ `damp_inner[0]` and R ≥ `damp_outer[1]`, ramped to none at
    /// `damp_inner[1]` and `damp_outer[0]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub damp_inner: Option<[f64; 2]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub damp_outer: Option<[f64; 2]>,
    /// The damping time at full weight in local orbital periods (0 when there is no zone).
    pub damp_time: f64,
}

impl Gravity {
    /// The point mass and its zones as the device's kernels take them.
    pub fn point_mass(&self) -> dustsph_device::gravity::PointMass {
        dustsph_device::gravity::PointMass {
            gm: self.central_mass,
            pos: self.position,
            soft2: self.softening * self.softening,
            damp_inner: self.damp_inner.unwrap_or([0.0; 2]),
            damp_outer: self.damp_outer.unwrap_or([0.0; 2]),
            damp_per_omega: if self.damp_time > 0.0 {
                1.0 / (2.0 * std::f64::consts::PI * self.damp_time)
            } else {
                0.0
            },
        }
    }
}

/// `[units]`: one code unit of length and of mass in cgs; time from G = 1 (Phantom's code
/// units), so T = √(L³/(G M)).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Units {
    /// cm per code length (`units.length`).
    #[serde(rename = "length")]
    pub length_cm: f64,
    /// g per code mass (`units.mass`).
    #[serde(rename = "mass")]
    pub mass_g: f64,
}

impl Units {
    /// Newton's G in cgs (CODATA 2018).
    pub const G_CGS: f64 = 6.674_30e-8;

    /// Seconds per code time: √(L³/(G M)).
    pub fn time_s(&self) -> f64 {
        (self.length_cm.powi(3) / (Self::G_CGS * self.mass_g)).sqrt()
    }

    /// cm s⁻¹ per code velocity.
    pub fn velocity_cm_s(&self) -> f64 {
        self.length_cm / self.time_s()
    }

    /// g cm⁻² per code surface density (a grain's s ρ_s).
    pub fn surface_density_g_cm2(&self) -> f64 {
        self.mass_g / (self.length_cm * self.length_cm)
    }
}

/// A dusty disc, 2D razor-thin or 3D (host/setup/dustydisc.rs).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DiscCfg {
    pub r_in: f64,
    pub r_out: f64,
    pub p: f64,
    /// Σ at r_ref (given, or from `disc_mass`).
    pub sigma_ref: f64,
    /// The exponential cut-off radius (`None`: no cut-off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub r_c: Option<f64>,
    /// The gas particle count asked for (`None`: the resolution is `sph.n`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub particles: Option<usize>,
    pub dust_velocity: DustStart,
    pub relax: bool,
}

impl DiscCfg {
    /// Σ(R)/Σ_ref: (R/r_ref)^(−p) (1 − √(r_in/R)) e^(−(R/r_c)^(2−p)), normalised to 1 at r_ref
    /// (method.md §D).
    pub fn sigma_shape(&self, r: f64, r_ref: f64) -> f64 {
        let raw = |r: f64| {
            let cut = self
                .r_c
                .map_or(1.0, |rc| (-(r / rc).powf(2.0 - self.p)).exp());
            r.powf(-self.p) * (1.0 - (self.r_in / r).sqrt()) * cut
        };
        raw(r) / raw(r_ref)
    }

    /// d ln Σ/d ln R: −p, the inner taper's ½√(r_in/R)/(1 − √(r_in/R)) and the cut-off's
    /// −(2 − p)(R/r_c)^(2−p).
    pub fn dln_sigma(&self, r: f64) -> f64 {
        let s = (self.r_in / r).sqrt();
        let cut = self
            .r_c
            .map_or(0.0, |rc| -(2.0 - self.p) * (r / rc).powf(2.0 - self.p));
        -self.p + 0.5 * s / (1.0 - s) + cut
    }

    /// ∫ 2πR Σ dR over [a, b] for Σ_ref = `sigma_ref` (composite Simpson in √(R − r_in), where
    /// the taper's √ is smooth: 512 pieces).
    pub fn mass_between(&self, a: f64, b: f64, r_ref: f64, sigma_ref: f64) -> f64 {
        let (ua, ub) = (
            (a - self.r_in).max(0.0).sqrt(),
            (b - self.r_in).max(0.0).sqrt(),
        );
        let k = 512;
        let du = (ub - ua) / k as f64;
        let f = |u: f64| {
            let r = self.r_in + u * u;
            2.0 * std::f64::consts::PI * r * sigma_ref * self.sigma_shape(r, r_ref) * 2.0 * u
        };
        du / 3.0
            * (0..=k)
                .map(|j| {
                    let c = match j {
                        0 => 1.0,
                        j if j == k => 1.0,
                        j if j % 2 == 1 => 4.0,
                        _ => 2.0,
                    };
                    c * f(ua + j as f64 * du)
                })
                .sum::<f64>()
    }
}

/// Initial conditions from an HDF5 file (host/setup/file.rs).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FileCfg {
    /// The path as the scene gives it.
    pub path: String,
    /// `path` from the scene file's folder (set when the scene is parsed).
    #[serde(skip)]
    pub resolved: std::path::PathBuf,
    pub periodic: [bool; 3],
}

/// The model as [`Scene::to_toml`] writes it: the scene file's sections and keys, the
/// background state under `[gas]`.
#[derive(Serialize)]
struct ModelToml<'a> {
    scene: MetaToml<'a>,
    gas: GasToml,
    #[serde(skip_serializing_if = "Option::is_none")]
    dust: Option<&'a Dust>,
    sph: &'a Sph,
    idic: &'a Idic,
    drag: &'a Drag,
    external: &'a External,
    time: &'a Time,
    numerics: &'a Numerics,
    #[serde(skip_serializing_if = "Option::is_none")]
    units: Option<&'a Units>,
    #[serde(skip_serializing_if = "Option::is_none")]
    gravity: Option<&'a Gravity>,
    #[serde(flatten)]
    problem: &'a ProblemCfg,
}

#[derive(Serialize)]
struct MetaToml<'a> {
    name: &'a str,
    problem: Problem,
    dim: u32,
}

#[derive(Serialize)]
struct GasToml {
    #[serde(flatten)]
    eos: GasEos,
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    background: Option<GasState>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disc(r_c: Option<f64>) -> DiscCfg {
        DiscCfg {
            r_in: 10.0,
            r_out: 100.0,
            p: 1.0,
            sigma_ref: 1.0,
            r_c,
            particles: None,
            dust_velocity: DustStart::Drift,
            relax: true,
        }
    }

    /// The disc's mass (what `dustydisc.disc_mass` is converted with): for p = 1 without a
    /// cut-off ∫2πR Σ dR = 2π Σ_ref r_ref [R − 2√(r_in R)]/(1 − √(r_in/r_ref)) exactly; with a
    /// cut-off against a fine midpoint sum; d ln Σ/d ln R against differences of ln Σ.
    #[test]
    fn the_discs_mass_and_slope_follow_its_profile() {
        let (r_ref, d) = (30.0, disc(None));
        let prim = |r: f64| r - 2.0 * (d.r_in * r).sqrt();
        let exact = 2.0 * std::f64::consts::PI * r_ref * (prim(100.0) - prim(10.0))
            / (1.0 - (d.r_in / r_ref).sqrt());
        let got = d.mass_between(10.0, 100.0, r_ref, 1.0);
        assert!((got / exact - 1.0).abs() < 1e-10, "{got} vs {exact}");
        for dc in [disc(None), disc(Some(40.0))] {
            let n = 200_000;
            let w = 90.0 / n as f64;
            let fine: f64 = (0..n)
                .map(|i| {
                    let r = 10.0 + (i as f64 + 0.5) * w;
                    2.0 * std::f64::consts::PI * r * dc.sigma_shape(r, r_ref) * w
                })
                .sum();
            let got = dc.mass_between(10.0, 100.0, r_ref, 1.0);
            assert!(
                (got / fine - 1.0).abs() < 1e-7,
                "{:?}: {got} vs {fine}",
                dc.r_c
            );
            for r in [12.0, 30.0, 70.0] {
                let e = 1e-6;
                let fd = (dc.sigma_shape(r * (1.0 + e), r_ref).ln()
                    - dc.sigma_shape(r * (1.0 - e), r_ref).ln())
                    / (2.0 * e);
                assert!((dc.dln_sigma(r) - fd).abs() < 1e-7, "{:?} R {r}", dc.r_c);
            }
        }
    }
}
