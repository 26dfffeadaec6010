//! Particles as they travel between ranks: [`ParticleRecord`] (a plain-data row per particle)
//! and the conversions from and to a [`State`]. Plain data without MPI: the ranks (with the mpi
//! feature) send them as bytes.
use crate::particles::{Gas, Phase, State};

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
    /// Gas under the leapfrog: the closing forces (A, ė, v_sig) the next step starts from.
    pub closing_forces: [f64; 5],
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

#[cfg(feature = "mpi")]
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
        if let Some(f) = &g.next_forces {
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
    let nph = 1 + template.dust.len();
    let mut phases: Vec<Phase> = (0..nph)
        .map(|k| {
            let n = counts.get(k).copied().unwrap_or(0);
            Phase {
                id: Vec::with_capacity(n),
                x: Vec::with_capacity(n),
                v: Vec::with_capacity(n),
                m: Vec::with_capacity(n),
                rho: Vec::with_capacity(n),
                ..Phase::default()
            }
        })
        .collect();
    let mut fixed: Vec<Vec<bool>> = (0..nph)
        .map(|k| Vec::with_capacity(counts.get(k).copied().unwrap_or(0)))
        .collect();
    let gas = || Vec::with_capacity(counts.first().copied().unwrap_or(0));
    let has_e = template.gas.e.is_some();
    let mut e = if has_e { gas() } else { Vec::new() };
    let (mut pres, mut cs) = (gas(), gas());
    // The solved h and Ω and the closing forces only while every gas record has them.
    let (mut h, mut omega) = (gas(), gas());
    let mut nf: Vec<[f64; 5]> = Vec::with_capacity(counts.first().copied().unwrap_or(0));
    let (mut all_h, mut all_nf) = (true, true);
    let mut some_gas = false;
    for r in recs {
        let k = r.phase as usize;
        some_gas |= k == 0;
        let ph = &mut phases[k];
        ph.id.push(r.id);
        ph.x.push(r.x);
        ph.v.push(r.v);
        ph.m.push(r.m);
        ph.rho.push(r.rho);
        fixed[k].push(r.fixed != 0);
        if k == 0 {
            if has_e {
                e.push(r.e);
            }
            pres.push(r.p);
            cs.push(r.c);
            if all_h && r.flags & ParticleRecord::HAS_H != 0 {
                h.push(r.h);
                omega.push(r.omega);
            } else if all_h {
                all_h = false;
                (h, omega) = (Vec::new(), Vec::new());
            }
            if all_nf && r.flags & ParticleRecord::HAS_CLOSING_FORCES != 0 {
                nf.push(r.closing_forces);
            } else if all_nf {
                all_nf = false;
                nf = Vec::new();
            }
        }
    }
    // Fixed particles: the scene's walls, and the halo's outer shell.
    let mut with_fixed = |k: usize, t: &Phase| {
        let f = std::mem::take(&mut fixed[k]);
        (t.fixed.is_some() || f.iter().any(|&f| f)).then_some(f)
    };
    let mut gas_ph = std::mem::take(&mut phases[0]);
    gas_ph.fixed = with_fixed(0, &template.gas.ph);
    let dust = phases
        .into_iter()
        .enumerate()
        .skip(1)
        .map(|(k, mut p)| {
            p.fixed = with_fixed(k, &template.dust[k - 1]);
            p
        })
        .collect();
    State {
        t: template.t,
        step: template.step,
        gas: Gas {
            ph: gas_ph,
            e: template.gas.e.as_ref().map(|_| e),
            // A resumed layer: the solved h and Ω and the closing forces travel with their
            // particles (the engine then keeps them, as on resume).
            h: (some_gas && all_h).then_some(h),
            omega: (some_gas && all_h).then_some(omega),
            next_forces: (some_gas && all_nf).then_some(nf),
            p: pres,
            c: cs,
        },
        dust,
    }
}

#[cfg(test)]
mod tests {
    use super::{records, state_of};
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

    /// A state made into records and back is the same state, and each of its columns is
    /// allocated once at its size (a state gathered at an output is built this way: grown by
    /// doubling it held up to twice its size).
    #[test]
    fn records_round_trip_into_columns_allocated_at_their_size() {
        let n = 1000;
        let st = State {
            t: 0.5,
            step: 7,
            gas: Gas {
                ph: phase(n, 0.0),
                p: vec![2.0; n],
                c: vec![1.5; n],
                e: Some(vec![3.0; n]),
                h: Some(vec![0.02; n]),
                omega: Some(vec![1.01; n]),
                next_forces: None,
            },
            dust: vec![phase(300, -5.0), phase(77, 9.0)],
        };
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
}
