//! The time bins individual steps would give a state (method.md §T): each particle's own step
//! from its own limits ([`crate::step::timestep::own_step`]: CFL with its h and signal speed,
//! force, the edge zones, `time.dt_max`), its power-of-two bin
//! ([`dustsph_device::timestep::bin_of`]), then the neighbour limiter of Saitoh & Makino (2009,
//! ApJ 697, L99): no particle steps more than [`NEIGHBOUR_SPAN`] bins slower than a particle
//! of its phase within its kernel support, and a grain steps no slower than the gas within its
//! support, its drag partners ([`PARTNER_SPAN`]). What it measures: the particle updates a
//! global step takes for each one individual steps would, on the run's own state.
use super::support_grid::SupportGrid;
use crate::particles::State;
use crate::scene::Time;
use crate::step::timestep::own_step;
use crate::step::Physics;
use dustsph_device::timestep::bin_of;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Bins counted: steps from dt_min to 2^(MAX_BIN) dt_min.
pub const MAX_BIN: u32 = 15;
/// The limiter's span: a particle's bin at most this many bins above any neighbour's of its
/// own phase.
pub const NEIGHBOUR_SPAN: u32 = 2;
/// A grain steps no slower than the gas within its support (its drag partners): the dust has
/// no pressure to set its step, the drag with its gas does (method.md §T). Not the other way:
/// over overlapping supports a two-way rule would chain every particle to the shortest bin.
pub const PARTNER_SPAN: u32 = 0;

/// The bins of one state.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct BinCensus {
    pub t: f64,
    /// The shortest own step of any particle: bin j steps 2^j dt_min.
    pub dt_min: f64,
    /// Gas particles per bin (j = 0 first).
    pub gas: Vec<u64>,
    /// Dust particles per bin (all fractions; particles held fixed left out).
    pub dust: Vec<u64>,
    /// Particles whose bin the neighbour limiter shortened.
    pub limited: u64,
    /// Σ 1 / Σ 2^-j over the particles: the updates a global step at dt_min takes per update
    /// of individual steps, to the same time (synchronisation at outputs not counted).
    pub update_ratio: f64,
    /// The run's own global step at this state ([`crate::step::timestep::StepPlanner`]'s rule:
    /// the reference h with the largest signal speed and |A|). Under variable h it differs from
    /// dt_min either way: the particles' own h are smaller or larger than the reference.
    pub dt_global: f64,
    /// The updates the run's global step takes per update of individual steps:
    /// update_ratio × dt_min / dt_global.
    pub update_ratio_vs_run: f64,
}

/// Each particle's bin before the limiter, and its kernel support, gas first then each dust
/// fraction's moving particles.
struct Own {
    x: Vec<[f64; 3]>,
    support: Vec<f64>,
    dt: Vec<f64>,
    n_gas: usize,
    /// The global step's rule on the same limits.
    dt_global: f64,
}

/// Each particle's own step and bin, gas first then each fraction's moving grains.
#[derive(Debug, Clone)]
pub struct Bins {
    /// The particle's own step ([`own_step`]).
    pub own: Vec<f64>,
    /// Its bin after the limiters: it steps 2^bin dt_min.
    pub bin: Vec<u32>,
    /// Its bin from its own step alone.
    pub alone: Vec<u32>,
    pub dt_min: f64,
    /// The run's global step rule on the same state.
    pub dt_global: f64,
    pub n_gas: usize,
}

impl Bins {
    /// The step particle `a` takes.
    pub fn step(&self, a: usize) -> f64 {
        self.dt_min * 2f64.powi(self.bin[a] as i32)
    }
}

/// The bins of `state` (synced) with each gas particle's |A| and signal speed in the same
/// order; `None` for a fixed `time.dt` (every particle takes the same step) or no particles.
pub fn particle_bins(
    state: &State,
    phys: &Physics,
    time: &Time,
    (acc, vsig): (&[[f64; 3]], &[f64]),
) -> Option<Bins> {
    let own = own_steps(state, phys, time, (acc, vsig))?;
    let dt_min = own.dt.iter().copied().fold(f64::INFINITY, f64::min);
    if !(dt_min.is_finite() && dt_min > 0.0) {
        return None;
    }
    let alone: Vec<u32> = own.dt.iter().map(|&d| bin_of(d, dt_min, MAX_BIN)).collect();
    let mut bin = alone.clone();
    limit_by_neighbours(&own, &mut bin);
    Some(Bins {
        bin,
        alone,
        dt_min,
        dt_global: own.dt_global,
        n_gas: own.n_gas,
        own: own.dt,
    })
}

