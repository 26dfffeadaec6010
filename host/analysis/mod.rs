//! Comparison with exact solutions (method.md §8) and conservation diagnostics.
pub mod ball;
pub mod bins;
pub mod disc;
pub mod norms;
pub mod profiles;
pub mod radial;
pub mod spherical;
pub mod support_grid;

use crate::dist::Comm;
use crate::exact::dustybox::{DustyBox, Forcing};
use crate::exact::dustywave::WaveGas;
use crate::exact::riemann::{DustyRiemann, Prim};
use crate::particles::{Phase, State};
use crate::scene::{
    BallCfg, BoxCfg, GasEos, GasState, ProblemCfg, Scene, SettleCfg, ShockCfg, WaveCfg,
};
use crate::setup::dustywave;
use norms::Norms;
use serde::{Deserialize, Serialize};

/// Error norms of one field.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct FieldError {
    pub field: String,
    #[serde(flatten)]
    pub norms: Norms,
}

/// Errors of a snapshot against the scene's exact solution.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ExactErrors {
    pub t: f64,
    /// What the errors are measured against, and how they are normalised.
    pub reference: String,
    pub fields: Vec<FieldError>,
}

impl ExactErrors {
    pub fn get(&self, field: &str) -> Option<&Norms> {
        self.fields
            .iter()
            .find(|f| f.field == field)
            .map(|f| &f.norms)
    }
}

/// The dusty box's linear drag problem, and its initial gas and dust velocities.
fn dustybox_model(scene: &Scene, b: &BoxCfg) -> (DustyBox, f64, Vec<f64>) {
    let bg = b.background;
    let cs = scene.gas.eos.sound_speed(bg);
    let fr = scene.fractions();
    let eps: Vec<f64> = fr.iter().map(|f| f.eps).collect();
    let t_stop = fr
        .iter()
        .map(|f| f.law.stopping_time(bg.rho, f.eps * bg.rho, cs))
        .collect();
    (DustyBox { eps, t_stop }, b.v_gas, b.u_dust.clone())
}

fn phase_errors(
    c: &dyn Comm,
    name: &str,
    ph: &Phase,
    rho_scale: f64,
    v_scale: f64,
    exact: impl Fn([f64; 3]) -> (f64, f64),
) -> [FieldError; 2] {
    let active: Vec<usize> = (0..ph.len()).filter(|&i| !ph.is_fixed(i)).collect();
    let m: Vec<f64> = active.iter().map(|&i| ph.m[i]).collect();
    let ex: Vec<(f64, f64)> = active.iter().map(|&i| exact(ph.x[i])).collect();
    let rho: Vec<f64> = active
        .iter()
        .zip(&ex)
        .map(|(&i, e)| (ph.rho[i] - e.0) / rho_scale)
        .collect();
    let v: Vec<f64> = active
        .iter()
        .zip(&ex)
        .map(|(&i, e)| (ph.v[i][0] - e.1) / v_scale)
        .collect();
    [
        FieldError {
            field: format!("rho_{name}"),
            norms: Norms::over(c, &rho, &m),
        },
        FieldError {
            field: format!("{}_{name}", if name == "g" { "v" } else { "u" }),
            norms: Norms::over(c, &v, &m),
        },
    ]
}

/// v_x errors of one phase normalised by the rms of the exact v_x over its particles (all three
/// norms use that scale); mass-weighted like every other norm (equal masses: plain means).
fn relative_velocity_error(
    c: &dyn Comm,
    name: &str,
    ph: &Phase,
    exact: impl Fn([f64; 3]) -> f64,
) -> FieldError {
    let active: Vec<usize> = (0..ph.len()).filter(|&i| !ph.is_fixed(i)).collect();
    let m: Vec<f64> = active.iter().map(|&i| ph.m[i]).collect();
    let ex: Vec<f64> = active.iter().map(|&i| exact(ph.x[i])).collect();
    let rms = Norms::over(c, &ex, &m).l2.max(f64::MIN_POSITIVE);
    let err: Vec<f64> = active
        .iter()
        .zip(&ex)
        .map(|(&i, e)| (ph.v[i][0] - e) / rms)
        .collect();
    FieldError {
        field: name.into(),
        norms: Norms::over(c, &err, &m),
    }
}

