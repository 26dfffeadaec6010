//! The decomposition over ranks and the halo: the Morton cut agreed by every rank, the
//! migration of particles to their owners, the halo's copies, the thin halo's refresh between
//! the step's passes ([`RankGhosts`]) and the deep halo's shell.
use super::comm::{Comm, World};
use super::records::{full_pos, ParticleRecord};
use crate::decomp::{CellBox, Cells, Partition};
use crate::particles::KeyMap;
use crate::step::engine::GhostSync;

/// Decomposition cells per halo reach: cells half the reach wide (the halo then spans the
/// cells within three of a rank's own), so that a reach of several supports still leaves a
/// small domain enough cells to cut evenly.
pub const CELLS_PER_REACH: f64 = 2.0;

/// The Morton cut of this step, the same on every rank (collective): global bounds (the period
/// on periodic axes) and per-cell counts of every rank's positions `xs`, in cells
/// `reach / CELLS_PER_REACH` wide, with a halo ring of cells that holds every particle within
/// `reach` of a rank's own. With `cost` (the same kind on every rank: this rank's measured
/// cost per particle) the ranges hold equal costs instead of equal counts.
pub fn cut(
    world: &World,
    xs: &[[f64; 3]],
    domain: &crate::grid::Domain,
    reach: f64,
    cost: Option<f64>,
) -> Partition {
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
    let mut cells = Cells::from_counts(counts.iter().map(|&c| c as u32).collect(), cbox);
    if let Some(w) = cost {
        let mut load = vec![0.0; cbox.len()];
        for &x in xs {
            load[cbox.index(cbox.cell_of(x))] += w;
        }
        world.sum_f64(&mut load);
        cells = cells.with_cost(load);
    }
    Partition::with_ring(&cells, world.size(), ring)
}

/// Every record to the rank owning its cell (collective): what this rank now owns (its own
/// that stay, then those that arrived, in rank order), and the bytes it sent to other ranks.
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
    // Only the particles that leave go through the exchange (its buffers hold them alone).
    let mut kept = std::mem::take(&mut sends[me]);
    kept.extend(world.exchange(&sends)?);
    Ok((kept, bytes))
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
/// holding it as a ghost, every table in one exchange per refresh (collective). The rows
/// carry no keys: which particle each row is was agreed once, when the halo was built
/// ([`RankGhosts::new`]), and which slot it is in after each sort ([`GhostSync::reorder`]).
pub(super) struct RankGhosts {
    comm: World,
    /// Per rank, the keys (phase, id) of the owned particles it holds as ghosts, in the order
    /// their rows go.
    sends: Vec<Vec<(u64, u64)>>,
    /// The keys of the rows that arrive, in their order (rank by rank, each in its send order).
    arriving: Vec<(u64, u64)>,
    /// Per rank, the (table, slot) of each row sent, after the last sort.
    send_slots: Vec<Vec<(usize, usize)>>,
    /// Per arriving row, its table and its slot here (every arriving row is held).
    recv_slots: Vec<(usize, usize)>,
    /// Per table, the slots of the rows sent (rank by rank) and of the rows written (in the
    /// order they arrive): [`GhostSync::send_slots`], `recv_slots`.
    send_list: [Vec<u32>; 2],
    recv_list: [Vec<u32>; 2],
    /// Refreshes before one fails (`DUSTSPH_FAIL_IN_STEP`, set per step by the rank's
    /// stepper; negative: none fails).
    fail: std::sync::Arc<std::sync::atomic::AtomicI64>,
    /// The refresh's send and receive buffers, kept across refreshes.
    send_buf: Vec<u8>,
    recv_buf: Vec<u8>,
}

/// The phase table of a key: 0 the gas, 1 the dust (every fraction).
fn table(key: (u64, u64)) -> usize {
    (key.0 != 0) as usize
}

impl RankGhosts {
    /// The refresh of a halo: `sends[q]`, the keys of the owned particles sent to rank q as
    /// halo candidates; `kept[q]`, which of the candidates rank q sent here this rank keeps as
    /// ghosts (in the order they came), and `arriving` the keys of those, in that order. Tells
    /// every sender which of its candidates are held, so that the refreshes carry only those
    /// rows (the shell test leaves out some of what the cut's boxes send). Collective.
    pub(super) fn new(
        comm: World,
        sends: Vec<Vec<(u64, u64)>>,
        kept: Vec<Vec<u8>>,
        arriving: Vec<(u64, u64)>,
        fail: std::sync::Arc<std::sync::atomic::AtomicI64>,
    ) -> Result<RankGhosts, String> {
        let replies = kept;
        // Each rank's answer about the keys sent to it, in rank order.
        let kept = comm.exchange(&replies)?;
        let mut at = 0;
        let sends: Vec<Vec<(u64, u64)>> = (sends.into_iter())
            .map(|s| {
                let mask = &kept[at..at + s.len()];
                at += s.len();
                (s.into_iter().zip(mask))
                    .filter(|(_, &k)| k != 0)
                    .map(|(key, _)| key)
                    .collect()
            })
            .collect();
        Ok(RankGhosts {
            send_slots: vec![Vec::new(); sends.len()],
            comm,
            sends,
            arriving,
            recv_slots: Vec::new(),
            send_list: [Vec::new(), Vec::new()],
            recv_list: [Vec::new(), Vec::new()],
            fail,
            send_buf: Vec::new(),
            recv_buf: Vec::new(),
        })
    }

