//! The stiffness and extremes matrix: IDIC on cases where an explicit drag would need a
//! million steps or break (τ/t_stop up to 1e6, dust-to-gas ratios 1e-3 … 100, up to 16
//! fractions with t_stop over six decades, cells with dust only, gas only or one particle,
//! particles leaving the initial domain, zero and huge relative velocities).
//!
//! Every case must stay finite, conserve total momentum to ≤ 1e-12 relative to max_t Σ m|v|,
//! keep every density positive, and, for waves, carry the mode with the exact amplitude (no
//! over-damping), for boxes reproduce IDIC's discrete solution. `dustsph stiffness` writes the
//! table (`docs/stiffness.md`); `tests/stiffness.rs` runs the reduced grid in CI and the full grid
//! on demand.
use crate::analysis;
use crate::exact::complex::C;
use crate::particles::{Gas, Phase, State};
use crate::scene::{self, DragMethod, Lattice, PositionUpdate, Scene};
use crate::setup::{self, dustywave};
use crate::sim::Simulation;
use crate::step::backend::{Backend, DeviceChoice};
use crate::step::{Physics, StepError};
use dustsph_device::drag::StoppingLaw;
use dustsph_device::eos::Eos;
use std::fmt::Write as _;
use std::path::Path;
use std::path::PathBuf;

const WAVE: &str = include_str!("../../configs/dustywave.toml");
const BOX: &str = include_str!("../../configs/dustybox.toml");
const BALL: &str = include_str!("../../configs/dusty_ball.toml");
const PHANTOM_WAVE: &str = include_str!("../../configs/dustywave_phantom.toml");

/// Largest allowed max_t |P(t) − P(0)| / S, with S = max_t Σ m|v|, or Σ m c_s (c_s the largest
/// initial gas sound speed) when everything is at rest to round-off (max_t Σ m|v| < 1e-8 Σ m c_s).
pub const MOMENTUM_TOL: f64 = 1e-12;
/// Waves: | |ρ̂_num| − |ρ̂_exact| | ≤ this × max(|ρ̂_exact|, 0.1) at t_end (mode amplitudes in units
/// of the initial amplitude A). IDIC's own first-order error at n = 64, τ = 0.005 is 1–3 %
/// (measured); an over-damped equilibrium mode loses far more.
pub const WAVE_AMPLITUDE_TOL: f64 = 0.05;
/// Boxes: L∞ of every velocity against IDIC's discrete solution (I + τM)⁻ⁿ, relative to the
/// largest initial slip (or to the velocity scale when there is no slip).
pub const BOX_ORACLE_TOL: f64 = 1e-10;
/// Disordered boxes (`jitter`, glass): the pressure noise of the arrangement moves every
/// particle, so each phase's mass-weighted mean velocity is held to the oracle instead, to this
/// tolerance on the same scale (measured: ≤ 2e-4 on the group's cases).
pub const DISORDERED_MEAN_TOL: f64 = 1e-3;

/// Wave set-up shared by the wave cases: n = 64 per wavelength and phase, h = 4Δx, τ = 0.005.
const WAVE_DT: f64 = 0.005;

#[derive(Debug, Clone)]
enum Kind {
    /// A scene from configs/ with overrides; `wave` enables the amplitude check.
    Scene {
        base: &'static str,
        sets: Vec<String>,
    },
    /// 1D slab of gas expanding into vacuum, a dust slab half outside it (dust-only cells) and
    /// single dust particles (one-particle cells).
    Slab,
}

/// One row of the matrix.
#[derive(Debug, Clone)]
pub struct Case {
    pub group: &'static str,
    pub name: String,
    /// Part of the reduced (CI) grid.
    pub reduced: bool,
    kind: Kind,
}

fn fractions(eps: &[f64], t_stop: &[f64]) -> String {
    let f: Vec<String> = eps
        .iter()
        .zip(t_stop)
        .map(|(e, t)| format!("{{eps={e:e}, t_stop={t:e}}}"))
        .collect();
    format!("dust.fractions=[{}]", f.join(", "))
}

