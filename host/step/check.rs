//! What a step hands back: the forces' time-step maxima, the errors that stop a run, and the
//! host-side check of a state (used to word the message when the engine flags a particle).
use crate::grid::GridError;
use crate::particles::{Phase, State};
use dustsph_device::dot;
use rayon::prelude::*;

/// The time-step maxima of the gas forces at a layer (the accelerations themselves stay on the
/// engine's launcher).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Forces {
    /// Largest signal speed (for the CFL limit).
    pub vsig_max: f64,
    /// Largest |A| (for the force limit).
    pub acc_max: f64,
    /// Largest edge-zone damping rate (`[gravity] damp_inner`/`damp_outer`; 0 without zones):
    /// the step keeps τ ≤ 1/rate.
    pub damp_rate_max: f64,
}

impl Forces {
    /// From per-particle rows (A_x, A_y, A_z, ė, v_sig); no damping rate (the rows do not
    /// hold it). `own_h`: variable h's (h_ref, each particle's h), the maxima scaled by
    /// h_ref/h_a as the forces kernel takes them (method.md §T); particles held `fixed` left
    /// out, as the kernel leaves them.
    pub fn from_rows(
        rows: &[crate::particles::ClosingForces],
        own_h: Option<(f64, &[f64])>,
        fixed: Option<&[bool]>,
    ) -> Forces {
        let mut f = Forces {
            vsig_max: 0.0,
            acc_max: 0.0,
            damp_rate_max: 0.0,
        };
        for (i, r) in rows.iter().enumerate() {
            if fixed.is_some_and(|f| f[i]) {
                continue;
            }
            let scale = own_h.map_or(1.0, |(h, hs)| h / hs[i]);
            f.acc_max = f.acc_max.max(dot(r.acc, r.acc).sqrt() * scale);
            f.vsig_max = f.vsig_max.max(r.vsig * scale);
        }
        f
    }
}

/// The total momentum of every particle (gas and dust, walls included) and its scale Σ m|v|,
/// summed on the engine's launcher: what the run's momentum drift is measured from after every
/// step (docs/validation.md, "The diagnostics in `summary.json`").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Momentum {
    pub p: [f64; 3],
    pub scale: f64,
    /// Σ m (x − x_c) × v about the point mass (the origin without one).
    pub l: [f64; 3],
    /// Particles inside the accretion radius (0 without one).
    pub inside: usize,
}

#[derive(Debug)]
pub enum StepError {
    Grid(GridError),
    /// A non-finite value or negative density: step, phase, particle id, field.
    Blowup(String),
    /// The scene asks for something this backend does not do.
    Unsupported(String),
}

impl std::fmt::Display for StepError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StepError::Grid(e) => write!(f, "grid: {e}"),
            StepError::Blowup(s) | StepError::Unsupported(s) => f.write_str(s),
        }
    }
}
impl std::error::Error for StepError {}

impl From<GridError> for StepError {
    fn from(e: GridError) -> Self {
        StepError::Grid(e)
    }
}

/// The first particle with a non-finite position or velocity, a non-positive density or a
/// negative energy, named by step, time, phase, id and field.
pub fn check_state(state: &State, dust_density_fresh: bool) -> Result<(), StepError> {
    let bad = |phase: &str,
               ph: &Phase,
               check_rho: bool,
               extra: Option<(&str, &[f64])>|
     -> Option<String> {
        let rho_ok = |i: usize| !check_rho || (ph.rho[i].is_finite() && ph.rho[i] > 0.0);
        let i = (0..ph.len()).into_par_iter().find_first(|&i| {
            !(ph.x[i].iter().all(|v| v.is_finite())
                && ph.v[i].iter().all(|v| v.is_finite())
                && rho_ok(i)
                && extra.is_none_or(|(_, e)| e[i].is_finite() && e[i] >= 0.0))
        })?;
        let field = if !ph.x[i].iter().all(|v| v.is_finite()) {
            "position"
        } else if !ph.v[i].iter().all(|v| v.is_finite()) {
            "velocity"
        } else if !rho_ok(i) {
            "density"
        } else {
            extra.map_or("?", |e| e.0)
        };
        Some(format!(
                "step {}, t = {:.6e}: {phase} particle id {} has a bad {field} (x = {:?}, v = {:?}, rho = {:?})",
                state.step,
                state.t,
                ph.id[i],
                ph.x[i],
                ph.v[i],
                ph.rho.get(i)
            ))
    };
    let g = &state.gas;
    if let Some(m) = bad(
        "gas",
        &g.ph,
        true,
        g.e.as_deref().map(|e| ("internal energy", e)),
    ) {
        return Err(StepError::Blowup(m));
    }
    for (k, d) in state.dust.iter().enumerate() {
        if let Some(m) = bad(&format!("dust fraction {k}"), d, dust_density_fresh, None) {
            return Err(StepError::Blowup(m));
        }
    }
    Ok(())
}

/// The kernel support in units of h (re-exported for set-ups).
pub const SUPPORT: f64 = dustsph_device::kernel::SUPPORT;
