//! The thin halo's motion test, pair by pair of nearby cells (docs/scaling.md, "A resident
//! engine"). A halo built `reach` deep holds, for a pass that reads neighbours within `near`,
//! until some particle of one rank and some particle of another that was beyond the halo have
//! closed in from `reach` to `near`: until their relative displacement since the build
//! exceeds `reach − near`. The displacements' global spread bounds every pair's, but an
//! expanding ball or an orbiting disc moves its far sides apart while neighbours move
//! together, and dust drifting through gas moves the two phases apart while each keeps its
//! own spacing. Here each particle's displacement is binned, by phase, in the cell its build
//! position lies in; for every pair of cells within [`REACH_CELLS`] reaches that holds
//! particles of two ranks, the bins bound the pair's relative displacement, and the pair's
//! distance at the build (at least the cells' gap) and the phases' own `near` (the gas and
//! the dust meet only in an IDIC cell under the cell coupling) give it more room. Pairs of
//! cells further apart keep the global bound.
use super::Comm;
use crate::decomp::CellBox;

/// How many halo reaches either way the test pairs cells: pairs further apart are at least
/// this many reaches apart, and the global bound serves them.
pub const REACH_CELLS: i64 = 2;

/// Cells per halo reach: finer cells bound the motion of closer neighbours (a disc's inner
/// orbits turn across a cell one reach wide), but pair (2K + 1)^dim cells each. In 3D cells a
/// quarter reach wide would pair about 2500 times as many (64 times the cells, 39 times the
/// partners each); a reach per cell pairs 5–27 × 10³ on the ball at 2 × 248 439 particles,
/// listed in 5–13 ms.
pub fn cells_per_reach(dim: u32) -> u32 {
    if dim <= 2 {
        4
    } else {
        1
    }
}

/// Phase classes binned apart: the gas and the dust (every fraction).
const CLASSES: usize = 2;

/// Each class's bin: the displacements' upper bounds and their negated lower bounds, so that
/// the ranks' bins merge in one maximum.
const BIN: usize = 6;

/// Where a cell's bins sit: densely for a small box, by hash for a large sparse one.
enum Slots {
    Dense(Vec<u32>),
    Sparse(std::collections::HashMap<usize, u32>),
}

const NONE: u32 = u32::MAX;

/// The most cells a box may have for its lookups to be arrays.
const DENSE_CELLS: usize = 1 << 21;

/// Cells whose bins are merged and compared, agreed by every rank when a halo is built.
pub struct MotionCells {
    cbox: CellBox,
    slots: Slots,
    /// Pairs of slots holding particles of two ranks, with the cells' least distance apart.
    pairs: Vec<(u32, u32, f64)>,
    /// The least distance of a pair of cells not listed that could hold particles of two
    /// ranks ([`REACH_CELLS`] reaches).
    beyond: f64,
    /// The bins of this step ([`MotionCells::clear`], [`MotionCells::add`]).
    bins: Vec<f64>,
}

/// The ranks present in a cell, as their least and largest.
type Present = (u32, u32);

impl MotionCells {
    /// Cells `reach / per_reach` wide over the build's box `within` (the cut's), paired where
    /// two ranks hold particles in them or in cells within [`REACH_CELLS`] reaches along the
    /// scene's `dim` axes (collective): `anchors` are this rank's own particles' positions at
    /// the build.
    pub fn new(
        c: &dyn Comm,
        within: &CellBox,
        reach: f64,
        (dim, per_reach): (u32, u32),
        anchors: impl Iterator<Item = [f64; 3]>,
    ) -> MotionCells {
        let cbox = Self::cells_for(within, reach, per_reach);
        let mut mine: Vec<u64> = anchors
            .map(|x| cbox.index(cbox.cell_of(x)) as u64)
            .collect();
        mine.sort_unstable();
        mine.dedup();
        let bytes: Vec<u8> = mine.iter().flat_map(|i| i.to_le_bytes()).collect();
        let mut present: std::collections::HashMap<usize, Present> = Default::default();
        for (r, b) in c.all_gather_bytes(&bytes).iter().enumerate() {
            for w in b.chunks_exact(8) {
                let i = u64::from_le_bytes(w.try_into().expect("8 bytes")) as usize;
                let e = present.entry(i).or_insert((r as u32, r as u32));
                e.0 = e.0.min(r as u32);
                e.1 = e.1.max(r as u32);
            }
        }
        let mut cells: Vec<(usize, Present)> = present.iter().map(|(&i, &p)| (i, p)).collect();
        cells.sort_unstable();
        let k = REACH_CELLS * per_reach as i64;
        // Occupancy by index where the box is small, else by hash.
        const ABSENT: Present = (1, 0);
        let dense = (cbox.len() <= DENSE_CELLS).then(|| {
            let mut d = vec![ABSENT; cbox.len()];
            for &(i, p) in &cells {
                d[i] = p;
            }
            d
        });
        let at = |i: usize| match &dense {
            Some(d) => (d[i] != ABSENT).then_some(d[i]),
            None => present.get(&i).copied(),
        };
        let (pairs_at, beyond) = pairs_of(&cbox, &cells, (dim, k), at);
        drop(dense);
        // Slots for the cells in a pair only.
        let mut listed: Vec<usize> = pairs_at.iter().flat_map(|&(a, b, _)| [a, b]).collect();
        listed.sort_unstable();
        listed.dedup();
        let slots = if cbox.len() <= DENSE_CELLS {
            let mut d = vec![NONE; cbox.len()];
            for (s, &i) in listed.iter().enumerate() {
                d[i] = s as u32;
            }
            Slots::Dense(d)
        } else {
            Slots::Sparse(
                listed
                    .iter()
                    .enumerate()
                    .map(|(s, &i)| (i, s as u32))
                    .collect(),
            )
        };
        let slot = |i: usize| listed.binary_search(&i).expect("listed") as u32;
        let pairs = pairs_at
            .iter()
            .map(|&(a, b, g)| (slot(a), slot(b), g))
            .collect();
        MotionCells {
            cbox,
            slots,
            pairs,
            beyond,
            bins: vec![f64::NEG_INFINITY; listed.len() * CLASSES * BIN],
        }
    }