fn wave(eps: &[f64], t_stop: &[f64]) -> Kind {
    Kind::Scene {
        base: WAVE,
        sets: vec![
            "time.cfl=".into(),
            format!("time.dt={WAVE_DT}"),
            "time.output_dt=".into(),
            "sph.n=64".into(),
            "dustywave.mode=\"sine\"".into(),
            fractions(eps, t_stop),
        ],
    }
}

fn dusty_box(eps: &[f64], t_stop: &[f64], v0: f64, u0: f64) -> Kind {
    let u: Vec<String> = eps.iter().map(|_| format!("{u0:e}")).collect();
    Kind::Scene {
        base: BOX,
        sets: vec![
            "time.t_end=0.5".into(),
            "time.output_dt=".into(),
            fractions(eps, t_stop),
            format!("dustybox.v_gas={v0:e}"),
            format!("dustybox.u_dust=[{}]", u.join(", ")),
        ],
    }
}

/// t_stop spanning six decades, 1e-7 … 1e-1, log-spaced (one fraction: 1e-4).
fn six_decades(n: usize) -> Vec<f64> {
    if n == 1 {
        return vec![1e-4];
    }
    (0..n)
        .map(|k| 10f64.powf(-7.0 + 6.0 * k as f64 / (n - 1) as f64))
        .collect()
}