/// The constant part of a phase's density error: the mass-weighted mean of ρ − ρ_exact.
fn density_offset(c: &dyn Comm, ph: &Phase, exact: impl Fn([f64; 3]) -> f64) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for i in (0..ph.len()).filter(|&i| !ph.is_fixed(i)) {
        num += ph.m[i] * (ph.rho[i] - exact(ph.x[i]));
        den += ph.m[i];
    }
    let mut s = [num, den];
    c.sum_f64(&mut s);
    let [num, den] = s;
    if den > 0.0 {
        num / den
    } else {
        0.0
    }
}

/// The density perturbation of a phase, ρ − (mass-weighted mean ρ), against the exact
/// perturbation `exact(x)`, relative to the rms of the exact perturbation (as
/// [`relative_velocity_error`]).
fn relative_perturbation_error(
    c: &dyn Comm,
    name: &str,
    ph: &Phase,
    exact: impl Fn([f64; 3]) -> f64,
) -> FieldError {
    let active: Vec<usize> = (0..ph.len()).filter(|&i| !ph.is_fixed(i)).collect();
    let m: Vec<f64> = active.iter().map(|&i| ph.m[i]).collect();
    let mut s = [
        m.iter().sum::<f64>(),
        active.iter().map(|&i| ph.m[i] * ph.rho[i]).sum::<f64>(),
    ];
    c.sum_f64(&mut s);
    let mean = s[1] / s[0];
    let ex: Vec<f64> = active.iter().map(|&i| exact(ph.x[i])).collect();
    let rms = Norms::over(c, &ex, &m).l2.max(f64::MIN_POSITIVE);
    let err: Vec<f64> = active
        .iter()
        .zip(&ex)
        .map(|(&i, e)| (ph.rho[i] - mean - e) / rms)
        .collect();
    FieldError {
        field: name.into(),
        norms: Norms::over(c, &err, &m),
    }
}

fn all_phase_errors(
    c: &dyn Comm,
    state: &State,
    rho_scale: &dyn Fn(usize) -> f64,
    v_scale: f64,
    exact_gas: impl Fn([f64; 3]) -> (f64, f64),
    exact_dust: impl Fn(usize, [f64; 3]) -> (f64, f64),
) -> Vec<FieldError> {
    let mut out: Vec<FieldError> = phase_errors(
        c,
        "g",
        &state.gas.ph,
        rho_scale(usize::MAX),
        v_scale,
        exact_gas,
    )
    .into();
    for (k, d) in state.dust.iter().enumerate() {
        out.extend(phase_errors(
            c,
            &format!("d{k}"),
            d,
            rho_scale(k),
            v_scale,
            |x| exact_dust(k, x),
        ));
    }
    out
}

/// Whether a scene's outputs read every particle at once: the settling column's drift, which
/// interpolates the gas velocity between the gas particles around each dust particle. Over
/// MPI ranks its outputs are written from the whole state gathered on rank 0; every other
/// scene's are written by share, no rank holding every particle, with its errors
/// ([`exact_errors_over`]) and the ball's core reduced over the ranks.
pub fn outputs_read_whole_state(scene: &Scene) -> bool {
    matches!(scene.problem, ProblemCfg::Dustysettle(_))
}

/// Errors against the exact solution of the scene (`None` if the problem has none).
/// `dt_fixed` enables the discrete IDIC oracle of the dusty box.
pub fn exact_errors(scene: &Scene, state: &State, dt_fixed: Option<f64>) -> Vec<ExactErrors> {
    exact_errors_over(&crate::dist::Alone, scene, state, dt_fixed)
}

