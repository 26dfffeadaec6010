//! The run's diagnostics, defined once (docs/validation.md, "The diagnostics in `summary.json`"): the step sizes, the
//! steps the explicit drag's limit set, the largest CFL number, and the conservation of mass,
//! momentum and energy. Every command that steps (run, resume, study, stiffness) reports these
//! same quantities, updated after every step by [`crate::sim::Simulation::step`].
use crate::particles::State;
use crate::step::timestep::Taken;
use crate::step::Momentum;
use serde::{Deserialize, Serialize};

/// Particle counts per phase, and how many are held fixed (walls).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ParticleCounts {
    pub gas: usize,
    pub gas_fixed: usize,
    pub dust: Vec<usize>,
    pub dust_fixed: Vec<usize>,
}

/// The sums over every particle that the conservation figures compare, and the counts: of
/// one process's state, or over MPI ranks of every rank's share ([`Totals::reduce`]).
#[derive(Debug, Clone)]
pub struct Totals {
    pub counts: ParticleCounts,
    pub mass_gas: f64,
    pub mass_dust: Vec<f64>,
    pub momentum: [f64; 3],
    /// Kinetic and thermal.
    pub energy: f64,
    /// The largest sound speed.
    pub c_max: f64,
    /// (Σ m r², Σ m) of the gas and of all the dust (the ball's radius estimates).
    pub moments: [(f64, f64); 2],
}

impl Totals {
    pub fn of(state: &State) -> Totals {
        Totals {
            counts: ParticleCounts::of(state),
            mass_gas: state.gas.ph.total_mass(),
            mass_dust: state.dust.iter().map(|d| d.total_mass()).collect(),
            momentum: state.total_momentum(),
            energy: state.total_energy(),
            c_max: state.gas.c.iter().copied().fold(0.0, f64::max),
            moments: [
                moments(&[&state.gas.ph]),
                moments(&state.dust.iter().collect::<Vec<_>>()),
            ],
        }
    }

    /// Summed (the largest sound speed: the largest) over the processes of `c`, each holding
    /// a share of the particles (collective).
    pub fn reduce(mut self, c: &dyn crate::dist::Comm) -> Totals {
        let nd = self.mass_dust.len();
        let [(a, b), (d, e)] = self.moments;
        let mut f: Vec<f64> = [self.mass_gas, self.energy, a, b, d, e]
            .into_iter()
            .chain(self.momentum)
            .chain(self.mass_dust.iter().copied())
            .collect();
        c.sum_f64(&mut f);
        self.mass_gas = f[0];
        self.energy = f[1];
        self.moments = [(f[2], f[3]), (f[4], f[5])];
        self.momentum = [f[6], f[7], f[8]];
        self.mass_dust = f[9..9 + nd].to_vec();
        let n = &self.counts;
        let mut u: Vec<u64> = [n.gas, n.gas_fixed]
            .into_iter()
            .chain(n.dust.iter().copied())
            .chain(n.dust_fixed.iter().copied())
            .map(|x| x as u64)
            .collect();
        c.sum_u64(&mut u);
        self.counts = ParticleCounts {
            gas: u[0] as usize,
            gas_fixed: u[1] as usize,
            dust: u[2..2 + nd].iter().map(|&x| x as usize).collect(),
            dust_fixed: u[2 + nd..2 + 2 * nd].iter().map(|&x| x as usize).collect(),
        };
        let mut cm = [self.c_max];
        c.max_f64(&mut cm);
        self.c_max = cm[0];
        self
    }
}