/// The full matrix (`reduced` marks the CI subset).
pub fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    let mut add = |group, name: String, reduced, kind| {
        v.push(Case {
            group,
            name,
            reduced,
            kind,
        })
    };
    for r in [1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6] {
        add(
            "τ/t_stop",
            format!("wave N=1, ε=1, τ/t_stop={}", scene::num(r)),
            [1e-3, 1.0, 1e6].contains(&r),
            wave(&[1.0], &[WAVE_DT / r]),
        );
    }
    for e in [1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2] {
        for r in [1.0, 1e4] {
            add(
                "dust-to-gas ratio",
                format!("wave N=1, ε={}, τ/t_stop={}", scene::num(e), scene::num(r)),
                (e == 1e-3 || e == 1e2) && r == 1e4,
                wave(&[e], &[WAVE_DT / r]),
            );
        }
    }
    for n in [1usize, 2, 4, 8, 16] {
        let t = six_decades(n);
        let eps = vec![1.0 / n as f64; n];
        let span = if n == 1 {
            "t_stop=1e-4".to_string()
        } else {
            "t_stop 1e-7…1e-1".to_string()
        };
        add(
            "fractions",
            format!("wave N={n}, Σε=1, {span}"),
            n == 16,
            wave(&eps, &t),
        );
        add(
            "fractions",
            format!("box N={n}, Σε=1, {span}, slip 1"),
            n == 16,
            dusty_box(&eps, &t, 0.0, 1.0),
        );
    }
    add(
        "fractions",
        "box N=16, Σε=100, t_stop 1e-7…1e-1, slip 1".into(),
        false,
        dusty_box(&[100.0 / 16.0; 16], &six_decades(16), 0.0, 1.0),
    );
    add(
        "fractions",
        "box 2D N=16, Σε=1, t_stop 1e-7…1e-1, slip 1".into(),
        false,
        {
            let mut k = dusty_box(&[1.0 / 16.0; 16], &six_decades(16), 0.0, 1.0);
            if let Kind::Scene { sets, .. } = &mut k {
                sets.extend(["scene.dim=2".to_string(), "sph.n=32".to_string()]);
            }
            k
        },
    );
    add(
        "τ/t_stop",
        "wave N=1, ε=1, t_stop=1e-9 (τ/t_stop ≈ 5e6), n=256, CFL 0.3".into(),
        false,
        Kind::Scene {
            base: WAVE,
            sets: vec![
                "time.output_dt=".into(),
                "dustywave.mode=\"sine\"".into(),
                fractions(&[1.0], &[1e-9]),
            ],
        },
    );
    add(
        "velocities",
        "box N=1, ε=1, t_stop=1e-6, all at rest".into(),
        true,
        dusty_box(&[1.0], &[1e-6], 0.0, 0.0),
    );
    add(
        "velocities",
        "box N=1, ε=1, t_stop=1e-6, no slip, v=u=1e3".into(),
        false,
        dusty_box(&[1.0], &[1e-6], 1e3, 1e3),
    );
    add(
        "velocities",
        "box N=1, ε=1, t_stop=1e-6, slip 1e6".into(),
        true,
        dusty_box(&[1.0], &[1e-6], 0.0, 1e6),
    );
    add(
        "velocities",
        "box N=4, ε=100, t_stop=1e-8, slip 2e8 (v=−1e8, u=1e8)".into(),
        false,
        dusty_box(&[25.0; 4], &[1e-8; 4], -1e8, 1e8),
    );
    // Dust off the gas at ≈57 neighbours (3D, hfact 1.2), with the kernel coupling
    // (docs/method.md §K): the regime the nearest cell cannot couple.
    let placed = |mut k: Kind, shift: &str| {
        if let Kind::Scene { sets, .. } = &mut k {
            sets.extend([
                "scene.dim=3".to_string(),
                "sph.n=16".to_string(),
                "sph.hfact=1.2".to_string(),
                format!("dustybox.dust_shift={shift}"),
                "idic.coupling=\"kernel\"".to_string(),
            ]);
        }
        k
    };
    add(
        "placement (3D, ≈57 nb)",
        "box 3D N=4, Σε=1, t_stop 1e-8…1e-5 (τ/t_stop ≤ 1e6), dust offset 0.5 Δ, kernel coupling"
            .into(),
        true,
        placed(
            dusty_box(&[0.25; 4], &[1e-8, 1e-7, 1e-6, 1e-5], 0.0, 1.0),
            "0.5",
        ),
    );
    add(
        "placement (3D, ≈57 nb)",
        "box 3D N=16, Σε=1, t_stop 1e-7…1e-1, dust offset 0.25 Δ, kernel coupling".into(),
        false,
        placed(
            dusty_box(&[1.0 / 16.0; 16], &six_decades(16), 0.0, 1.0),
            "0.25",
        ),
    );
    add(
        "placement (3D, ≈57 nb)",
        "box 3D N=1, ε=100, t_stop=1e-8, slip 1e6, dust offset 0.5 Δ, kernel coupling".into(),
        false,
        placed(dusty_box(&[100.0], &[1e-8], 0.0, 1e6), "0.5"),
    );
    // The same off any lattice: a relaxed glass and jittered lattices (docs/method.md §K,
    // "Disordered particles"), every phase drawn on its own.
    let disordered = |k: Kind, arrangement: &str| {
        let mut k = placed(k, "0");
        if let Kind::Scene { sets, .. } = &mut k {
            sets.push(arrangement.to_string());
        }
        k
    };
    add(
        "disordered (3D, ≈57 nb)",
        "box 3D N=4, Σε=1, t_stop 1e-8…1e-5 (τ/t_stop ≤ 1e6), glass, kernel coupling".into(),
        true,
        disordered(
            dusty_box(&[0.25; 4], &[1e-8, 1e-7, 1e-6, 1e-5], 0.0, 1.0),
            "dustybox.lattice=\"glass\"",
        ),
    );
    add(
        "disordered (3D, ≈57 nb)",
        "box 3D N=16, Σε=1, t_stop 1e-7…1e-1, jitter 0.3, kernel coupling".into(),
        false,
        disordered(
            dusty_box(&[1.0 / 16.0; 16], &six_decades(16), 0.0, 1.0),
            "dustybox.jitter=0.3",
        ),
    );
    add(
        "disordered (3D, ≈57 nb)",
        "box 3D N=16, Σε=100, t_stop 1e-7…1e-1, glass, kernel coupling".into(),
        false,
        disordered(
            dusty_box(&[100.0 / 16.0; 16], &six_decades(16), 0.0, 1.0),
            "dustybox.lattice=\"glass\"",
        ),
    );
    add(
        "disordered (3D, ≈57 nb)",
        "box 3D N=1, ε=100, t_stop=1e-8, slip 1e6, jitter 0.2, kernel coupling".into(),
        false,
        disordered(
            dusty_box(&[100.0], &[1e-8], 0.0, 1e6),
            "dustybox.jitter=0.2",
        ),
    );
    for k in ["1e5", "1e7"] {
        add(
            "placement (3D, ≈57 nb)",
            format!(
                "Phantom wave 3D n=32, K={k} (τ/t_stop ≈ {}), dust offset 0.5 Δ, kernel coupling",
                if k == "1e5" { "1e3" } else { "1e5" }
            ),
            false,
            Kind::Scene {
                base: PHANTOM_WAVE,
                sets: vec![
                    "sph.n=32".into(),
                    "time.output_dt=".into(),
                    "dustywave.dust_shift=0.5".into(),
                    "idic.coupling=\"kernel\"".into(),
                    format!("dust.fractions.0.k={k}"),
                ],
            },
        );
    }
    add(
        "cells",
        "slab into vacuum: dust-only, gas-only and one-particle cells; particles leave the initial domain".into(),
        true,
        Kind::Slab,
    );
    add(
        "cells",
        "3D ball into vacuum (n=8, h=2Δ): Epstein t_stop, particles leave the initial domain"
            .into(),
        false,
        Kind::Scene {
            base: BALL,
            sets: vec![
                "sph.n=8".into(),
                "sph.h=".into(),
                "sph.hfact=2.0".into(),
                "time.output_dt=".into(),
            ],
        },
    );
    v
}

