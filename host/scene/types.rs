//! The scene schema. Every struct denies unknown keys.
use serde::Deserialize;

type VResult = Result<(), (String, String)>;

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

fn positive(key: &str, v: f64) -> VResult {
    if !(v.is_finite() && v > 0.0) {
        return Err((
            key.into(),
            format!("must be a finite number > 0 (got {})", num(v)),
        ));
    }
    in_range(key, v)
}

/// |v| within [1/MAX_MAGNITUDE, MAX_MAGNITUDE] (or 0).
fn in_range(key: &str, v: f64) -> VResult {
    let a = v.abs();
    if a != 0.0 && !(1.0 / MAX_MAGNITUDE..=MAX_MAGNITUDE).contains(&a) {
        return Err((
            key.into(),
            format!(
                "{} is outside [1e-100, 1e100] in magnitude: the run's derived quantities \
                 (masses, momenta, energies) would overflow; change the units",
                num(v)
            ),
        ));
    }
    Ok(())
}

fn non_negative(key: &str, v: f64) -> VResult {
    if !(v.is_finite() && v >= 0.0) {
        return Err((
            key.into(),
            format!("must be a finite number ≥ 0 (got {})", num(v)),
        ));
    }
    in_range(key, v)
}

fn finite(key: &str, v: f64) -> VResult {
    if !v.is_finite() {
        return Err((key.into(), format!("must be finite (got {})", num(v))));
    }
    in_range(key, v)
}

/// A scene file as written: the problem's parameters are one of five optional sections.
/// [`SceneFile::validate`] checks that exactly the one `scene.problem` names is there;
/// [`Scene::from_file`] then makes it the tagged [`ProblemCfg`].
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub scene: Meta,
    pub gas: GasCfg,
    #[serde(default)]
    pub dust: Option<DustCfg>,
    pub sph: SphCfg,
    #[serde(default)]
    pub idic: IdicCfg,
    #[serde(default)]
    pub drag: DragCfg,
    /// Constant external accelerations (drift, settling).
    #[serde(default)]
    pub external: ExternalCfg,
    pub time: TimeCfg,
    /// The float type of the step (docs/accuracy.md).
    #[serde(default)]
    pub numerics: NumericsCfg,
    #[serde(default)]
    pub dustybox: Option<BoxCfg>,
    #[serde(default)]
    pub dustywave: Option<WaveCfg>,
    #[serde(default)]
    pub dustyshock: Option<ShockCfg>,
    #[serde(default)]
    pub dustyball: Option<BallCfg>,
    #[serde(default)]
    pub dustysettle: Option<SettleCfg>,
}

/// A validated scene: everything the run needs, the problem's own section as one tagged enum.
#[derive(Debug, Clone)]
pub struct Scene {
    pub scene: Meta,
    pub gas: GasCfg,
    pub dust: Option<DustCfg>,
    pub sph: SphCfg,
    pub idic: IdicCfg,
    pub drag: DragCfg,
    pub external: ExternalCfg,
    pub time: TimeCfg,
    pub numerics: NumericsCfg,
    /// The section of `scene.problem`.
    pub problem: ProblemCfg,
}

/// The problem's own parameters (`[dustybox]`, `[dustywave]`, …), selected by `scene.problem`.
#[derive(Debug, Clone)]
pub enum ProblemCfg {
    Dustybox(BoxCfg),
    Dustywave(WaveCfg),
    Dustyshock(ShockCfg),
    Dustyball(BallCfg),
    Dustysettle(SettleCfg),
}

impl Scene {
    /// The validated file as a scene (`f` must have passed [`SceneFile::validate`], which
    /// guarantees the section of `scene.problem`).
    pub fn from_file(f: SceneFile) -> Scene {
        const CHECKED: &str = "SceneFile::validate requires the problem's section";
        let problem = match f.scene.problem {
            Problem::Dustybox => ProblemCfg::Dustybox(f.dustybox.expect(CHECKED)),
            Problem::Dustywave => ProblemCfg::Dustywave(f.dustywave.expect(CHECKED)),
            Problem::Dustyshock => ProblemCfg::Dustyshock(f.dustyshock.expect(CHECKED)),
            Problem::Dustyball => ProblemCfg::Dustyball(f.dustyball.expect(CHECKED)),
            Problem::Dustysettle => ProblemCfg::Dustysettle(f.dustysettle.expect(CHECKED)),
        };
        Scene {
            scene: f.scene,
            gas: f.gas,
            dust: f.dust,
            sph: f.sph,
            idic: f.idic,
            drag: f.drag,
            external: f.external,
            time: f.time,
            numerics: f.numerics,
            problem,
        }
    }

