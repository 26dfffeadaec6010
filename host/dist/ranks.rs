//! Stepping a scene over MPI ranks (docs/scaling.md). Each step the particles are cut along
//! the Morton curve and migrated, and every rank builds an engine on its owned particles plus a
//! halo, in one of two forms:
//! - thin (a run's): ghosts within one reach (kernel support or IDIC cell, plus a margin for
//!   the step's motion), refreshed from their owners between the step's neighbour passes
//!   ([`RankGhosts`], the engine's `GhostSync` hooks); a step that outran the margin is retaken;
//! - deep (`mpi-check --depth K`, and a step where a rank holds no gas): a halo K supports deep
//!   whose chain of passes is recomputed here, and a shell one support beyond held fixed at the
//!   owners' values.
//!
//! The step size comes from the maxima over all ranks; each rank keeps its owned particles'
//! results.
use super::comm::World;
use crate::decomp::{CellBox, Cells, Partition};
use crate::particles::{IntHasher, KeyMap, KeySet, State};
use crate::step::backend::{Backend, DeviceChoice};
use crate::step::engine::{GhostRows, GhostSync, InitialLayer};
use crate::step::timestep::{Plan, PlanError, StepPlanner};
use crate::step::{Forces, Physics};

/// Halo depth in kernel supports that a run over ranks needs for its step's chain of
/// neighbour passes to be exact on the owned particles (docs/scaling.md): the first-order step
/// 1 + max(1, c), the leapfrog 3 + max(1, c), where c is an IDIC cell's diagonal in supports
/// (a particle's drag reads its cell-mates' forces); with the kernel coupling (dust → gas
/// deposits, the solve on the gas, the return to the dust) 4 and 6. Measured on 3 ranks, as
/// the least depth exact to 1e-12 over 20 steps: the 1D wave (cells 0.5 h) 2; with cells of 4 h
/// 3; the Phantom slab (leapfrog, variable h, IAD) 4; with the kernel coupling the wave 3, the
/// settling column (IAD) 4, the Phantom slab 5.
pub fn depth_for(phys: &Physics) -> f64 {
    let kdk = phys.integrator == crate::scene::Integrator::Kdk;
    let chain = if kdk { 3.0 } else { 1.0 };
    if phys.coupling == crate::scene::Coupling::Kernel && !phys.laws.is_empty() {
        return chain + 3.0;
    }
    let cell = phys.cell_size * (phys.dim as f64).sqrt() / phys.support();
    chain + cell.max(1.0)
}

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
    pub(crate) fn of(phase: usize, ph: &crate::particles::Phase, i: usize) -> ParticleRecord {
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
pub fn records(st: &crate::particles::State) -> Vec<ParticleRecord> {
    let mut out = Vec::new();
    for (k, ph) in std::iter::once(&st.gas.ph)
        .chain(st.dust.iter())
        .enumerate()
    {
        for i in 0..ph.len() {
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
            out.push(r);
        }
    }
    out
}

/// A state from records (phases in order; `template` gives the phase count and whether the
/// gas has an energy or fixed particles).
pub fn state_of(
    recs: &[ParticleRecord],
    template: &crate::particles::State,
) -> crate::particles::State {
    use crate::particles::{Gas, Phase, State};
    let nph = 1 + template.dust.len();
    let mut phases: Vec<Phase> = (0..nph).map(|_| Phase::default()).collect();
    let mut fixed: Vec<Vec<bool>> = vec![Vec::new(); nph];
    let mut e = Vec::new();
    let (mut h, mut omega, mut nf) = (Vec::new(), Vec::new(), Vec::new());
    let (mut pres, mut cs) = (Vec::new(), Vec::new());
    let (mut all_h, mut all_nf) = (true, true);
    for r in recs {
        let k = r.phase as usize;
        let ph = &mut phases[k];
        ph.id.push(r.id);
        ph.x.push(r.x);
        ph.v.push(r.v);
        ph.m.push(r.m);
        ph.rho.push(r.rho);
        fixed[k].push(r.fixed != 0);
        if k == 0 {
            e.push(r.e);
            all_h &= r.flags & ParticleRecord::HAS_H != 0;
            all_nf &= r.flags & ParticleRecord::HAS_CLOSING_FORCES != 0;
            h.push(r.h);
            omega.push(r.omega);
            nf.push(r.closing_forces);
            pres.push(r.p);
            cs.push(r.c);
        }
    }
    let some_gas = recs.iter().any(|r| r.phase == 0);
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
            p: pres,
            c: cs,
        },
        dust,
    }
}