/// What a case measured.
#[derive(Debug, Clone)]
pub struct CaseReport {
    pub group: &'static str,
    pub name: String,
    pub steps: u64,
    /// Steps the explicit baseline would need (its limit at t = 0).
    pub explicit_steps: f64,
    /// Largest τ/t_k* of the first step (the stiffness actually met).
    pub max_beta: f64,
    pub momentum_drift: f64,
    pub min_density: f64,
    /// Waves: (|ρ̂_g| numerical, exact) / A at t_end.
    pub wave_amplitude: Option<(f64, f64)>,
    /// Boxes: L∞ velocity error against IDIC's discrete solution (relative).
    pub box_oracle: Option<f64>,
    /// Largest L1 error against the exact solution at t_end (any field), where there is one.
    pub l1_max: Option<f64>,
    /// Every check that failed (empty: passed).
    pub failures: Vec<String>,
}

impl CaseReport {
    pub fn passed(&self) -> bool {
        self.failures.is_empty()
    }
}

/// The slab case: physics and initial state.
fn slab() -> (Physics, State, f64, f64) {
    let n = 100;
    let dx = 1.0 / n as f64;
    let lattice = |lo: f64, count: usize| -> Vec<[f64; 3]> {
        (0..count)
            .map(|i| [lo + (i as f64 + 0.5) * dx, 0.0, 0.0])
            .collect()
    };
    let phase = |x: Vec<[f64; 3]>, m: f64, u: f64, id0: u64| {
        let k = x.len();
        Phase {
            v: vec![[u, 0.0, 0.0]; k],
            m: vec![m; k],
            rho: vec![1.0; k],
            id: (id0..id0 + k as u64).collect(),
            fixed: None,
            x,
        }
    };
    let gas = phase(lattice(-0.5, n), dx, 0.0, 0);
    // Half of this slab lies outside the gas: dust-only cells; it moves outwards.
    let dust0 = phase(lattice(0.0, n), dx, 0.5, 1000);
    // Seven lone particles 0.15 apart (cells are 0.01): one particle per cell, moving left.
    let lone: Vec<[f64; 3]> = (0..7)
        .map(|i| [-0.45 + 0.15 * i as f64, 0.0, 0.0])
        .collect();
    let dust1 = phase(lone, 0.01 * dx, -2.0, 2000);
    let ng = gas.len();
    let st = State {
        t: 0.0,
        step: 0,
        gas: Gas {
            ph: gas,
            p: vec![0.0; ng],
            c: vec![0.0; ng],
            e: None,
            h: None,
            omega: None,
            next_forces: None,
        },
        dust: vec![dust0, dust1],
    };
    let h = 2.0 * dx;
    let phys = Physics::open_1d(
        h,
        Eos::Isothermal { cs: 1.0 },
        vec![
            StoppingLaw::ConstantTime { t_stop: 1e-3 },
            StoppingLaw::ConstantTime { t_stop: 1e-6 },
        ],
    );
    (phys, st, 1e-3, 0.5)
}