    pub fn dim(&self) -> u32 {
        self.scene.dim
    }

    pub fn n_fractions(&self) -> usize {
        self.dust.as_ref().map_or(0, |d| d.fractions.len())
    }

    /// The ball's section, if this is the ball.
    pub fn ball(&self) -> Option<&BallCfg> {
        match &self.problem {
            ProblemCfg::Dustyball(b) => Some(b),
            _ => None,
        }
    }
}

#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Problem {
    Dustybox,
    Dustywave,
    Dustyshock,
    Dustyball,
    Dustysettle,
}

impl Problem {
    pub fn name(self) -> &'static str {
        match self {
            Problem::Dustybox => "dustybox",
            Problem::Dustywave => "dustywave",
            Problem::Dustyshock => "dustyshock",
            Problem::Dustyball => "dustyball",
            Problem::Dustysettle => "dustysettle",
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Meta {
    pub name: String,
    pub problem: Problem,
    pub dim: u32,
}

#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum EosKind {
    Isothermal,
    Adiabatic,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GasCfg {
    pub eos: EosKind,
    /// Isothermal sound speed.
    pub cs: Option<f64>,
    /// Adiabatic index.
    pub gamma: Option<f64>,
    /// Background gas density (box, wave).
    pub rho: Option<f64>,
    /// Background pressure (adiabatic box, wave).
    pub p: Option<f64>,
}

#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum LawKind {
    /// t_stop given per fraction.
    ConstantT,
    /// Drag coefficient K given per fraction: t = ρ_d/K.
    ConstantK,
    /// Epstein: t = s ρ_s/(ρ_g c_s), `s_rho` given per fraction.
    Epstein,
}

impl LawKind {
    /// The name a scene file uses (`dust.law`).
    pub fn name(self) -> &'static str {
        match self {
            LawKind::ConstantT => "constant_t",
            LawKind::ConstantK => "constant_k",
            LawKind::Epstein => "epstein",
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DustCfg {
    pub law: LawKind,
    /// Frictional heating of the gas by drag (method.md §1.3); adiabatic gas only.
    #[serde(default)]
    pub heating: bool,
    /// Default stopping time for fractions that give none (constant_t law).
    pub t_stop: Option<f64>,
    pub fractions: Vec<FractionCfg>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FractionCfg {
    /// Dust-to-gas density ratio ε_k of this fraction in the background state.
    pub eps: f64,
    pub t_stop: Option<f64>,
    pub k: Option<f64>,
    pub s_rho: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphCfg {
    /// Gas particles per unit length along each axis (box, wave); left state for the shock tube.
    pub n: usize,
    /// Smoothing length in units of the scene's reference gas spacing.
    pub hfact: Option<f64>,
    /// Absolute smoothing length (instead of hfact).
    pub h: Option<f64>,
    /// Variable smoothing length for the gas (Phantom's): h_a = hfact (m_a/ρ_a)^(1/d) solved
    /// with the density by Newton–Raphson, grad-h terms in the forces. Needs `hfact`; every
    /// dust fraction's density is solved the same way (from the reference h each step).
    #[serde(default)]
    pub variable_h: bool,
    /// How the gas density is obtained: `summation` (the default) or `continuity`.
    #[serde(default)]
    pub density: DensityMethod,
    /// The SPH gradient in the gas forces and energy rate: `standard` or `iad`.
    #[serde(default)]
    pub gradient: GradientMethod,
    #[serde(default)]
    pub viscosity: bool,
    #[serde(default = "one")]
    pub alpha: f64,
    #[serde(default = "two")]
    pub beta: f64,
}

/// Gas density method (dust densities are always summed).
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum DensityMethod {
    /// ρ_a = Σ_b m_b W_ab every step (method.md §2).
    #[default]
    Summation,
    /// dρ_a/dt = Σ_b m_b v_ab·∇_a W_ab, integrated with the new velocities at the new
    /// positions: ρ^{n+1} = ρ^n + τ Σ_b m_b v_ab^{n+1}·∇_a W_ab(x^{n+1}); the initial density is
    /// the set-up's (exact) one. With a fixed h, summation responds to a compression through
    /// the lattice sum Σ W(h/Δ), whose slope at h = 1.2Δ mis-scales the pressure response by
    /// ~10% (docs/phantom_comparison.md); the continuity form does not.
    Continuity,
}

/// The kernel gradient of the gas pair terms.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum GradientMethod {
    /// ∇W (with grad-h terms for variable h): method.md §2, Phantom's.
    #[default]
    Standard,
    /// Integral approach to derivatives (García-Senz et al. 2012; SPHYNX, SPH-EXA): ∇W
    /// replaced by −C r W with C the inverse second-moment matrix, exact for linear fields on
    /// any particle arrangement. Removes the resolution-independent lattice error of the sound
    /// speed (1.2% at hfact 1.2 on the close-packed lattice). One more neighbour pass.
    Iad,
}

fn one() -> f64 {
    1.0
}
fn two() -> f64 {
    2.0
}
fn half() -> f64 {
    0.5
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdicCfg {
    /// IDIC cell size in units of h (the seed's 0.5h).
    #[serde(default = "half")]
    pub cell: f64,
    /// How gas and dust meet in the drag solve (docs/method.md §K).
    #[serde(default)]
    pub coupling: Coupling,
    /// GPU only, kernel coupling: how the deposits on the gas particles are summed.
    #[serde(default)]
    pub deposit: DepositForm,
}

/// How the GPU sums the kernel coupling's deposits.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum DepositForm {
    /// Each gas particle walks the particles around it: deterministic, bit-identical to the CPU.
    #[default]
    Gather,
    /// Each particle adds its share to the gas particles around it with atomic adds (the
    /// design card's atomicAdd): the order of the sums is the hardware's.
    Scatter,
}

impl Default for IdicCfg {
    fn default() -> Self {
        IdicCfg {
            cell: 0.5,
            coupling: Coupling::default(),
            deposit: DepositForm::default(),
        }
    }
}

/// Where the implicit drag solve takes its local means.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum Coupling {
    /// The source report's IDIC (method.md §3.3): the means of the particles that share a grid
    /// cell of size `idic.cell` h; a particle couples only to partners in its own cell.
    #[default]
    Cell,
    /// The gas particles are the cells: every particle spreads over the gas particles within
    /// 2h with normalised kernel weights, each gas particle solves the same closed form on
    /// those means, and the particles receive the increments back with the same weights
    /// (docs/method.md §K). Indifferent to where the dust sits relative to the gas.
    Kernel,
}

impl Coupling {
    pub fn name(self) -> &'static str {
        match self {
            Coupling::Cell => "cell",
            Coupling::Kernel => "kernel",
        }
    }
}

/// How the drag is integrated.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum DragMethod {
    /// Implicit drag in cell (method.md §3): no time-step limit from the drag.
    #[default]
    Idic,
    /// The comparison baseline: the same particle equations and cell means, drag evaluated at the
    /// known velocities (forward Euler); needs τ ≤ 0.9 t_s (see `drag::explicit_rate`).
    Explicit,
}

impl DragMethod {
    pub fn name(self) -> &'static str {
        match self {
            DragMethod::Idic => "idic",
            DragMethod::Explicit => "explicit",
        }
    }
}