/// Decomposition cells per halo reach: cells half the reach wide (the halo then spans the
/// cells within three of a rank's own), so that a reach of several supports still leaves a
/// small domain enough cells to cut evenly.
pub const CELLS_PER_REACH: f64 = 2.0;

/// The Morton cut of this step, the same on every rank (collective): global bounds (the period
/// on periodic axes) and per-cell counts of every rank's positions `xs`, in cells
/// `reach / CELLS_PER_REACH` wide, with a halo ring of cells that holds every particle within
/// `reach` of a rank's own.
pub fn cut(world: &World, xs: &[[f64; 3]], domain: &crate::grid::Domain, reach: f64) -> Partition {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for x in xs {
        for k in 0..3 {
            lo[k] = lo[k].min(x[k]);
            hi[k] = hi[k].max(x[k]);
        }
    }
    world.min_f64(&mut lo);
    world.max_f64(&mut hi);
    let mut periodic = [false; 3];
    for k in 0..3 {
        if let Some((p0, len)) = domain.periodic[k] {
            (lo[k], hi[k], periodic[k]) = (p0, p0 + len, true);
        }
    }
    let cbox = CellBox::new(lo, hi, reach / CELLS_PER_REACH, periodic);
    // A particle within `reach` of one in cell i lies in cells i − ring … i + ring (one more
    // than reach/size, whatever the rounding of a position to its cell).
    let ring = (0..3)
        .filter(|&k| cbox.n[k] > 1)
        .map(|k| (reach / cbox.size[k]).floor() as u32 + 1)
        .max()
        .unwrap_or(1);
    let mut counts = vec![0u64; cbox.len()];
    for &x in xs {
        counts[cbox.index(cbox.cell_of(x))] += 1;
    }
    world.sum_u64(&mut counts);
    let cells = Cells::from_counts(counts.iter().map(|&c| c as u32).collect(), cbox);
    Partition::with_ring(&cells, world.size(), ring)
}

/// Every record to the rank owning its cell (collective): what this rank now owns, and the
/// bytes it sent to other ranks.
pub fn migrate<T: bytemuck::Pod>(
    world: &World,
    part: &Partition,
    recs: &[T],
    pos: impl Fn(&T) -> [f64; 3],
) -> Result<(Vec<T>, usize), String> {
    let mut sends: Vec<Vec<T>> = vec![Vec::new(); world.size() as usize];
    for r in recs {
        sends[part.owner_at(pos(r)) as usize].push(*r);
    }
    let me = world.rank() as usize;
    let bytes = sends
        .iter()
        .enumerate()
        .filter(|(q, _)| *q != me)
        .map(|(_, s)| std::mem::size_of_val(s.as_slice()))
        .sum();
    Ok((world.exchange(&sends)?, bytes))
}

/// Copies of the owned records in cells next to another rank's cells, to those ranks
/// (collective): the halo this rank receives, and the bytes it sent.
pub fn halo_copies<T: bytemuck::Pod>(
    world: &World,
    part: &Partition,
    owned: &[T],
    pos: impl Fn(&T) -> [f64; 3],
) -> Result<(Vec<T>, usize), String> {
    let sends: Vec<Vec<T>> = halo_sends(world.size(), part, owned, pos)
        .into_iter()
        .map(|to| to.into_iter().map(|i| owned[i]).collect())
        .collect();
    let bytes = sends
        .iter()
        .map(|s| std::mem::size_of_val(s.as_slice()))
        .sum();
    Ok((world.exchange(&sends)?, bytes))
}

/// For each rank q, the indices of the owned records that go to q as halo (those in cells
/// within the partition's ring of one of q's cells).
pub fn halo_sends<T>(
    ranks: u32,
    part: &Partition,
    owned: &[T],
    pos: impl Fn(&T) -> [f64; 3],
) -> Vec<Vec<usize>> {
    let mut sends: Vec<Vec<usize>> = vec![Vec::new(); ranks as usize];
    // The ranks a cell's particles go to, found once per cell.
    let mut by_cell: std::collections::HashMap<usize, Vec<u32>> = Default::default();
    for (i, r) in owned.iter().enumerate() {
        let c = part.cbox.cell_of(pos(r));
        let to = by_cell.entry(part.cbox.index(c)).or_insert_with(|| {
            let mut to = Vec::new();
            part.halo_ranks(c, &mut to);
            to
        });
        for &q in to.iter() {
            sends[q as usize].push(i);
        }
    }
    sends
}

