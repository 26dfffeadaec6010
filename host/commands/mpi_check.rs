//! `dustsph mpi-check SCENE`, under `mpirun -n R`: the decomposition and the particle exchange
//! of issue 14 on a scene's real particles, checked on every rank (docs/scaling.md).
//!
//! Every rank builds the scene's particles (the set-up is deterministic) and starts from a
//! scrambled share (particle k on rank k mod R). Then, as a run over ranks would each step:
//! global bounds and per-cell counts by all-reduce, the same Morton cut on every rank
//! ([`Partition`], cells at least `depth` kernel supports wide), migration of each particle to
//! the rank owning its cell, and the halo exchange (copies of the particles in cells that touch
//! another rank's cells). Checks: every particle is owned by exactly one rank, the one owning
//! its cell; owned and halo counts equal the partition's; and no particle within `depth`
//! supports of an owned particle (minimum image on periodic axes) is missing from owned ∪ halo.
//! A rank that fails reports why and every rank exits 1 (an all-reduce of the failure flag:
//! no rank waits forever on another).
use crate::decomp::{CellBox, Cells, Partition};
use crate::dist::comm::World;
use std::time::Instant;

/// One particle on the wire: id, phase (0 gas, 1 + k dust fraction k), position bits.
type Rec = [u64; 5];

fn rec(id: u64, phase: u64, x: [f64; 3]) -> Rec {
    [id, phase, x[0].to_bits(), x[1].to_bits(), x[2].to_bits()]
}

fn pos(r: &Rec) -> [f64; 3] {
    [
        f64::from_bits(r[2]),
        f64::from_bits(r[3]),
        f64::from_bits(r[4]),
    ]
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
    let phys = crate::engine::Physics::from_scene(scene, su.h, su.domain);
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
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for r in &mine {
        let x = pos(r);
        for k in 0..3 {
            lo[k] = lo[k].min(x[k]);
            hi[k] = hi[k].max(x[k]);
        }
    }
    world.min_f64(&mut lo);
    world.max_f64(&mut hi);
    let mut periodic = [false; 3];
    for k in 0..3 {
        if let Some((p0, len)) = su.domain.periodic[k] {
            (lo[k], hi[k], periodic[k]) = (p0, p0 + len, true);
        }
    }
    let cbox = CellBox::new(lo, hi, reach, periodic);
    let mut counts = vec![0u64; cbox.len()];
    for r in &mine {
        counts[cbox.index(cbox.cell_of(pos(r)))] += 1;
    }
    world.sum_u64(&mut counts);
    let cells = Cells::from_counts(counts.iter().map(|&c| c as u32).collect(), cbox);
    let part = Partition::of(&cells, ranks);

    // Migration to the owners.
    let t0 = Instant::now();
    let mut sends: Vec<Vec<Rec>> = vec![Vec::new(); ranks as usize];
    for r in &mine {
        sends[part.owner_at(pos(r)) as usize].push(*r);
    }
    let mut bytes_sent: usize = sends
        .iter()
        .enumerate()
        .filter(|(q, _)| *q as u32 != me)
        .map(|(_, s)| s.len() * std::mem::size_of::<Rec>())
        .sum();
    let owned = world.exchange(&sends)?;
    let migrate_s = t0.elapsed().as_secs_f64();

    // Halo: each owned particle to the ranks owning a cell next to its own.
    let t1 = Instant::now();
    let mut sends: Vec<Vec<Rec>> = vec![Vec::new(); ranks as usize];
    let mut to = Vec::new();
    for r in &owned {
        part.halo_ranks(cbox.cell_of(pos(r)), &mut to);
        for &q in &to {
            sends[q as usize].push(*r);
        }
    }
    bytes_sent += sends
        .iter()
        .map(|s| s.len() * std::mem::size_of::<Rec>())
        .sum::<usize>();
    let halo = world.exchange(&sends)?;
    let halo_s = t1.elapsed().as_secs_f64();
    let peers = {
        let mut p: Vec<u64> = halo.iter().map(|r| part.owner_at(pos(r)) as u64).collect();
        p.sort_unstable();
        p.dedup();
        p.len()
    };

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
                r[0], r[1]
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
    let key = |r: &Rec| (r[0], r[1]);
    let mut have: Vec<(u64, u64)> = owned.iter().chain(halo).map(key).collect();
    have.sort_unstable();
    if have.windows(2).any(|w| w[0] == w[1]) {
        return "a particle arrived twice (owned and halo, or two copies)".into();
    }
    // Completeness by brute force: every particle within reach of an owned one is here.
    let sep = |a: [f64; 3], b: [f64; 3]| -> f64 {
        let mut s = 0.0;
        for k in 0..3 {
            let mut d = a[k] - b[k];
            if let Some((_, len)) = domain.periodic[k] {
                d -= len * (d / len).round();
            }
            s += d * d;
        }
        s
    };
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
                p[0], p[1], o[0]
            );
        }
    }
    String::new()
}

