//! A rank's particles for a step: its own migrated by the step's cut, and the halo (thin or
//! deep) exchanged with the other ranks; the state's rows by phase and key.
use super::{max_over, Comm, RankStepper, World};
use crate::dist::halo::{cut, halo_sends, shell};
use crate::dist::records::{append_records, record_at, ParticleRecord};
use crate::particles::{KeySet, State};

/// A rank's halo for one step ([`RankStepper::local_layer`]), beside its own particles (the
/// stepper's, migrated by the step's cut).
pub(super) struct LocalLayer {
    /// Per rank, the keys of the own particles sent to it as halo candidates.
    pub(super) to: Vec<Vec<(u64, u64)>>,
    /// Per rank, which of the candidates it sent here are kept ([`shell`]).
    pub(super) replies: Vec<Vec<u8>>,
    /// The halo's particles.
    pub(super) halo: Vec<ParticleRecord>,
    pub(super) ghost_keys: KeySet,
    pub(super) support: f64,
    /// The reach of one neighbour pass: the support or an IDIC cell's diagonal.
    pub(super) near: f64,
    /// How far the halo reaches.
    pub(super) reach: f64,
    /// The cut's cells.
    pub(super) cbox: crate::decomp::CellBox,
}

impl RankStepper {
    /// This rank's particles for a step: its own migrated by this step's cut, in place (only
    /// those that leave travel, as records), and the halo (thin: every neighbour and IDIC
    /// cell-mate of an owned particle, now and after the step's drift, the margin; deep: the
    /// step's chain of passes, and a fixed shell). `None` when the thin halo cannot serve (a
    /// rank holds no gas: the ghosts' refresh is collective inside the step, and every rank
    /// must step an engine). Collective.
    pub(super) fn local_layer(&mut self, thin: bool) -> Result<Option<LocalLayer>, String> {
        let world = &self.world;
        let domain = self.phys.domain;
        // The support: of the largest h over all ranks where h varies (the reference h at
        // least), so that the halo holds every neighbour of its stepped particles.
        let solved = self.own.gas.h.iter().flatten();
        let h_max = max_over(world, solved.fold(self.phys.h, |a, &h| a.max(h)));
        let support = crate::step::SUPPORT * h_max;
        let cell = self.phys.cell_diagonal();
        let near = support.max(cell);
        let (inner, reach) = if thin {
            (near + self.margin, near + self.margin)
        } else {
            (self.depth * support, (self.depth + 1.0) * support)
        };
        let xs: Vec<[f64; 3]> = positions(&self.own).collect();
        let part = cut(world, &xs, &domain, reach, self.cost);
        self.rebalances += (thin && self.cost.is_some()) as u64;
        drop(xs);
        migrate_own(world, &part, &mut self.own)?;
        let own = &self.own;
        let xs: Vec<[f64; 3]> = positions(own).collect();
        let to = halo_sends(world.size(), &part, &xs, |x| *x);
        drop(xs);
        // Rank by rank in one buffer: one copy of each record sent, received straight into
        // records.
        let at = row_of(own);
        let sends: Vec<ParticleRecord> = (to.iter().flatten())
            .map(|&n| {
                let (k, i) = at(n);
                record_at(own, k, i)
            })
            .collect();
        let counts: Vec<usize> = to.iter().map(Vec::len).collect();
        let (halo, from) = world.exchange_flat_from(&sends, &counts)?;
        // Only the owned particles sent as halo can lie within `reach` of one received: an
        // owned particle within reach of a particle of rank q has a cell of q within its ring.
        let (kept, flags) = shell(&sends, &halo, inner, reach, &domain);
        // Which of each rank's candidates are kept, for its refreshes.
        let mut flag = flags.iter().map(|&f| f as u8);
        let replies = (from.iter())
            .map(|&c| flag.by_ref().take(c).collect())
            .collect();
        let mut sent = sends.iter().map(ParticleRecord::key);
        let to = (counts.iter())
            .map(|&c| sent.by_ref().take(c).collect())
            .collect();
        drop((sends, halo));
        let ghost_keys: KeySet = kept.iter().map(|r| r.key()).collect();
        let gas_here = !own.gas.ph.is_empty() || kept.iter().any(|r| r.phase == 0);
        if thin && world.any(!gas_here) {
            return Ok(None);
        }
        Ok(Some(LocalLayer {
            to,
            replies,
            halo: kept,
            ghost_keys,
            support,
            near,
            reach,
            cbox: part.cbox,
        }))
    }
}

/// Every particle's position in a state, gas first, then each dust fraction (the order of
/// [`State::retain_rows`]).
pub(super) fn positions(st: &State) -> impl Iterator<Item = [f64; 3]> + '_ {
    std::iter::once(&st.gas.ph)
        .chain(&st.dust)
        .flat_map(|ph| ph.x.iter().copied())
}

/// Every particle's key (phase, id), in the order of [`positions`].
pub(super) fn keys_of(st: &State) -> impl Iterator<Item = (u64, u64)> + '_ {
    (std::iter::once(&st.gas.ph).chain(&st.dust))
        .enumerate()
        .flat_map(|(k, ph)| ph.id.iter().map(move |&id| (k as u64, id)))
}

/// The phase and index of a state's n-th particle (the order of [`positions`]).
pub(super) fn row_of(st: &State) -> impl Fn(usize) -> (usize, usize) {
    let mut starts = vec![0usize];
    for ph in std::iter::once(&st.gas.ph).chain(&st.dust) {
        starts.push(starts.last().copied().unwrap_or(0) + ph.len());
    }
    move |n| {
        let k = starts.partition_point(|&s| s <= n) - 1;
        (k, n - starts[k])
    }
}

/// Records per phase (phase 0 the gas, then each of `nph - 1` dust fractions).
pub(super) fn phase_counts(recs: &[ParticleRecord], nph: usize) -> Vec<usize> {
    let mut c = vec![0; nph];
    for r in recs {
        c[r.phase as usize] += 1;
    }
    c
}

/// A rank's own particles to the ranks owning their cells under `part` (collective): those
/// that leave go as records and are dropped here, those that arrive are appended; the rest
/// stay where they lie.
fn migrate_own(
    world: &World,
    part: &crate::decomp::Partition,
    own: &mut State,
) -> Result<(), String> {
    let me = world.rank();
    let mut sends: Vec<Vec<ParticleRecord>> = vec![Vec::new(); world.size() as usize];
    let at = row_of(own);
    let stays: Vec<bool> = (positions(own).enumerate())
        .map(|(n, x)| {
            let q = part.owner_at(x);
            if q != me {
                let (k, i) = at(n);
                sends[q as usize].push(record_at(own, k, i));
            }
            q == me
        })
        .collect();
    own.retain_rows(&stays);
    drop(stays);
    let arrived = world.exchange(&sends)?;
    drop(sends);
    let counts = phase_counts(&arrived, 1 + own.dust.len());
    append_records(own, arrived.into_iter(), &counts);
    Ok(())
}
