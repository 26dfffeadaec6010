//! Particles as they travel between ranks: [`ParticleRecord`] (a plain-data row per particle)
//! and the conversions from and to a [`State`]. Plain data without MPI: the ranks (with the mpi
//! feature) send them as bytes.
use crate::particles::{ClosingForces, Phase, State};

/// A particle's whole state as it travels between ranks (migration, the halo, the gather for
/// output): everything a rank's engine needs to step it, as plain data (`Pod`: sent as bytes,
/// read back to the bit).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ParticleRecord {
    pub id: u64,
    /// 0 gas, 1 + k dust fraction k.
    pub phase: u64,
    pub x: [f64; 3],
    pub v: [f64; 3],
    pub m: f64,
    pub rho: f64,
    /// Gas: the internal energy (0 without an energy equation).
    pub e: f64,
    /// 1: held fixed (a wall of the scene, or the deep halo's outer shell).
    pub fixed: u64,
    /// [`ParticleRecord::HAS_H`] | [`ParticleRecord::HAS_CLOSING_FORCES`].
    pub flags: u64,
    /// Gas with variable h: h and Ω of its last solve.
    pub h: f64,
    pub omega: f64,
    /// Gas under the leapfrog: the closing forces the next step starts from.
    pub closing_forces: ClosingForces,
    /// Gas: pressure and sound speed of its layer.
    pub p: f64,
    pub c: f64,
}

// SAFETY: `repr(C)` of 8-byte fields only (no padding), and every bit pattern is a valid
// u64 or f64.
unsafe impl bytemuck::Zeroable for ParticleRecord {}
unsafe impl bytemuck::Pod for ParticleRecord {}

impl ParticleRecord {
    pub const HAS_H: u64 = 1;
    pub const HAS_CLOSING_FORCES: u64 = 2;

    /// Particle i of phase `phase` (position, velocity, mass, density, fixed).
    pub(crate) fn of(phase: usize, ph: &Phase, i: usize) -> ParticleRecord {
        ParticleRecord {
            id: ph.id[i],
            phase: phase as u64,
            x: ph.x[i],
            v: ph.v[i],
            m: ph.m[i],
            rho: ph.rho.get(i).copied().unwrap_or(0.0),
            fixed: ph.is_fixed(i) as u64,
            ..Default::default()
        }
    }

    /// (phase, id): a particle's key over the ranks.
    pub fn key(&self) -> (u64, u64) {
        (self.phase, self.id)
    }

    /// h where it was solved (variable h), else 0.
    pub fn solved_h(&self) -> f64 {
        if self.flags & Self::HAS_H != 0 {
            self.h
        } else {
            0.0
        }
    }
}

pub(crate) fn full_pos(r: &ParticleRecord) -> [f64; 3] {
    r.x
}

/// Every particle of a state as records.
pub fn records(st: &State) -> Vec<ParticleRecord> {
    records_where(st, |_, _| true)
}

/// The particles of a state `keep(n, key)` says to keep, as records: n counts every
/// particle, gas first, then each dust fraction (the order of [`records`]).
pub fn records_where(
    st: &State,
    keep: impl FnMut(usize, (u64, u64)) -> bool,
) -> Vec<ParticleRecord> {
    let mut out = Vec::new();
    records_into(st, keep, &mut out);
    out
}

/// [`records_where`] into `out` (emptied first; its allocation kept).
pub fn records_into(
    st: &State,
    mut keep: impl FnMut(usize, (u64, u64)) -> bool,
    out: &mut Vec<ParticleRecord>,
) {
    out.clear();
    let mut n = 0;
    for (k, ph) in std::iter::once(&st.gas.ph)
        .chain(st.dust.iter())
        .enumerate()
    {
        for i in 0..ph.len() {
            n += 1;
            if keep(n - 1, (k as u64, ph.id[i])) {
                out.push(record_at(st, k, i));
            }
        }
    }
}

/// The record of particle i of phase k (0 the gas, then each dust fraction) of a state.
pub fn record_at(st: &State, k: usize, i: usize) -> ParticleRecord {
    let ph = if k == 0 { &st.gas.ph } else { &st.dust[k - 1] };
    let mut r = ParticleRecord::of(k, ph, i);
    if k == 0 {
        let g = &st.gas;
        if let Some(e) = &g.e {
            r.e = e[i];
        }
        if let (Some(h), Some(o)) = (&g.h, &g.omega) {
            r.flags |= ParticleRecord::HAS_H;
            r.h = h[i];
            r.omega = o[i];
        }
        if g.p.len() == ph.len() && g.c.len() == ph.len() {
            r.p = g.p[i];
            r.c = g.c[i];
        }
        if let Some(f) = &g.closing_forces {
            r.flags |= ParticleRecord::HAS_CLOSING_FORCES;
            r.closing_forces = f[i];
        }
    }
    r
}

