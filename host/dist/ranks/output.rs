//! Outputs over the ranks: the dust's fields on each rank's engine, written by share or
//! gathered on rank 0 as streams of records merged in key order.
use super::layer::{keys_of, row_of};
use super::resident::ghost_flags;
use super::{abort_job, Comm, RankStepper, World, STAGE_BUILD, STAGE_OUTPUT, STAGE_OWN_OUTPUT};
use crate::dist::records::{record_at, state_from, ParticleRecord};
use crate::particles::State;

impl RankStepper {
    /// An output's dust densities and stopping times per fraction, on the resident engine
    /// (built first where there is none: timed as a build, not as the output), for every
    /// particle of its host copy at time `t`, step `step`, which is synced whole beside its
    /// ghost flags; the refresh's buffers freed until the next step (collective). `None` where
    /// no rank steps on a thin halo.
    fn output_fields_here(
        &mut self,
        t: f64,
        step: u64,
        t0: &mut std::time::Instant,
    ) -> Result<Option<Vec<Vec<f64>>>, String> {
        if self.thin && self.resident.is_none() {
            self.resident = self.build_resident(step)?;
            self.timers.add(STAGE_BUILD, t0.elapsed().as_secs_f64());
            *t0 = std::time::Instant::now();
        }
        let Some(res) = self.resident.as_mut() else {
            return Ok(None);
        };
        res.local.t = t;
        res.local.step = step;
        let ts = (res.eng.dust_stopping_times(&mut res.local))
            .unwrap_or_else(|x| abort_job(&self.world, step, &x));
        res.flags = ghost_flags(&res.eng);
        res.eng.free_refresh_buffers();
        Ok(Some(ts))
    }

    /// `f` of this rank's own particles as they stand, at time `t`, step `step`, read where they
    /// lie (the resident engine's host copy drops its ghost rows until the next sync: a retake
    /// of the next step starts from them, none flagged), and the ranks.
    pub fn with_own<R>(&mut self, t: f64, step: u64, f: impl FnOnce(&State, &World) -> R) -> R {
        let own = match (self.resident.as_mut(), self.owned_stale) {
            (Some(res), true) => {
                res.local
                    .retain_rows(&res.flags.iter().map(|&g| !g).collect::<Vec<_>>());
                res.flags = vec![false; res.local.len()];
                &mut res.local
            }
            _ => &mut self.own,
        };
        own.t = t;
        own.step = step;
        f(own, &self.world)
    }

    /// An output written by share: `write` gets this rank's own particles at time `t`, step
    /// `step`, with the dust densities and stopping times per fraction its engine computed for
    /// them (the ghosts refreshed between), and the ranks (collective); `None` on every rank
    /// where no rank steps on a thin halo (the deep halo, a rank without gas: the output is
    /// gathered instead).
    pub fn own_output<R>(
        &mut self,
        t: f64,
        step: u64,
        write: impl FnOnce(&State, &[Vec<f64>], &World) -> R,
    ) -> Result<Option<R>, String> {
        let mut t0 = std::time::Instant::now();
        let Some(ts) = self.output_fields_here(t, step, &mut t0)? else {
            return Ok(None);
        };
        let res = self.resident.as_ref().expect("fields computed");
        // The stopping times of the own rows (`with_own` drops the ghosts' rows).
        let mut at = res.local.gas.ph.len();
        let ts: Vec<Vec<f64>> = (ts.into_iter().zip(&res.local.dust))
            .map(|(v, ph)| {
                let g = &res.flags[at..at + ph.len()];
                at += ph.len();
                v.into_iter()
                    .zip(g)
                    .filter(|p| !*p.1)
                    .map(|p| p.0)
                    .collect()
            })
            .collect();
        let done = self.with_own(t, step, |own, world| write(own, &ts, world));
        self.timers
            .add(STAGE_OWN_OUTPUT, t0.elapsed().as_secs_f64());
        Ok(Some(done))
    }