fn encode(r: &RankReport) -> String {
    format!(
        "{}\t{}\t{}\t{}\t{}\t{:e}\t{:e}\t{}",
        r.rank, r.owned, r.halo, r.peers, r.bytes_sent, r.migrate_s, r.halo_s, r.failure
    )
}

fn decode(s: &str) -> RankReport {
    let f: Vec<&str> = s.splitn(8, '\t').collect();
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
        failure: f.get(7).unwrap_or(&"").to_string(),
    }
}

/// A particle's whole state for the stepping check, as bits: id, phase, x, v, m, ρ, e, fixed,
/// flags (1: h and Ω, 2: the leapfrog's closing forces), h, Ω, the closing forces (5).
type Full = [u64; 20];

fn pack(id: u64, phase: usize, ph: &crate::particles::Phase, i: usize) -> Full {
    let b = |v: f64| v.to_bits();
    let mut r = [0u64; 20];
    r[0] = id;
    r[1] = phase as u64;
    for k in 0..3 {
        r[2 + k] = b(ph.x[i][k]);
        r[5 + k] = b(ph.v[i][k]);
    }
    r[8] = b(ph.m[i]);
    r[9] = b(ph.rho.get(i).copied().unwrap_or(0.0));
    r[11] = ph.is_fixed(i) as u64;
    r
}

fn full_pos(r: &Full) -> [f64; 3] {
    [
        f64::from_bits(r[2]),
        f64::from_bits(r[3]),
        f64::from_bits(r[4]),
    ]
}

/// Every particle of a state as records.
fn records(st: &crate::particles::State) -> Vec<Full> {
    let mut out = Vec::new();
    for (k, ph) in std::iter::once(&st.gas.ph)
        .chain(st.dust.iter())
        .enumerate()
    {
        for i in 0..ph.len() {
            let mut r = pack(ph.id[i], k, ph, i);
            if k == 0 {
                let g = &st.gas;
                if let Some(e) = &g.e {
                    r[10] = e[i].to_bits();
                }
                if let (Some(h), Some(o)) = (&g.h, &g.omega) {
                    r[12] |= 1;
                    r[13] = h[i].to_bits();
                    r[14] = o[i].to_bits();
                }
                if let Some(f) = &g.next_forces {
                    r[12] |= 2;
                    for (j, v) in f[i].iter().enumerate() {
                        r[15 + j] = v.to_bits();
                    }
                }
            }
            out.push(r);
        }
    }
    out
}