/// A state from records (phases in order; `template` gives the phase count and whether the
/// gas has an energy or fixed particles).
pub fn state_of(recs: &[ParticleRecord], template: &State) -> State {
    let mut counts = vec![0; 1 + template.dust.len()];
    for r in recs {
        counts[r.phase as usize] += 1;
    }
    state_from(recs.iter().copied(), template, &counts)
}

/// [`state_of`] from records read one by one, `counts[k]` of phase k: each column allocated
/// once at its size (grown by doubling, a state built at an output took up to twice its
/// size).
pub fn state_from(
    recs: impl Iterator<Item = ParticleRecord>,
    template: &State,
    counts: &[usize],
) -> State {
    let mut st = template.shape();
    append_records(&mut st, recs, counts);
    st
}

/// Records read one by one appended to a state's phases (`counts[k]` of phase k: each column
/// grows once): a rank's own particles taking in those that arrive, and its halo. Each column
/// the records carry in part stays only while every particle has it: the gas's solved h and Ω
/// and closing forces; a phase's fixed flags appear where a record is fixed.
pub fn append_records(
    st: &mut State,
    recs: impl Iterator<Item = ParticleRecord>,
    counts: &[usize],
) {
    let nph = 1 + st.dust.len();
    let n_gas = st.gas.ph.len();
    let g = &mut st.gas;
    // Pressure and sound speed travel with every gas record (0 where the state had none).
    g.p.resize(n_gas, 0.0);
    g.c.resize(n_gas, 0.0);
    let gas_more = counts.first().copied().unwrap_or(0);
    // A column every gas particle so far has (all of none, where there was no gas yet).
    fn whole<T>(col: Option<Vec<T>>, n: usize) -> Option<Vec<T>> {
        match col {
            Some(v) if v.len() == n => Some(v),
            None if n == 0 => Some(Vec::new()),
            _ => None,
        }
    }
    let (mut h, mut omega) = (whole(g.h.take(), n_gas), whole(g.omega.take(), n_gas));
    let mut nf = whole(g.closing_forces.take(), n_gas);
    for v in [&mut h, &mut omega].into_iter().flatten() {
        v.reserve_exact(gas_more);
    }
    if let Some(v) = &mut nf {
        v.reserve_exact(gas_more);
    }
    {
        let g = &mut st.gas;
        for v in [&mut g.p, &mut g.c].into_iter().chain(&mut g.e) {
            v.reserve_exact(gas_more);
        }
    }
    for k in 0..nph {
        let more = counts.get(k).copied().unwrap_or(0);
        let ph = if k == 0 {
            &mut st.gas.ph
        } else {
            &mut st.dust[k - 1]
        };
        ph.id.reserve_exact(more);
        ph.x.reserve_exact(more);
        ph.v.reserve_exact(more);
        ph.m.reserve_exact(more);
        ph.rho.reserve_exact(more);
        if let Some(f) = &mut ph.fixed {
            f.reserve_exact(more);
        }
    }
    for r in recs {
        let k = r.phase as usize;
        let ph = if k == 0 {
            &mut st.gas.ph
        } else {
            &mut st.dust[k - 1]
        };
        ph.id.push(r.id);
        ph.x.push(r.x);
        ph.v.push(r.v);
        ph.m.push(r.m);
        ph.rho.push(r.rho);
        // Fixed particles: the scene's walls, and the deep halo's outer shell.
        if ph.fixed.is_none() && r.fixed != 0 {
            let mut f = vec![false; ph.id.len() - 1];
            f.reserve_exact(counts.get(k).copied().unwrap_or(0));
            ph.fixed = Some(f);
        }
        if let Some(f) = &mut ph.fixed {
            f.push(r.fixed != 0);
        }
        if k == 0 {
            let g = &mut st.gas;
            if let Some(e) = &mut g.e {
                e.push(r.e);
            }
            g.p.push(r.p);
            g.c.push(r.c);
            // A resumed layer: the solved h and Ω and the closing forces travel with their
            // particles (the engine then keeps them, as on resume).
            if r.flags & ParticleRecord::HAS_H != 0 {
                if let (Some(h), Some(o)) = (&mut h, &mut omega) {
                    h.push(r.h);
                    o.push(r.omega);
                }
            } else {
                (h, omega) = (None, None);
            }
            if r.flags & ParticleRecord::HAS_CLOSING_FORCES != 0 {
                if let Some(f) = &mut nf {
                    f.push(r.closing_forces);
                }
            } else {
                nf = None;
            }
        }
    }
    let g = &mut st.gas;
    let some_gas = !g.ph.is_empty();
    (g.h, g.omega) = if some_gas { (h, omega) } else { (None, None) };
    g.closing_forces = nf.filter(|_| some_gas);
}

