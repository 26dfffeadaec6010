//! The start of a run (or of a resumed one): the scene's physics and initial state, the engine on
//! the device asked for, and the checks and warnings said before anything is written.
use super::RunError;
use crate::particles::State;
use crate::scene::LoadedScene;
use crate::setup::file::IcSource;
use crate::step::backend::{Backend, DeviceChoice, StartError};
use crate::step::timestep::{dt_limits, StepPlanner};
use crate::step::{Forces, Physics, StepError};

/// Share of dust particles without gas in their IDIC cell above which a run with the
/// nearest-cell coupling warns (their drag is off).
const UNCOUPLED_WARNING: f64 = 0.05;

/// A checkpointed run's physics and state: the set-up's h and periodic axes from the
/// checkpoint (`layout`), so nothing is set up again (a run from a file needs no file); a
/// checkpoint without them sets its scene up again.
pub fn prepare_resumed(
    loaded: &LoadedScene,
    state: State,
    layout: Option<&super::checkpoint::Layout>,
    warn: bool,
) -> Result<(Physics, State), RunError> {
    match layout {
        Some(l) => {
            let domain = crate::grid::Domain {
                dim: loaded.scene.dim(),
                periodic: l.periodic,
            };
            Ok((Physics::from_scene(&loaded.scene, l.h, domain), state))
        }
        None => prepare(loaded, Some(state), warn).map(|(p, s, _)| (p, s)),
    }
}

/// The scene's physics and its initial state (or a given, checkpointed one), and the
/// initial-conditions file it came from; `warn`: say what the set-up found worth a warning
/// (one process, or rank 0 only).
pub fn prepare(
    loaded: &LoadedScene,
    state: Option<State>,
    warn: bool,
) -> Result<(Physics, State, Option<IcSource>), RunError> {
    let (phys, state, source, _) = prepare_on(loaded, state, warn, &crate::dist::Alone)?;
    Ok((phys, state, source))
}

/// [`prepare`] as one of the processes in `c` (collective): the state is this process's share
/// where the last value is true (initial conditions from a file, read by share over MPI
/// ranks), every particle otherwise.
pub fn prepare_on(
    loaded: &LoadedScene,
    state: Option<State>,
    warn: bool,
    c: &dyn crate::dist::Comm,
) -> Result<(Physics, State, Option<IcSource>, bool), RunError> {
    let file = loaded.path.display().to_string();
    let su = crate::setup::build_on(&loaded.scene, c)
        .map_err(|e| RunError::Input(format!("{file}: {e}")))?;
    if warn && state.is_none() {
        for n in &su.notes {
            eprintln!("dustsph: {n}");
        }
    }
    let t_end = loaded.scene.time.t_end;
    if state.is_none() && su.state.t >= t_end {
        return Err(RunError::Input(format!(
            "{file}: key `time.t_end`: {t_end} is not after the initial conditions' time t = {} \
             (the file's Header/Time)",
            su.state.t
        )));
    }
    let share = su.share && state.is_none();
    let state = state.unwrap_or(su.state);
    let phys = Physics::from_scene(&loaded.scene, su.h, su.domain);
    // The nearest-cell coupling's blind spot: over every rank's share where each holds its
    // own, else on the process that says it.
    let found = match (phys.coupling == crate::scene::Coupling::Cell, share, warn) {
        (true, true, _) => crate::step::dust_without_gas_in_cell(&phys, &state, c),
        (true, false, true) => {
            crate::step::dust_without_gas_in_cell(&phys, &state, &crate::dist::Alone)
        }
        _ => (0, 0),
    };
    if let (true, Some(w)) = (warn, uncoupled_warning(found)) {
        eprintln!("dustsph: warning: {w}");
    }
    Ok((phys, state, su.source, share))
}

/// The warning on dust particles without gas in their IDIC cell (`found`: how many of how
/// many, under the nearest-cell coupling), where too many of them are left without drag.
pub fn uncoupled_warning(found: (usize, usize)) -> Option<String> {
    let (alone, total) = found;
    let f = alone as f64 / total.max(1) as f64;
    (total > 0 && f > UNCOUPLED_WARNING).then(|| {
        format!(
            "{:.0}% of the dust particles share no IDIC cell with a gas particle, so the \
             nearest-cell coupling (idic.coupling = \"cell\") leaves their drag off; \
             idic.coupling = \"kernel\" couples them wherever they sit (docs/method.md §K)",
            100.0 * f
        )
    })
}