    /// The per-table slot lists from the per-rank ones (after each sort).
    fn relist(&mut self) {
        for l in self.send_list.iter_mut().chain(self.recv_list.iter_mut()) {
            l.clear();
        }
        for to in &self.send_slots {
            for &(k, i) in to {
                self.send_list[k].push(i as u32);
            }
        }
        for &(k, i) in &self.recv_slots {
            self.recv_list[k].push(i as u32);
        }
    }
}

/// Whether `DUSTSPH_FAIL_IN_STEP=rank:step` names this rank and step (tests/mpi.rs: a failure
/// inside a step stops the job, with its message, and does not hang).
pub(super) fn fail_requested(rank: u32, step: u64) -> bool {
    crate::env::check("DUSTSPH_FAIL_IN_STEP")
        && crate::env::var("DUSTSPH_FAIL_IN_STEP").is_some_and(|v| v == format!("{rank}:{step}"))
}

impl GhostSync for RankGhosts {
    fn reorder(&mut self, slots: &[Vec<(u64, u64)>]) -> Result<(), String> {
        let at: Vec<KeyMap<usize>> = (slots.iter())
            .map(|keys| keys.iter().enumerate().map(|(i, &k)| (k, i)).collect())
            .collect();
        for (q, keys) in self.sends.iter().enumerate() {
            let out = &mut self.send_slots[q];
            out.clear();
            for &key in keys {
                let i = *(at[table(key)].get(&key))
                    .ok_or_else(|| format!("particle {key:?} is not on its owner"))?;
                out.push((table(key), i));
            }
        }
        self.recv_slots = (self.arriving.iter())
            .map(|&key| match at[table(key)].get(&key) {
                Some(&i) => Ok((table(key), i)),
                None => Err(format!("ghost {key:?} is not held here")),
            })
            .collect::<Result<_, String>>()?;
        self.relist();
        Ok(())
    }

    fn permute(&mut self, new_of_old: &[Vec<u32>]) -> Result<(), String> {
        let moved = |k: usize, i: usize| -> Result<usize, String> {
            (new_of_old[k].get(i).map(|&j| j as usize))
                .ok_or_else(|| "a sort changed the particles of a halo".to_string())
        };
        for to in self.send_slots.iter_mut() {
            for (k, i) in to.iter_mut() {
                *i = moved(*k, *i)?;
            }
        }
        for (k, i) in self.recv_slots.iter_mut() {
            *i = moved(*k, *i)?;
        }
        self.relist();
        Ok(())
    }

    fn send_slots(&self, table: usize) -> &[u32] {
        &self.send_list[table]
    }

    fn recv_slots(&self, table: usize) -> &[u32] {
        &self.recv_list[table]
    }

    fn trim(&mut self) {
        self.send_buf = Vec::new();
        self.recv_buf = Vec::new();
    }

    fn refresh(
        &mut self,
        row: [usize; 2],
        out: [&[u8]; 2],
        back: &mut [Vec<u8>; 2],
    ) -> Result<(), String> {
        use std::sync::atomic::Ordering;
        match self.fail.load(Ordering::Relaxed) {
            0 => return Err("failure requested by DUSTSPH_FAIL_IN_STEP".into()),
            n if n > 0 => self.fail.store(n - 1, Ordering::Relaxed),
            _ => {}
        }
        // Each rank's rows in its send order, taken from the tables in turn, into the one
        // send buffer (kept, as the receive buffer is, across refreshes).
        let mut next = [0usize; 2];
        let mut counts = Vec::with_capacity(self.send_slots.len());
        self.send_buf.clear();
        for to in &self.send_slots {
            let start = self.send_buf.len();
            for &(k, _) in to {
                let r = row[k];
                self.send_buf
                    .extend_from_slice(&out[k][next[k] * r..(next[k] + 1) * r]);
                next[k] += 1;
            }
            counts.push(self.send_buf.len() - start);
        }
        (self.comm).exchange_bytes_into(&self.send_buf, &counts, &mut self.recv_buf)?;
        let got = &self.recv_buf;
        let expected: usize = self.recv_slots.iter().map(|&(k, _)| row[k]).sum();
        if got.len() != expected {
            return Err("a rank sent ghost rows of another layout".into());
        }
        for b in back.iter_mut() {
            b.clear();
        }
        let mut at = 0;
        for &(k, _) in &self.recv_slots {
            let r = row[k];
            back[k].extend_from_slice(&got[at..at + r]);
            at += r;
        }
        Ok(())
    }
}