    /// Every rank's particles as one state on rank 0 for an output (`None` on the other
    /// ranks), with the dust densities and stopping times each rank's engine computed for its
    /// own particles, the ghosts refreshed between (collective). Where no rank steps on a thin
    /// halo (the deep halo, a rank without gas) the stopping times are `None`: rank 0 computes
    /// them on the gathered state.
    #[allow(clippy::type_complexity)]
    pub fn gather_output(
        &mut self,
        t: f64,
        step: u64,
    ) -> Result<Option<(State, Option<Vec<Vec<f64>>>)>, String> {
        let mut t0 = std::time::Instant::now();
        let Some(ts) = self.output_fields_here(t, step, &mut t0)? else {
            return Ok(self.gather(t, step)?.map(|st| (st, None)));
        };
        let (res, world) = (
            self.resident.as_mut().expect("fields computed"),
            &self.world,
        );
        // The own particles in key order (phase, index), read where they lie: the engine's
        // host copy keeps them (the output's dust densities too, which the next steps start
        // from, as one process's engine does), and their records only pass through the
        // stream to rank 0, a message at a time.
        let (ghost, local) = (&res.flags, &res.local);
        let mut own: Vec<((u64, u64), u32, u32)> = Vec::with_capacity(ghost.len());
        let phases = std::iter::once(&local.gas.ph).chain(local.dust.iter());
        let mut n = 0;
        for (k, ph) in phases.enumerate() {
            for i in 0..ph.len() {
                if !ghost[n] {
                    own.push(((k as u64, ph.id[i]), k as u32, i as u32));
                }
                n += 1;
            }
        }
        own.sort_unstable_by_key(|o| o.0);
        let at = |j: usize| {
            let (k, i) = (own[j].1 as usize, own[j].2 as usize);
            (record_at(local, k, i), (k > 0).then(|| ts[k - 1][i]))
        };
        let mut counts = vec![0u64; 1 + local.dust.len()];
        for o in &own {
            counts[o.1 as usize] += 1;
        }
        let gathered = gather_sorted(world, &self.template, &counts, at, true, (t, step));
        self.timers.add(STAGE_OUTPUT, t0.elapsed().as_secs_f64());
        Ok(gathered)
    }

    /// Every rank's particles as one state on rank 0 (phases in order, each by particle id),
    /// at time `t`, step `step`; `None` on the other ranks. Collective.
    fn gather(&mut self, t: f64, step: u64) -> Result<Option<State>, String> {
        let own = &self.own;
        let row = row_of(own);
        let mut order: Vec<((u64, u64), u32, u32)> = (keys_of(own).enumerate())
            .map(|(n, key)| {
                let (k, i) = row(n);
                (key, k as u32, i as u32)
            })
            .collect();
        order.sort_unstable_by_key(|o| o.0);
        let at = |j: usize| {
            (
                record_at(own, order[j].1 as usize, order[j].2 as usize),
                None,
            )
        };
        let counts: Vec<u64> = (std::iter::once(&own.gas.ph).chain(&own.dust))
            .map(|ph| ph.len() as u64)
            .collect();
        let st = gather_sorted(&self.world, &self.template, &counts, at, false, (t, step));
        Ok(st.map(|(st, _)| st))
    }
}

/// Records per message of a rank's stream to rank 0 at an output (5.8 MB): no rank holds its
/// whole share as records for the gather, nor rank 0 every rank's.
const STREAM_RECORDS: usize = 32 * 1024;

/// [`STREAM_RECORDS`], or `DUSTSPH_STREAM_RECORDS` where set (tests/mpi.rs streams a small
/// run in many short messages).
fn stream_records() -> usize {
    crate::env::count("DUSTSPH_STREAM_RECORDS", STREAM_RECORDS)
}

/// Every rank's particles as one state on rank 0 (phases in order, each by particle id), at
/// time `t`, step `step`; `None` on the other ranks. Collective. This rank has `n`, `at(j)` the
/// j-th in key order: its record and, with `values`, a value per dust record (gathered per
/// fraction in the state's order). Each rank streams its records in key order to rank 0 a
/// message at a time ([`stream_records`]: records, then the values of the dust among them),
/// and rank 0 merges the streams with its own, reading each record once, in order.
#[allow(clippy::type_complexity)]
fn gather_sorted(
    world: &World,
    template: &State,
    phase_counts: &[u64],
    at: impl Fn(usize) -> (ParticleRecord, Option<f64>),
    values: bool,
    (t, step): (f64, u64),
) -> Option<(State, Option<Vec<Vec<f64>>>)> {
    let per_msg = stream_records();
    let n = phase_counts.iter().sum::<u64>() as usize;
    let Some(counts) = world.gather_bytes(bytemuck::cast_slice(phase_counts)) else {
        stream_to_root(world, n, per_msg, &at);
        return None;
    };
    let runs = counts.len();
    let (totals, mut left) = totals_and_left(&counts, phase_counts.len());
    let mut own_at = 0;
    let mut pending: Vec<std::vec::IntoIter<(ParticleRecord, Option<f64>)>> =
        (0..runs).map(|_| Vec::new().into_iter()).collect();
    // A run's next record: rank 0's own read where it lies, the others' from their streams
    // (a malformed message stops the job: the other ranks have gone on to the next step).
    let mut pull = |r: usize| -> Option<(ParticleRecord, Option<f64>)> {
        if r == 0 {
            own_at += 1;
            return (own_at <= n).then(|| at(own_at - 1));
        }
        if let Some(x) = pending[r].next() {
            return Some(x);
        }
        if left[r] == 0 {
            return None;
        }
        let k = left[r].min(per_msg);
        left[r] -= k;
        let msg = world.receive_from(r as u32);
        pending[r] = read_message(world, step, (r, k), &msg, values).into_iter();
        pending[r].next()
    };
    let mut head = Vec::with_capacity(runs);
    for r in 0..runs {
        head.push(pull(r));
    }
    let mut per_fraction: Vec<Vec<f64>> = (1..totals.len())
        .map(|k| Vec::with_capacity(if values { totals[k] } else { 0 }))
        .collect();
    let merged = std::iter::from_fn(|| {
        let r = (0..runs)
            .filter(|&r| head[r].is_some())
            .min_by_key(|&r| head[r].map(|h| h.0.key()))?;
        let (rec, v) = head[r].take().expect("a run's head");
        head[r] = pull(r);
        if let Some(v) = v {
            per_fraction[rec.phase as usize - 1].push(v);
        }
        Some(rec)
    });
    let mut st = state_from(merged, template, &totals);
    st.t = t;
    st.step = step;
    Some((st, values.then_some(per_fraction)))
}

