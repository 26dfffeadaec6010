//! Particle data, structure of arrays. One [`Phase`] for the gas and one per dust fraction.
//! Fields a scene does not use are `None` (not allocated).

/// One SPH particle set (the gas, or one dust fraction).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Phase {
    pub x: Vec<[f64; 3]>,
    pub v: Vec<[f64; 3]>,
    pub m: Vec<f64>,
    pub rho: Vec<f64>,
    pub id: Vec<u64>,
    /// Fixed wall particles (shock tube ends): never moved, no drag, constant density.
    /// Allocated only for scenes with walls.
    pub fixed: Option<Vec<bool>>,
}

impl Phase {
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Give back the arrays' spare capacity (a phase grown particle by particle).
    pub fn shrink_to_fit(&mut self) {
        self.x.shrink_to_fit();
        self.v.shrink_to_fit();
        self.m.shrink_to_fit();
        self.rho.shrink_to_fit();
        self.id.shrink_to_fit();
        if let Some(f) = &mut self.fixed {
            f.shrink_to_fit();
        }
    }

    #[inline(always)]
    pub fn is_fixed(&self, i: usize) -> bool {
        self.fixed.as_ref().is_some_and(|f| f[i])
    }

    /// Reorder every array by `perm` (new index → old index).
    pub fn permute(&mut self, perm: &[u32]) {
        fn apply<T: Copy>(v: &mut Vec<T>, perm: &[u32]) {
            let out: Vec<T> = perm.iter().map(|&p| v[p as usize]).collect();
            *v = out;
        }
        apply(&mut self.x, perm);
        apply(&mut self.v, perm);
        apply(&mut self.m, perm);
        apply(&mut self.rho, perm);
        apply(&mut self.id, perm);
        if let Some(f) = &mut self.fixed {
            apply(f, perm);
        }
    }

    /// Keep the particles `keep` marks (`keep[i]` for particle i), in their order, in place:
    /// no column is reallocated (a rank's own particles dropping its ghosts, or those that left
    /// it).
    pub fn retain_rows(&mut self, keep: &[bool]) {
        retain_by(&mut self.x, keep);
        retain_by(&mut self.v, keep);
        retain_by(&mut self.m, keep);
        retain_by(&mut self.rho, keep);
        retain_by(&mut self.id, keep);
        if let Some(f) = &mut self.fixed {
            retain_by(f, keep);
        }
    }

    pub fn total_mass(&self) -> f64 {
        self.m.iter().sum()
    }

    pub fn momentum(&self) -> [f64; 3] {
        let mut p = [0.0; 3];
        for (m, v) in self.m.iter().zip(&self.v) {
            for d in 0..3 {
                p[d] += m * v[d];
            }
        }
        p
    }

    pub fn kinetic_energy(&self) -> f64 {
        self.m
            .iter()
            .zip(&self.v)
            .map(|(m, v)| 0.5 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
            .sum()
    }
}

/// Gas: a phase plus thermodynamics.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Gas {
    pub ph: Phase,
    pub p: Vec<f64>,
    pub c: Vec<f64>,
    /// Specific internal energy: adiabatic gas only.
    pub e: Option<Vec<f64>>,
    /// Per-particle smoothing length and grad-h term Ω (variable-h SPH only; `None` until the
    /// first density solve).
    pub h: Option<Vec<f64>>,
    pub omega: Option<Vec<f64>>,
    /// Leapfrog (time.integrator = "kdk") only: the forces the next step opens with, per
    /// particle (A_x, A_y, A_z, ė, v_sig), computed by the last step's closing kick from
    /// predicted velocities and energies; kept with the state so that a resumed run is
    /// bit-identical. `None` otherwise.
    pub next_forces: Option<Vec<[f64; 5]>>,
}

impl Gas {
    pub fn permute(&mut self, perm: &[u32]) {
        self.ph.permute(perm);
        let apply = |v: &mut Vec<f64>| *v = perm.iter().map(|&p| v[p as usize]).collect();
        apply(&mut self.p);
        apply(&mut self.c);
        for f in [&mut self.e, &mut self.h, &mut self.omega]
            .into_iter()
            .flatten()
        {
            apply(f);
        }
        if let Some(f) = &mut self.next_forces {
            *f = perm.iter().map(|&p| f[p as usize]).collect();
        }
    }

