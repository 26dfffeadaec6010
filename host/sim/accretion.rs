//! Accretion onto the `[gravity]` point mass (method.md §1.2): after a step, every particle
//! (not held fixed) closer to the star than `accretion_radius` is removed, and its mass,
//! momentum and angular momentum about the star go to the star's record, so the totals of
//! particles plus record are conserved. No particle leaves silently: the record counts them
//! per phase and the summary reports it.
use crate::particles::{Phase, State};
use serde::{Deserialize, Serialize};

/// What the star has taken in (summary.json `conservation.star`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Accreted {
    pub gas_particles: usize,
    pub gas_mass: f64,
    /// Per dust fraction.
    pub dust_particles: Vec<usize>,
    pub dust_mass: Vec<f64>,
    /// Σ m v of what was accreted.
    pub momentum: [f64; 3],
    /// Σ m (x − x_star) × v of what was accreted, at its removal.
    pub angular_momentum: [f64; 3],
}

impl Accreted {
    /// Remove the particles of `state` inside `r_acc` of `centre` and add them to the record.
    /// Returns how many were removed (the engine must be rebuilt when any was).
    pub fn take(&mut self, state: &mut State, centre: [f64; 3], r_acc: f64) -> usize {
        let nf = state.dust.len();
        if self.dust_mass.len() < nf {
            self.dust_mass.resize(nf, 0.0);
            self.dust_particles.resize(nf, 0);
        }
        let gone = self.keep(&state.gas.ph, centre, r_acc);
        let mut removed = 0;
        if let Some((keep, n, m)) = gone {
            state.gas.permute(&keep);
            // The closing forces had the removed particles in their sums: the next step
            // computes them again.
            state.gas.closing_forces = None;
            self.gas_particles += n;
            self.gas_mass += m;
            removed += n;
        }
        for k in 0..nf {
            if let Some((keep, n, m)) = self.keep(&state.dust[k], centre, r_acc) {
                state.dust[k].permute(&keep);
                self.dust_particles[k] += n;
                self.dust_mass[k] += m;
                removed += n;
            }
        }
        removed
    }

    /// The rows of `ph` to keep, with the count and mass of the others (their momentum and
    /// angular momentum added here); `None` when every row stays.
    fn keep(&mut self, ph: &Phase, c: [f64; 3], r_acc: f64) -> Option<(Vec<u32>, usize, f64)> {
        let r2 = r_acc * r_acc;
        let mut keep = Vec::with_capacity(ph.len());
        let (mut n, mut mass) = (0, 0.0);
        for i in 0..ph.len() {
            let d = dustsph_device::sub(ph.x[i], c);
            if ph.is_fixed(i) || dustsph_device::dot(d, d) >= r2 {
                keep.push(i as u32);
                continue;
            }
            let (m, v) = (ph.m[i], ph.v[i]);
            n += 1;
            mass += m;
            for (p, vk) in self.momentum.iter_mut().zip(v) {
                *p += m * vk;
            }
            for (lk, ck) in self
                .angular_momentum
                .iter_mut()
                .zip(dustsph_device::cross(d, v))
            {
                *lk += m * ck;
            }
        }
        (n > 0).then_some((keep, n, mass))
    }

    pub fn is_empty(&self) -> bool {
        self.gas_particles == 0 && self.dust_particles.iter().all(|&n| n == 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The particles inside the radius leave the state with their ids; mass, momentum and
    /// angular momentum of state plus record are what the state had.
    #[test]
    fn accreted_particles_leave_with_their_mass_momentum_and_angular_momentum() {
        let mut st = State::default();
        let ph = |xs: &[[f64; 3]]| Phase {
            x: xs.to_vec(),
            v: xs.iter().map(|x| [-x[1] + 0.3, x[0], 0.1]).collect(),
            m: (0..xs.len()).map(|i| 1.0 + i as f64).collect(),
            rho: vec![1.0; xs.len()],
            id: (0..xs.len() as u64).collect(),
            fixed: None,
        };
        st.gas.ph = ph(&[[0.05, 0.0, 0.0], [1.0, 0.5, 0.0], [0.0, -0.08, 0.0]]);
        st.gas.p = vec![1.0; 3];
        st.gas.c = vec![1.0; 3];
        st.dust = vec![ph(&[[2.0, 0.0, 0.0], [0.01, 0.01, 0.0]])];
        let totals = |s: &State, a: &Accreted| {
            let mut m = a.gas_mass + a.dust_mass.iter().sum::<f64>();
            let (mut p, mut l) = (a.momentum, a.angular_momentum);
            for ph in std::iter::once(&s.gas.ph).chain(&s.dust) {
                for i in 0..ph.len() {
                    let (x, v, mi) = (ph.x[i], ph.v[i], ph.m[i]);
                    m += mi;
                    for k in 0..3 {
                        p[k] += mi * v[k];
                    }
                    l[2] += mi * (x[0] * v[1] - x[1] * v[0]);
                }
            }
            (m, p, l[2])
        };
        let mut acc = Accreted::default();
        let before = totals(&st, &acc);
        assert_eq!(acc.take(&mut st, [0.0; 3], 0.1), 3);
        assert_eq!(st.gas.ph.id, vec![1]);
        assert_eq!(st.gas.p.len(), 1);
        assert_eq!(st.dust[0].id, vec![0]);
        assert_eq!(
            (acc.gas_particles, acc.dust_particles.clone()),
            (2, vec![1])
        );
        let after = totals(&st, &acc);
        assert!((after.0 - before.0).abs() < 1e-14);
        for k in 0..3 {
            assert!((after.1[k] - before.1[k]).abs() < 1e-14);
        }
        assert!((after.2 - before.2).abs() < 1e-14);
        assert_eq!(acc.take(&mut st, [0.0; 3], 0.1), 0);
    }
}