/// The shell test's cells, in units of its radius: small enough that a halo particle beyond
/// the radius scans few owned particles (those in cells the sphere cuts), large enough that
/// it visits few cells. On the ball's halos over 2 ranks (`--set sph.h=0.0308`) the test took
/// 0.30–0.45 s at 0.25, 0.10–0.15 s at 0.5, 0.20–0.60 s at 1.
const SHELL_CELL: f64 = 0.5;

/// The halo as the step needs it: particles within `inner` of an owned particle are stepped
/// (their passes recomputed here); those up to `outer` (one support further) are held fixed at
/// their owners' values (their density and pressure are exact at the start of the step, so the
/// stepped halo's forces are too, and no particle with an incomplete neighbourhood enters the
/// step's maxima); the rest, which no stepped particle reaches, are left out. `owned` need
/// only hold the owned particles that can lie within `outer` of a halo particle (those sent as
/// halo to its owner). Returns the halo kept, and whether each particle of `halo` is.
pub(super) fn shell(
    owned: &[ParticleRecord],
    halo: &[ParticleRecord],
    inner: f64,
    outer: f64,
    domain: &crate::grid::Domain,
) -> (Vec<ParticleRecord>, Vec<bool>) {
    let xs: Vec<[f64; 3]> = owned.iter().map(full_pos).collect();
    if xs.is_empty() {
        return (Vec::new(), vec![false; halo.len()]);
    }
    let grid = ShellGrid::new(xs, inner, domain);
    let mut scratch = (Vec::new(), Vec::new(), Vec::new());
    let mut flags = Vec::with_capacity(halo.len());
    let kept = (halo.iter())
        .filter_map(|h| {
            let x = full_pos(h);
            let k = if grid.within(x, inner, &mut scratch) {
                Some(*h)
            } else {
                (outer > inner && grid.within(x, outer, &mut scratch)).then(|| {
                    let mut r = *h;
                    r.fixed = 1;
                    r
                })
            };
            flags.push(k.is_some());
            k
        })
        .collect();
    (kept, flags)
}

/// One axis of the shell test's cells: (origin, cell size, cells per period on a periodic
/// axis).
type ShellAxis = (f64, f64, Option<i64>);

/// The axes of cells `cell` wide (on a periodic axis a whole number per period).
fn shell_axes(domain: &crate::grid::Domain, cell: f64) -> [ShellAxis; 3] {
    [0, 1, 2].map(|k| match domain.periodic[k] {
        Some((lo, len)) => {
            let n = (len / cell).ceil().max(1.0) as i64;
            (lo, len / n as f64, Some(n))
        }
        None => (0.0, cell, None),
    })
}

/// The index of coordinate v's cell along axis k (clamped into the period on a periodic
/// axis).
fn shell_index(axes: &[ShellAxis; 3], k: usize, v: f64) -> i64 {
    let (lo, size, n) = axes[k];
    let i = ((v - lo) / size).floor() as i64;
    n.map_or(i, |n| i.clamp(0, n - 1))
}

/// The owned positions in cells of [`SHELL_CELL`] × the test radius (the indices wrapping on
/// a periodic axis): a halo particle scans only the cells across the edge of its sphere. They
/// are held as one array over the box of the owned particles' cells (a lookup is an index,
/// not a hash), made coarser where that box would hold many more cells than particles.
struct ShellGrid<'a> {
    domain: &'a crate::grid::Domain,
    axes: [ShellAxis; 3],
    /// The box's first cell and its cells along each axis.
    first: [i64; 3],
    dims: [usize; 3],
    /// Cell c holds pts[start[c]..start[c + 1]].
    start: Vec<u32>,
    pts: Vec<[f64; 3]>,
}