/// `[external] gas = [ax, ay, az]`, `dust = [ax, ay, az]`: constant accelerations added to the
/// non-drag acceleration of every gas (A^n) and every dust particle (B^n, method.md §3.3).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExternalCfg {
    #[serde(default)]
    pub gas: [f64; 3],
    #[serde(default)]
    pub dust: [f64; 3],
}

impl ExternalCfg {
    pub fn is_zero(&self) -> bool {
        self.gas.iter().chain(&self.dust).all(|a| *a == 0.0)
    }
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DragCfg {
    #[serde(default)]
    pub method: DragMethod,
}

#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum PositionUpdate {
    /// x^{n+1} = x^n + τ v^n (the authors' code).
    Old,
    /// x^{n+1} = x^n + τ v^{n+1} (symplectic Euler); the default, chosen by measurement.
    #[default]
    New,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NumericsCfg {
    /// `f64` (the reference) or `f32`; `--precision` on the command line sets it too.
    #[serde(default)]
    pub precision: Precision,
    /// Per-particle neighbour lists, built once per layer and replayed by every neighbour
    /// pass of the gas: `auto` (on with the CPU launcher; the GPU kernels are built without lists),
    /// `on`, `off`. Results are bit-identical either way (docs/performance.md).
    #[serde(default)]
    pub neighbour_list: ListChoice,
}

#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ListChoice {
    #[default]
    Auto,
    On,
    Off,
}

