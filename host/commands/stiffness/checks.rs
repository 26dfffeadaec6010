//! One case run and judged: its set-up, the run with the momentum drift checked, the end state
//! and the exact solution.
use super::{
    Case, CaseReport, Kind, BOX_ORACLE_TOL, DISORDERED_MEAN_TOL, MOMENTUM_TOL, WAVE_AMPLITUDE_TOL,
};
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
use std::path::Path;

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
            closing_forces: None,
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

/// The case's physics, initial state, time settings and (for scene cases) scene; a scene or
/// set-up that fails is recorded in `rep`.
pub(super) fn prepare_case(
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
pub(super) fn explicit_reference(phys: &Physics, state: &State) -> (f64, f64) {
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
pub(super) fn run_checked(
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
pub(super) fn check_final_state(rep: &mut CaseReport, sim: &mut Simulation) -> Option<()> {
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
pub(super) fn check_exact(rep: &mut CaseReport, sc: &Scene, state: &State) {
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
