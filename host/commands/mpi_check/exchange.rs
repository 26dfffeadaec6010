//! `dustsph mpi-check SCENE`, under `mpirun -n R`: the decomposition and the particle exchange
//! of issue 14 on a scene's real particles, checked on every rank (docs/scaling.md).
//!
//! Every rank builds the scene's particles (the set-up is deterministic) and starts from a
//! scrambled share (particle k on rank k mod R). Then, as a run over ranks would each step:
//! global bounds and per-cell counts by all-reduce, the same Morton cut on every rank
//! ([`Partition`], cells half `depth` kernel supports wide), migration of each particle to
//! the rank owning its cell, and the halo exchange (copies of the particles in the cells within
//! reach of another rank's cells). Checks: every particle is owned by exactly one rank, the one owning
//! its cell; owned and halo counts equal the partition's; and no particle within `depth`
//! supports of an owned particle (minimum image on periodic axes) is missing from owned ∪ halo.
//! A rank that fails reports why and every rank exits 1 (an all-reduce of the failure flag:
//! no rank waits forever on another).
use crate::decomp::Partition;
use crate::dist::comm::{Comm, World};
use crate::dist::halo::{cut, halo_copies, migrate};
use crate::dist::ranks::RankStepper;
use crate::dist::records::{records, ParticleRecord};
use std::time::Instant;

/// One particle on the wire for the exchange check: its key and position.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
struct Rec {
    id: u64,
    /// 0 gas, 1 + k dust fraction k.
    phase: u64,
    x: [f64; 3],
}

// SAFETY: `repr(C)` of 8-byte fields (no padding); every bit pattern is valid.
unsafe impl bytemuck::Zeroable for Rec {}
unsafe impl bytemuck::Pod for Rec {}

fn rec(id: u64, phase: u64, x: [f64; 3]) -> Rec {
    Rec { id, phase, x }
}

fn pos(r: &Rec) -> [f64; 3] {
    r.x
}

/// What one rank measured.
#[derive(Debug, Clone, Default)]
pub struct RankReport {
    pub rank: u32,
    pub owned: usize,
    pub halo: usize,
    pub peers: usize,
    pub bytes_sent: usize,
    pub migrate_s: f64,
    pub halo_s: f64,
    /// Gathering every particle's whole record (what a run's output gathers on rank 0).
    pub gather_s: f64,
    /// Why this rank's checks failed (empty: passed).
    pub failure: String,
}

/// Run the check on this rank; `fail_rank` makes that rank report a failure (to test the
/// clean stop). Returns every rank's report (on every rank) and whether all passed.
pub fn run(
    world: &World,
    scene: &crate::scene::Scene,
    depth: f64,
    fail_rank: Option<u32>,
) -> Result<(Vec<RankReport>, bool), String> {
    let (me, ranks) = (world.rank(), world.size());
    let su = crate::setup::build(scene).map_err(|e| e.to_string())?;
    let phys = crate::step::Physics::from_scene(scene, su.h, su.domain);
    let reach = depth * phys.support();
    let st = &su.state;
    let all: Vec<Rec> = std::iter::once(&st.gas.ph)
        .chain(st.dust.iter())
        .enumerate()
        .flat_map(|(k, ph)| {
            ph.id
                .iter()
                .zip(&ph.x)
                .map(move |(&id, &x)| rec(id, k as u64, x))
        })
        .collect();
    let mine: Vec<Rec> = all
        .iter()
        .enumerate()
        .filter(|(k, _)| *k as u32 % ranks == me)
        .map(|(_, r)| *r)
        .collect();

    // Global bounds (periodic axes: the period), then the same cells and cut everywhere.
    let xs: Vec<[f64; 3]> = mine.iter().map(pos).collect();
    let part = cut(world, &xs, &su.domain, reach, None);

    // Migration to the owners.
    let t0 = Instant::now();
    let (owned, mut bytes_sent) = migrate(world, &part, &mine, pos)?;
    let migrate_s = t0.elapsed().as_secs_f64();

    // Halo: each owned particle to the ranks owning a cell next to its own.
    let t1 = Instant::now();
    let (halo, sent) = halo_copies(world, &part, &owned, pos)?;
    bytes_sent += sent;
    let halo_s = t1.elapsed().as_secs_f64();
    let peers = {
        let mut p: Vec<u64> = halo.iter().map(|r| part.owner_at(pos(r)) as u64).collect();
        p.sort_unstable();
        p.dedup();
        p.len()
    };

    // The output's gather: every owned particle's whole record to rank 0's buffer (the same
    // volume as `dist::ranks::RankStepper::gather`).
    let t2 = Instant::now();
    let full = vec![0u8; owned.len() * std::mem::size_of::<ParticleRecord>()];
    let gathered = world.gather_bytes(&full);
    let gather_s = t2.elapsed().as_secs_f64();
    drop(gathered);
    let mut failure = check(me, &all, &owned, &halo, &part, reach, &su.domain);
    let mut total = [owned.len() as u64];
    world.sum_u64(&mut total);
    if total[0] != all.len() as u64 && failure.is_empty() {
        failure = format!(
            "{} particles owned over all ranks, of {}",
            total[0],
            all.len()
        );
    }
    if fail_rank == Some(me) {
        failure = "failure requested by --fail-rank".into();
    }
    let report = RankReport {
        rank: me,
        owned: owned.len(),
        halo: halo.len(),
        peers,
        bytes_sent,
        migrate_s,
        halo_s,
        gather_s,
        failure,
    };
    let failed = world.any(!report.failure.is_empty());
    let reports = world
        .all_gather_bytes(encode(&report).as_bytes())
        .iter()
        .map(|b| decode(&String::from_utf8_lossy(b)))
        .collect();
    Ok((reports, !failed))
}

