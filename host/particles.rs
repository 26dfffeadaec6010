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

    /// Every per-particle column of the phase, each visited once (the one list of them: the
    /// operations on every column below are written over it). Columns a scene does not use
    /// (`None`) are left out.
    pub fn for_each_column(&mut self, f: &mut impl ColumnVisitor) {
        f.visit("x", &mut self.x);
        f.visit("v", &mut self.v);
        f.visit("m", &mut self.m);
        f.visit("rho", &mut self.rho);
        f.visit("id", &mut self.id);
        if let Some(c) = &mut self.fixed {
            f.visit("fixed", c);
        }
    }

    /// Give back the arrays' spare capacity (a phase grown particle by particle).
    pub fn shrink_to_fit(&mut self) {
        self.for_each_column(&mut Shrink);
    }

    #[inline(always)]
    pub fn is_fixed(&self, i: usize) -> bool {
        self.fixed.as_ref().is_some_and(|f| f[i])
    }

    /// Reorder every array by `perm` (new index → old index).
    pub fn permute(&mut self, perm: &[u32]) {
        self.for_each_column(&mut Permute(perm));
    }

    /// Keep the particles `keep` marks (`keep[i]` for particle i), in their order, in place:
    /// no column is reallocated (a rank's own particles dropping its ghosts, or those that left
    /// it).
    pub fn retain_rows(&mut self, keep: &[bool]) {
        self.for_each_column(&mut Retain(keep));
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
    /// particle, computed by the last step's closing kick from predicted velocities and
    /// energies; kept with the state so that a resumed run is bit-identical. `None` otherwise.
    pub closing_forces: Option<Vec<ClosingForces>>,
}

/// A gas particle's forces at the close of a leapfrog step, which the next step opens with.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ClosingForces {
    /// The acceleration A.
    pub acc: [f64; 3],
    /// The rate of the specific internal energy ė (0 for an isothermal gas).
    pub dedt: f64,
    /// The largest signal speed over the particle's pairs (the CFL's v_sig).
    pub vsig: f64,
}

// SAFETY: `repr(C)` of f64 only (no padding), and every bit pattern is a valid f64.
unsafe impl bytemuck::Zeroable for ClosingForces {}
unsafe impl bytemuck::Pod for ClosingForces {}

impl Gas {
    /// The gas's own per-particle columns (those of its phase aside), each visited once; the
    /// optional ones only where present.
    pub fn for_each_gas_column(&mut self, f: &mut impl ColumnVisitor) {
        f.visit("p", &mut self.p);
        f.visit("c", &mut self.c);
        for (name, c) in [
            ("e", &mut self.e),
            ("h", &mut self.h),
            ("omega", &mut self.omega),
        ] {
            if let Some(c) = c {
                f.visit(name, c);
            }
        }
        if let Some(c) = &mut self.closing_forces {
            f.visit("closing_forces", c);
        }
    }

    pub fn permute(&mut self, perm: &[u32]) {
        self.ph.permute(perm);
        self.for_each_gas_column(&mut Permute(perm));
    }

    /// [`Phase::retain_rows`] over every gas column (one left empty stays so).
    pub fn retain_rows(&mut self, keep: &[bool]) {
        self.ph.retain_rows(keep);
        self.for_each_gas_column(&mut Retain(keep));
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

/// An operation on every per-particle column ([`Phase::for_each_column`],
/// [`Gas::for_each_gas_column`]), whatever its element type.
pub trait ColumnVisitor {
    fn visit<T: Copy>(&mut self, name: &'static str, column: &mut Vec<T>);
}

struct Shrink;

impl ColumnVisitor for Shrink {
    fn visit<T: Copy>(&mut self, _: &'static str, column: &mut Vec<T>) {
        column.shrink_to_fit();
    }
}

/// `column[i] ← column[perm[i]]`.
struct Permute<'a>(&'a [u32]);

impl ColumnVisitor for Permute<'_> {
    fn visit<T: Copy>(&mut self, _: &'static str, column: &mut Vec<T>) {
        *column = self.0.iter().map(|&p| column[p as usize]).collect();
    }
}

/// Keep the rows marked; a column left empty (a gas column not yet computed) stays so.
struct Retain<'a>(&'a [bool]);

impl ColumnVisitor for Retain<'_> {
    fn visit<T: Copy>(&mut self, _: &'static str, column: &mut Vec<T>) {
        if column.len() == self.0.len() {
            retain_by(column, self.0);
        }
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

#[cfg(test)]
mod tests {
    use super::{ClosingForces, Gas, Phase, State};
    use crate::dist::records::record_at;

    /// A state with every column, optional ones included, each value distinct.
    fn full_state(n: usize) -> State {
        let f = |k: usize, i: usize| (100 * k + i) as f64 + 0.25;
        let phase = |k: usize| Phase {
            x: (0..n).map(|i| [f(k, i), -f(k, i), 2.0 * f(k, i)]).collect(),
            v: (0..n).map(|i| [f(k + 1, i), 0.5, -f(k + 2, i)]).collect(),
            m: (0..n).map(|i| f(k + 3, i)).collect(),
            rho: (0..n).map(|i| f(k + 4, i)).collect(),
            id: (0..n as u64).map(|i| 7 * i + k as u64).collect(),
            fixed: Some((0..n).map(|i| i % 3 == 0).collect()),
        };
        State {
            t: 0.5,
            step: 3,
            gas: Gas {
                ph: phase(0),
                p: (0..n).map(|i| f(10, i)).collect(),
                c: (0..n).map(|i| f(11, i)).collect(),
                e: Some((0..n).map(|i| f(12, i)).collect()),
                h: Some((0..n).map(|i| f(13, i)).collect()),
                omega: Some((0..n).map(|i| f(14, i)).collect()),
                closing_forces: Some(
                    (0..n)
                        .map(|i| ClosingForces {
                            acc: [f(15, i), 1.0, 2.0],
                            dedt: 3.0,
                            vsig: f(16, i),
                        })
                        .collect(),
                ),
            },
            dust: vec![phase(20), phase(30)],
        }
    }

    /// Permuting and retaining rows act on every column a particle's record carries (the
    /// records list the fields on their own): particle i of the permuted state has the record
    /// of particle perm[i], and the rows kept have their records, in order.
    #[test]
    fn permute_and_retain_move_every_column_a_record_carries() {
        let n = 9;
        let st = full_state(n);
        let perm: Vec<u32> = vec![4, 0, 8, 2, 6, 1, 3, 7, 5];
        let mut p = st.clone();
        p.gas.permute(&perm);
        for ph in &mut p.dust {
            ph.permute(&perm);
        }
        let keep: Vec<bool> = (0..n).map(|i| i % 4 != 1).collect();
        let mut r = st.clone();
        r.retain_rows(&keep.repeat(3));
        for k in 0..3 {
            for (i, &from) in perm.iter().enumerate() {
                assert_eq!(record_at(&p, k, i), record_at(&st, k, from as usize));
            }
            let kept: Vec<usize> = (0..n).filter(|&i| keep[i]).collect();
            for (j, &i) in kept.iter().enumerate() {
                assert_eq!(record_at(&r, k, j), record_at(&st, k, i));
            }
        }
        assert_eq!(r.len(), 3 * (n - 2));
    }
}