/// Complex Fourier amplitude of ρ − ρ0 at wavenumber k over a periodic phase.
fn density_mode(ph: &Phase, rho0: f64, k: f64) -> C {
    let n = ph.len() as f64;
    let (mut re, mut im) = (0.0, 0.0);
    for (x, r) in ph.x.iter().zip(&ph.rho) {
        re += 2.0 / n * (r - rho0) * (k * x[0]).cos();
        im -= 2.0 / n * (r - rho0) * (k * x[0]).sin();
    }
    C::new(re, im)
}

/// Run one case.
/// One case of the matrix: set up, run to the end with the momentum checked every step,
/// then the final state and, for scenes with one, the exact solution.
pub fn run_case(case: &Case) -> CaseReport {
    let mut rep = CaseReport {
        group: case.group,
        name: case.name.clone(),
        steps: 0,
        explicit_steps: f64::NAN,
        max_beta: f64::NAN,
        momentum_drift: f64::NAN,
        min_density: f64::NAN,
        wave_amplitude: None,
        box_oracle: None,
        l1_max: None,
        failures: Vec::new(),
    };
    let Some((phys, state, time, scene)) = prepare_case(case, &mut rep) else {
        return rep;
    };
    let (explicit_limit, t_min) = explicit_reference(&phys, &state);
    let Some(mut sim) = run_checked(&mut rep, phys, state, &time, (explicit_limit, t_min)) else {
        return rep;
    };
    if check_final_state(&mut rep, &mut sim).is_none() {
        return rep;
    }
    if let Some(sc) = scene {
        check_exact(&mut rep, &sc, &sim.state);
    }
    rep
}

/// The case's physics, initial state, time settings and (for scene cases) scene; a scene or
/// set-up that fails is recorded in `rep`.
fn prepare_case(
    case: &Case,
    rep: &mut CaseReport,
) -> Option<(Physics, State, crate::scene::Time, Option<Scene>)> {
    let fixed = |t_end: f64, dt: f64| crate::scene::Time {
        t_end,
        step: crate::scene::StepRule::Fixed { dt },
        output: crate::scene::OutputSchedule::EndOnly,
        position_update: PositionUpdate::New,
        integrator: crate::scene::Integrator::FirstOrder,
    };
    Some(match &case.kind {
        Kind::Slab => {
            let (p, s, dt, t) = slab();
            (p, s, fixed(t, dt), None)
        }
        Kind::Scene { base, sets } => {
            let sc = match scene::parse(base, Path::new("stiffness case"), sets) {
                Ok(s) => s,
                Err(e) => {
                    rep.failures.push(format!("scene: {e}"));
                    return None;
                }
            };
            let su = match setup::build(&sc) {
                Ok(s) => s,
                Err(e) => {
                    rep.failures.push(format!("set-up: {e}"));
                    return None;
                }
            };
            let p = Physics::from_scene(&sc, su.h, su.domain);
            let time = sc.time.clone();
            (p, su.state, time, Some(sc))
        }
    })
}

/// The explicit baseline's limit on the initial state, and the smallest cell stopping time.
fn explicit_reference(phys: &Physics, state: &State) -> (f64, f64) {
    let mut st = state.clone();
    let mut p = phys.clone();
    p.drag = DragMethod::Explicit;
    let limits = |st: &mut crate::particles::State| -> Result<(f64, f64), StepError> {
        let mut e = Backend::new(DeviceChoice::Cpu, p, st)?;
        let lim = e.drag_dt_limit()?;
        let ts = e.dust_stopping_times(st)?;
        let t_min = ts.iter().flatten().copied().fold(f64::INFINITY, f64::min);
        Ok((lim, t_min))
    };
    limits(&mut st).unwrap_or((f64::NAN, f64::NAN))
}