#[cfg(test)]
mod tests {
    use super::{append_records, records, records_where, state_of, ParticleRecord};
    use crate::particles::{Gas, Phase, State};

    fn phase(n: usize, x0: f64) -> Phase {
        Phase {
            x: (0..n).map(|i| [x0 + i as f64, 0.5, -0.25]).collect(),
            v: (0..n).map(|i| [0.1 * i as f64, -1.0, 2.0]).collect(),
            m: vec![0.01; n],
            rho: (0..n).map(|i| 1.0 + i as f64).collect(),
            id: (0..n as u64).collect(),
            fixed: None,
        }
    }

    /// A gas of `n` particles with an energy and a solved h, and two dust fractions.
    fn state(n: usize) -> State {
        State {
            t: 0.5,
            step: 7,
            gas: Gas {
                ph: phase(n, 0.0),
                p: vec![2.0; n],
                c: vec![1.5; n],
                e: Some((0..n).map(|i| 3.0 + i as f64).collect()),
                h: Some((0..n).map(|i| 0.02 + 1e-4 * i as f64).collect()),
                omega: Some(vec![1.01; n]),
                closing_forces: None,
            },
            dust: vec![phase(300, -5.0), phase(77, 9.0)],
        }
    }

    /// A state made into records and back is the same state, and each of its columns is
    /// allocated once at its size (a state gathered at an output is built this way: grown by
    /// doubling it held up to twice its size).
    #[test]
    fn records_round_trip_into_columns_allocated_at_their_size() {
        let st = state(1000);
        let back = state_of(&records(&st), &st.shape());
        assert_eq!(back.gas, st.gas);
        assert_eq!(back.dust, st.dust);
        let exact = |len: usize, cap: usize| assert_eq!(len, cap, "a column's capacity");
        for ph in std::iter::once(&back.gas.ph).chain(&back.dust) {
            exact(ph.x.len(), ph.x.capacity());
            exact(ph.v.len(), ph.v.capacity());
            exact(ph.m.len(), ph.m.capacity());
            exact(ph.rho.len(), ph.rho.capacity());
            exact(ph.id.len(), ph.id.capacity());
        }
        let g = &back.gas;
        exact(g.p.len(), g.p.capacity());
        exact(g.c.len(), g.c.capacity());
        for col in [&g.e, &g.h, &g.omega].into_iter().flatten() {
            exact(col.len(), col.capacity());
        }
    }

    /// A rank's migration in place: the particles that leave dropped from the columns and
    /// appended again as records give back the same particles (in another order), each column
    /// grown once; a column the appended records lack (h and Ω) is dropped, and a fixed
    /// record gives its phase fixed flags, false for the particles already there.
    #[test]
    fn particles_dropped_in_place_and_appended_as_records_are_the_same_particles() {
        let st = state(500);
        let keep: Vec<bool> = (0..st.len()).map(|n| n % 3 != 1).collect();
        let leaving = records_where(&st, |n, _| !keep[n]);
        let mut counts = vec![0; 3];
        for r in &leaving {
            counts[r.phase as usize] += 1;
        }
        let mut own = st.clone();
        own.retain_rows(&keep);
        assert_eq!(own.len(), keep.iter().filter(|&&k| k).count());
        append_records(&mut own, leaving.into_iter(), &counts);
        // Each phase by id: the particles and every column of theirs as they were.
        let by_id = |st: &State| {
            let mut r = records(st);
            r.sort_by_key(|r| r.key());
            r
        };
        assert_eq!(by_id(&own), by_id(&st));
        assert!(own.gas.h.is_some() && own.gas.e.is_some());
        let g = &own.gas;
        for (len, cap) in [
            (g.ph.x.len(), g.ph.x.capacity()),
            (g.p.len(), g.p.capacity()),
            (
                g.h.as_ref().unwrap().len(),
                g.h.as_ref().unwrap().capacity(),
            ),
        ] {
            assert_eq!(len, cap, "a column grown more than once");
        }
        // A gas record without a solved h, and a fixed dust record.
        let mut bare = ParticleRecord::of(0, &st.gas.ph, 0);
        bare.id = 10_000;
        let mut wall = ParticleRecord::of(1, &st.dust[0], 0);
        (wall.id, wall.fixed) = (10_001, 1);
        append_records(&mut own, [bare, wall].into_iter(), &[1, 1, 0]);
        assert!(own.gas.h.is_none() && own.gas.omega.is_none());
        let f = own.dust[0]
            .fixed
            .as_ref()
            .expect("fixed flags once a particle is fixed");
        assert_eq!(f.len(), own.dust[0].len());
        assert_eq!(f.iter().filter(|&&f| f).count(), 1);
        assert!(f[f.len() - 1]);
    }
}