impl ListChoice {
    pub fn name(self) -> &'static str {
        match self {
            ListChoice::Auto => "auto",
            ListChoice::On => "on",
            ListChoice::Off => "off",
        }
    }
}

/// The float type the step's kernels run in, on the CPU and the GPU alike. The host's time,
/// step count, grid geometry, conservation sums and output stay f64; f32 is measured against
/// f64 in docs/accuracy.md.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    #[default]
    F64,
    F32,
}

impl Precision {
    pub fn name(self) -> &'static str {
        match self {
            Precision::F64 => "f64",
            Precision::F32 => "f32",
        }
    }
}

/// The most steps a fixed `time.dt` may ask for (1e9: days of a small run).
pub const MAX_FIXED_STEPS: f64 = 1e9;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeCfg {
    pub t_end: f64,
    /// Fixed time step τ.
    pub dt: Option<f64>,
    /// CFL factor (with a force limit); used when `dt` is absent.
    pub cfl: Option<f64>,
    /// Snapshot interval (t = 0 and t_end are always written).
    pub output_dt: Option<f64>,
    /// Explicit snapshot times (instead of output_dt).
    pub output_times: Option<Vec<f64>>,
    #[serde(default)]
    pub position_update: PositionUpdate,
    /// The time integrator: `first_order` (the report's step) or `kdk` (leapfrog).
    #[serde(default)]
    pub integrator: Integrator,
}

/// How a step advances the particles.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// The report's step (method.md §3.6): v^{n+1} from the forces of layer n and the IDIC
    /// drag over τ, x^{n+1} = x^n + τ v^{n+1}, e^{n+1} = e^n + τ ė^n. First order; one force
    /// and one drag pass per step. Runs on the CPU and the GPU.
    #[default]
    FirstOrder,
    /// Kick–drift–kick leapfrog (Phantom's): half kicks of τ/2 (pressure forces, then the IDIC
    /// drag over τ/2, implicit as ever), a drift with v^{n+1/2}, forces at the new layer from
    /// predicted v and e (themselves a τ/2 IDIC kick), and the closing half kick. Second order
    /// for the gas; still one force evaluation per step (the closing forces are the next
    /// step's opening ones), three drag passes.
    Kdk,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxCfg {
    #[serde(default = "one")]
    pub length: f64,
    /// Initial gas velocity (x component).
    #[serde(default)]
    pub v_gas: f64,
    /// Initial dust velocity per fraction (x component).
    pub u_dust: Vec<f64>,
    /// Offset of the dust lattice from the gas lattice, in lattice spacings along every axis
    /// (0: each dust particle sits on a gas particle).
    #[serde(default)]
    pub dust_shift: f64,
    /// 2D/3D lattice: cubic (default) or close-packed (hexagonal rows / fcc, Phantom's); the
    /// close-packed box keeps `length` along x and the nearest whole number of rows (even in
    /// 2D, a multiple of 6 in 3D) across, so its sides along y and z differ slightly.
    #[serde(default = "cubic")]
    pub lattice: Lattice,
}

fn cubic() -> Lattice {
    Lattice::Cubic
}

#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum WaveMode {
    /// The least-damped acoustic eigenmode (Benítez-Llambay et al. 2019).
    Eigen,
    /// Equal sine perturbations in every phase (Laibe & Price 2011 / Phantom set-up).
    Sine,
}

/// Particle lattice of the 2D/3D wave (the 1D wave is a uniform line either way).
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum Lattice {
    /// Close-packed: hexagonal rows in 2D, face-centred cubic (ABC-stacked hexagonal layers)
    /// in 3D, as Phantom's `set_unifdis('closepacked')`.
    #[default]
    Closepacked,
    /// Cubic (square in 2D).
    Cubic,
}