/// [`exact_errors`] of the particles every process of `c` holds a share of (`state`: this
/// process's; collective): the same norms, their sums reduced over the processes. Not for
/// the settling column ([`outputs_read_whole_state`]).
pub fn exact_errors_over(
    c: &dyn Comm,
    scene: &Scene,
    state: &State,
    dt_fixed: Option<f64>,
) -> Vec<ExactErrors> {
    match &scene.problem {
        ProblemCfg::Dustyball(b) => ball_reference_errors(c, scene, b, state),
        ProblemCfg::Dustybox(b) => box_errors(c, scene, b, state, dt_fixed),
        ProblemCfg::Dustywave(w) => wave_errors(c, scene, w, state),
        ProblemCfg::Dustysettle(s) => vec![settle_errors(c, scene, s, state)],
        ProblemCfg::Dustyshock(s) => shock_errors(c, scene, s, state),
        ProblemCfg::File(_) | ProblemCfg::Dustydisc(_) => Vec::new(),
    }
}

/// The dusty box against the exact solution of its linear drag ODE, and (fixed τ, IDIC) against
/// IDIC's own discrete solution.
fn box_errors(
    c: &dyn Comm,
    scene: &Scene,
    b: &BoxCfg,
    state: &State,
    dt_fixed: Option<f64>,
) -> Vec<ExactErrors> {
    let t = state.t;
    let mut out = Vec::new();
    let rho = b.background.rho;
    let (bx, v0, u0) = dustybox_model(scene, b);
    let eps = bx.eps.clone();
    // `[external]` accelerations (x components; the errors compare v_x) drive the box toward
    // the terminal drift w*_k = t_k (a_d − a_g)/(1 + Σε).
    let a = box_forcing(scene);
    let (vg, ud) = bx.exact_forced(v0, &u0, a, t);
    let rs = |k: usize| if k == usize::MAX { rho } else { rho * eps[k] };
    let scale = box_velocity_scale(&bx, v0, &u0, a);
    out.push(ExactErrors {
            t,
            reference: "exact (matrix) solution of the linear drag ODE (with the [external] accelerations along x); densities relative to ρ0, velocities relative to the largest of |u0 − v0| and the terminal drifts |w*_k|".into(),
            fields: all_phase_errors(c, state, &rs, scale, |_| (rho, vg), |k, _| (rho * eps[k], ud[k])),
        });
    // The oracle is IDIC's own discrete solution; the explicit baseline has none here.
    let idic = scene.drag.method == crate::scene::DragMethod::Idic;
    if let Some(dt) = dt_fixed.filter(|_| idic) {
        if let Some(n) = whole_steps(t, dt) {
            let (vg, ud) = bx.implicit_euler_forced(v0, &u0, a, dt, n);
            out.push(ExactErrors {
                t,
                reference: format!(
                    "discrete IDIC oracle (I + τM)^-n with τ = {dt}, n = {n}; same normalisation"
                ),
                fields: all_phase_errors(
                    c,
                    state,
                    &rs,
                    scale,
                    |_| (rho, vg),
                    |k, _| (rho * eps[k], ud[k]),
                ),
            });
        }
    }
    out
}

/// The largest deviation of a phase's mass-weighted mean v_x from IDIC's discrete oracle (the
/// forced drag ODE stepped by τ = `dt`), relative to the box's velocity scale as in
/// [`exact_errors`]: the box's check on disordered particles, whose pressure noise moves each
/// particle but not the means. `None` when t is not a whole number of steps.
pub fn box_oracle_mean_deviation(scene: &Scene, b: &BoxCfg, state: &State, dt: f64) -> Option<f64> {
    let n = whole_steps(state.t, dt)?;
    let (bx, v0, u0) = dustybox_model(scene, b);
    let a = box_forcing(scene);
    let (vg, ud) = bx.implicit_euler_forced(v0, &u0, a, dt, n);
    let scale = box_velocity_scale(&bx, v0, &u0, a);
    let mean = |p: &Phase| {
        let m: f64 = p.m.iter().sum();
        p.m.iter().zip(&p.v).map(|(m, v)| m * v[0]).sum::<f64>() / m
    };
    let mut dev = (mean(&state.gas.ph) - vg).abs();
    for (d, u) in state.dust.iter().zip(&ud) {
        dev = dev.max((mean(d) - u).abs());
    }
    Some(dev / scale)
}