    /// [`Phase::retain_rows`] over every gas column (one left empty stays so).
    pub fn retain_rows(&mut self, keep: &[bool]) {
        let n = self.ph.len();
        self.ph.retain_rows(keep);
        for f in [&mut self.p, &mut self.c].into_iter().chain(
            [&mut self.e, &mut self.h, &mut self.omega]
                .into_iter()
                .flatten(),
        ) {
            if f.len() == n {
                retain_by(f, keep);
            }
        }
        if let Some(f) = self.next_forces.as_mut().filter(|f| f.len() == n) {
            retain_by(f, keep);
        }
    }

    pub fn thermal_energy(&self) -> f64 {
        match &self.e {
            Some(e) => self.ph.m.iter().zip(e).map(|(m, e)| m * e).sum(),
            None => 0.0,
        }
    }
}

/// The whole particle state at one time level.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct State {
    pub t: f64,
    pub step: u64,
    pub gas: Gas,
    /// One phase per dust fraction.
    pub dust: Vec<Phase>,
}

impl State {
    /// The same phases, time and step, without particles (whether the gas has an energy and
    /// which phases have fixed particles is kept).
    pub fn shape(&self) -> State {
        let empty = |p: &Phase| Phase {
            fixed: p.fixed.as_ref().map(|_| Vec::new()),
            ..Default::default()
        };
        State {
            t: self.t,
            step: self.step,
            gas: Gas {
                ph: empty(&self.gas.ph),
                e: self.gas.e.as_ref().map(|_| Vec::new()),
                ..Default::default()
            },
            dust: self.dust.iter().map(empty).collect(),
        }
    }

    /// Keep the particles `keep` marks, `keep[n]` for the n-th counting the gas first, then
    /// each dust fraction; in their order, in place ([`Phase::retain_rows`]).
    pub fn retain_rows(&mut self, keep: &[bool]) {
        let n = self.gas.ph.len();
        self.gas.retain_rows(&keep[..n]);
        let mut at = n;
        for ph in &mut self.dust {
            let n = ph.len();
            ph.retain_rows(&keep[at..at + n]);
            at += n;
        }
    }

    /// Particles of every phase.
    pub fn len(&self) -> usize {
        self.gas.ph.len() + self.dust.iter().map(Phase::len).sum::<usize>()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn total_momentum(&self) -> [f64; 3] {
        let mut p = self.gas.ph.momentum();
        for d in &self.dust {
            let q = d.momentum();
            for k in 0..3 {
                p[k] += q[k];
            }
        }
        p
    }

    /// Σ m|v| over all phases: the scale for relative momentum drift.
    pub fn momentum_scale(&self) -> f64 {
        let f = |ph: &Phase| -> f64 {
            ph.m.iter()
                .zip(&ph.v)
                .map(|(m, v)| m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
                .sum()
        };
        f(&self.gas.ph) + self.dust.iter().map(f).sum::<f64>()
    }

    pub fn total_energy(&self) -> f64 {
        self.gas.ph.kinetic_energy()
            + self.gas.thermal_energy()
            + self.dust.iter().map(|d| d.kinetic_energy()).sum::<f64>()
    }
}

/// Keep `v[i]` where `keep[i]`, in order, in place.
fn retain_by<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
    debug_assert_eq!(v.len(), keep.len());
    let mut w = 0;
    for r in 0..v.len() {
        if keep[r] {
            v[w] = v[r];
            w += 1;
        }
    }
    v.truncate(w);
}

/// A cheap hasher for integer keys (FxHash's multiply-rotate): particle keys and cell indices
/// of the halo's bookkeeping, where the std SipHash took a visible share of a step over ranks.
#[derive(Default)]
pub struct IntHasher(u64);

/// Particle keys (phase: 0 gas, 1 + k dust fraction k; id), hashed cheaply.
pub type KeySet = std::collections::HashSet<(u64, u64), std::hash::BuildHasherDefault<IntHasher>>;
/// A map from particle keys (phase, id).
pub type KeyMap<V> =
    std::collections::HashMap<(u64, u64), V, std::hash::BuildHasherDefault<IntHasher>>;

impl std::hash::Hasher for IntHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes.chunks(8) {
            let mut w = [0u8; 8];
            w[..b.len()].copy_from_slice(b);
            self.write_u64(u64::from_le_bytes(w));
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i64(&mut self, v: i64) {
        self.write_u64(v as u64);
    }
}