/// The ghost refresh of a thin halo ([`GhostSync`]): each owned particle's row to the ranks
/// holding it as a ghost, one exchange per phase table (collective).
struct RankGhosts {
    comm: World,
    /// Per rank, the keys (phase, id) of the owned particles it received as halo (a rank that
    /// left one out, being beyond its reach, ignores its row).
    sends: Vec<Vec<(u64, u64)>>,
    /// Refreshes before this one fails, if it is to (the test of a failure inside a step:
    /// `DUSTSPH_FAIL_IN_STEP=rank:step` fails the step's second refresh, in its forces).
    fail: Option<u32>,
}

/// Whether `DUSTSPH_FAIL_IN_STEP=rank:step` names this rank and step (tests/mpi.rs: a failure
/// inside a step stops the job, with its message, and does not hang).
fn fail_requested(rank: u32, step: u64) -> bool {
    std::env::var("DUSTSPH_FAIL_IN_STEP").is_ok_and(|v| v == format!("{rank}:{step}"))
}

impl GhostSync for RankGhosts {
    fn refresh(&mut self, tables: &mut [GhostRows<'_>]) -> Result<(), String> {
        match &mut self.fail {
            Some(0) => return Err("failure requested by DUSTSPH_FAIL_IN_STEP".into()),
            Some(n) => *n -= 1,
            None => {}
        }
        for (k, t) in tables.iter_mut().enumerate() {
            let slot: KeyMap<usize> = t
                .keys
                .iter()
                .enumerate()
                .map(|(i, &key)| (key, i))
                .collect();
            let mut out: Vec<Vec<u8>> = vec![Vec::new(); self.sends.len()];
            for (q, keys) in self.sends.iter().enumerate() {
                for key in keys.iter().filter(|key| (key.0 == 0) == (k == 0)) {
                    let i = *slot
                        .get(key)
                        .ok_or_else(|| format!("particle {key:?} is not on its owner"))?;
                    for w in [key.0, key.1, t.row as u64] {
                        out[q].extend_from_slice(&w.to_le_bytes());
                    }
                    out[q].extend_from_slice(&t.data[i * t.row..(i + 1) * t.row]);
                }
            }
            let got = self.comm.exchange(&out)?;
            let rec = 24 + t.row;
            let word = |r: &[u8], j: usize| {
                u64::from_le_bytes(r[8 * j..8 * j + 8].try_into().expect("8 bytes"))
            };
            if got.len() % rec != 0 {
                return Err("a rank sent ghost rows of another layout".into());
            }
            for r in got.chunks_exact(rec) {
                if word(r, 2) != t.row as u64 {
                    return Err("a rank sent ghost rows of another layout".into());
                }
                if let Some(&i) = slot.get(&(word(r, 0), word(r, 1))) {
                    t.data[i * t.row..(i + 1) * t.row].copy_from_slice(&r[24..]);
                }
            }
        }
        Ok(())
    }
}

/// How a try at a step ended.
enum Tried {
    Done((Plan, f64, f64)),
    /// A rank holds no gas: this step takes the deep halo (the thin one's refresh needs an
    /// engine, hence gas, on every rank).
    NoGasOnARank,
    /// Particles moved (or h grew) beyond the thin halo's margin: again, with `need` beyond
    /// the support.
    Moved {
        need: f64,
    },
}

/// The thin halo's least margin beyond the support, in supports.
const MIN_MARGIN: f64 = 0.1;

/// One rank's share of a scene stepped over the ranks.
pub struct RankStepper {
    pub world: World,
    phys: Physics,
    template: State,
    owned: Vec<ParticleRecord>,
    depth: f64,
    /// Where this rank steps: its own GPU (rank r on device r mod count), or the CPU.
    dev: RankDevice,
    /// Every rank's device, for the summary (gathered at the start).
    devices: Vec<String>,
    /// Whether the owned particles' densities are those of their layer (after a step here);
    /// the first step computes them, as one process does at its start or resume.
    layer_given: bool,
    /// The thin halo (one reach deep, refreshed between the step's passes) or the deep one.
    thin: bool,
    /// The thin halo's margin beyond the reach, for the step's motion (adapted each step).
    margin: f64,
    /// Steps taken again because the particles outran the margin.
    pub retakes: u64,
    /// Steps the thin halo handed to the deep one (a rank held no gas).
    deep_steps: u64,
    /// The largest halo over any rank and step, as a multiple of the rank's own particles.
    halo_ratio: f64,
}

/// The launcher a rank steps on, kept across its steps (a GPU's kernels are loaded once).
enum RankDevice {
    Cpu,
    Cuda(crate::launch::Cuda),
}

impl RankDevice {
    /// The engine on this device for the rank's local state of one step.
    fn engine(
        &self,
        phys: Physics,
        state: &mut State,
        layer: InitialLayer,
    ) -> Result<Backend, crate::step::StepError> {
        match self {
            RankDevice::Cpu => Backend::on_cpu_at(phys, state, layer),
            RankDevice::Cuda(d) => Backend::on_cuda_at(d.clone(), phys, state, layer),
        }
    }
}

/// Rank `me`'s device for `asked` (`--device`): with a GPU, device `me` mod the count this
/// process sees, tried on the rank's share before anything is written; `auto` falls back to
/// the CPU (with a note) where that fails, `cuda` stops. `Err` is the rank's message.
fn rank_device(
    asked: DeviceChoice,
    me: u32,
    phys: &Physics,
    share: &mut State,
) -> Result<(RankDevice, Option<String>), String> {
    use crate::launch::Cuda;
    let (device, note) = crate::step::backend::select(asked)?;
    if device != DeviceChoice::Cuda {
        return Ok((RankDevice::Cpu, note));
    }
    let tried = crate::launch::cuda::device_count()
        .and_then(|n| {
            let ordinal = me as usize % n.max(1);
            Cuda::new(ordinal, crate::launch::PTX)
                .map_err(|e| format!("CUDA device {ordinal}: {e}"))
        })
        .and_then(|d| {
            if share.gas.ph.x.is_empty() && share.dust.iter().all(|p| p.x.is_empty()) {
                return Ok(d);
            }
            Backend::on_cuda(d.clone(), phys.clone(), share)
                .map(|_| d)
                .map_err(|e| e.to_string())
        });
    match (tried, asked) {
        (Ok(d), _) => Ok((RankDevice::Cuda(d), None)),
        (Err(e), DeviceChoice::Auto) => Ok((
            RankDevice::Cpu,
            Some(format!("rank {me}: no GPU used ({e}); stepping on the CPU")),
        )),
        (Err(e), _) => Err(format!("--device cuda on rank {me}: {e}")),
    }
}

impl RankStepper {
    /// This rank's share of `full` (the scene's whole state, built alike on every rank): the
    /// particles of id + phase ≡ rank (mod R), until the first step's cut moves them to their
    /// owners.
    /// Each rank steps on the device `device` resolves to for it ([`rank_device`]); a rank
    /// that cannot stops every rank (collective), before anything is written.
    pub fn new(
        world: World,
        phys: Physics,
        full: &State,
        depth: f64,
        device: DeviceChoice,
        verbose: bool,
    ) -> Result<RankStepper, String> {
        let (me, ranks) = (world.rank(), world.size());
        // By particle key, not position: rank 0's copy of the scene is sorted by its engine,
        // the others' are not.
        let owned: Vec<ParticleRecord> = records(full)
            .into_iter()
            .filter(|r| (r.id.wrapping_add(r.phase) % ranks as u64) as u32 == me)
            .collect();
        // The shape of the state (phases, energy, fixed particles), without its particles.
        let template = full.shape();
        let mut share = state_of(&owned, &template);
        let chosen = rank_device(device, me, &phys, &mut share);
        if world.any(chosen.is_err()) {
            return Err(chosen.err().unwrap_or_else(|| {
                "another rank cannot use the device asked for (its message above)".into()
            }));
        }
        let (dev, note) = chosen?;
        // The same note on every rank (no GPU here at all) is said once, by rank 0.
        if let (Some(n), true) = (note, verbose) {
            if me == 0 || n.starts_with("rank ") {
                eprintln!("dustsph: {n}");
            }
        }
        let mine = match &dev {
            RankDevice::Cpu => format!(
                "cpu ({})",
                crate::launch::threads(rayon::current_num_threads())
            ),
            RankDevice::Cuda(d) => format!("cuda: {}", crate::launch::Launcher::describe(d)),
        };
        let devices = world
            .all_gather_bytes(mine.as_bytes())
            .into_iter()
            .map(|b| String::from_utf8_lossy(&b).into_owned())
            .collect();
        // The thin halo, unless a step finds a rank without gas (`Tried::NoGasOnARank`) or
        // `use_deep_halo` asks for the deep one.
        let (thin, margin) = (true, 0.5 * phys.support());
        Ok(RankStepper {
            world,
            phys,
            template,
            owned,
            depth,
            dev,
            devices,
            layer_given: false,
            thin,
            margin,
            retakes: 0,
            deep_steps: 0,
            halo_ratio: 0.0,
        })
    }