/// n when t is n fixed steps of `dt` (to 1e-9 relative): the discrete oracle's step count.
fn whole_steps(t: f64, dt: f64) -> Option<usize> {
    let n = (t / dt).round() as usize;
    (((n as f64) * dt - t).abs() <= 1e-9 * t.max(dt)).then_some(n)
}

/// The `[external]` accelerations along x (the box's errors compare v_x).
fn box_forcing(scene: &Scene) -> Forcing {
    Forcing {
        gas: scene.external.gas[0],
        dust: scene.external.dust[0],
    }
}

/// The box's velocity scale: the largest of |u0 − v0| and the terminal drifts |w*_k|.
fn box_velocity_scale(bx: &DustyBox, v0: f64, u0: &[f64], a: Forcing) -> f64 {
    u0.iter()
        .map(|u| (u - v0).abs())
        .chain(bx.terminal_drift(a).iter().map(|w| w.abs()))
        .fold(0.0, f64::max)
        .max(1e-300)
}

/// The dusty wave against the exact linear solution, in two metrics: this code's (normalised
/// by the amplitude) and Phantom's DUSTYWAVE one.
fn wave_errors(c: &dyn Comm, scene: &Scene, w: &WaveCfg, state: &State) -> Vec<ExactErrors> {
    let t = state.t;
    let mut out = Vec::new();
    let lw = dustywave::model(scene, w);
    let y = lw.evolve(&dustywave::initial_amplitudes(w, &lw), t);
    let (a, k) = (w.amplitude, lw.k);
    let cs = lw.sound_speed();
    let rho0 = lw.rho_g0;
    let rd0 = lw.rho_d0.clone();
    let rs = |kf: usize| a * if kf == usize::MAX { rho0 } else { rd0[kf] };
    let rho_g_ex = |x: [f64; 3]| dustywave::field(rho0, a, y.rho_g, k, x[0]);
    let rho_d_ex = |kf: usize, x: [f64; 3]| dustywave::field(rd0[kf], a, y.rho_d[kf], k, x[0]);
    // The summed density of a lattice sits a constant fraction off ρ0 (0.2 % on the 3D
    // close-packed lattice, 20 amplitudes): the errors are measured with each phase's
    // constant offset removed, and the offset is reported on its own line.
    let off_g = density_offset(c, &state.gas.ph, rho_g_ex);
    let off_d: Vec<f64> = state
        .dust
        .iter()
        .enumerate()
        .map(|(kf, d)| density_offset(c, d, |x| rho_d_ex(kf, x)))
        .collect();
    let mut fields = all_phase_errors(
        c,
        state,
        &rs,
        a * cs,
        |x| {
            (
                rho_g_ex(x) + off_g,
                dustywave::field(0.0, a, y.v_g, k, x[0]),
            )
        },
        |kf, x| {
            (
                rho_d_ex(kf, x) + off_d[kf],
                dustywave::field(0.0, a, y.v_d[kf], k, x[0]),
            )
        },
    );
    let offset = |name: String, off: f64, scale: f64| FieldError {
        field: name,
        norms: Norms {
            l1: off.abs() / scale,
            l2: off.abs() / scale,
            linf: off.abs() / scale,
        },
    };
    fields.push(offset("rho_g offset".into(), off_g, rs(usize::MAX)));
    for (kf, off) in off_d.iter().enumerate() {
        fields.push(offset(format!("rho_d{kf} offset"), *off, rs(kf)));
    }
    out.push(ExactErrors {
            t,
            reference: format!(
                "exact linear solution (matrix exponential), {}; ρ errors / (A ρ0) with each phase's constant lattice offset removed (the offset: `rho_* offset`), v errors / (A c_s)",
                match lw.gas {
                    WaveGas::Isothermal { .. } => "isothermal",
                    WaveGas::Adiabatic { .. } => "adiabatic",
                }
            ),
            fields,
        });
    // Phantom's DUSTYWAVE metric: L2 of v_x − exact over the particles of a phase,
    // divided by the rms of the exact v_x over the same particles.
    let mut fields = vec![relative_velocity_error(c, "v_g", &state.gas.ph, |x| {
        dustywave::field(0.0, a, y.v_g, k, x[0])
    })];
    for (kf, d) in state.dust.iter().enumerate() {
        fields.push(relative_velocity_error(c, &format!("u_d{kf}"), d, |x| {
            dustywave::field(0.0, a, y.v_d[kf], k, x[0])
        }));
    }
    // The density perturbation in the same metric: the phase's mean density removed (the
    // summed density of a lattice sits a fixed fraction off ρ0, far above the amplitude).
    fields.push(relative_perturbation_error(
        c,
        "rho_g",
        &state.gas.ph,
        |x| dustywave::field(0.0, a, y.rho_g, k, x[0]),
    ));
    for (kf, d) in state.dust.iter().enumerate() {
        fields.push(relative_perturbation_error(
            c,
            &format!("rho_d{kf}"),
            d,
            |x| dustywave::field(0.0, a, y.rho_d[kf], k, x[0]),
        ));
    }
    out.push(ExactErrors {
            t,
            reference: "exact linear solution; v_x errors relative to the rms of the exact v_x of the phase (Phantom's DUSTYWAVE metric: l2 = L2(v_x − v_exact)/rms(v_exact)); ρ: the perturbation ρ − mean ρ of the phase against the exact perturbation, in the same metric".into(),
            fields,
        });
    out
}

