//! The scene file as written: serde structs that mirror the TOML, one per section, every
//! struct denying unknown keys. A key that may be left out is an `Option` here; what leaving it
//! out means (its default) is decided once, where the file is resolved into the [`Scene`]
//! model (`resolve.rs`).
//!
//! [`Scene`]: super::Scene
use serde::{Deserialize, Serialize};

/// A scene file as written: the problem's parameters are one of five optional sections, of
/// which exactly the one `scene.problem` names must be there.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub scene: MetaSection,
    pub gas: GasSection,
    pub dust: Option<DustSection>,
    pub sph: SphSection,
    pub idic: Option<IdicSection>,
    pub drag: Option<DragSection>,
    /// Constant external accelerations (drift, settling).
    pub external: Option<ExternalSection>,
    pub time: TimeSection,
    /// The float type of the step (docs/accuracy.md).
    pub numerics: Option<NumericsSection>,
    pub dustybox: Option<BoxSection>,
    pub dustywave: Option<WaveSection>,
    pub dustyshock: Option<ShockSection>,
    pub dustyball: Option<BallSection>,
    pub dustysettle: Option<SettleSection>,
    /// Initial conditions from an HDF5 file (`scene.problem = "file"`).
    pub file: Option<FileSection>,
    /// A dusty disc about the point mass of `[gravity]`.
    pub dustydisc: Option<DiscSection>,
    /// Physical units of the scene's numbers (G = 1 sets the time unit).
    pub units: Option<UnitsSection>,
    /// A central point mass (G = 1).
    pub gravity: Option<GravitySection>,
}