/// The engine on a scene's state (sorted in place). Sorting an already sorted state is the
/// identity and densities are recomputed by the same code in the same order, so a resumed
/// run continues bit for bit. A failure here is bad input: the initial grid and densities
/// come from the scene alone.
pub fn engine(
    loaded: &LoadedScene,
    phys: Physics,
    state: &mut State,
    device: DeviceChoice,
    verbose: bool,
) -> Result<Backend, RunError> {
    let file = loaded.path.display().to_string();
    let (eng, note) = Backend::start(device, phys, state).map_err(|e| match e {
        StartError::Device(m) => RunError::Input(m),
        StartError::Step(StepError::Unsupported(m)) => RunError::Input(format!("{file}: {m}")),
        StartError::Step(e) => RunError::Input(format!(
            "{file}: the initial state cannot be set up (check idic.cell, sph.h/hfact, sph.n): {e}"
        )),
    })?;
    if let (Some(n), true) = (note, verbose) {
        eprintln!("dustsph: {n}");
    }
    Ok(eng)
}

/// The first step's size, before anything is written (with --force the old run's files
/// would already be gone): a CFL step that has collapsed at t = 0, or a t_end beyond the
/// step count allowed, is bad input, not a run to start. The forces are computed again by
/// the first step (the same ones: the engine's forces are a pure function of its state).
/// Warnings on the start are printed here.
pub fn check_first_step(
    loaded: &LoadedScene,
    eng: &mut Backend,
    state: &State,
) -> Result<(), RunError> {
    let Some(&t1) = super::output::output_times(loaded, state.t).get(1) else {
        return Ok(());
    };
    let planner = StepPlanner::new(&loaded.scene.time, eng.phys().h);
    match eng.plan(&planner, state, t1) {
        Err(e) => Err(RunError::Input(format!(
            "{}: the first step cannot be taken: {e}",
            loaded.path.display()
        ))),
        Ok(taken) => {
            for w in start_warnings(loaded, eng.phys(), state, &taken.forces) {
                eprintln!("dustsph: warning: {w}");
            }
            Ok(())
        }
    }
}

/// What a physicist should hear before a run that will likely be noise or unstable: a fixed
/// step above the CFL/force limit of the initial state, and kernels holding too few
/// neighbours to be SPH sums (method.md §2).
pub fn start_warnings(
    loaded: &LoadedScene,
    phys: &Physics,
    state: &State,
    f: &Forces,
) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(dt) = loaded.scene.time.fixed_dt() {
        let (dt_cfl, dt_force) = dt_limits(phys.h, f);
        let limit = dt_cfl.min(dt_force);
        if dt > limit {
            out.push(format!(
                "time.dt = {dt} is {:.2}× the step limit min(h/v_sig, √(h/|A|)) = {limit:.3e} of \
                 the initial state: explicit SPH is stable only below ≈0.3–0.5 of it (lower \
                 time.dt, or use time.cfl)",
                dt / limit
            ));
        }
    }
    // Fewer neighbours than a kernel of half the usual width would hold (hfact ≈ 0.6).
    let least = [2.0, 5.0, 12.0][(phys.domain.dim as usize).clamp(1, 3) - 1];
    let own_h = phys.variable_h.is_some() && state.gas.h.is_some();
    if let Ok(nb) = crate::commands::bench::mean_gas_neighbours(phys, state) {
        if !state.gas.ph.x.is_empty() && nb < least {
            out.push(format!(
                "the gas particles have {nb:.1} neighbours each within {} on average (fewer \
                 than {least} in {}D): the SPH sums are noise at this resolution; raise {}",
                if own_h { "its own 2h" } else { "2h" },
                phys.domain.dim,
                if own_h {
                    "sph.hfact"
                } else {
                    "sph.hfact (or sph.h)"
                }
            ));
        }
    }
    out
}