/// (Σ m r², Σ m) of the phases, in their order.
fn moments(phs: &[&crate::particles::Phase]) -> (f64, f64) {
    let (mut mr2, mut m) = (0.0, 0.0);
    for ph in phs {
        for (mi, x) in ph.m.iter().zip(&ph.x) {
            mr2 += mi * (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
            m += mi;
        }
    }
    (mr2, m)
}

impl ParticleCounts {
    pub fn of(state: &State) -> ParticleCounts {
        let fixed =
            |ph: &crate::particles::Phase| (0..ph.len()).filter(|&i| ph.is_fixed(i)).count();
        ParticleCounts {
            gas: state.gas.ph.len(),
            gas_fixed: fixed(&state.gas.ph),
            dust: state.dust.iter().map(|d| d.len()).collect(),
            dust_fixed: state.dust.iter().map(fixed).collect(),
        }
    }

    pub fn total(&self) -> usize {
        self.gas + self.dust.iter().sum::<usize>()
    }
}

/// A system at rest has no momentum scale of its own: below this fraction of M·c_s (its total
/// mass times the largest sound speed at the start) the drift is measured against M·c_s.
const AT_REST: f64 = 1e-8;

/// Everything a run accumulates about itself besides its outputs (a checkpoint carries it).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Diagnostics {
    /// Steps taken (over every session of a resumed run).
    pub steps: u64,
    /// +∞ before the first step (JSON has no ∞: written as null).
    #[serde(with = "infinite_as_null")]
    pub dt_min: f64,
    pub dt_max: f64,
    /// The first step's size before landing (the step the physics sets at t = 0).
    pub first_dt_free: Option<f64>,
    /// Largest τ·v_sig/h of the run.
    pub cfl_max: f64,
    /// Steps whose size the explicit drag's limit set (always 0 with IDIC).
    pub drag_limited_steps: u64,
    pub counts: ParticleCounts,
    /// Gas mass and each fraction's mass at the start.
    pub mass0: (f64, Vec<f64>),
    pub momentum0: [f64; 3],
    /// Kinetic (+ thermal) energy at the start.
    pub energy0: f64,
    /// The largest Σ m|v| after any step (the start included).
    pub momentum_scale: f64,
    /// M·c_s at the start: the scale of a system at rest.
    pub rest_scale: f64,
    /// The largest |P(t) − P(0)| after any step.
    pub momentum_change_max: f64,
    /// Σ m (x − x_star) × v at the start (about the origin without a point mass).
    #[serde(default)]
    pub angular_momentum0: [f64; 3],
    /// The largest |L(t) + L_accreted(t) − L(0)| after any step.
    #[serde(default)]
    pub angular_momentum_change_max: f64,
    /// L of the particles after the last step (the reduction's).
    #[serde(default)]
    pub angular_momentum: [f64; 3],
    /// What the point mass has accreted.
    #[serde(default)]
    pub accreted: super::accretion::Accreted,
}

impl Diagnostics {
    /// At the start of a run: `state` (host copy, up to date) and its momentum from the
    /// stepper's reduction (the sums every later step is compared with).
    pub fn start(totals: &Totals, m: Momentum) -> Diagnostics {
        let t = totals;
        let mass: f64 = t.mass_gas + t.mass_dust.iter().sum::<f64>();
        Diagnostics {
            steps: 0,
            dt_min: f64::INFINITY,
            dt_max: 0.0,
            first_dt_free: None,
            cfl_max: 0.0,
            drag_limited_steps: 0,
            counts: t.counts.clone(),
            mass0: (t.mass_gas, t.mass_dust.clone()),
            momentum0: m.p,
            energy0: t.energy,
            momentum_scale: m.scale,
            rest_scale: mass * t.c_max,
            momentum_change_max: 0.0,
            angular_momentum0: m.l,
            angular_momentum_change_max: 0.0,
            angular_momentum: m.l,
            accreted: Default::default(),
        }
    }