/// The census of `state` (synced) with each gas particle's |A| and signal speed in the same
/// order; `None` for a fixed `time.dt` (every particle takes the same step) or no particles.
pub fn census(
    state: &State,
    phys: &Physics,
    time: &Time,
    limits: (&[[f64; 3]], &[f64]),
) -> Option<BinCensus> {
    let b = particle_bins(state, phys, time, limits)?;
    let mut gas = vec![0u64; MAX_BIN as usize + 1];
    let mut dust = gas.clone();
    for (i, &j) in b.bin.iter().enumerate() {
        let c = if i < b.n_gas { &mut gas } else { &mut dust };
        c[j as usize] += 1;
    }
    let trim = |c: &mut Vec<u64>| {
        while c.last() == Some(&0) {
            c.pop();
        }
    };
    trim(&mut gas);
    trim(&mut dust);
    let updates: f64 = b.bin.iter().map(|&j| 0.5f64.powi(j as i32)).sum();
    let update_ratio = b.bin.len() as f64 / updates;
    Some(BinCensus {
        t: state.t,
        dt_min: b.dt_min,
        gas,
        dust,
        limited: b.bin.iter().zip(&b.alone).filter(|(a, c)| a != c).count() as u64,
        update_ratio,
        dt_global: b.dt_global,
        update_ratio_vs_run: update_ratio * b.dt_min / b.dt_global,
    })
}

fn own_steps(
    state: &State,
    phys: &Physics,
    time: &Time,
    (acc, vsig): (&[[f64; 3]], &[f64]),
) -> Option<Own> {
    let g = &state.gas;
    let pm = &phys.gravity;
    let norm = |a: [f64; 3]| dustsph_device::dot(a, a).sqrt();
    let mut own = Own {
        x: Vec::new(),
        support: Vec::new(),
        dt: Vec::new(),
        n_gas: g.ph.len(),
        dt_global: 0.0,
    };
    let (mut vsig_max, mut acc_max, mut damp_max) = (0.0f64, 0.0f64, 0.0f64);
    for i in 0..g.ph.len() {
        let h = g.h.as_ref().map_or(phys.h, |h| h[i]);
        let x = g.ph.x[i];
        let (a, rate) = (norm(acc[i]), pm.damp_rate(x));
        own.dt.push(own_step(time, h, vsig[i], a, rate)?);
        // The global rule's maxima, each with the particle's own h (method.md §T).
        let scale = phys.h / h;
        (vsig_max, acc_max) = (vsig_max.max(vsig[i] * scale), acc_max.max(a * scale));
        damp_max = damp_max.max(rate);
        own.x.push(x);
        own.support.push(2.0 * h);
    }
    let dim = phys.dim as i32;
    for ph in &state.dust {
        for i in 0..ph.len() {
            if ph.fixed.as_ref().is_some_and(|f| f[i]) {
                continue;
            }
            let x = ph.x[i];
            // Variable h: the dust's h from its density, as the snapshots write it.
            let h = match phys.variable_h {
                Some(hfact) if ph.rho[i] > 0.0 => {
                    hfact * (ph.m[i] / ph.rho[i]).powf(1.0 / dim as f64)
                }
                _ => phys.h,
            };
            let a = dustsph_device::timestep::dust_pull(pm, phys.ext_dust, x);
            let rate = pm.damp_rate(x);
            own.dt.push(own_step(time, h, 0.0, a, rate)?);
            (acc_max, damp_max) = (acc_max.max(a), damp_max.max(rate));
            own.x.push(x);
            own.support.push(2.0 * h);
        }
    }
    own.dt_global = own_step(time, phys.h, vsig_max, acc_max, damp_max)?;
    (!own.dt.is_empty()).then_some(own)
}