/// The dusty shock tube against the equilibrium (t_stop → 0) mixture Riemann solution.
fn shock_errors(c: &dyn Comm, scene: &Scene, s: &ShockCfg, state: &State) -> Vec<ExactErrors> {
    let t = state.t;
    let mut out = Vec::new();
    let eps_k: Vec<f64> = scene.fractions().iter().map(|f| f.eps).collect();
    let eps: f64 = eps_k.iter().sum();
    let x0 = 0.5 * s.length;
    let prim = |st: GasState| Prim {
        rho: st.rho,
        u: 0.0,
        p: st.p,
    };
    let sol = match scene.gas.eos {
        GasEos::Adiabatic { gamma } => DustyRiemann::ideal(prim(s.left), prim(s.right), eps, gamma),
        GasEos::Isothermal { cs } => DustyRiemann::isothermal(prim(s.left), prim(s.right), eps, cs),
        // Refused for the built-in problems (scene checks): no uniform state to solve from.
        GasEos::LocallyIsothermal { .. } => None,
    };
    if let Some(sol) = sol {
        out.push(ExactErrors {
            t,
            reference: "equilibrium (t_stop → 0) mixture Riemann solution; absolute errors".into(),
            fields: all_phase_errors(
                c,
                state,
                &|_| 1.0,
                1.0,
                |x| {
                    let (rg, _, v, _) = sol.sample(x[0], x0, t);
                    (rg, v)
                },
                |kf, x| {
                    let (rg, _, v, _) = sol.sample(x[0], x0, t);
                    (rg * eps_k[kf], v)
                },
            ),
        });
    }
    out
}