/// A state from records (phases in order; `template` gives the phase count and whether the
/// gas has an energy or fixed particles).
fn state_of(recs: &[Full], template: &crate::particles::State) -> crate::particles::State {
    use crate::particles::{Gas, Phase, State};
    let nph = 1 + template.dust.len();
    let mut phases: Vec<Phase> = (0..nph).map(|_| Phase::default()).collect();
    let mut fixed: Vec<Vec<bool>> = vec![Vec::new(); nph];
    let mut e = Vec::new();
    let (mut h, mut omega, mut nf) = (Vec::new(), Vec::new(), Vec::new());
    let (mut all_h, mut all_nf) = (true, true);
    for r in recs {
        let k = r[1] as usize;
        let f = |j: usize| f64::from_bits(r[j]);
        let ph = &mut phases[k];
        ph.id.push(r[0]);
        ph.x.push([f(2), f(3), f(4)]);
        ph.v.push([f(5), f(6), f(7)]);
        ph.m.push(f(8));
        ph.rho.push(f(9));
        fixed[k].push(r[11] != 0);
        if k == 0 {
            e.push(f(10));
            all_h &= r[12] & 1 != 0;
            all_nf &= r[12] & 2 != 0;
            h.push(f(13));
            omega.push(f(14));
            nf.push([f(15), f(16), f(17), f(18), f(19)]);
        }
    }
    let some_gas = recs.iter().any(|r| r[1] == 0);
    // Fixed particles: the scene's walls, and the halo's outer shell.
    let with_fixed = |k: usize, t: &Phase| {
        (t.fixed.is_some() || fixed[k].iter().any(|&f| f)).then(|| fixed[k].clone())
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
            ..Gas::default()
        },
        dust,
    }
}

/// The steps the stepping check supports (not yet the kernel coupling), or why not.
pub fn steppable(scene: &crate::scene::Scene) -> Result<(), String> {
    use crate::scene::Coupling;
    let why = if scene.idic.coupling == Coupling::Kernel {
        "the kernel coupling"
    } else {
        return Ok(());
    };
    Err(format!("--steps: the stepping check does not cover {why}"))
}