impl Lattice {
    /// The name a scene file uses (`lattice`).
    pub fn name(self) -> &'static str {
        match self {
            Lattice::Closepacked => "closepacked",
            Lattice::Cubic => "cubic",
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaveCfg {
    #[serde(default = "one")]
    pub length: f64,
    pub amplitude: f64,
    pub mode: WaveMode,
    /// 2D/3D: the lattice of the unperturbed particles.
    #[serde(default)]
    pub lattice: Lattice,
    /// 2D/3D: lattice rows across the slab along y (and layers along z); the slab is periodic
    /// and this many rows thick. Phantom's DUSTYWAVE uses 12.
    #[serde(default = "twelve")]
    pub layers: usize,
    /// Offset of every dust lattice from the gas lattice, in units of the spacing Δ along x,
    /// applied along every axis (Phantom's `dust_shift`); 0 puts each dust particle on a gas
    /// particle.
    #[serde(default)]
    pub dust_shift: f64,
}

fn twelve() -> usize {
    12
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShockState {
    pub rho: f64,
    pub p: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShockCfg {
    #[serde(default = "one")]
    pub length: f64,
    pub left: ShockState,
    pub right: ShockState,
}

/// Dust settling through an isothermal gas column in hydrostatic equilibrium under the
/// constant `[external]` acceleration (docs/method.md §S). 1D: the column runs along x from
/// x = 0 (bottom) to `height`, closed by fixed gas particles beyond both ends.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SettleCfg {
    #[serde(default = "one")]
    pub height: f64,
    /// Dust placed this many gas spacings (in mass coordinate) above the gas particles
    /// (0: each dust particle on a gas particle).
    #[serde(default)]
    pub dust_shift: f64,
}

/// The seed's ball (method.md §6.1): uniform gas and dust at rest in a ball, vacuum outside.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BallCfg {
    #[serde(default = "one")]
    pub radius: f64,
}

impl SceneFile {
    pub fn dim(&self) -> u32 {
        self.scene.dim
    }

    pub fn n_fractions(&self) -> usize {
        self.dust.as_ref().map_or(0, |d| d.fractions.len())
    }

    /// Semantic checks; returns (key, message) for the first failure.
    ///
    /// (`MAX_FIXED_STEPS` bounds a fixed step's count: `time.dt = 1e-300` would never end.)
    pub fn validate(&self) -> VResult {
        let s = &self.scene;
        if s.name.trim().is_empty() {
            return Err(("scene.name".into(), "must not be empty".into()));
        }
        // The default output folder is output/<name>: a name must not lead anywhere else.
        if s.name.contains(['/', '\\', '\0']) || s.name == "." || s.name.contains("..") {
            return Err((
                "scene.name".into(),
                format!(
                    "{:?} is not a plain name: no path separators or \"..\" (it names the \
                     output folder output/<name>; use --out for another place)",
                    s.name
                ),
            ));
        }
        if !(1..=3).contains(&s.dim) {
            return Err((
                "scene.dim".into(),
                format!("must be 1, 2 or 3 (got {})", s.dim),
            ));
        }
        match s.problem {
            Problem::Dustyshock | Problem::Dustysettle if s.dim != 1 => {
                return Err((
                    "scene.dim".into(),
                    format!(
                        "problem `{}` is one-dimensional: dim must be 1",
                        s.problem.name()
                    ),
                ))
            }
            _ => {}
        }
        // The problem's own section must be present, the others absent.
        let sections = [
            (Problem::Dustybox, self.dustybox.is_some()),
            (Problem::Dustywave, self.dustywave.is_some()),
            (Problem::Dustyshock, self.dustyshock.is_some()),
            (Problem::Dustyball, self.dustyball.is_some()),
            (Problem::Dustysettle, self.dustysettle.is_some()),
        ];
        for (p, present) in sections {
            if p == s.problem && !present {
                return Err((
                    p.name().into(),
                    format!("section [{}] is required by scene.problem", p.name()),
                ));
            }
            if p != s.problem && present {
                return Err((
                    p.name().into(),
                    format!(
                        "section [{}] does not belong to problem `{}`",
                        p.name(),
                        s.problem.name()
                    ),
                ));
            }
        }
        self.validate_gas()?;
        self.validate_dust()?;
        self.validate_sph()?;
        positive("idic.cell", self.idic.cell)?;
        // Below 0.05h the neighbour reach (2h/Δc rows per axis) explodes; above 4h a cell
        // averages over several kernel supports.
        if !(0.05..=4.0).contains(&self.idic.cell) {
            return Err((
                "idic.cell".into(),
                format!(
                    "must be between 0.05 and 4 (cell size in units of h; got {})",
                    num(self.idic.cell)
                ),
            ));
        }
        for (name, a) in [("gas", self.external.gas), ("dust", self.external.dust)] {
            for (i, v) in a.iter().enumerate() {
                finite(&format!("external.{name}.{i}"), *v)?;
            }
            if (self.scene.dim as usize) < 3
                && a[self.scene.dim as usize..].iter().any(|v| *v != 0.0)
            {
                return Err((
                    format!("external.{name}"),
                    format!(
                        "has a component along an axis a {}D scene does not have",
                        self.scene.dim
                    ),
                ));
            }
        }
        if self.idic.deposit == DepositForm::Scatter && self.idic.coupling != Coupling::Kernel {
            return Err((
                "idic.deposit".into(),
                "\"scatter\" sums the kernel coupling's deposits; it needs idic.coupling = \"kernel\"".into(),
            ));
        }
        if self.idic.coupling == Coupling::Kernel && self.drag.method == DragMethod::Explicit {
            return Err((
                "idic.coupling".into(),
                "\"kernel\" is an implicit coupling; the explicit baseline uses \"cell\"".into(),
            ));
        }
        if self.drag.method == DragMethod::Explicit && self.dust.is_none() {
            return Err((
                "drag.method".into(),
                "\"explicit\" drag needs a [dust] section (without dust there is no drag)".into(),
            ));
        }
        self.validate_time()?;
        self.validate_problem()
    }

    fn validate_gas(&self) -> VResult {
        let g = &self.gas;
        match g.eos {
            EosKind::Isothermal => {
                positive(
                    "gas.cs",
                    g.cs.ok_or((
                        "gas.cs".to_string(),
                        "required for isothermal gas".to_string(),
                    ))?,
                )?;
                if g.gamma.is_some() {
                    return Err((
                        "gas.gamma".into(),
                        "not used by isothermal gas (remove it)".into(),
                    ));
                }
                if g.p.is_some() {
                    return Err((
                        "gas.p".into(),
                        "isothermal pressure is cs²ρ (remove it)".into(),
                    ));
                }
            }
            EosKind::Adiabatic => {
                let gamma = g.gamma.ok_or((
                    "gas.gamma".to_string(),
                    "required for adiabatic gas".to_string(),
                ))?;
                if !(gamma.is_finite() && gamma > 1.0) {
                    return Err(("gas.gamma".into(), format!("must be > 1 (got {gamma})")));
                }
                if g.cs.is_some() {
                    return Err((
                        "gas.cs".into(),
                        "adiabatic sound speed follows from γ, p, ρ (remove it)".into(),
                    ));
                }
            }
        }
        let needs_background = self.scene.problem != Problem::Dustyshock;
        if needs_background {
            positive(
                "gas.rho",
                g.rho
                    .ok_or(("gas.rho".to_string(), "required".to_string()))?,
            )?;
            if g.eos == EosKind::Adiabatic {
                positive(
                    "gas.p",
                    g.p.ok_or((
                        "gas.p".to_string(),
                        "required for adiabatic gas".to_string(),
                    ))?,
                )?;
            }
        } else {
            if g.rho.is_some() {
                return Err((
                    "gas.rho".into(),
                    "the shock tube takes dustyshock.left/right instead".into(),
                ));
            }
            if g.p.is_some() {
                return Err((
                    "gas.p".into(),
                    "the shock tube takes dustyshock.left/right instead".into(),
                ));
            }
        }
        Ok(())
    }

    fn validate_dust(&self) -> VResult {
        let Some(d) = &self.dust else {
            if self.scene.problem == Problem::Dustybox {
                return Err((
                    "dust".into(),
                    "dustybox needs a [dust] section with at least one fraction".into(),
                ));
            }
            return Ok(());
        };
        if d.fractions.is_empty() {
            return Err((
                "dust.fractions".into(),
                "must list at least one fraction ([[dust.fractions]])".into(),
            ));
        }
        let max = dustsph_device::kernels::MAX_FRACTIONS;
        if d.fractions.len() > max {
            return Err((
                "dust.fractions".into(),
                format!(
                    "{} fractions given; at most {max} are supported (the GPU cell kernel keeps them in registers)",
                    d.fractions.len()
                ),
            ));
        }
        if d.heating && self.gas.eos == EosKind::Isothermal {
            return Err((
                "dust.heating".into(),
                "drag heating needs adiabatic gas".into(),
            ));
        }
        if let Some(t) = d.t_stop {
            positive("dust.t_stop", t)?;
            if d.law != LawKind::ConstantT {
                return Err((
                    "dust.t_stop".into(),
                    "only used with law = \"constant_t\"".into(),
                ));
            }
        }
        for (i, f) in d.fractions.iter().enumerate() {
            let key = |k: &str| format!("dust.fractions.{i}.{k}");
            positive(&key("eps"), f.eps)?;
            let (want, other): (&str, [(&str, Option<f64>); 2]) = match d.law {
                LawKind::ConstantT => ("t_stop", [("k", f.k), ("s_rho", f.s_rho)]),
                LawKind::ConstantK => ("k", [("t_stop", f.t_stop), ("s_rho", f.s_rho)]),
                LawKind::Epstein => ("s_rho", [("t_stop", f.t_stop), ("k", f.k)]),
            };
            for (name, v) in other {
                if v.is_some() {
                    return Err((
                        key(name),
                        format!("not used by law `{}` (expects `{want}`)", d.law.name()),
                    ));
                }
            }
            let v = match d.law {
                LawKind::ConstantT => f.t_stop.or(d.t_stop),
                LawKind::ConstantK => f.k,
                LawKind::Epstein => f.s_rho,
            };
            let v = v.ok_or((key(want), "required by dust.law".to_string()))?;
            positive(&key(want), v)?;
        }
        Ok(())
    }

    fn validate_sph(&self) -> VResult {
        let s = &self.sph;
        if s.n < 2 {
            return Err((
                "sph.n".into(),
                format!("must be ≥ 2 particles per unit length (got {})", s.n),
            ));
        }
        match (s.h, s.hfact) {
            (Some(_), Some(_)) => {
                return Err((
                    "sph.h".into(),
                    "give either sph.h or sph.hfact, not both".into(),
                ))
            }
            (None, None) => {
                return Err((
                    "sph.hfact".into(),
                    "give sph.hfact (h in units of the particle spacing) or sph.h".into(),
                ))
            }
            (Some(h), None) => positive("sph.h", h)?,
            (None, Some(f)) => positive("sph.hfact", f)?,
        }
        if s.variable_h {
            if s.hfact.is_none() {
                return Err((
                    "sph.variable_h".into(),
                    "needs sph.hfact (h = hfact (m/ρ)^(1/d)), not sph.h".into(),
                ));
            }
            if s.density == DensityMethod::Continuity {
                return Err((
                    "sph.variable_h".into(),
                    "variable h defines the density by summation (sph.density = \"continuity\" excludes it)".into(),
                ));
            }
        }
        non_negative("sph.alpha", s.alpha)?;
        non_negative("sph.beta", s.beta)?;
        Ok(())
    }

    fn validate_time(&self) -> VResult {
        let t = &self.time;
        positive("time.t_end", t.t_end)?;
        if t.integrator == Integrator::Kdk && t.position_update == PositionUpdate::Old {
            return Err((
                "time.position_update".into(),
                "\"old\" belongs to the first-order step; time.integrator = \"kdk\" drifts with v^{n+1/2}".into(),
            ));
        }
        match (t.dt, t.cfl) {
            (Some(_), Some(_)) => {
                return Err((
                    "time.dt".into(),
                    "give either time.dt (fixed) or time.cfl, not both".into(),
                ))
            }
            (None, None) => {
                return Err((
                    "time.dt".into(),
                    "give time.dt (fixed step) or time.cfl".into(),
                ))
            }
            (Some(dt), None) => {
                positive("time.dt", dt)?;
                let steps = (t.t_end / dt).ceil();
                if steps.is_nan() || steps > MAX_FIXED_STEPS {
                    return Err((
                        "time.dt".into(),
                        format!(
                            "{steps:e} steps of {dt:e} to time.t_end = {}: more than {MAX_FIXED_STEPS:e}; \
                             a larger time.dt or time.cfl",
                            t.t_end
                        ),
                    ));
                }
            }
            (None, Some(c)) => {
                positive("time.cfl", c)?;
                if c > 1.0 {
                    return Err(("time.cfl".into(), format!("must be ≤ 1 (got {c})")));
                }
            }
        }
        match (&t.output_dt, &t.output_times) {
            (Some(_), Some(_)) => {
                return Err((
                    "time.output_dt".into(),
                    "give output_dt or output_times, not both".into(),
                ))
            }
            (Some(d), None) => {
                positive("time.output_dt", *d)?;
                if t.t_end / d > 100_000.0 {
                    return Err((
                        "time.output_dt".into(),
                        format!(
                            "{} snapshots would be written (limit 100000)",
                            (t.t_end / d).floor()
                        ),
                    ));
                }
            }
            (None, Some(ts)) => {
                if ts.len() > 100_000 {
                    return Err((
                        "time.output_times".into(),
                        format!("{} snapshots would be written (limit 100000)", ts.len()),
                    ));
                }
                for (i, &x) in ts.iter().enumerate() {
                    let key = format!("time.output_times.{i}");
                    non_negative(&key, x)?;
                    if x > t.t_end {
                        return Err((key, format!("{x} is after time.t_end = {}", t.t_end)));
                    }
                }
            }
            (None, None) => {}
        }
        Ok(())
    }

    fn validate_problem(&self) -> VResult {
        let nf = self.n_fractions();
        if let Some(b) = &self.dustybox {
            positive("dustybox.length", b.length)?;
            finite("dustybox.v_gas", b.v_gas)?;
            if b.u_dust.len() != nf {
                return Err((
                    "dustybox.u_dust".into(),
                    format!(
                        "needs one velocity per dust fraction ({nf}), got {}",
                        b.u_dust.len()
                    ),
                ));
            }
            for (i, &u) in b.u_dust.iter().enumerate() {
                finite(&format!("dustybox.u_dust.{i}"), u)?;
            }
            finite("dustybox.dust_shift", b.dust_shift)?;
        }
        if let Some(c) = &self.dustysettle {
            positive("dustysettle.height", c.height)?;
            finite("dustysettle.dust_shift", c.dust_shift)?;
            if !(0.0..1.0).contains(&c.dust_shift) {
                return Err((
                    "dustysettle.dust_shift".into(),
                    format!("must be in [0, 1) gas spacings (got {})", num(c.dust_shift)),
                ));
            }
            if self.gas.eos != EosKind::Isothermal {
                return Err((
                    "gas.eos".into(),
                    "dustysettle is an isothermal column: eos must be \"isothermal\"".into(),
                ));
            }
            if self.dust.is_none() {
                return Err((
                    "dust".into(),
                    "dustysettle needs a [dust] section with at least one fraction".into(),
                ));
            }
            let g = -self.external.gas[0];
            if g.is_nan() || g <= 0.0 {
                return Err((
                    "external.gas".into(),
                    "dustysettle needs gravity along −x: external.gas = [-g, 0, 0] with g > 0"
                        .into(),
                ));
            }
            if self.external.dust != self.external.gas {
                return Err((
                    "external.dust".into(),
                    "dustysettle: gas and dust fall under the same gravity (external.dust = external.gas)"
                        .into(),
                ));
            }
        }
        if let Some(w) = &self.dustywave {
            positive("dustywave.length", w.length)?;
            positive("dustywave.amplitude", w.amplitude)?;
            finite("dustywave.dust_shift", w.dust_shift)?;
            if self.scene.dim > 1 {
                let need = match (w.lattice, self.scene.dim) {
                    // Hexagonal rows alternate (period 2); fcc layers repeat every 3.
                    (Lattice::Closepacked, 2) => 2,
                    (Lattice::Closepacked, _) => 6,
                    (Lattice::Cubic, _) => 1,
                };
                if w.layers == 0 || w.layers % need != 0 {
                    return Err((
                        "dustywave.layers".into(),
                        format!(
                            "must be a positive multiple of {need} for a periodic {} lattice in {}D (got {})",
                            w.lattice.name(), self.scene.dim, w.layers
                        ),
                    ));
                }
            }
            if w.amplitude > 0.1 {
                return Err((
                    "dustywave.amplitude".into(),
                    format!(
                        "a linear wave needs a small amplitude (≤ 0.1, got {})",
                        w.amplitude
                    ),
                ));
            }
        }
        if let Some(b) = &self.dustyball {
            positive("dustyball.radius", b.radius)?;
        }
        if let Some(s) = &self.dustyshock {
            positive("dustyshock.length", s.length)?;
            for (side, st) in [("left", s.left), ("right", s.right)] {
                positive(&format!("dustyshock.{side}.rho"), st.rho)?;
                match (self.gas.eos, st.p) {
                    (EosKind::Adiabatic, None) => {
                        return Err((
                            format!("dustyshock.{side}.p"),
                            "required for adiabatic gas".into(),
                        ))
                    }
                    (EosKind::Adiabatic, Some(p)) => positive(&format!("dustyshock.{side}.p"), p)?,
                    (EosKind::Isothermal, Some(_)) => {
                        return Err((
                            format!("dustyshock.{side}.p"),
                            "isothermal pressure is cs²ρ (remove it)".into(),
                        ))
                    }
                    (EosKind::Isothermal, None) => {}
                }
            }
        }
        Ok(())
    }
}