    /// The cells `reach / per_reach` wide over the cut's box `within`.
    pub fn cells_for(within: &CellBox, reach: f64, per_reach: u32) -> CellBox {
        let hi: [f64; 3] =
            std::array::from_fn(|k| within.lo[k] + within.n[k] as f64 * within.size[k]);
        CellBox::new(within.lo, hi, reach / per_reach as f64, within.periodic)
    }

    /// Cell pairs compared per step.
    pub fn pairs(&self) -> usize {
        self.pairs.len()
    }

    /// Empty bins for a step's displacements.
    pub fn clear(&mut self) {
        self.bins.fill(f64::NEG_INFINITY);
    }

    /// One own particle's displacement `d` since its build position `anchor` (class 0 the
    /// gas, 1 the dust).
    pub fn add(&mut self, class: usize, anchor: [f64; 3], d: [f64; 3]) {
        let i = self.cbox.index(self.cbox.cell_of(anchor));
        let s = match &self.slots {
            Slots::Dense(v) => v[i],
            Slots::Sparse(m) => m.get(&i).copied().unwrap_or(NONE),
        };
        if s == NONE {
            return;
        }
        let bin = &mut self.bins[(s as usize * CLASSES + class) * BIN..][..BIN];
        for k in 0..3 {
            bin[k] = bin[k].max(d[k]);
            bin[3 + k] = bin[3 + k].max(-d[k]);
        }
    }

    /// The bound that replaces twice the global relative motion in the halo's test `near +
    /// bound ≤ reach` (collective: the ranks' bins merged): the largest, over the listed
    /// pairs and phase classes, of the pair's relative displacement less the room its
    /// distance at the build and its classes' `near` leave, and for the pairs not listed the
    /// global bound `global` (twice the relative motion) less their room; never above
    /// `global`. `near` is the classes' own reach (gas–gas, dust–dust), `cross` the gas–dust
    /// one.
    pub fn bound(&mut self, c: &dyn Comm, reach: f64, near: f64, cross: f64, global: f64) -> f64 {
        c.max_f64(&mut self.bins);
        let bins = &self.bins;
        let bin = |s: u32, k: usize| &bins[(s as usize * CLASSES + k) * BIN..][..BIN];
        let mut worst = global - (self.beyond.max(reach) - reach);
        for &(a, b, gap) in &self.pairs {
            let room = gap.max(reach) - reach;
            for ka in 0..CLASSES {
                let ba = bin(a, ka);
                if ba[0] == f64::NEG_INFINITY {
                    continue;
                }
                for kb in 0..CLASSES {
                    let bb = bin(b, kb);
                    if bb[0] == f64::NEG_INFINITY {
                        continue;
                    }
                    let rel2: f64 = (0..3)
                        .map(|k| (ba[k] + bb[3 + k]).max(bb[k] + ba[3 + k]).powi(2))
                        .sum();
                    let own = if ka == kb { near } else { cross };
                    worst = worst.max(rel2.sqrt() - room - (near - own));
                }
            }
        }
        worst.clamp(0.0, global.max(0.0))
    }
}