/// Run to the end with the run's diagnostics (the momentum drift after every step); a step
/// that fails is recorded in `rep`.
fn run_checked(
    rep: &mut CaseReport,
    phys: Physics,
    state: State,
    time: &crate::scene::Time,
    (explicit_limit, t_min): (f64, f64),
) -> Option<Simulation> {
    let t_end = time.t_end;
    let mut sim = match Simulation::local(phys, time, state, DeviceChoice::Cpu) {
        Ok((s, _)) => s,
        Err(e) => {
            rep.failures.push(format!("initial state: {e}"));
            return None;
        }
    };
    let ran = sim.run(t_end, &mut [], None);
    let d = &sim.diagnostics;
    rep.steps = d.steps;
    if let Some(tau) = d.first_dt_free {
        rep.explicit_steps = (t_end / tau.min(explicit_limit)).ceil();
        rep.max_beta = tau / t_min;
    }
    if let Err(e) = ran {
        rep.failures.push(format!("not finite or density ≤ 0: {e}"));
        return None;
    }
    let drift = d.momentum_drift();
    rep.momentum_drift = drift;
    if drift.is_nan() || drift > MOMENTUM_TOL {
        rep.failures
            .push(format!("momentum drift {drift:.2e} > {MOMENTUM_TOL:e}"));
    }
    Some(sim)
}

/// Densities positive, positions and velocities finite at the end.
fn check_final_state(rep: &mut CaseReport, sim: &mut Simulation) -> Option<()> {
    if let Err(e) = sim.refresh_dust_density() {
        rep.failures.push(format!("dust density: {e}"));
        return None;
    }
    let state = &sim.state;
    let min_rho = state
        .dust
        .iter()
        .chain(std::iter::once(&state.gas.ph))
        .flat_map(|ph| ph.rho.iter().copied())
        .fold(f64::INFINITY, f64::min);
    rep.min_density = min_rho;
    if !(min_rho > 0.0 && min_rho.is_finite()) {
        rep.failures.push(format!("smallest density {min_rho:e}"));
    }
    let all_finite = std::iter::once(&state.gas.ph).chain(&state.dust).all(|ph| {
        ph.x.iter()
            .chain(&ph.v)
            .all(|a| a.iter().all(|v| v.is_finite()))
    });
    if !all_finite {
        rep.failures.push("non-finite position or velocity".into());
    }
    Some(())
}

/// Against the exact solution: the wave's amplitude, the box's discrete IDIC oracle.
fn check_exact(rep: &mut CaseReport, sc: &Scene, state: &State) {
    let errs = analysis::exact_errors(sc, state, sc.time.fixed_dt());
    // Box velocity norms are relative to the slip (to 1e-300 without slip): rescale those to
    // the largest of slip, velocity scale and 1, as for the oracle check below.
    let vel_factor = match &sc.problem {
        crate::scene::ProblemCfg::Dustybox(b) => box_velocity_factor(b),
        _ => 1.0,
    };
    rep.l1_max = errs.first().map(|e| {
        e.fields
            .iter()
            .map(|f| {
                let velocity = f.field.starts_with('v') || f.field.starts_with('u');
                f.norms.l1 * if velocity { vel_factor } else { 1.0 }
            })
            .fold(0.0, f64::max)
    });
    match &sc.problem {
        crate::scene::ProblemCfg::Dustywave(w) => {
            let lw = dustywave::model(sc, w);
            let a = w.amplitude;
            let y = lw.evolve(&dustywave::initial_amplitudes(w, &lw), state.t);
            let exact = y.rho_g.norm();
            let num = density_mode(&state.gas.ph, lw.rho_g0, lw.k).norm() / a;
            rep.wave_amplitude = Some((num, exact));
            let dev = (num - exact).abs();
            if dev.is_nan() || dev > WAVE_AMPLITUDE_TOL * exact.max(0.1) {
                rep.failures.push(format!(
                    "wave amplitude {num:.4} against exact {exact:.4} (relative tolerance {WAVE_AMPLITUDE_TOL})"
                ));
            }
        }
        crate::scene::ProblemCfg::Dustybox(b) if b.jitter > 0.0 || b.lattice == Lattice::Glass => {
            // Disordered: each phase's mean velocity against the discrete oracle.
            let rel = sc
                .time
                .fixed_dt()
                .and_then(|dt| analysis::box_oracle_mean_deviation(sc, b, state, dt))
                .map(|e| e * box_velocity_factor(b));
            judge_box(rep, rel, DISORDERED_MEAN_TOL, "phase mean velocities");
        }
        crate::scene::ProblemCfg::Dustybox(b) => {
            // The second comparison is IDIC's discrete oracle; velocities relative to the slip.
            let e = errs.get(1).map(|o| {
                o.fields
                    .iter()
                    .filter(|f| f.field.starts_with('v') || f.field.starts_with('u'))
                    .map(|f| f.norms.linf)
                    .fold(0.0, f64::max)
            });
            let rel = e.map(|e| e * box_velocity_factor(b));
            judge_box(rep, rel, BOX_ORACLE_TOL, "velocities");
        }
        _ => {}
    }
}