    /// Step with the deep halo (`depth` supports) even where the thin one would do.
    pub fn use_deep_halo(&mut self) {
        self.thin = false;
    }

    /// Particles this rank owns.
    pub fn owned(&self) -> usize {
        self.owned.len()
    }

    /// Rank 0 writes the output.
    pub fn is_root(&self) -> bool {
        self.world.rank() == 0
    }

    /// Whether any rank says so (collective).
    pub fn any(&self, flag: bool) -> bool {
        self.world.any(flag)
    }

    /// "R MPI ranks", for the summary.
    pub fn describe(&self) -> String {
        let on = if self.devices.iter().all(|d| *d == self.devices[0]) {
            format!("each stepping on {}", self.devices[0])
        } else {
            let each: Vec<String> = (self.devices.iter().enumerate())
                .map(|(r, d)| format!("rank {r} on {d}"))
                .collect();
            format!("stepping {}", each.join("; "))
        };
        let depth = format!("{:.2}", self.depth);
        let halo = if self.thin {
            format!(
                "a thin halo refreshed between the step's passes, at most {:.2} × a rank's own \
                 particles",
                self.halo_ratio
            )
        } else {
            format!(
                "a halo {} supports deep",
                depth.trim_end_matches('0').trim_end_matches('.')
            )
        };
        let mut retaken = match self.retakes {
            0 => String::new(),
            n => format!(", {n} steps retaken with a wider margin"),
        };
        if self.thin && self.deep_steps > 0 {
            retaken += &format!(
                ", {} steps on a halo {} supports deep (a rank held no gas)",
                self.deep_steps,
                depth.trim_end_matches('0').trim_end_matches('.')
            );
        }
        format!("{} MPI ranks ({halo}{retaken}), {on}", self.world.size())
    }