/// This rank's checks (empty string: passed).
fn check(
    me: u32,
    all: &[Rec],
    owned: &[Rec],
    halo: &[Rec],
    part: &Partition,
    reach: f64,
    domain: &crate::grid::Domain,
) -> String {
    for r in owned {
        let o = part.owner_at(pos(r));
        if o != me {
            return format!(
                "particle id {} (phase {}) is owned here, its cell by rank {o}",
                r.id, r.phase
            );
        }
    }
    if owned.len() as u64 != part.owned[me as usize] || halo.len() as u64 != part.halo[me as usize]
    {
        return format!(
            "owned {} / halo {}, the partition says {} / {}",
            owned.len(),
            halo.len(),
            part.owned[me as usize],
            part.halo[me as usize]
        );
    }
    let key = |r: &Rec| (r.id, r.phase);
    let mut have: Vec<(u64, u64)> = owned.iter().chain(halo).map(key).collect();
    have.sort_unstable();
    if have.windows(2).any(|w| w[0] == w[1]) {
        return "a particle arrived twice (owned and halo, or two copies)".into();
    }
    // Completeness by brute force: every particle within reach of an owned one is here.
    let sep = |a: [f64; 3], b: [f64; 3]| domain.distance2(a, b);
    let r2 = reach * reach;
    for p in all {
        if have.binary_search(&key(p)).is_ok() {
            continue;
        }
        let x = pos(p);
        if let Some(o) = owned.iter().find(|o| sep(pos(o), x) < r2) {
            return format!(
                "particle id {} (phase {}) lies within {reach:e} of owned particle id {} but is \
                 neither owned nor halo here",
                p.id, p.phase, o.id
            );
        }
    }
    String::new()
}

fn encode(r: &RankReport) -> String {
    format!(
        "{}\t{}\t{}\t{}\t{}\t{:e}\t{:e}\t{:e}\t{}",
        r.rank,
        r.owned,
        r.halo,
        r.peers,
        r.bytes_sent,
        r.migrate_s,
        r.halo_s,
        r.gather_s,
        r.failure
    )
}