/// DUSTYSETTLE against the hydrostatic column with dust at its terminal velocity
/// ([`crate::exact::settle`]), over the particles in the middle 60% of the column: ρ_g and the
/// dust velocities relative to their exact values (u_dk: (u − u_term)/|u_term|), the gas
/// velocity in units of the largest terminal speed in the column.
fn settle_errors(c: &dyn Comm, scene: &Scene, cfg: &SettleCfg, state: &State) -> ExactErrors {
    let col = crate::setup::dustysettle::column(scene, cfg);
    let laws: Vec<_> = scene.fractions().iter().map(|f| f.law).collect();
    let h = crate::setup::dustysettle::smoothing(scene, cfg).0;
    // Away from the walls: the middle 60% of the column (sound from the walls needs 0.2 L/c_s
    // to get there) and at least 4h from either end.
    let (lo, hi) = (
        (0.2 * cfg.height).max(4.0 * h),
        (0.8 * cfg.height).min(cfg.height - 4.0 * h),
    );
    let inside = |x: f64| x > lo && x < hi;
    let mut fields = Vec::new();
    let g = &state.gas.ph;
    let idx: Vec<usize> = (0..g.len())
        .filter(|&i| !g.is_fixed(i) && inside(g.x[i][0]))
        .collect();
    let m: Vec<f64> = idx.iter().map(|&i| g.m[i]).collect();
    let rho: Vec<f64> = idx
        .iter()
        .map(|&i| g.rho[i] / col.rho_gas(g.x[i][0]) - 1.0)
        .collect();
    let u_max = (0..laws.len())
        .map(|k| col.u_terminal(k, laws[k], cfg.height).abs())
        .fold(f64::MIN_POSITIVE, f64::max);
    let v: Vec<f64> = idx.iter().map(|&i| g.v[i][0] / u_max).collect();
    fields.push(FieldError {
        field: "rho_g".into(),
        norms: Norms::over(c, &rho, &m),
    });
    fields.push(FieldError {
        field: "v_g".into(),
        norms: Norms::over(c, &v, &m),
    });
    // The gas velocity at a point by linear interpolation between the gas particles around it
    // (1D): the drift u − v is what the drag sets, whatever small motion the gas column has.
    let mut line: Vec<(f64, f64)> = (0..g.len()).map(|i| (g.x[i][0], g.v[i][0])).collect();
    line.sort_by(|a, b| a.0.total_cmp(&b.0));
    let v_gas_at = |x: f64| {
        let i = line.partition_point(|p| p.0 <= x).clamp(1, line.len() - 1);
        let ((x0, v0), (x1, v1)) = (line[i - 1], line[i]);
        v0 + (v1 - v0) * (x - x0) / (x1 - x0)
    };
    for (k, ph) in state.dust.iter().enumerate() {
        let idx: Vec<usize> = (0..ph.len()).filter(|&j| inside(ph.x[j][0])).collect();
        let m: Vec<f64> = idx.iter().map(|&j| ph.m[j]).collect();
        let ex: Vec<f64> = idx
            .iter()
            .map(|&j| col.u_terminal(k, laws[k], ph.x[j][0]))
            .collect();
        let u: Vec<f64> = idx
            .iter()
            .zip(&ex)
            .map(|(&j, e)| (ph.v[j][0] - e) / e.abs())
            .collect();
        let w: Vec<f64> = idx
            .iter()
            .zip(&ex)
            .map(|(&j, e)| (ph.v[j][0] - v_gas_at(ph.x[j][0]) - e) / e.abs())
            .collect();
        fields.push(FieldError {
            field: format!("u_d{k}"),
            norms: Norms::over(c, &u, &m),
        });
        fields.push(FieldError {
            field: format!("drift_d{k}"),
            norms: Norms::over(c, &w, &m),
        });
    }
    ExactErrors {
        t: state.t,
        reference: "hydrostatic isothermal column, dust at its terminal velocity −g t_k(x); relative errors over the middle 60% of the column (and ≥ 4h from the walls): u_dk = (u − u_term)/|u_term|, drift_dk = (u − v_gas(x) − u_term)/|u_term| with v_gas interpolated; v_g in units of the largest terminal speed".into(),
        fields,
    }
}

/// Zones of the 1D reference: 2000 is converged to ~3e-5 in ρ (far below SPH errors).
const BALL_REFERENCE_ZONES: usize = 2000;

/// The 1D equilibrium reference of a ball scene at time t, in the scene's geometry (a slab in
/// 1D, a disc in 2D, a ball in 3D); None for other scenes, and for isothermal gas (the γ → 1
/// limit is outside the reference).
pub fn ball_reference(scene: &Scene, t: f64) -> Option<radial::RadialCurve> {
    let b = scene.ball()?;
    let GasEos::Adiabatic { gamma } = scene.gas.eos else {
        return None;
    };
    let eps: f64 = scene.fractions().iter().map(|f| f.eps).sum();
    let prob = spherical::BallProblem {
        rho_gas: b.background.rho,
        rho_dust: eps * b.background.rho,
        p: b.background.p,
        gamma,
        radius: b.radius,
    };
    Some(spherical::equilibrium_ball_in(
        &prob,
        scene.dim(),
        t,
        BALL_REFERENCE_ZONES,
    ))
}