/// Lower each bin to at most [`NEIGHBOUR_SPAN`] above the lowest bin of its phase, and a
/// grain's to the lowest gas bin, within the particle's support (|x_b − x_a| < 2h_a), repeated
/// until nothing changes (a lowered bin lowers its neighbours' in turn; each pass reads the last
/// pass's bins, so the result does not depend on the threads). Cells of half the median
/// support: those wholly inside the support count by their lowest bins, those it cuts particle
/// by particle.
fn limit_by_neighbours(own: &Own, bins: &mut [u32]) {
    let mut s: Vec<f64> = own.support.clone();
    s.sort_by(f64::total_cmp);
    let grid = SupportGrid::new(&own.x, 0.5 * s[s.len() / 2]);
    let phase = |a: usize| (a >= own.n_gas) as usize;
    loop {
        // Each cell's lowest bin of each phase (gas, dust).
        let lowest: rustc_hash::FxHashMap<[i64; 3], [u32; 2]> = (grid.members.iter())
            .map(|(k, m)| {
                let mut l = [u32::MAX; 2];
                for &a in m {
                    l[phase(a)] = l[phase(a)].min(bins[a]);
                }
                (*k, l)
            })
            .collect();
        let old: &[u32] = bins;
        let limited: Vec<u32> = (0..old.len())
            .into_par_iter()
            .map(|a| {
                let (xa, r) = (own.x[a], own.support[a]);
                let mut l = [u32::MAX; 2];
                grid.cells_within(xa, r, |c, m, whole| {
                    if whole {
                        let lc = lowest[&c];
                        l = [l[0].min(lc[0]), l[1].min(lc[1])];
                        return;
                    }
                    for &b in m {
                        let d = dustsph_device::sub(own.x[b], xa);
                        if dustsph_device::dot(d, d) < r * r {
                            l[phase(b)] = l[phase(b)].min(old[b]);
                        }
                    }
                });
                let p = phase(a);
                let mut most = l[p].saturating_add(NEIGHBOUR_SPAN);
                if p == 1 {
                    most = most.min(l[0].saturating_add(PARTNER_SPAN));
                }
                old[a].min(most)
            })
            .collect();
        if limited == bins {
            break;
        }
        bins.copy_from_slice(&limited);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Particles on a line at unit spacing, support 2.5 (two neighbours each side): gas with
    /// own steps `gas_dt`, then dust at the same places with `dust_dt`.
    fn line(gas_dt: &[f64], dust_dt: &[f64]) -> (Own, Vec<u32>) {
        let at = |i: usize| [i as f64, 0.0, 0.0];
        let x: Vec<[f64; 3]> = (0..gas_dt.len())
            .map(at)
            .chain((0..dust_dt.len()).map(at))
            .collect();
        let dt: Vec<f64> = gas_dt.iter().chain(dust_dt).copied().collect();
        let bins = dt.iter().map(|&d| bin_of(d, 1.0, MAX_BIN)).collect();
        let own = Own {
            support: vec![2.5; x.len()],
            x,
            dt,
            n_gas: gas_dt.len(),
            dt_global: 1.0,
        };
        (own, bins)
    }

    #[test]
    fn the_limiter_keeps_a_particle_within_two_bins_of_its_neighbours_and_grains_with_their_gas() {
        // Gas: 20 particles at bin 0, then 40 that alone could take bin 10; dust everywhere
        // alone at bin 12 (no force), except one grain at bin 0 among the slow gas.
        let gas: Vec<f64> = (0..60).map(|i| if i < 20 { 1.0 } else { 1024.0 }).collect();
        let mut dust = vec![4096.0; 60];
        dust[50] = 1.0;
        let (own, mut bins) = line(&gas, &dust);
        let alone = bins.clone();
        limit_by_neighbours(&own, &mut bins);
        let n = own.n_gas;
        for a in 0..bins.len() {
            assert!(
                bins[a] <= alone[a],
                "particle {a}: the limiter lengthened its step"
            );
            for b in 0..bins.len() {
                let d = (own.x[a][0] - own.x[b][0]).abs();
                if d >= own.support[a] {
                    continue;
                }
                if (a < n) == (b < n) {
                    assert!(bins[a] <= bins[b] + NEIGHBOUR_SPAN, "{a} vs {b}: {bins:?}");
                } else if a >= n {
                    assert!(
                        bins[a] <= bins[b],
                        "grain {a} slower than gas {b}: {bins:?}"
                    );
                }
            }
        }
        // The ramp away from the fast gas: two bins per two particles (the support reaches two
        // neighbours), and the far gas keeps its own bin 10.
        assert_eq!(&bins[20..26], &[2, 2, 4, 4, 6, 6]);
        assert_eq!(bins[59], 10);
        // The fast grain does not shorten the gas around it.
        assert_eq!(bins[49], 10);
        // A grain takes its gas's bin, not its own bin 12.
        assert_eq!(bins[n + 59], 10);
        assert_eq!(bins[n + 50], 0, "a grain's own short step stays");
    }
}