/// A record's bytes in a rank's stream to rank 0.
const REC: usize = std::mem::size_of::<ParticleRecord>();

/// A rank's stream to rank 0 ([`gather_sorted`]): its `n` records `at(j)` in key order,
/// `per_msg` a message (records, then the values of the dust among them).
fn stream_to_root(
    world: &World,
    n: usize,
    per_msg: usize,
    at: &impl Fn(usize) -> (ParticleRecord, Option<f64>),
) {
    let mut msg = Vec::with_capacity(per_msg.min(n) * (REC + 8));
    let mut vals = Vec::new();
    for lo in (0..n).step_by(per_msg) {
        msg.clear();
        vals.clear();
        for j in lo..(lo + per_msg).min(n) {
            let (rec, v) = at(j);
            msg.extend_from_slice(bytemuck::bytes_of(&rec));
            vals.extend(v);
        }
        msg.extend_from_slice(bytemuck::cast_slice(&vals));
        world.send_to_root(&msg);
    }
}

/// From every rank's count per phase (`counts`, as gathered bytes; `nph` phases): the whole
/// state's (its columns are allocated at their size), and the records left to receive from
/// each rank (none from rank 0, whose own are read where they lie).
fn totals_and_left(counts: &[Vec<u8>], nph: usize) -> (Vec<usize>, Vec<usize>) {
    let per_phase = |b: &Vec<u8>| -> Vec<usize> {
        (b.chunks_exact(8))
            .map(|c| u64::from_le_bytes(c.try_into().expect("a count")) as usize)
            .collect()
    };
    let mut totals = vec![0usize; nph];
    let mut left: Vec<usize> = Vec::with_capacity(counts.len());
    for b in counts {
        let c = per_phase(b);
        for (t, x) in totals.iter_mut().zip(&c) {
            *t += x;
        }
        left.push(c.iter().sum());
    }
    left[0] = 0;
    (totals, left)
}

/// Rank `r`'s next message of its stream to rank 0, `k` records (with `values`, each dust
/// record's value): the records and their values, in order. A malformed message stops the
/// job (the other ranks have gone on to the next step).
fn read_message(
    world: &World,
    step: u64,
    (r, k): (usize, usize),
    msg: &[u8],
    values: bool,
) -> Vec<(ParticleRecord, Option<f64>)> {
    let malformed = |want: usize| -> ! {
        let why = format!(
            "rank {r}'s output stream sent {} bytes where {k} records need {want}",
            msg.len()
        );
        abort_job(world, step, &why)
    };
    if msg.len() < k * REC {
        malformed(k * REC);
    }
    let recs: Vec<ParticleRecord> = (0..k)
        .map(|i| bytemuck::pod_read_unaligned(&msg[i * REC..][..REC]))
        .collect();
    let dust = recs.iter().filter(|x| x.phase > 0).count();
    let want = k * REC + if values { 8 * dust } else { 0 };
    if msg.len() != want {
        malformed(want);
    }
    let mut v = (msg[k * REC..].chunks_exact(8)).map(bytemuck::pod_read_unaligned);
    (recs.into_iter())
        .map(|x| (x, (values && x.phase > 0).then(|| v.next()).flatten()))
        .collect()
}