/// A box's distance `rel` from IDIC's discrete solution against `tol` (`what` differs).
fn judge_box(rep: &mut CaseReport, rel: Option<f64>, tol: f64, what: &str) {
    rep.box_oracle = rel;
    match rel {
        Some(r) if r <= tol => {}
        Some(r) => rep.failures.push(format!(
            "{what} differ from IDIC's discrete solution by {r:.2e} > {tol:e}"
        )),
        None => rep.failures.push("no discrete oracle".into()),
    }
}

/// The box's velocity norms are relative to the slip (to 1e-300 when there is none): the
/// factor that makes them absolute, then relative to the largest of slip, velocity scale and 1.
fn box_velocity_factor(b: &crate::scene::BoxCfg) -> f64 {
    let slip = b
        .u_dust
        .iter()
        .map(|u| (u - b.v_gas).abs())
        .fold(0.0, f64::max);
    let vscale = b.u_dust.iter().fold(b.v_gas.abs(), |m, u| m.max(u.abs()));
    (if slip > 0.0 { slip } else { 1e-300 }) / slip.max(vscale).max(1.0)
}

/// The Markdown report of a run of the matrix.
pub fn markdown(reports: &[CaseReport], full: bool, command: &str) -> String {
    let mut s = String::new();
    let passed = reports.iter().filter(|r| r.passed()).count();
    let _ = writeln!(s, "# Stiffness and extremes matrix\n");
    let _ = writeln!(
        s,
        "Generated by `{command}` (dustsph {}, git {}); {} grid: **{passed} of {} cases pass**.\n",
        env!("CARGO_PKG_VERSION"),
        env!("DUSTSPH_GIT"),
        if full { "full" } else { "reduced (CI)" },
        reports.len()
    );
    let _ = writeln!(
        s,
        "IDIC, CPU, f64. Waves: periodic 1D sine wave (amplitude 1e-4), isothermal c_s = 1, n = 64 \
         particles per wavelength and phase, h = 4Δx, fixed τ = {WAVE_DT}, t = 1. Boxes: \
         `configs/dustybox.toml` (n = 64, τ = 0.01) to t = 0.5. Slab: gas on [−0.5, 0.5] expanding \
         into vacuum, a dust slab on [0, 1] moving out at 0.5 (t_stop = 1e-3; dust-only cells), seven \
         lone dust particles 0.15 apart moving at −2 (t_stop = 1e-6; one-particle cells), τ = 1e-3, \
         t = 0.5. Ball: `configs/dusty_ball.toml` at n = 8, h = 2Δ. Placement: the box in 3D at \
         n = 16 per axis, hfact 1.2 (≈57 neighbours), every dust lattice offset from the gas lattice \
         along each axis, and Phantom's 3D wave (`configs/dustywave_phantom.toml`, n = 32, \
         adiabatic, variable h, IAD, leapfrog) with its dust offset by half a spacing; all with the \
         kernel coupling (`idic.coupling = \"kernel\"`, docs/method.md §K). Disordered: the same 3D \
         box with the dust on no lattice: each phase a relaxed glass, or the lattices jittered by up \
         to ±0.2 or ±0.3 spacings per axis, every phase drawn on its own.\n"
    );
    let _ = writeln!(
        s,
        "Checks: every position, velocity and density finite, densities > 0; total momentum drift \
         max_t |P(t) − P(0)| / S ≤ {MOMENTUM_TOL:e} with S = max_t Σ m|v| (Σ m c_s for a system at rest, \
         where Σ m|v| is round-off: < 1e-8 Σ m c_s); waves: |ρ̂_g| at t_end within \
         {} % of the exact linear solution (relative to max(|ρ̂_exact|, 0.1 A)) \
         (matrix exponential, all N fractions; over-damping shows as a smaller amplitude); boxes: \
         every velocity equal to IDIC's discrete solution (I + τM)⁻ⁿ to {BOX_ORACLE_TOL:e} relative \
         to the initial slip; disordered boxes (a glass or jitter, whose pressure noise moves every \
         particle): each phase's mass-weighted mean velocity to {DISORDERED_MEAN_TOL:e}. *max τ/t* is the largest τ/t_k* met in the first step; *explicit steps* is what \
         the explicit baseline (τ ≤ 0.9/Λ) would need for the same run. *L1 max* is the largest L1 \
         error over all fields against the exact solution (wave: /(A ρ0), /(A c_s); box: / slip).\n",
        WAVE_AMPLITUDE_TOL * 100.0
    );
    let _ = writeln!(
        s,
        "| group | case | max τ/t | IDIC steps | explicit steps | momentum drift | min ρ | wave amplitude num / exact | box vs oracle | L1 max | result |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
    let g = |v: f64| {
        if v.is_finite() {
            format!("{v:.2e}")
        } else {
            "–".into()
        }
    };
    for r in reports {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.group,
            r.name,
            g(r.max_beta),
            r.steps,
            if r.explicit_steps.is_finite() {
                format!("{:.0}", r.explicit_steps)
            } else {
                "–".into()
            },
            g(r.momentum_drift),
            g(r.min_density),
            r.wave_amplitude
                .map_or("–".into(), |(n, e)| format!("{n:.4} / {e:.4}")),
            r.box_oracle.map_or("–".into(), g),
            r.l1_max.map_or("–".into(), g),
            if r.passed() {
                "pass".to_string()
            } else {
                format!("**FAIL**: {}", r.failures.join("; "))
            }
        );
    }
    s
}