impl<'a> ShellGrid<'a> {
    /// The grid of the owned positions `xs` (not empty) for the test radius `inner`.
    fn new(xs: Vec<[f64; 3]>, inner: f64, domain: &'a crate::grid::Domain) -> ShellGrid<'a> {
        let mut cell = SHELL_CELL * inner;
        let (axes, first, dims) = loop {
            let axes = shell_axes(domain, cell);
            let mut first = [i64::MAX; 3];
            let mut last = [i64::MIN; 3];
            for x in &xs {
                for k in 0..3 {
                    let i = shell_index(&axes, k, x[k]);
                    first[k] = first[k].min(i);
                    last[k] = last[k].max(i);
                }
            }
            for k in 0..3 {
                if let Some(n) = axes[k].2 {
                    (first[k], last[k]) = (0, n - 1);
                }
            }
            let dims = [0, 1, 2].map(|k| (last[k] - first[k] + 1) as usize);
            let cells = dims.iter().map(|&d| d as f64).product::<f64>();
            if cells <= (8 * xs.len() + 4096) as f64 {
                break (axes, first, dims);
            }
            cell *= 2.0;
        };
        let mut grid = ShellGrid {
            domain,
            axes,
            first,
            dims,
            start: Vec::new(),
            pts: Vec::new(),
        };
        grid.sort(xs);
        grid
    }

    /// Places the owned positions by cell (a counting sort).
    fn sort(&mut self, xs: Vec<[f64; 3]>) {
        let dims = self.dims;
        let at: Vec<usize> = (xs.iter())
            .map(|x| {
                (self.flat([0, 1, 2].map(|k| self.index(k, x[k])))).expect("within the owned box")
            })
            .collect();
        let mut start = vec![0u32; dims[0] * dims[1] * dims[2] + 1];
        for &c in &at {
            start[c + 1] += 1;
        }
        for c in 1..start.len() {
            start[c] += start[c - 1];
        }
        let mut fill = start.clone();
        let mut pts = vec![[0.0; 3]; xs.len()];
        for (x, &c) in xs.iter().zip(&at) {
            pts[fill[c] as usize] = *x;
            fill[c] += 1;
        }
        drop((at, fill, xs));
        (self.start, self.pts) = (start, pts);
    }

    /// The index of coordinate v's cell along axis k.
    fn index(&self, k: usize, v: f64) -> i64 {
        shell_index(&self.axes, k, v)
    }

    /// A cell's place in the array, `None` outside the owned particles' box.
    fn flat(&self, c: [i64; 3]) -> Option<usize> {
        let (first, dims) = (self.first, self.dims);
        let r = [0, 1, 2].map(|k| c[k] - first[k]);
        (0..3)
            .all(|k| r[k] >= 0 && (r[k] as usize) < dims[k])
            .then(|| (r[2] as usize * dims[1] + r[1] as usize) * dims[0] + r[0] as usize)
    }

    /// The owned positions in cell c (none outside the box).
    fn in_cell(&self, c: [i64; 3]) -> &[[f64; 3]] {
        self.flat(c).map_or(&[], |c| {
            &self.pts[self.start[c] as usize..self.start[c + 1] as usize]
        })
    }

    /// Along axis k, the cells within `radius` of coordinate v: (index, lower bound of the
    /// distance, less a rounding margin, and upper bound, plus one); every cell of a period the
    /// reach spans whole (upper bound +∞ there).
    fn cells_along(&self, k: usize, v: f64, radius: f64, out: &mut Vec<(i64, f64, f64)>) {
        out.clear();
        let r2 = radius * radius;
        let (lo, size, n) = self.axes[k];
        let c = self.index(k, v);
        let reach = (radius / size).ceil() as i64;
        if let Some(n) = n {
            if 2 * reach + 1 >= n {
                out.extend((0..n).map(|i| (i, 0.0, f64::INFINITY)));
                return;
            }
        }
        let face_lo = v - (lo + c as f64 * size);
        let face_hi = size - face_lo;
        // Nearest cells first: a particle within the radius is found in few lookups.
        for o in (0..=2 * reach).map(|j| if j % 2 == 1 { (j + 1) / 2 } else { -(j / 2) }) {
            let (g, far) = match o {
                0 => (0.0, face_lo.max(face_hi)),
                o if o > 0 => ((o - 1) as f64 * size + face_hi, o as f64 * size + face_hi),
                o => ((-o - 1) as f64 * size + face_lo, -o as f64 * size + face_lo),
            };
            let g = (g - 1e-9 * size).max(0.0);
            let far = far + 1e-9 * size;
            if g * g <= r2 {
                let i = n.map_or(c + o, |n| (c + o).rem_euclid(n));
                out.push((i, g * g, far * far));
            }
        }
    }

    /// Whether an owned particle lies within `radius` of x: a cell wholly within it answers
    /// without a scan of its particles. `scratch` holds the cells along each axis.
    fn within(&self, x: [f64; 3], radius: f64, scratch: &mut ShellScratch) -> bool {
        let (cx, cy, cz) = scratch;
        let sep2 = |a: [f64; 3], b: [f64; 3]| self.domain.distance2(a, b);
        let r2 = radius * radius;
        self.cells_along(0, x[0], radius, cx);
        self.cells_along(1, x[1], radius, cy);
        self.cells_along(2, x[2], radius, cz);
        cz.iter().any(|&(iz, gz, fz)| {
            cy.iter().any(|&(iy, gy, fy)| {
                gz + gy <= r2
                    && cx.iter().any(|&(ix, gx, fx)| {
                        gz + gy + gx <= r2 && {
                            let v = self.in_cell([ix, iy, iz]);
                            !v.is_empty()
                                && (fz + fy + fx <= r2 || v.iter().any(|&o| sep2(o, x) <= r2))
                        }
                    })
            })
        })
    }
}

/// The cells along x, y and z of one shell test (kept across tests).
type ShellScratch = (
    Vec<(i64, f64, f64)>,
    Vec<(i64, f64, f64)>,
    Vec<(i64, f64, f64)>,
);

#[cfg(test)]
mod tests {
    use super::shell;
    use crate::dist::records::ParticleRecord;
    use crate::grid::Domain;