/// The ball against the 1D spherical equilibrium reference (method.md §6.1): L1/L2/L∞ of ρ_g,
/// p, radial v_g, ρ_d, radial u_d inside r < R0 − 2h (away from the kernel-truncated edge) and
/// over the whole ball. Absolute errors (the initial state is ρ_g = 1, p = 1 in the seed).
fn ball_reference_errors(
    c: &dyn Comm,
    scene: &Scene,
    b: &BallCfg,
    state: &State,
) -> Vec<ExactErrors> {
    let Some(reference) = ball_reference(scene, state.t) else {
        return Vec::new();
    };
    let h = crate::setup::smoothing_length(scene, 1.0 / scene.sph.n as f64);
    let r_in = b.radius - 2.0 * h;
    let radius = |x: &[f64; 3]| (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
    let radial = |x: &[f64; 3], v: &[f64; 3]| {
        let r = radius(x);
        if r > 0.0 {
            (x[0] * v[0] + x[1] * v[1] + x[2] * v[2]) / r
        } else {
            0.0
        }
    };
    let mut out = Vec::new();
    for (label, r_max) in [
        (format!("r < R0 − 2h = {r_in}"), r_in),
        ("the whole ball".to_string(), f64::INFINITY),
    ] {
        let mut fields = Vec::new();
        let g = &state.gas;
        let sel: Vec<usize> = (0..g.ph.len())
            .filter(|&i| radius(&g.ph.x[i]) < r_max)
            .collect();
        // A region without particles (a ball under two smoothing lengths: R0 − 2h ≤ 0) has no
        // error to report, rather than a zero one.
        let mut n = [sel.len() as u64];
        c.sum_u64(&mut n);
        if n[0] == 0 {
            out.push(ExactErrors {
                t: state.t,
                reference: format!("{label}: no particles, nothing compared"),
                fields,
            });
            continue;
        }
        let m: Vec<f64> = sel.iter().map(|&i| g.ph.m[i]).collect();
        let refs: Vec<_> = sel
            .iter()
            .map(|&i| reference.sample(radius(&g.ph.x[i])))
            .collect();
        let field = |name: &str, err: Vec<f64>, m: &[f64]| FieldError {
            field: name.into(),
            norms: Norms::over(c, &err, m),
        };
        fields.push(field(
            "rho_g",
            sel.iter()
                .zip(&refs)
                .map(|(&i, r)| g.ph.rho[i] - r.rho_g)
                .collect(),
            &m,
        ));
        fields.push(field(
            "p",
            sel.iter().zip(&refs).map(|(&i, r)| g.p[i] - r.p).collect(),
            &m,
        ));
        fields.push(field(
            "v_g",
            sel.iter()
                .zip(&refs)
                .map(|(&i, r)| radial(&g.ph.x[i], &g.ph.v[i]) - r.v)
                .collect(),
            &m,
        ));
        // The reference knows the total dust density: density is compared for a single
        // fraction; velocities (shared in the equilibrium limit) for every fraction.
        let mut dm = Vec::new();
        let (mut drho, mut du) = (Vec::new(), Vec::new());
        for d in &state.dust {
            for j in (0..d.len()).filter(|&j| radius(&d.x[j]) < r_max) {
                let r = reference.sample(radius(&d.x[j]));
                dm.push(d.m[j]);
                drho.push(d.rho[j] - r.rho_d);
                du.push(radial(&d.x[j], &d.v[j]) - r.u);
            }
        }
        if state.dust.len() == 1 {
            fields.push(field("rho_d0", drho, &dm));
            fields.push(field("u_d0", du, &dm));
        } else if !state.dust.is_empty() {
            fields.push(field("u_d", du, &dm));
        }
        out.push(ExactErrors {
            t: state.t,
            reference: format!(
                "1D {} Lagrangian equilibrium (t_stop → 0) solution, {BALL_REFERENCE_ZONES} zones; {label}; absolute errors, radial velocities",
                spherical::geometry_name(scene.dim())
            ),
            fields,
        });
    }
    out
}