    /// After a step of the planner's `taken`, with the momentum it left.
    pub fn after_step(&mut self, taken: &Taken, m: Momentum, h: f64) {
        let dt = taken.plan.dt;
        if self.first_dt_free.is_none() {
            self.first_dt_free = Some(taken.plan.dt_free);
        }
        self.steps += 1;
        self.dt_min = self.dt_min.min(dt);
        self.dt_max = self.dt_max.max(dt);
        self.cfl_max = self.cfl_max.max(dt * taken.forces.vsig_max / h);
        self.drag_limited_steps += u64::from(taken.plan.by_drag);
        self.momentum_scale = self.momentum_scale.max(m.scale);
        let dp = (0..3)
            .map(|k| (m.p[k] - self.momentum0[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        self.momentum_change_max = self.momentum_change_max.max(dp);
        let a = &self.accreted;
        let dl = (0..3)
            .map(|k| (m.l[k] + a.angular_momentum[k] - self.angular_momentum0[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        self.angular_momentum_change_max = self.angular_momentum_change_max.max(dl);
        self.angular_momentum = m.l;
    }

    /// The angular momentum's drift: max over the steps of |L(t) + L_accreted − L(0)|
    /// relative to |L(0)| (absolute when L(0) = 0).
    pub fn angular_momentum_drift(&self) -> f64 {
        let l0 = self
            .angular_momentum0
            .iter()
            .map(|x| x * x)
            .sum::<f64>()
            .sqrt();
        if l0 > 0.0 {
            self.angular_momentum_change_max / l0
        } else {
            self.angular_momentum_change_max
        }
    }

    /// The momentum drift: max over the steps of |P(t) − P(0)|, relative to the largest
    /// Σ m|v| of the run (M·c_s for a system at rest).
    pub fn momentum_drift(&self) -> f64 {
        let scale = if self.momentum_scale < AT_REST * self.rest_scale {
            self.rest_scale
        } else {
            self.momentum_scale
        };
        if scale > 0.0 {
            self.momentum_change_max / scale
        } else {
            self.momentum_change_max
        }
    }
}

/// An f64 that may be +∞ in JSON: written as null, read back as +∞ (serde_json writes every
/// non-finite number as null, which it cannot read as an f64).
pub mod infinite_as_null {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_none()
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(serde::Serialize, serde::Deserialize)]
    struct T {
        #[serde(with = "infinite_as_null")]
        v: f64,
    }

    #[test]
    fn infinity_round_trips_through_json() {
        for v in [f64::INFINITY, 0.25, 1e-300] {
            let text = serde_json::to_string(&T { v }).unwrap();
            let back: T = serde_json::from_str(&text).unwrap();
            assert_eq!(back.v, v, "{text}");
        }
    }

    /// Diagnostics written before the first step (dt_min = +∞) read back.
    #[test]
    fn diagnostics_before_the_first_step_read_back() {
        let d = Diagnostics::start(
            &Totals::of(&State::default()),
            Momentum {
                p: [0.0; 3],
                scale: 0.0,
                l: [0.0; 3],
                inside: 0,
            },
        );
        assert_eq!(d.dt_min, f64::INFINITY);
        let text = serde_json::to_string(&d).unwrap();
        let back: Diagnostics = serde_json::from_str(&text).unwrap();
        assert_eq!(back.dt_min, f64::INFINITY);
    }

    /// The drift is the largest change over the steps, not the last one; at rest it is
    /// measured against M·c_s.
    #[test]
    fn momentum_drift_is_the_largest_change_against_the_largest_scale() {
        let mut d = Diagnostics::start(
            &Totals::of(&State::default()),
            Momentum {
                p: [1.0, 0.0, 0.0],
                scale: 2.0,
                l: [0.0; 3],
                inside: 0,
            },
        );
        let taken = Taken {
            plan: crate::step::timestep::Plan {
                dt: 0.1,
                dt_free: 0.1,
                by_drag: false,
                landing: false,
                t_target: 1.0,
            },
            forces: crate::step::Forces {
                vsig_max: 1.0,
                acc_max: 0.0,
                damp_rate_max: 0.0,
            },
        };
        let at = |x: f64, s: f64| Momentum {
            p: [x, 0.0, 0.0],
            scale: s,
            l: [0.0; 3],
            inside: 0,
        };
        d.after_step(&taken, at(1.5, 4.0), 1.0);
        d.after_step(&taken, at(1.1, 3.0), 1.0);
        assert_eq!(d.momentum_drift(), 0.5 / 4.0);
        d.rest_scale = 1e12;
        assert_eq!(d.momentum_drift(), 0.5 / 1e12);
    }
}