/// `[gravity]`: a central point mass pulling every gas and dust particle.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GravitySection {
    /// M (G = 1: GM in code units).
    pub central_mass: f64,
    pub position: Option<[f64; 3]>,
    /// Plummer softening length ε.
    pub softening: Option<f64>,
    /// Particles closer to the point mass than this are accreted at the end of a step.
    pub accretion_radius: Option<f64>,
    /// Inner edge damping zone [R_full, R_none] (cylindrical R).
    pub damp_inner: Option<[f64; 2]>,
    /// Outer edge damping zone [R_none, R_full].
    pub damp_outer: Option<[f64; 2]>,
    /// The zones' damping time at full weight, in local orbital periods.
    pub damp_time: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MetaSection {
    pub name: String,
    pub problem: Problem,
    pub dim: u32,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Problem {
    Dustybox,
    Dustywave,
    Dustyshock,
    Dustyball,
    Dustysettle,
    /// The particles of an HDF5 file (`[file]`): a user's own initial conditions.
    File,
    /// A dusty disc about a point mass, its dust on the steady drift (`[dustydisc]`).
    Dustydisc,
}

impl Problem {
    pub fn name(self) -> &'static str {
        match self {
            Problem::File => "file",
            Problem::Dustydisc => "dustydisc",
            Problem::Dustybox => "dustybox",
            Problem::Dustywave => "dustywave",
            Problem::Dustyshock => "dustyshock",
            Problem::Dustyball => "dustyball",
            Problem::Dustysettle => "dustysettle",
        }
    }
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum EosKind {
    Isothermal,
    Adiabatic,
    /// p = c_s(x)² ρ with c_s = cs0 (R/r_ref)^(−q) (discs; Phantom's ieos = 3 with
    /// `radius = "spherical"`).
    LocallyIsothermal,
}

/// Which radius a locally isothermal sound speed depends on.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum RadiusKind {
    /// R = √(x² + y²) about the z axis through the centre.
    Cylindrical,
    /// r = |x − centre| (Phantom's ieos = 3).
    Spherical,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GasSection {
    pub eos: EosKind,
    /// Isothermal sound speed.
    pub cs: Option<f64>,
    /// Adiabatic index.
    pub gamma: Option<f64>,
    /// Background gas density (every problem but the shock tube).
    pub rho: Option<f64>,
    /// Background pressure (adiabatic gas, every problem but the shock tube).
    pub p: Option<f64>,
    /// Locally isothermal gas: c_s at `r_ref`, the power q, the reference radius and which
    /// radius (about `gravity.position`, or the origin).
    pub cs0: Option<f64>,
    pub q: Option<f64>,
    pub r_ref: Option<f64>,
    pub radius: Option<RadiusKind>,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
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
pub struct DustSection {
    pub law: LawKind,
    /// Frictional heating of the gas by drag (method.md §1.3); adiabatic gas only.
    pub heating: Option<bool>,
    /// Default stopping time for fractions that give none (constant_t law).
    pub t_stop: Option<f64>,
    /// Epstein law: the grains' material density in g cm⁻³ for fractions that give a `size`
    /// and no density of their own (needs `[units]`).
    pub grain_density: Option<f64>,
    /// Epstein law: whose form (docs/scenes.md): the source report's t = sρ_s/(ρ_g c_s) or
    /// Phantom's, with the mean thermal speed √(8/(πγ)) c_s in place of c_s.
    pub epstein: Option<EpsteinForm>,
    /// Epstein grains given by `size`: the gas molecules' collision cross-section in cm²
    /// (the mean free path λ = μ m_H/(ρ_g σ) sets where the Stokes regime begins, s > 9λ/4).
    pub cross_section: Option<f64>,
    /// The gas's mean molecular weight μ (in m_H) for the mean free path.
    pub mean_molecular_weight: Option<f64>,
    /// The fractions one by one (or none, with `sizes`).
    #[serde(default)]
    pub fractions: Vec<FractionSection>,
    /// Epstein grains of `count` sizes log-spaced between `min` and `max` (instead of
    /// `fractions`).
    pub sizes: Option<SizesSection>,
}

/// `[dust.sizes]`: a size distribution dn/ds ∝ s^(−index) between `min` and `max` (cm) in
/// `count` log-spaced bins, each a fraction at the bin's log-centre with the bin's share of the
/// dust mass (∝ ∫ s³ s^(−index) ds), the shares summing to `dust_to_gas`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SizesSection {
    pub min: f64,
    pub max: f64,
    pub count: usize,
    /// The power of the number distribution (3.5: Mathis, Rumpl & Nordsieck 1977).
    pub index: Option<f64>,
    /// The total dust-to-gas mass ratio over the fractions.
    pub dust_to_gas: f64,
}

/// The Epstein law's speed.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum EpsteinForm {
    /// t = s ρ_s /(ρ_g c_s) (the source report's, Stoyanovskaya et al.).
    Report,
    /// t = s ρ_s /(ρ_g v_th), v_th = √(8/(πγ)) c_s (Phantom's, without its (ρ_g + ρ_d)
    /// in dustsph's t_k convention, method.md §1.1).
    Phantom,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FractionSection {
    /// Dust-to-gas density ratio ε_k of this fraction in the background state (required by
    /// the built-in problems; initial conditions from a file take it from their masses).
    pub eps: Option<f64>,
    /// Epstein law with `[units]`: the grain radius in cm (with `grain_density`, instead of
    /// `s_rho`).
    pub size: Option<f64>,
    /// The grain material density in g cm⁻³ (overrides `dust.grain_density`).
    pub grain_density: Option<f64>,
    pub t_stop: Option<f64>,
    pub k: Option<f64>,
    pub s_rho: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphSection {
    /// Gas particles per unit length along each axis (box, wave); for the shock tube, on its
    /// denser side; for the settling column, at its base; for the ball, of its lattice. Not
    /// used by initial conditions from a file (its particles are the resolution).
    pub n: Option<usize>,
    /// Smoothing length in units of the scene's reference gas spacing.
    pub hfact: Option<f64>,
    /// Absolute smoothing length (instead of hfact).
    pub h: Option<f64>,
    /// Variable smoothing length for the gas (Phantom's): h_a = hfact (m_a/ρ_a)^(1/d) solved
    /// with the density by Newton–Raphson, grad-h terms in the forces. Needs `hfact`; every
    /// dust fraction's density is solved the same way (from the reference h each step).
    pub variable_h: Option<bool>,
    /// How the gas density is obtained: `summation` (the default) or `continuity`.
    pub density: Option<DensityMethod>,
    /// The SPH gradient in the gas forces and energy rate: `standard` or `iad`.
    pub gradient: Option<GradientMethod>,
    pub viscosity: Option<bool>,
    pub alpha: Option<f64>,
    pub beta: Option<f64>,
    /// The disc viscosity: a target Shakura–Sunyaev α (method.md §D, "Disc viscosity"); turns
    /// the viscosity on in the disc form (needs `[gravity]`; instead of `alpha`).
    pub alpha_ss: Option<f64>,
}

/// Gas density method (dust densities are always summed).
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DensityMethod {
    /// ρ_a = Σ_b m_b W_ab every step (method.md §2).
    Summation,
    /// dρ_a/dt = Σ_b m_b v_ab·∇_a W_ab, integrated with the new velocities at the new
    /// positions: ρ^{n+1} = ρ^n + τ Σ_b m_b v_ab^{n+1}·∇_a W_ab(x^{n+1}); the initial density is
    /// the set-up's (exact) one. With a fixed h, summation responds to a compression through
    /// the lattice sum Σ W(h/Δ), whose slope at h = 1.2Δ mis-scales the pressure response by
    /// ~10% (docs/phantom_comparison.md); the continuity form does not.
    Continuity,
}

/// The kernel gradient of the gas pair terms.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum GradientMethod {
    /// ∇W (with grad-h terms for variable h): method.md §2, Phantom's.
    Standard,
    /// Integral approach to derivatives (García-Senz et al. 2012; SPHYNX, SPH-EXA): ∇W
    /// replaced by −C r W with C the inverse second-moment matrix, exact for linear fields on
    /// any particle arrangement. Removes the resolution-independent lattice error of the sound
    /// speed (1.2% at hfact 1.2 on the close-packed lattice). One more neighbour pass.
    Iad,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdicSection {
    /// IDIC cell size in units of h (the seed's 0.5h).
    pub cell: Option<f64>,
    /// How gas and dust meet in the drag solve (docs/method.md §K).
    pub coupling: Option<Coupling>,
    /// Kernel coupling only: how the deposits on the gas particles are summed (by the CPU's
    /// launcher and the GPU's alike).
    pub deposit: Option<DepositForm>,
    /// Kernel coupling only: whether each dust particle's unresolved velocity deviation is
    /// kept (each particle gets the smoothed increments alone) or damped at the drag rate.
    pub dispersion: Option<Dispersion>,
    /// Kernel coupling only: where each deposit on a gas particle is read (method.md §K,
    /// "Sampling offsets").
    pub sampling: Option<Sampling>,
}

/// Where the kernel coupling reads the deposits of gas and dust on a gas particle.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Sampling {
    /// At the gas particle: each phase's mean less the gas's velocity gradient (fitted over
    /// the particle's gas row) times the offset of that phase's centroid.
    Linear,
    /// At each phase's own centroid: the plain mass-weighted means (the source's form).
    Mean,
}

/// The kernel coupling's treatment of a dust particle's velocity deviation from the smoothed
/// field it should follow (method.md §K, "The unresolved dispersion").
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Dispersion {
    /// Kept: each particle receives the smoothed increments only.
    Kept,
    /// Damped at the drag rate, its momentum handed to the gas around it.
    Damped,
}

/// How the kernel coupling's deposits on the gas particles are summed.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DepositForm {
    /// Each gas particle walks the particles around it: deterministic, the same sums on every
    /// launcher.
    Gather,
    /// Each particle adds its share to the gas particles around it with atomic adds (the
    /// design card's atomicAdd): the order of the sums is the hardware's (or the threads').
    Scatter,
}