    /// One step from time `t` (step count `step`) toward `t_target` on every rank: the plan
    /// taken (the same on every rank: the one process's) and the new time. With the thin halo
    /// a step whose particles moved (or whose h grew) further than the halo's margin allows is
    /// taken again with a wider margin.
    pub fn step(
        &mut self,
        drv: &StepPlanner,
        t: f64,
        step: u64,
        t_target: f64,
    ) -> Result<(Plan, f64, f64), String> {
        let mut thin = self.thin;
        loop {
            match self.try_step(drv, t, step, t_target, thin)? {
                Tried::Done(r) => return Ok(r),
                Tried::NoGasOnARank => {
                    thin = false;
                    self.deep_steps += 1;
                }
                Tried::Moved { need } => {
                    self.margin = 1.5 * need;
                    self.retakes += 1;
                }
            }
        }
    }

    fn try_step(
        &mut self,
        drv: &StepPlanner,
        t: f64,
        step: u64,
        t_target: f64,
        thin: bool,
    ) -> Result<Tried, String> {
        let world = &self.world;
        let me = world.rank();
        let domain = self.phys.domain;
        // The support: of the largest h over all ranks where h varies (the reference h at
        // least), so that the halo holds every neighbour of its stepped particles.
        let h_of = |r: &ParticleRecord| r.solved_h();
        let mut h_max = [self.owned.iter().fold(self.phys.h, |a, r| a.max(h_of(r)))];
        world.max_f64(&mut h_max);
        let support = crate::step::SUPPORT * h_max[0];
        // Thin: every neighbour and IDIC cell-mate of an owned particle, now and after the
        // step's drift (the margin). Deep: the step's chain of passes, and a fixed shell.
        let cell = self.phys.cell_size * (self.phys.dim as f64).sqrt();
        let near = support.max(cell);
        let (inner, reach) = if thin {
            (near + self.margin, near + self.margin)
        } else {
            (self.depth * support, (self.depth + 1.0) * support)
        };
        let xs: Vec<[f64; 3]> = self.owned.iter().map(full_pos).collect();
        let part = cut(world, &xs, &domain, reach);
        let (owned, _) = migrate(world, &part, &self.owned, full_pos)?;
        let to = halo_sends(world.size(), &part, &owned, full_pos);
        let sends: Vec<Vec<ParticleRecord>> = (to.iter())
            .map(|ix| ix.iter().map(|&i| owned[i]).collect())
            .collect();
        let halo = world.exchange(&sends)?;
        let mine: KeySet = owned.iter().map(|r| r.key()).collect();
        let mut local_recs = owned.clone();
        let kept = shell(&owned, &halo, inner, reach, &domain);
        let ghost_keys: KeySet = kept.iter().map(|r| r.key()).collect();
        local_recs.extend(kept);
        // The ghosts' refresh is collective inside the step: every rank steps an engine.
        if thin && world.any(!local_recs.iter().any(|r| r.phase == 0)) {
            return Ok(Tried::NoGasOnARank);
        }
        let mut local = state_of(&local_recs, &self.template);
        local.t = t;
        local.step = step;
        // Forces on every rank, the step size from the maxima over all ranks, the advance.
        let mut err = String::new();
        let mut eng = None;
        if !local_recs.is_empty() {
            let layer = if self.layer_given {
                InitialLayer::FromState
            } else {
                InitialLayer::Compute
            };
            match self.dev.engine(self.phys.clone(), &mut local, layer) {
                Ok(e) => eng = Some(e),
                Err(x) => err = x.to_string(),
            }
        }
        if world.any(!err.is_empty()) {
            return Err(failure(world, step, me, &err));
        }
        // With a thin halo a failure inside the step leaves the other ranks waiting in a
        // refresh it will not reach: it stops the job (its message first).
        let stop = |x: &dyn std::fmt::Display| -> ! {
            eprintln!("error: {}", failure(world, step, me, &x.to_string()));
            world.abort(1)
        };
        if thin {
            let keys: Vec<Vec<(u64, u64)>> = (to.iter())
                .map(|ix| ix.iter().map(|&i| owned[i].key()).collect())
                .collect();
            let sync = Box::new(RankGhosts {
                comm: world.dup(),
                sends: keys,
                fail: fail_requested(me, step).then_some(1),
            });
            if let Some(e) = &mut eng {
                if let Err(x) = e.set_ghosts(sync, ghost_keys) {
                    stop(&x);
                }
            }
        }
        let mut forces = None;
        if let Some(e) = &mut eng {
            match e.forces() {
                Ok(f) => forces = Some(f),
                Err(x) if thin => stop(&x),
                Err(x) => err = x.to_string(),
            }
        }
        if world.any(!err.is_empty()) {
            return Err(failure(world, step, me, &err));
        }
        let mut most = [
            forces.as_ref().map_or(0.0, |f| f.vsig_max),
            forces.as_ref().map_or(0.0, |f| f.acc_max),
        ];
        world.max_f64(&mut most);
        let global = Forces {
            vsig_max: most[0],
            acc_max: most[1],
        };
        // The explicit drag's limit: the least over the ranks of each one's cells that hold a
        // particle of its own (a cell of ghosts only may lack members beyond the halo).
        let explicit = self.phys.drag == crate::scene::DragMethod::Explicit;
        if explicit && !thin {
            return Err(format!(
                "step {step}: the explicit drag baseline (drag.method = \"explicit\") steps \
                 over ranks with the thin halo only, and a rank holds no gas"
            ));
        }
        let mut drag = [f64::INFINITY];
        if let (true, Some(e)) = (explicit, &mut eng) {
            match e.timed_drag_limit() {
                Ok(d) => drag[0] = d,
                Err(x) => err = x.to_string(),
            }
        }
        if world.any(!err.is_empty()) {
            return Err(failure(world, step, me, &err));
        }
        world.min_f64(&mut drag);
        let drag = explicit.then_some(drag[0]);
        let mut plan = None;
        let mut next = Vec::new();
        if let (Some(e), Some(f)) = (&mut eng, forces) {
            let r = (|| -> Result<Plan, crate::step::StepError> {
                let _ = f;
                let drag = drag.unwrap_or(f64::INFINITY);
                let p = match drv.plan(&global, drag, t, step, t_target) {
                    Ok(p) => p,
                    Err(PlanError::NoLimit(m)) => return Err(crate::step::StepError::Blowup(m)),
                    Err(PlanError::Collapsed(m)) => {
                        let why = format!("{m}; {}", e.dt_culprits()?);
                        return Err(crate::step::StepError::Blowup(why));
                    }
                };
                e.take(&mut local, &p)?;
                // The dust densities stay as a step leaves them (fresh only where the drag
                // needs them each step): rank 0 computes them for an output.
                e.sync(&mut local)?;
                Ok(p)
            })();
            match r {
                Ok(p) => plan = Some(p),
                Err(x) if thin => stop(&x),
                Err(x) => err = x.to_string(),
            }
            next = records(&local)
                .into_iter()
                .filter(|r| mine.contains(&r.key()))
                .collect();
        }
        if world.any(!err.is_empty()) {
            return Err(failure(world, step, me, &err));
        }
        if thin {
            // Did every neighbour and cell-mate of an owned particle at the new layer lie in
            // the halo? Two particles close in by at most twice the largest displacement.
            let old: KeyMap<[f64; 3]> = owned.iter().map(|r| (r.key(), full_pos(r))).collect();
            let mut worst = [
                0.0f64,
                0.0,
                (local_recs.len() - owned.len()) as f64 / owned.len().max(1) as f64,
            ];
            for r in &next {
                let d2 = domain.distance2(old[&r.key()], full_pos(r));
                worst[0] = worst[0].max(d2.sqrt());
                worst[1] = worst[1].max(h_of(r));
            }
            world.max_f64(&mut worst);
            self.halo_ratio = self.halo_ratio.max(worst[2]);
            let need = (crate::step::SUPPORT * worst[1]).max(near) + 2.0 * worst[0];
            if need > reach {
                return Ok(Tried::Moved { need: need - near });
            }
            // The next step's margin: room for this step's motion, and more.
            self.margin = (3.0 * worst[0]).max(MIN_MARGIN * support);
        }
        // Every rank took the same step (a rank without particles learns it from the others).
        let mut tt = [if plan.is_some() {
            local.t
        } else {
            f64::NEG_INFINITY
        }];
        world.max_f64(&mut tt);
        // A rank without particles rebuilds the step from the new time (the others' plan).
        let plan = plan.unwrap_or(Plan {
            dt: tt[0] - t,
            dt_free: tt[0] - t,
            by_drag: false,
            landing: tt[0] == t_target,
            t_target,
        });
        self.owned = next;
        self.layer_given = true;
        Ok(Tried::Done((plan, tt[0], most[0])))
    }