fn decode(s: &str) -> RankReport {
    let f: Vec<&str> = s.splitn(9, '\t').collect();
    let num = |i: usize| {
        f.get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    RankReport {
        rank: num(0) as u32,
        owned: num(1) as usize,
        halo: num(2) as usize,
        peers: num(3) as usize,
        bytes_sent: num(4) as usize,
        migrate_s: num(5),
        halo_s: num(6),
        gather_s: num(7),
        failure: f.get(8).unwrap_or(&"").to_string(),
    }
}

/// What the stepping check found: the largest difference from the one-process run over every
/// particle, per field, relative to the field's largest magnitude (velocities: at least the
/// largest sound speed).
#[derive(Debug, Clone)]
pub struct StepReport {
    pub steps: u64,
    /// How the ranks stepped (the summary's `backend`: halos built, steps retaken, …).
    pub stepping: String,
    pub particles: usize,
    /// (field, max |a − b| / max |b|).
    pub fields: Vec<(&'static str, f64)>,
}

/// Step the scene `steps` times over the ranks ([`RankStepper`], a halo `depth` supports
/// deep, by default a run's [`crate::dist::ranks::depth_for`]) and, on rank 0, compare every particle with the same steps in one process.
pub fn step_over_ranks(
    world: World,
    scene: &crate::scene::Scene,
    depth: Option<f64>,
    steps: u64,
) -> Result<Option<StepReport>, String> {
    use crate::sim::{Simulation, Stepper};
    use crate::step::backend::DeviceChoice;
    let mut su = crate::setup::build(scene).map_err(|e| e.to_string())?;
    let phys = crate::step::Physics::from_scene(scene, su.h, su.domain);
    // Every rank sets the scene up whole (one process steps it too, below) and keeps its
    // share: `su.state` is left without particles.
    let mut ranks = RankStepper::new(
        world,
        phys.clone(),
        &mut su.state,
        false,
        depth.unwrap_or_else(|| crate::dist::ranks::depth_for(&phys)),
        DeviceChoice::Cpu,
        false,
    )?;
    if depth.is_some() {
        ranks.use_deep_halo();
    }
    ranks.rebalance_at(scene.numerics.rebalance_at);
    let err = |e: crate::step::StepError| e.to_string();
    let stepper = Stepper::Ranks {
        ranks: Box::new(ranks),
        t_stop: None,
        output: None,
        stale: false,
        // The check compares the whole state, gathered.
        by_share: false,
    };
    let mut over =
        Simulation::new(phys.clone(), &scene.time, su.state.shape(), stepper).map_err(err)?;
    for _ in 0..steps {
        over.step(scene.time.t_end).map_err(err)?;
    }
    // The dust densities as an output over ranks has them: from the ranks' engines on the
    // thin halo, from rank 0's on the gathered state after the deep halo's steps.
    over.refresh_dust_density().map_err(err)?;
    if !over.is_root() {
        return Ok(None);
    }
    let stepping = over.stepper.describe();
    let mut dist = over.state.clone();
    let (mut sim, _) = Simulation::of_scene(scene, DeviceChoice::Cpu)?;
    for _ in 0..steps {
        sim.step(scene.time.t_end).map_err(err)?;
    }
    sim.refresh_dust_density().map_err(err)?;
    let one = sim.state;
    let c_max = one.gas.c.iter().fold(0.0f64, |a, &c| a.max(c));
    let mut reference = records(&one);
    let mut dist_recs = records(&dist);
    dist.gas.c.clear();
    let key = |r: &ParticleRecord| r.key();
    dist_recs.sort_unstable_by_key(key);
    reference.sort_unstable_by_key(key);
    if dist_recs.len() != reference.len()
        || dist_recs
            .iter()
            .zip(&reference)
            .any(|(a, b)| key(a) != key(b))
    {
        return Err(format!(
            "the ranks hold {} particles after {steps} steps, one process {}; or their ids differ",
            dist_recs.len(),
            reference.len()
        ));
    }
    // Each field as its components.
    type Columns = fn(&ParticleRecord) -> Vec<f64>;
    let fields: [(&'static str, Columns); 5] = [
        ("x", |r| r.x.to_vec()),
        ("v", |r| r.v.to_vec()),
        ("m", |r| vec![r.m]),
        ("rho", |r| vec![r.rho]),
        ("e", |r| vec![r.e]),
    ];
    // A velocity is measured against the flow's own scale, at least the sound speed (a
    // linear wave's velocities are 1e-4 of it, and round-off follows the sound speed).
    let out = fields
        .iter()
        .map(|&(name, cols)| {
            let scale = reference
                .iter()
                .flat_map(|r| cols(r).into_iter().map(f64::abs))
                .fold(0.0f64, f64::max);
            let diff = dist_recs
                .iter()
                .zip(&reference)
                .flat_map(|(a, b)| cols(a).into_iter().zip(cols(b)).map(|(x, y)| (x - y).abs()))
                .fold(0.0f64, f64::max);
            let scale = if name == "v" { scale.max(c_max) } else { scale };
            (name, if scale > 0.0 { diff / scale } else { diff })
        })
        .collect();
    Ok(Some(StepReport {
        steps,
        stepping,
        particles: reference.len(),
        fields: out,
    }))
}

#[cfg(test)]
mod tests {
    use super::step_over_ranks;
    use crate::dist::threads::Threads;
    use crate::dist::World;

    /// The rank code without OpenMPI: the scene stepped over 2 and 3 ranks that are threads of
    /// this process (the thin halo and its refreshes, the migration, the gather) matches one
    /// process to 1e-12 of each field's scale, as `mpi-check --steps` asks of MPI ranks; the
    /// dusty wave with the kernel coupling under the leapfrog, and the settling column (walls,
    /// an external field).
    #[test]
    fn ranks_as_threads_step_as_one_process() {
        let cases: [(&str, &[&str]); 2] = [
            (
                "configs/dustywave_phantom.toml",
                &[
                    "sph.n=32",
                    "idic.coupling=\"kernel\"",
                    "time.integrator=\"kdk\"",
                ],
            ),
            ("configs/dustysettle.toml", &[]),
        ];
        for (name, sets) in cases {
            let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            let scene = crate::scene::load_shipped(name, &sets).unwrap().scene;
            for ranks in [2, 3] {
                let handles: Vec<_> = (Threads::group(ranks).into_iter())
                    .map(|t| {
                        let scene = scene.clone();
                        std::thread::spawn(move || {
                            step_over_ranks(World::over(Box::new(t)), &scene, None, 4)
                        })
                    })
                    .collect();
                let reports: Vec<_> = handles.into_iter().map(|h| h.join().unwrap()).collect();
                let report =
                    (reports.into_iter().next().unwrap().unwrap()).expect("rank 0 compares");
                assert_eq!(report.steps, 4);
                for (field, d) in &report.fields {
                    assert!(*d <= 1e-12, "{name} on {ranks} ranks: {field} off by {d:e}");
                }
            }
        }
    }
}