/// The pairs (a, b) of occupied cells (a ≤ b by index) within `k` cells of each other on
/// each of the first `dim` axes (across the period on periodic axes; every particle shares its
/// coordinate on the others) that could hold particles of two ranks, with their least
/// distance apart; and the least distance apart of cells further than that.
fn pairs_of(
    cbox: &CellBox,
    cells: &[(usize, Present)],
    (dim, k): (u32, i64),
    at: impl Fn(usize) -> Option<Present>,
) -> (Vec<(usize, usize, f64)>, f64) {
    let mut pairs = Vec::new();
    // Rounding: a position on a cell's face may fall either side.
    let shave = 1e-9 * cbox.size.iter().fold(0.0f64, |a, &s| a.max(s));
    let single = |p: Present| p.0 == p.1;
    for &(ia, pa) in cells {
        let ca = cell_coords(cbox, ia);
        let span = |a: usize| {
            if a < dim as usize && cbox.n[a] > 1 {
                k
            } else {
                0
            }
        };
        let (kx, ky, kz) = (span(0), span(1), span(2));
        for dz in -kz..=kz {
            for dy in -ky..=ky {
                for dx in -kx..=kx {
                    let o = [dx, dy, dz];
                    let Some(cb) = offset(cbox, ca, o) else {
                        continue;
                    };
                    let ib = cbox.index(cb);
                    if ib < ia {
                        continue;
                    }
                    let Some(pb) = at(ib) else {
                        continue;
                    };
                    if single(pa) && single(pb) && pa.0 == pb.0 {
                        continue;
                    }
                    let gap2: f64 = (0..3)
                        .map(|a| ((o[a].abs() - 1).max(0) as f64 * cbox.size[a]).powi(2))
                        .sum();
                    pairs.push((ia, ib, (gap2.sqrt() - shave).max(0.0)));
                }
            }
        }
    }
    let beyond = (0..3)
        .filter(|&a| a < dim as usize && cbox.n[a] as i64 > k + 1)
        .map(|a| k as f64 * cbox.size[a])
        .fold(f64::INFINITY, f64::min)
        - shave;
    (pairs, beyond)
}

fn cell_coords(cbox: &CellBox, i: usize) -> [u32; 3] {
    let (nx, ny) = (cbox.n[0] as usize, cbox.n[1] as usize);
    [
        (i % nx) as u32,
        ((i / nx) % ny) as u32,
        (i / (nx * ny)) as u32,
    ]
}