/// What the stepping check found: the largest difference from the one-process run over every
/// particle, per field, relative to the field's largest magnitude (velocities: at least the
/// largest sound speed).
#[derive(Debug, Clone)]
pub struct StepReport {
    pub steps: u64,
    pub particles: usize,
    /// (field, max |a − b| / max |b|).
    pub fields: Vec<(&'static str, f64)>,
}

/// Step the scene `steps` times over the ranks, the thick-halo way: each step the owned
/// particles are cut and migrated, every rank steps its owned particles with a halo `depth`
/// supports deep (the step's chain of neighbour passes recomputed redundantly on the halo)
/// and keeps the owned results. Rank 0 compares with the same steps in one process.
pub fn step_over_ranks(
    world: &World,
    scene: &crate::scene::Scene,
    depth: f64,
    steps: u64,
) -> Result<Option<StepReport>, String> {
    use crate::engine::backend::{Backend, DeviceChoice};
    use crate::engine::driver::Driver;
    steppable(scene)?;
    let (me, ranks) = (world.rank(), world.size());
    let su = crate::setup::build(scene).map_err(|e| e.to_string())?;
    let phys = crate::engine::Physics::from_scene(scene, su.h, su.domain);
    // The cut's cells hold the recomputed halo (`depth` supports) and, one support beyond,
    // a shell held fixed at its owners' values.
    let inner = depth * phys.support();
    let reach = (depth + 1.0) * phys.support();
    let template = su.state.clone();
    let drv = Driver::new(&scene.time, phys.h);
    let all = records(&su.state);
    let mut owned: Vec<Full> = all
        .iter()
        .enumerate()
        .filter(|(k, _)| *k as u32 % ranks == me)
        .map(|(_, r)| *r)
        .collect();
    let mut t = su.state.t;
    for step in 0..steps {
        // The cut of this step's positions (re-balanced every step), migration, halo.
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for r in &owned {
            let x = full_pos(r);
            for k in 0..3 {
                lo[k] = lo[k].min(x[k]);
                hi[k] = hi[k].max(x[k]);
            }
        }
        world.min_f64(&mut lo);
        world.max_f64(&mut hi);
        let mut periodic = [false; 3];
        for k in 0..3 {
            if let Some((p0, len)) = su.domain.periodic[k] {
                (lo[k], hi[k], periodic[k]) = (p0, p0 + len, true);
            }
        }
        let cbox = CellBox::new(lo, hi, reach, periodic);
        let mut counts = vec![0u64; cbox.len()];
        for r in &owned {
            counts[cbox.index(cbox.cell_of(full_pos(r)))] += 1;
        }
        world.sum_u64(&mut counts);
        let cells = Cells::from_counts(counts.iter().map(|&c| c as u32).collect(), cbox);
        let part = Partition::of(&cells, ranks);
        let mut sends: Vec<Vec<Full>> = vec![Vec::new(); ranks as usize];
        for r in &owned {
            sends[part.owner_at(full_pos(r)) as usize].push(*r);
        }
        owned = world.exchange(&sends)?;
        let mut sends: Vec<Vec<Full>> = vec![Vec::new(); ranks as usize];
        let mut to = Vec::new();
        for r in &owned {
            part.halo_ranks(cbox.cell_of(full_pos(r)), &mut to);
            for &q in &to {
                sends[q as usize].push(*r);
            }
        }
        let halo = world.exchange(&sends)?;
        let mine: std::collections::HashSet<(u64, u64)> =
            owned.iter().map(|r| (r[0], r[1])).collect();
        let mut local_recs = owned.clone();
        local_recs.extend(shell(&owned, &halo, inner, &su.domain));
        let mut local = state_of(&local_recs, &template);
        local.t = t;
        local.step = step;
        // The step: forces on every rank, the step size from the maxima over all ranks (the
        // one process's), then the advance.
        let mut err = String::new();
        let mut eng = None;
        let mut forces = None;
        if !local_recs.is_empty() {
            match Backend::new(DeviceChoice::Cpu, phys.clone(), &mut local) {
                Ok(mut e) => {
                    match e.forces(&local) {
                        Ok(f) => forces = Some(f),
                        Err(x) => err = x.to_string(),
                    }
                    eng = Some(e);
                }
                Err(x) => err = x.to_string(),
            }
        }
        if world.any(!err.is_empty()) {
            return Err(format!("step {step}: rank {me}: {err}"));
        }
        let mut most = [
            forces.as_ref().map_or(0.0, |f| f.vsig_max),
            forces.as_ref().map_or(0.0, |f| f.acc_max),
        ];
        world.max_f64(&mut most);
        let mut next = Vec::new();
        if let (Some(e), Some(f)) = (&mut eng, forces) {
            let global = crate::engine::Forces {
                acc: Vec::new(),
                dedt: None,
                vsig_max: most[0],
                acc_max: most[1],
            };
            let r = (|| -> Result<(), crate::engine::StepError> {
                let plan = drv.plan(e, &local, &global, scene.time.t_end)?;
                drv.take(
                    e,
                    &mut local,
                    &crate::engine::driver::Taken { plan, forces: f },
                )?;
                // Densities as an output has them (the dust's is refreshed only for output
                // unless its drag law needs it each step).
                e.refresh_dust_density(&mut local)?;
                e.sync(&mut local)
            })();
            err = r.err().map(|x| x.to_string()).unwrap_or_default();
            next = records(&local)
                .into_iter()
                .filter(|r| mine.contains(&(r[0], r[1])))
                .collect();
        }
        if world.any(!err.is_empty()) {
            return Err(format!("step {step}: rank {me}: {err}"));
        }
        // Every rank took the same τ: the time advances alike (a rank without particles
        // learns it from the others).
        let mut tt = [if local_recs.is_empty() {
            f64::NEG_INFINITY
        } else {
            local.t
        }];
        world.max_f64(&mut tt);
        t = tt[0];
        owned = next;
    }
    // Gather to rank 0 and compare with one process.
    let bytes: Vec<u8> = bytemuck::cast_slice(&owned).to_vec();
    let parts = world.all_gather_bytes(&bytes);
    if me != 0 {
        return Ok(None);
    }
    let mut dist: Vec<Full> = parts
        .iter()
        .flat_map(|b| b.chunks_exact(std::mem::size_of::<Full>()))
        .map(bytemuck::pod_read_unaligned::<Full>)
        .collect();
    let mut one = su.state;
    {
        let mut eng = Backend::new(DeviceChoice::Cpu, phys, &mut one).map_err(|e| e.to_string())?;
        for _ in 0..steps {
            drv.step(&mut eng, &mut one, scene.time.t_end)
                .map_err(|e| e.to_string())?;
        }
        eng.refresh_dust_density(&mut one)
            .map_err(|e| e.to_string())?;
        eng.sync(&mut one).map_err(|e| e.to_string())?;
    }
    let mut reference = records(&one);
    let key = |r: &Full| (r[1], r[0]);
    dist.sort_unstable_by_key(key);
    reference.sort_unstable_by_key(key);
    if dist.len() != reference.len() || dist.iter().zip(&reference).any(|(a, b)| key(a) != key(b)) {
        return Err(format!(
            "the ranks hold {} particles after {steps} steps, one process {}; or their ids differ",
            dist.len(),
            reference.len()
        ));
    }
    let fields: [(&'static str, &[usize]); 5] = [
        ("x", &[2, 3, 4]),
        ("v", &[5, 6, 7]),
        ("m", &[8]),
        ("rho", &[9]),
        ("e", &[10]),
    ];
    let f = |r: &Full, j: usize| f64::from_bits(r[j]);
    // A velocity is measured against the flow's own scale, at least the sound speed (a
    // linear wave's velocities are 1e-4 of it, and round-off follows the sound speed).
    let c_max = one.gas.c.iter().fold(0.0f64, |a, &c| a.max(c));
    let out = fields
        .iter()
        .map(|&(name, cols)| {
            let scale = reference
                .iter()
                .flat_map(|r| cols.iter().map(move |&j| f(r, j).abs()))
                .fold(0.0f64, f64::max);
            let diff = dist
                .iter()
                .zip(&reference)
                .flat_map(|(a, b)| cols.iter().map(move |&j| (f(a, j) - f(b, j)).abs()))
                .fold(0.0f64, f64::max);
            let scale = if name == "v" { scale.max(c_max) } else { scale };
            (name, if scale > 0.0 { diff / scale } else { diff })
        })
        .collect();
    Ok(Some(StepReport {
        steps,
        particles: reference.len(),
        fields: out,
    }))
}

/// The halo as the step needs it: particles within `inner` of an owned particle are stepped
/// (their passes recomputed here); the rest are held fixed at their owners' values (their
/// density and pressure are exact at the start of the step, so the stepped halo's forces are
/// too, and no particle with an incomplete neighbourhood enters the step's maxima).
fn shell(owned: &[Full], halo: &[Full], inner: f64, domain: &crate::grid::Domain) -> Vec<Full> {
    use std::collections::HashMap;
    let cell = |x: [f64; 3]| -> [i64; 3] { x.map(|v| (v / inner).floor() as i64) };
    let mut grid: HashMap<[i64; 3], Vec<[f64; 3]>> = HashMap::new();
    for r in owned {
        let x = full_pos(r);
        grid.entry(cell(x)).or_default().push(x);
    }
    let sep2 = |a: [f64; 3], b: [f64; 3]| -> f64 {
        (0..3)
            .map(|k| {
                let mut d = a[k] - b[k];
                if let Some((_, len)) = domain.periodic[k] {
                    d -= len * (d / len).round();
                }
                d * d
            })
            .sum()
    };
    // Near a periodic boundary the owned particle may be an image away: look in the cells of
    // the halo particle's images too.
    let images: Vec<[f64; 3]> = {
        let shifts = |k: usize| -> Vec<f64> {
            match domain.periodic[k] {
                Some((_, len)) => vec![0.0, len, -len],
                None => vec![0.0],
            }
        };
        let mut v = Vec::new();
        for a in shifts(0) {
            for b in shifts(1) {
                for c in shifts(2) {
                    v.push([a, b, c]);
                }
            }
        }
        v
    };
    let r2 = inner * inner;
    halo.iter()
        .map(|h| {
            let x = full_pos(h);
            let near = images.iter().any(|s| {
                let c = cell([x[0] + s[0], x[1] + s[1], x[2] + s[2]]);
                (0..27).any(|d| {
                    let q = [c[0] + d % 3 - 1, c[1] + (d / 3) % 3 - 1, c[2] + d / 9 - 1];
                    grid.get(&q)
                        .is_some_and(|v| v.iter().any(|&o| sep2(o, x) <= r2))
                })
            });
            let mut r = *h;
            if !near {
                r[11] = 1;
            }
            r
        })
        .collect()
}