/// Where the implicit drag solve takes its local means.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Coupling {
    /// The source report's IDIC (method.md §3.3): the means of the particles that share a grid
    /// cell of size `idic.cell` h; a particle couples only to partners in its own cell.
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
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DragMethod {
    /// Implicit drag in cell (method.md §3): no time-step limit from the drag.
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
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExternalSection {
    pub gas: Option<[f64; 3]>,
    pub dust: Option<[f64; 3]>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DragSection {
    pub method: Option<DragMethod>,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum PositionUpdate {
    /// x^{n+1} = x^n + τ v^n (the authors' code).
    Old,
    /// x^{n+1} = x^n + τ v^{n+1} (symplectic Euler); the default, chosen by measurement.
    New,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NumericsSection {
    /// `f64` (the reference) or `f32`; `--precision` on the command line sets it too.
    pub precision: Option<Precision>,
    /// Per-particle neighbour lists, built once per layer and replayed by every neighbour
    /// pass of the gas: `auto` (on with the CPU launcher; the GPU kernels are built without lists),
    /// `on`, `off`. Results are bit-identical either way (docs/performance.md).
    pub neighbour_list: Option<ListChoice>,
    /// How the kernel coupling's deposit rows are made from its return rows once per layer:
    /// `auto` (`chunks` on the CPU, `atomic` on the GPU), `chunks` (each thread a chunk of
    /// particles in order), `atomic` (a thread per particle, atomic cursors, each row sorted).
    /// The rows, and so the results, are bit-identical either way (docs/method.md §K).
    pub deposit_rows: Option<DepositRows>,
    /// Over MPI ranks: how far the busiest rank's work per step may exceed the mean before
    /// the next cut shares out the ranks' measured cost per particle (default 0.05; 0: at
    /// every judgement; `inf`: never, the cut by counts). Where the ranks cut moves only the
    /// sums' round-off (ranks match one process to 1e-12); the cut by measured cost follows
    /// the clock, so only `inf` makes runs over ranks repeat bit for bit.
    pub rebalance_at: Option<f64>,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DepositRows {
    Auto,
    Chunks,
    Atomic,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ListChoice {
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
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
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

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeSection {
    pub t_end: f64,
    /// Fixed time step τ.
    pub dt: Option<f64>,
    /// CFL factor (with a force limit); used when `dt` is absent.
    pub cfl: Option<f64>,
    /// With `cfl`: no step longer than this.
    pub dt_max: Option<f64>,
    /// Snapshot interval (t = 0 and t_end are always written).
    pub output_dt: Option<f64>,
    /// Explicit snapshot times (instead of output_dt).
    pub output_times: Option<Vec<f64>>,
    pub position_update: Option<PositionUpdate>,
    /// The time integrator: `first_order` (the report's step) or `kdk` (leapfrog).
    pub integrator: Option<Integrator>,
}

/// How a step advances the particles.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// The report's step (method.md §3.6): v^{n+1} from the forces of layer n and the IDIC
    /// drag over τ, x^{n+1} = x^n + τ v^{n+1}, e^{n+1} = e^n + τ ė^n. First order; one force
    /// and one drag pass per step. Runs on the CPU and the GPU.
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
pub struct BoxSection {
    pub length: Option<f64>,
    /// Initial gas velocity (x component).
    pub v_gas: Option<f64>,
    /// Initial dust velocity per fraction (x component).
    pub u_dust: Vec<f64>,
    /// Offset of the dust lattice from the gas lattice, in lattice spacings along every axis
    /// (0: each dust particle sits on a gas particle).
    pub dust_shift: Option<f64>,
    /// 2D/3D lattice: cubic (default) or close-packed (hexagonal rows / fcc, Phantom's); the
    /// close-packed box keeps `length` along x and the nearest whole number of rows (even in
    /// 2D, a multiple of 6 in 3D) across, so its sides along y and z differ slightly.
    pub lattice: Option<Lattice>,
    /// Disorder: every particle displaced by a uniform random vector of up to ±`jitter` lattice
    /// spacings per axis, gas and each dust fraction drawn independently (0: the lattice).
    pub jitter: Option<f64>,
    /// The seed of the `jitter` draws (the same seed gives the same particles everywhere).
    pub seed: Option<u64>,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum WaveMode {
    /// The least-damped acoustic eigenmode (Benítez-Llambay et al. 2019).
    Eigen,
    /// Equal sine perturbations in every phase (Laibe & Price 2011 / Phantom set-up).
    Sine,
}

/// Particle lattice of the 2D/3D wave and box (the 1D ones are a uniform line either way).
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Lattice {
    /// Close-packed: hexagonal rows in 2D, face-centred cubic (ABC-stacked hexagonal layers)
    /// in 3D, as Phantom's `set_unifdis('closepacked')`.
    Closepacked,
    /// Cubic (square in 2D).
    Cubic,
    /// A relaxed periodic glass made by the code from the cubic lattice's count and box
    /// (host/setup/glass.rs): disordered, its SPH density nearly uniform; each phase its own.
    Glass,
}

impl Lattice {
    /// The name a scene file uses (`lattice`).
    pub fn name(self) -> &'static str {
        match self {
            Lattice::Closepacked => "closepacked",
            Lattice::Cubic => "cubic",
            Lattice::Glass => "glass",
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WaveSection {
    pub length: Option<f64>,
    pub amplitude: f64,
    pub mode: WaveMode,
    /// 2D/3D: the lattice of the unperturbed particles (close-packed by default).
    pub lattice: Option<Lattice>,
    /// 2D/3D: lattice rows across the slab along y (and layers along z); the slab is periodic
    /// and this many rows thick. Phantom's DUSTYWAVE uses 12.
    pub layers: Option<usize>,
    /// Offset of every dust lattice from the gas lattice, in units of the spacing Δ along x,
    /// applied along every axis (Phantom's `dust_shift`); 0 puts each dust particle on a gas
    /// particle.
    pub dust_shift: Option<f64>,
    /// Disorder: every particle displaced by a uniform random vector of up to ±`jitter` spacings Δ
    /// (along x) per axis, gas and each dust fraction drawn independently (0: the lattice).
    pub jitter: Option<f64>,
    /// The seed of the `jitter` draws (the same seed gives the same particles everywhere).
    pub seed: Option<u64>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShockSideSection {
    pub rho: f64,
    pub p: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShockSection {
    pub length: Option<f64>,
    pub left: ShockSideSection,
    pub right: ShockSideSection,
}

/// Dust settling through an isothermal gas column in hydrostatic equilibrium under the
/// constant `[external]` acceleration (docs/method.md §S). 1D: the column runs along x from
/// x = 0 (bottom) to `height`, closed by fixed gas particles beyond both ends.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SettleSection {
    pub height: Option<f64>,
    /// Dust placed this many gas spacings (in mass coordinate) above the gas particles
    /// (0: each dust particle on a gas particle).
    pub dust_shift: Option<f64>,
}

/// The seed's ball (method.md §6.1): uniform gas and dust at rest in a ball, vacuum outside.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BallSection {
    pub radius: Option<f64>,
    /// The gas particles wanted (instead of `sph.n`): the lattice's particles per unit length
    /// follow (each dust fraction has as many).
    pub particles: Option<u64>,
}

/// `[file]`: initial conditions from an HDF5 file in the layout dustsph writes (GADGET/SWIFT:
/// `PartType0` gas, `PartType3` dust with `FractionIndex`; host/io/ics.rs).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileSection {
    /// The file, relative to the scene file's folder (or absolute).
    pub path: String,
    /// Which axes are periodic (the file's `Header/BoxSizePerAxis` and `CoordinateOffset`
    /// give the period); open by default.
    pub periodic: Option<[bool; 3]>,
}

/// `[units]`: what one unit of the scene's length and mass is; time follows from G = 1.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UnitsSection {
    pub length: Option<UnitValue>,
    pub mass: Option<UnitValue>,
}

/// A unit by name (`"au"`, `"cm"`, `"msun"`, `"g"`, …) or as a number of cm or g.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum UnitValue {
    Cgs(f64),
    Name(String),
}

/// `[dustydisc]`: a 2D razor-thin disc about the `[gravity]` point mass, Σ = sigma_ref
/// (R/r_ref)^(−p) (1 − √(r_in/R))/(1 − √(r_in/r_ref)) between `r_in` and `r_out` (r_ref is
/// the locally isothermal gas's), gas and dust on the steady drift (host/setup/dustydisc.rs).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiscSection {
    pub r_in: Option<f64>,
    pub r_out: Option<f64>,
    /// The power of Σ.
    pub p: Option<f64>,
    /// Σ at r_ref (the disc's mass follows); or `disc_mass`.
    pub sigma_ref: Option<f64>,
    /// The gas disc's mass between r_in and r_out (instead of `sigma_ref`).
    pub disc_mass: Option<f64>,
    /// An exponential outer cut-off: Σ also ∝ exp(−(R/r_c)^(2−p)) (Lynden-Bell & Pringle
    /// 1974's similarity profile); none when absent.
    pub r_c: Option<f64>,
    /// The number of gas particles (the particle mass is the disc's mass over it), instead
    /// of `sph.n`.
    pub particles: Option<usize>,
    /// The dust's start: `drift` (the steady drift and settling) or `keplerian` (Phantom's).
    pub dust_velocity: Option<DustStart>,
    /// Balance the gas with the run's own SPH forces before the start (3D: its vertical
    /// structure relaxed; both: rotation from the measured radial force).
    pub relax: Option<bool>,
}

/// How the disc's dust starts moving.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DustStart {
    /// On the exact steady radial drift (and, in 3D, the settling velocity) of every species.
    Drift,
    /// On circular Keplerian orbits with no drift and no settling (Phantom's set-up).
    Keplerian,
}