fn offset(cbox: &CellBox, c: [u32; 3], o: [i64; 3]) -> Option<[u32; 3]> {
    let mut out = [0u32; 3];
    for a in 0..3 {
        let n = cbox.n[a] as i64;
        let i = c[a] as i64 + o[a];
        out[a] = if (0..n).contains(&i) {
            i as u32
        } else if cbox.periodic[a] {
            i.rem_euclid(n) as u32
        } else {
            return None;
        };
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two ranks in one process: the other rank's cells come from its anchors as its own
    /// `MotionCells::new` would send them; every bin is filled here, so no merge is needed.
    struct Two {
        other: Vec<u8>,
    }

    impl Comm for Two {
        fn rank(&self) -> u32 {
            0
        }
        fn size(&self) -> u32 {
            2
        }
        fn reduce_f64(&self, _: &mut [f64], _: crate::dist::comm::Reduce) {}
        fn reduce_u64(&self, _: &mut [u64], _: crate::dist::comm::Reduce) {}
        fn all_gather_raw(&self, mine: &[u8]) -> Vec<Vec<u8>> {
            vec![mine.to_vec(), self.other.clone()]
        }
        fn gather_raw(&self, _: &[u8]) -> Option<Vec<Vec<u8>>> {
            unimplemented!("not used by the motion bound")
        }
        fn send_raw(&self, _: u32, _: &[u8]) {
            unimplemented!("not used by the motion bound")
        }
        fn receive_raw(&self, _: u32) -> Vec<u8> {
            unimplemented!("not used by the motion bound")
        }
        fn all_to_all_counts(&self, _: &[i32]) -> Vec<i32> {
            unimplemented!("not used by the motion bound")
        }
        fn all_to_all_raw(&self, _: &[u8], _: &[i32], _: &mut [u8], _: &[i32]) {
            unimplemented!("not used by the motion bound")
        }
        fn dup(&self) -> Box<dyn Comm> {
            unimplemented!("not used by the motion bound")
        }
        fn abort(&self, _: i32) -> ! {
            unimplemented!("not used by the motion bound")
        }
    }

    fn rng(seed: &mut u64) -> f64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    /// The bound holds every pair of particles of the two ranks: their relative displacement
    /// less the room their distance at the build and their phases' reach leave never
    /// exceeds it (so `near + bound ≤ reach` keeps every pair that meets within the halo),
    /// on displacement fields that are smooth (an expansion, a shear), that drift one phase
    /// through the other, and that scatter; and on the smooth fields it is well below the
    /// global bound.
    #[test]
    fn the_cell_pairs_bound_every_pair_of_two_ranks_and_beat_the_global_bound_on_smooth_motion() {
        let (reach, near, cross) = (0.1, 0.07, 0.03);
        let within = CellBox::new([0.0; 3], [1.0; 3], 0.05, [false, false, true]);
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        for (field, per_reach) in (0..4).flat_map(|f| [(f, 1), (f, 2)]) {
            let n = 1500;
            let x: Vec<[f64; 3]> = (0..n)
                .map(|_| [rng(&mut seed), rng(&mut seed), rng(&mut seed)])
                .collect();
            let class: Vec<usize> = (0..n).map(|i| i % 2).collect();
            let rank: Vec<usize> = x.iter().map(|p| (p[0] >= 0.53) as usize).collect();
            let t = 0.01 * (1 + field) as f64;
            let d: Vec<[f64; 3]> = (0..n)
                .map(|i| {
                    let p = x[i];
                    match field {
                        0 => [t * (p[0] - 0.5), t * (p[1] - 0.5), 0.0],
                        1 => [t * p[1], 0.0, 0.0],
                        2 => [t * class[i] as f64, 0.0, 0.0],
                        _ => [t * rng(&mut seed), t * rng(&mut seed), -t * rng(&mut seed)],
                    }
                })
                .collect();
            let cbox = MotionCells::cells_for(&within, reach, per_reach);
            let theirs: Vec<u8> = {
                let mut v: Vec<u64> = (0..n)
                    .filter(|&i| rank[i] == 1)
                    .map(|i| cbox.index(cbox.cell_of(x[i])) as u64)
                    .collect();
                v.sort_unstable();
                v.dedup();
                v.iter().flat_map(|i| i.to_le_bytes()).collect()
            };
            let two = Two { other: theirs };
            let mine = (0..n).filter(|&i| rank[i] == 0).map(|i| x[i]);
            let mut cells = MotionCells::new(&two, &within, reach, (3, per_reach), mine);
            assert!(cells.pairs() > 0);
            cells.clear();
            for i in 0..n {
                cells.add(class[i], x[i], d[i]);
            }
            let mut global = 0.0f64;
            let mut worst = 0.0f64;
            for i in 0..n {
                for j in 0..n {
                    let rel = (0..3)
                        .map(|k| (d[i][k] - d[j][k]).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    global = global.max(rel);
                    if rank[i] == 0 && rank[j] == 1 {
                        let dist2: f64 = (0..3)
                            .map(|k| {
                                let dx = x[i][k] - x[j][k];
                                let dx = if within.periodic[k] {
                                    dx - dx.round()
                                } else {
                                    dx
                                };
                                dx * dx
                            })
                            .sum();
                        let room = dist2.sqrt().max(reach) - reach;
                        let own = if class[i] == class[j] { near } else { cross };
                        worst = worst.max(rel - room - (near - own));
                    }
                }
            }
            let bound = cells.bound(&two, reach, near, cross, global);
            assert!(
                worst <= bound * (1.0 + 1e-12) + 1e-15,
                "field {field}, {per_reach} cells a reach: a pair needs {worst}, the bound is {bound}"
            );
            assert!(bound <= global, "field {field}: {bound} > {global}");
            if field < 3 {
                assert!(
                    bound < 0.7 * global,
                    "field {field}: {bound} against {global}"
                );
            }
        }
    }

    /// Two particles of two ranks alone in one cell, moving toward each other: their own
    /// cell's pair bounds them (no other cell is near).
    #[test]
    fn a_cell_two_ranks_share_bounds_the_pairs_inside_it() {
        let within = CellBox::new([0.0; 3], [1.0; 3], 0.05, [false; 3]);
        let (a, b) = ([0.42, 0.4, 0.4], [0.48, 0.4, 0.4]);
        let cbox = MotionCells::cells_for(&within, 0.1, 1);
        let other = (cbox.index(cbox.cell_of(b)) as u64).to_le_bytes().to_vec();
        let two = Two { other };
        let mut cells = MotionCells::new(&two, &within, 0.1, (3, 1), std::iter::once(a));
        assert_eq!(cells.pairs(), 1);
        cells.clear();
        cells.add(0, a, [0.02, 0.0, 0.0]);
        cells.add(0, b, [-0.02, 0.0, 0.0]);
        let bound = cells.bound(&two, 0.1, 0.07, 0.03, 0.05);
        assert!((bound - 0.04).abs() < 1e-12, "{bound}");
    }
}