    fn at(x: [f64; 3], id: u64) -> ParticleRecord {
        ParticleRecord {
            id,
            x,
            ..Default::default()
        }
    }

    /// The shell test keeps exactly the halo particles a pairwise search keeps: within `inner`
    /// of an owned particle stepped, within `outer` held fixed, the rest left out; on open and
    /// periodic axes (the minimum image), with owned particles clustered so that most cells are
    /// empty and many halo particles lie just beyond either radius.
    #[test]
    fn the_shell_keeps_exactly_the_halo_particles_a_pairwise_search_keeps() {
        let mut rng = fastrand::Rng::with_seed(7);
        // One cluster: the cells at their finest; four spread out: coarser cells, the box of
        // the owned particles' cells bounded by their count.
        let open = [None, None, None];
        let some = [Some((-1.0, 3.0)), None, Some((0.0, 2.0))];
        for (periodic, clusters) in [(open, 1), (open, 4), (some, 1), (some, 4)] {
            let domain = Domain { dim: 3, periodic };
            // Positions as the step keeps them: within the period on a periodic axis.
            let wrap = |x: [f64; 3]| {
                [0, 1, 2].map(|k| match periodic[k] {
                    Some((lo, len)) => lo + (x[k] - lo).rem_euclid(len),
                    None => x[k],
                })
            };
            let mut owned = Vec::new();
            for c in 0..clusters {
                let centre = [rng.f64() * 2.0 - 1.0, rng.f64(), rng.f64() * 2.0];
                for _ in 0..150 {
                    let x = [0, 1, 2].map(|k| centre[k] + 0.2 * (rng.f64() - 0.5));
                    owned.push(at(wrap(x), owned.len() as u64 + 1000 * c));
                }
            }
            let halo: Vec<ParticleRecord> = (0..3000)
                .map(|i| {
                    let x = [
                        3.0 * rng.f64() - 1.5,
                        2.0 * rng.f64() - 0.5,
                        2.5 * rng.f64() - 0.25,
                    ];
                    at(wrap(x), i)
                })
                .collect();
            let (inner, outer) = (0.07, 0.12);
            let (got, flags) = shell(&owned, &halo, inner, outer, &domain);
            let flagged: Vec<u64> = (halo.iter().zip(&flags))
                .filter(|(_, &f)| f)
                .map(|(h, _)| h.id)
                .collect();
            assert_eq!(flagged, got.iter().map(|r| r.id).collect::<Vec<_>>());
            let nearest = |x: [f64; 3]| {
                (owned.iter())
                    .map(|o| domain.distance2(o.x, x))
                    .fold(f64::INFINITY, f64::min)
                    .sqrt()
            };
            let want: Vec<(u64, u64)> = (halo.iter())
                .filter_map(|h| {
                    let d = nearest(h.x);
                    (d <= outer).then_some((h.id, (d > inner) as u64))
                })
                .collect();
            let got: Vec<(u64, u64)> = got.iter().map(|r| (r.id, r.fixed)).collect();
            assert_eq!(got, want, "periodic {periodic:?}, {clusters} clusters");
            assert!(want.iter().any(|w| w.1 == 1) && want.iter().any(|w| w.1 == 0));
            assert!(
                want.len() < halo.len() / 2,
                "most halo particles lie beyond `outer`"
            );
        }
    }
}