/// Run the matrix (the CI subset unless `full`), calling `progress` after each case.
pub fn run(full: bool, mut progress: impl FnMut(&CaseReport)) -> Vec<CaseReport> {
    cases()
        .iter()
        .filter(|c| full || c.reduced)
        .map(|c| {
            let r = run_case(c);
            progress(&r);
            r
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// The command line.

#[derive(clap::Args)]
pub struct StiffnessArgs {
    /// The full grid (default: the reduced CI grid)
    #[arg(long)]
    full: bool,
    /// Write the Markdown table to this file (e.g. docs/stiffness.md)
    #[arg(long)]
    out: Option<PathBuf>,
    /// Replace an existing --out file
    #[arg(long)]
    force: bool,
}

pub fn execute(a: StiffnessArgs) -> u8 {
    let StiffnessArgs { full, out, force } = a;
    if let Some(o) = &out {
        if o.exists() && !force {
            eprintln!("error: {} exists; give --force to replace it", o.display());
            return 2;
        }
        // Where the report goes must be writable before the matrix runs (minutes with --full).
        let dir = match o.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let probe = dir.join(format!(".dustsph-write-check-{}.tmp", std::process::id()));
        if o.is_dir() {
            eprintln!(
                "error: {} is a directory; --out names the report file",
                o.display()
            );
            return 2;
        }
        if let Err(e) = std::fs::write(&probe, b"") {
            eprintln!(
                "error: {}: cannot write the report there ({e})",
                o.display()
            );
            return 2;
        }
        let _ = std::fs::remove_file(&probe);
    }
    let reports = crate::commands::stiffness::run(full, |r| {
        eprintln!(
            "{:<6} {} — {}: {} steps (explicit would need {:.0}), momentum drift {:.1e}",
            if r.passed() { "pass" } else { "FAIL" },
            r.group,
            r.name,
            r.steps,
            r.explicit_steps,
            r.momentum_drift
        );
        for f in &r.failures {
            eprintln!("       {f}");
        }
    });
    let failed = reports.iter().filter(|r| !r.passed()).count();
    if let Some(o) = &out {
        let command = format!(
            "dustsph stiffness{} --out {} --force",
            if full { " --full" } else { "" },
            o.display()
        );
        let md = crate::commands::stiffness::markdown(&reports, full, &command);
        if let Err(e) = crate::io::write_bytes_atomic(o, md.as_bytes()) {
            eprintln!("error: {e}");
            return 1;
        }
        println!("wrote {}", o.display());
    }
    println!("{} of {} cases pass", reports.len() - failed, reports.len());
    if failed > 0 {
        1
    } else {
        0
    }
}