    /// The momentum and its scale Σ m|v| of every rank's own particles, summed over the ranks
    /// (collective).
    pub fn momentum(&self) -> crate::step::Momentum {
        let mut s = [0.0f64; 4];
        for r in &self.owned {
            for (sk, vk) in s.iter_mut().zip(r.v) {
                *sk += r.m * vk;
            }
            s[3] += r.m * dustsph_device::dot(r.v, r.v).sqrt();
        }
        self.world.sum_f64(&mut s);
        crate::step::Momentum {
            p: [s[0], s[1], s[2]],
            scale: s[3],
        }
    }

    /// Every rank's particles as one state on rank 0 (phases in order, each by particle id),
    /// at time `t`, step `step`; `None` on the other ranks. Collective.
    pub fn gather(&self, t: f64, step: u64) -> Result<Option<State>, String> {
        let bytes: Vec<u8> = bytemuck::cast_slice(&self.owned).to_vec();
        let Some(parts) = self.world.gather_bytes(&bytes) else {
            return Ok(None);
        };
        let mut all: Vec<ParticleRecord> = parts
            .iter()
            .flat_map(|b| b.chunks_exact(std::mem::size_of::<ParticleRecord>()))
            .map(bytemuck::pod_read_unaligned::<ParticleRecord>)
            .collect();
        all.sort_unstable_by_key(|r| r.key());
        let mut st = state_of(&all, &self.template);
        st.t = t;
        st.step = step;
        Ok(Some(st))
    }
}

/// A step's failure, with the rank that saw it (every rank reports its own; all stop).
fn failure(_world: &World, step: u64, me: u32, err: &str) -> String {
    if err.is_empty() {
        format!("step {step}: another rank failed (its message above)")
    } else {
        format!("step {step}: rank {me}: {err}")
    }
}

/// The halo as the step needs it: particles within `inner` of an owned particle are stepped
/// (their passes recomputed here); those up to `outer` (one support further) are held fixed at
/// their owners' values (their density and pressure are exact at the start of the step, so the
/// stepped halo's forces are too, and no particle with an incomplete neighbourhood enters the
/// step's maxima); the rest, which no stepped particle reaches, are left out.
fn shell(
    owned: &[ParticleRecord],
    halo: &[ParticleRecord],
    inner: f64,
    outer: f64,
    domain: &crate::grid::Domain,
) -> Vec<ParticleRecord> {
    use std::collections::HashMap;
    // Cells of about half the test radius (on a periodic axis a whole number per period, the
    // indices wrapping): a halo particle scans only the cells across the edge of its sphere.
    let axes: [(f64, f64, Option<i64>); 3] = [0, 1, 2].map(|k| match domain.periodic[k] {
        Some((lo, len)) => {
            let n = (len / (0.5 * inner)).ceil().max(1.0) as i64;
            (lo, len / n as f64, Some(n))
        }
        None => (0.0, 0.5 * inner, None),
    });
    let index = |k: usize, v: f64| -> i64 {
        let (lo, size, n) = axes[k];
        let i = ((v - lo) / size).floor() as i64;
        n.map_or(i, |n| i.clamp(0, n - 1))
    };
    let mut grid: HashMap<[i64; 3], Vec<[f64; 3]>, std::hash::BuildHasherDefault<IntHasher>> =
        HashMap::default();
    for r in owned {
        let x = full_pos(r);
        grid.entry([0, 1, 2].map(|k| index(k, x[k])))
            .or_default()
            .push(x);
    }
    let sep2 = |a: [f64; 3], b: [f64; 3]| domain.distance2(a, b);
    // Along axis k, the cells within `radius` of coordinate v: (index, lower bound of the
    // distance, less a rounding margin); every cell of a period the reach spans whole.
    let cells_along = |k: usize, v: f64, radius: f64, out: &mut Vec<(i64, f64)>| {
        out.clear();
        let r2 = radius * radius;
        let (lo, size, n) = axes[k];
        let c = index(k, v);
        let reach = (radius / size).ceil() as i64;
        if let Some(n) = n {
            if 2 * reach + 1 >= n {
                out.extend((0..n).map(|i| (i, 0.0)));
                return;
            }
        }
        let face_lo = v - (lo + c as f64 * size);
        let face_hi = size - face_lo;
        for o in -reach..=reach {
            let g = match o {
                0 => 0.0,
                o if o > 0 => (o - 1) as f64 * size + face_hi,
                o => (-o - 1) as f64 * size + face_lo,
            };
            let g = (g - 1e-9 * size).max(0.0);
            if g * g <= r2 {
                let i = n.map_or(c + o, |n| (c + o).rem_euclid(n));
                out.push((i, g * g));
            }
        }
    };
    let (mut cx, mut cy, mut cz) = (Vec::new(), Vec::new(), Vec::new());
    // Whether an owned particle lies within `radius` of x.
    let mut within = |x: [f64; 3], radius: f64| -> bool {
        let r2 = radius * radius;
        cells_along(0, x[0], radius, &mut cx);
        cells_along(1, x[1], radius, &mut cy);
        cells_along(2, x[2], radius, &mut cz);
        cz.iter().any(|&(iz, gz)| {
            cy.iter().any(|&(iy, gy)| {
                gz + gy <= r2
                    && cx.iter().any(|&(ix, gx)| {
                        gz + gy + gx <= r2
                            && grid
                                .get(&[ix, iy, iz])
                                .is_some_and(|v| v.iter().any(|&o| sep2(o, x) <= r2))
                    })
            })
        })
    };
    halo.iter()
        .filter_map(|h| {
            let x = full_pos(h);
            if within(x, inner) {
                return Some(*h);
            }
            within(x, outer).then(|| {
                let mut r = *h;
                r.fixed = 1;
                r
            })
        })
        .collect()
}
