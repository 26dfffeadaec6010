//! Domain decomposition along a space-filling curve, for the multi-rank model of issue 14
//! (docs/scaling.md). No MPI here: this is the partition a run over R ranks would use, and
//! the halo it implies, computed on the real particle distribution.
//!
//! Particles are binned into cells at least one interaction reach (the kernel support 2h)
//! wide: every neighbour of a particle lies in its own cell or one of the 26 around it
//! (across the period on periodic axes). Cells are ordered by their Morton key
//! (bit-interleaved integer coordinates) and cut into R contiguous key ranges of, as nearly as
//! whole cells allow, equal particle counts. A particle is in rank r's halo when its cell
//! belongs to another rank and touches one of r's cells: it must reach r before each
//! neighbour pass.

/// Morton key of integer cell coordinates (21 bits each): bits interleaved x, y, z.
pub fn morton(c: [u32; 3]) -> u64 {
    fn spread(v: u32) -> u64 {
        let mut x = (v as u64) & 0x1f_ffff;
        x = (x | x << 32) & 0x1f_0000_0000_ffff;
        x = (x | x << 16) & 0x1f_0000_ff00_00ff;
        x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
        x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
        x = (x | x << 2) & 0x1249_2492_4924_9249;
        x
    }
    spread(c[0]) | spread(c[1]) << 1 | spread(c[2]) << 2
}

/// A box of cells: `n` per axis, of size `size` (≥ the reach), lower corner `lo`; periodic axes
/// wrap their neighbours.
#[derive(Debug, Clone, Copy)]
pub struct CellBox {
    pub lo: [f64; 3],
    pub size: [f64; 3],
    pub n: [u32; 3],
    pub periodic: [bool; 3],
}

impl CellBox {
    /// Cells at least `reach` wide over [lo, hi]; on a periodic axis a whole number of cells
    /// tiles the period hi − lo.
    pub fn new(lo: [f64; 3], hi: [f64; 3], reach: f64, periodic: [bool; 3]) -> CellBox {
        let mut b = CellBox {
            lo,
            size: [reach; 3],
            n: [1; 3],
            periodic,
        };
        for k in 0..3 {
            let len = (hi[k] - lo[k]).max(0.0);
            let n = ((len / reach).floor() as u32).max(1);
            if periodic[k] {
                b.n[k] = n;
                b.size[k] = len / n as f64;
            } else {
                b.n[k] = n + 1;
            }
        }
        b
    }

    /// A cell's place along the curve: its Morton key on a grid of 2^k cells per axis (2^k
    /// the least power of two ≥ the most cells along any axis), the cell at ⌊c·2^k / n_max⌋ on
    /// every axis alike. The curve's halvings then cut the occupied box through its middle,
    /// its longest extent first, and each rank's range is a compact block; keyed on the raw
    /// cell coordinates, the first halving would fall wherever the box's cell count crosses a
    /// power of two, and equal counts would then be cut deep in the curve, along a jagged
    /// surface (on the periodic 3D box over 2 ranks a halo 1.6–1.8 times one slab's).
    pub fn key(&self, c: [u32; 3]) -> u64 {
        let most = *self.n.iter().max().expect("three axes") as u64;
        let grid = most.next_power_of_two();
        morton(c.map(|v| (v as u64 * grid / most) as u32))
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.n.iter().map(|&n| n as usize).product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Row-major index of a cell.
    pub fn index(&self, c: [u32; 3]) -> usize {
        (c[2] as usize * self.n[1] as usize + c[1] as usize) * self.n[0] as usize + c[0] as usize
    }

    /// The cell holding position p (clamped to the box).
    pub fn cell_of(&self, p: [f64; 3]) -> [u32; 3] {
        [0, 1, 2].map(|k| {
            let i = ((p[k] - self.lo[k]) / self.size[k]).floor();
            (i.max(0.0) as u32).min(self.n[k] - 1)
        })
    }
}

/// Particle counts per cell of a cloud, and the occupied cells in Morton order.
#[derive(Debug, Clone)]
pub struct Cells {
    pub cbox: CellBox,
    pub count: Vec<u32>,
    /// Occupied cells: (Morton key, coordinates), sorted by key.
    pub order: Vec<(u64, [u32; 3])>,
    pub total: u64,
    /// The measured cost per cell (row-major, summed over ranks), where the cut follows it
    /// rather than the counts ([`Cells::with_cost`]).
    pub cost: Option<Vec<f64>>,
}

impl Cells {
    pub fn bin(points: impl Iterator<Item = [f64; 3]>, cbox: CellBox) -> Cells {
        let mut count = vec![0u32; cbox.len()];
        for p in points {
            count[cbox.index(cbox.cell_of(p))] += 1;
        }
        Cells::from_counts(count, cbox)
    }

    /// From per-cell counts (row-major), e.g. summed over ranks.
    pub fn from_counts(count: Vec<u32>, cbox: CellBox) -> Cells {
        assert_eq!(count.len(), cbox.len(), "one count per cell");
        let total = count.iter().map(|&c| c as u64).sum();
        let mut order = Vec::new();
        for z in 0..cbox.n[2] {
            for y in 0..cbox.n[1] {
                for x in 0..cbox.n[0] {
                    if count[cbox.index([x, y, z])] > 0 {
                        order.push((cbox.key([x, y, z]), [x, y, z]));
                    }
                }
            }
        }
        order.sort_unstable_by_key(|c| c.0);
        Cells {
            cbox,
            count,
            order,
            total,
            cost: None,
        }
    }

    /// The same cells, cut into ranges of equal `cost` (one per cell, row-major) instead of
    /// equal counts.
    pub fn with_cost(self, cost: Vec<f64>) -> Cells {
        assert_eq!(cost.len(), self.count.len(), "one cost per cell");
        Cells {
            cost: Some(cost),
            ..self
        }
    }

    /// What the cut shares out in cell `i` (row-major): its cost where measured, else its
    /// particles.
    fn load(&self, i: usize) -> f64 {
        match &self.cost {
            Some(c) => c[i],
            None => self.count[i] as f64,
        }
    }
}

/// A partition of the cells into contiguous Morton ranges, and its halo.
#[derive(Debug, Clone)]
pub struct Partition {
    pub cbox: CellBox,
    /// The rank owning each cell (row-major; `u32::MAX` for empty cells).
    pub owner: Vec<u32>,
    /// The occupied cells' Morton keys and owners, in key order.
    pub keys: Vec<(u64, u32)>,
    /// Particles each rank owns.
    pub owned: Vec<u64>,
    /// Particles each rank receives as halo (owned elsewhere, in a cell touching its cells).
    pub halo: Vec<u64>,
    /// Ranks each rank receives halo from.
    pub peers: Vec<u32>,
    /// How many cells around its own a particle's halo reaches (1: the 26 neighbours).
    pub ring: u32,
}

const NOBODY: u32 = u32::MAX;

/// How far (a fraction of a rank's share) a cut may move from equal counts to fall between
/// coarser blocks of the curve. A cut inside a block leaves its two ranks a jagged face: on
/// the Phantom slab over 2 ranks (`--set sph.n=128`) one rank's halo was 0.20 of its own
/// particles where the plane between the halves, 0.8 % of a share away, gives 0.11.
pub const CUT_SLACK: f64 = 0.02;

/// Where each rank k ≥ 1 starts in the key-ordered cells: at the boundary nearest the equal
/// share k·L/R of the load L (the particles, or their measured cost: [`Cells::with_cost`];
/// the first cell whose load before it reaches k·L/R), or, within [`CUT_SLACK`] of a share of
/// it, at the boundary between the coarsest blocks of the curve there (the highest bit in
/// which the keys on either side differ), nearest first.
pub fn cut_points(cells: &Cells, ranks: u64) -> Vec<usize> {
    let n = cells.order.len();
    // The load before each cell along the curve.
    let mut before = Vec::with_capacity(n + 1);
    let mut run = 0.0;
    for &(_, c) in &cells.order {
        before.push(run);
        run += cells.load(cells.cbox.index(c));
    }
    before.push(run);
    let share = run / ranks as f64;
    // No rank starts at either end for a coarser boundary (an empty rank).
    let level = |j: usize| -> u32 {
        if j == 0 || j == n {
            return 0;
        }
        64 - (cells.order[j - 1].0 ^ cells.order[j].0).leading_zeros()
    };
    let mut starts = Vec::with_capacity(ranks as usize);
    let mut last = 0;
    for k in 1..ranks {
        let target = match cells.cost {
            // Whole particles: the integer share, as one process rounds it.
            None => (k * cells.total).div_ceil(ranks) as f64,
            Some(_) => k as f64 * share,
        };
        let equal = before.partition_point(|&b| b < target);
        let lo = before.partition_point(|&b| b < target - CUT_SLACK * share);
        let hi = before.partition_point(|&b| b <= target + CUT_SLACK * share);
        let best = (lo.max(last)..hi.max(lo.max(last)))
            .chain(std::iter::once(equal.max(last)))
            .max_by_key(|&j| (level(j), std::cmp::Reverse(j.abs_diff(equal))))
            .expect("the equal cut at least");
        starts.push(best);
        last = best;
    }
    starts.push(n);
    starts
}

impl Partition {
    /// Cut the key-ordered cells into `ranks` ranges of nearly equal particle counts
    /// ([`cut_points`]), then count every rank's halo.
    pub fn of(cells: &Cells, ranks: u32) -> Partition {
        Partition::with_ring(cells, ranks, 1)
    }

    /// As [`Partition::of`], with a halo `ring` cells deep: cells finer than the halo's reach
    /// cut the curve finer (a reach of several supports in cells one reach wide leaves a small
    /// domain only a few cells to share out).
    pub fn with_ring(cells: &Cells, ranks: u32, ring: u32) -> Partition {
        let r = ranks.max(1) as u64;
        let b = &cells.cbox;
        let mut owner = vec![NOBODY; cells.count.len()];
        let mut owned = vec![0u64; r as usize];
        let starts = cut_points(cells, r);
        let mut k = 0usize;
        for (j, &(_, c)) in cells.order.iter().enumerate() {
            while k + 1 < r as usize && j >= starts[k] {
                k += 1;
            }
            let i = b.index(c);
            owner[i] = k as u32;
            owned[k] += cells.count[i] as u64;
        }
        let mut halo = vec![0u64; r as usize];
        let mut peer_sets: Vec<std::collections::BTreeSet<u32>> =
            vec![Default::default(); r as usize];
        let keys = cells
            .order
            .iter()
            .map(|&(k, c)| (k, owner[b.index(c)]))
            .collect();
        let mut p = Partition {
            cbox: *b,
            owner,
            keys,
            owned,
            halo: Vec::new(),
            peers: Vec::new(),
            ring: ring.max(1),
        };
        let mut to: Vec<u32> = Vec::with_capacity(27);
        for &(_, c) in &cells.order {
            let i = b.index(c);
            p.halo_ranks(c, &mut to);
            for &o in &to {
                halo[o as usize] += cells.count[i] as u64;
                peer_sets[o as usize].insert(p.owner[i]);
            }
        }
        p.halo = halo;
        p.peers = peer_sets.iter().map(|s| s.len() as u32).collect();
        p
    }

    /// The rank owning the cell of position x: the cell's owner, or for a cell no particle
    /// occupied when the cut was made (one has moved there since) the owner of the occupied
    /// cell before it along the curve (ranks hold contiguous key ranges; rank 0 before all).
    pub fn owner_at(&self, x: [f64; 3]) -> u32 {
        let c = self.cbox.cell_of(x);
        let o = self.owner[self.cbox.index(c)];
        if o != NOBODY {
            return o;
        }
        let key = self.cbox.key(c);
        match self.keys.partition_point(|&(k, _)| k <= key) {
            0 => 0,
            i => self.keys[i - 1].1,
        }
    }

    /// The ranks other than the cell's owner that own one of the cells within `ring` cells of
    /// cell c (the 26 around it for ring 1; across the period on periodic axes): the ranks a
    /// particle in c is halo of, written to `to`.
    pub fn halo_ranks(&self, c: [u32; 3], to: &mut Vec<u32>) {
        let b = &self.cbox;
        to.clear();
        let own = self.owner[b.index(c)];
        let ring = self.ring as i64;
        // Each axis's cells in reach, once each (a short period wraps onto itself).
        let along = |k: usize| -> Vec<u32> {
            let n = b.n[k] as i64;
            let mut v: Vec<u32> = (-ring..=ring)
                .filter_map(|o| {
                    let i = c[k] as i64 + o;
                    if (0..n).contains(&i) {
                        Some(i as u32)
                    } else if b.periodic[k] {
                        Some(i.rem_euclid(n) as u32)
                    } else {
                        None
                    }
                })
                .collect();
            v.sort_unstable();
            v.dedup();
            v
        };
        let (xs, ys, zs) = (along(0), along(1), along(2));
        for &z in &zs {
            for &y in &ys {
                for &x in &xs {
                    let o = self.owner[b.index([x, y, z])];
                    if o != NOBODY && o != own && !to.contains(&o) {
                        to.push(o);
                    }
                }
            }
        }
    }

    /// Largest owned count over the mean: the load imbalance of the cut.
    pub fn imbalance(&self) -> f64 {
        let max = *self.owned.iter().max().unwrap_or(&0) as f64;
        let mean = self.owned.iter().sum::<u64>() as f64 / self.owned.len().max(1) as f64;
        if mean > 0.0 {
            max / mean
        } else {
            1.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_interleaves_and_orders_octants() {
        assert_eq!(morton([1, 0, 0]), 1);
        assert_eq!(morton([0, 1, 0]), 2);
        assert_eq!(morton([0, 0, 1]), 4);
        assert_eq!(morton([1, 1, 1]), 7);
        assert_eq!(morton([2, 0, 0]), 8);
        // Every cell of the first 2³ block precedes the next block along x.
        assert!((0..8).all(|i| morton([i & 1, (i >> 1) & 1, i >> 2]) < morton([2, 0, 0])));
        assert_eq!(morton([0x1f_ffff; 3]), (1u64 << 63) - 1);
    }

    /// 16³ cells of 8 particles each.
    fn cube(periodic: bool) -> Cells {
        cube_of(16, periodic)
    }

    /// A uniform cube cut in two along the curve: the halves are the two z halves (the top
    /// Morton bit of a 2^k cube is z's), balanced; each receives the other's face layer of
    /// cells as halo, and a second one across the period when periodic.
    #[test]
    fn a_cube_cut_in_two_is_its_halves_with_one_face_layer_of_halo() {
        let c = cube(false);
        assert_eq!(c.order.len(), 16 * 16 * 16);
        let p = Partition::of(&c, 2);
        assert_eq!(p.owned, vec![8 * 2048, 8 * 2048]);
        assert_eq!(p.imbalance(), 1.0);
        assert_eq!(p.halo, vec![8 * 256, 8 * 256]);
        assert_eq!(p.peers, vec![1, 1]);
        assert_eq!(Partition::of(&c, 1).halo, vec![0]);
        let p = Partition::of(&cube(true), 2);
        assert_eq!(p.halo, vec![2 * 8 * 256, 2 * 8 * 256]);
        // Eight ranks: the octants; each touches three others' faces (open cube).
        let p = Partition::of(&c, 8);
        assert!(p.owned.iter().all(|&o| o == 8 * 512));
        assert!(p.peers.iter().all(|&k| k == 7), "{:?}", p.peers);
        assert!(
            p.halo.iter().all(|&h| h == 8 * (3 * 64 + 3 * 8 + 1)),
            "{:?}",
            p.halo
        );
    }

    /// `cells` per axis of 8 particles each, on [0, cells)³, with `extra` more particles in
    /// the first cell.
    fn uniform(cells: u32, extra: u32) -> Cells {
        let mut c = cube_of(cells, false);
        c.count[0] += extra;
        c.total += extra as u64;
        c
    }

    /// n³ cells of 8 particles each, on [0, n)³.
    fn cube_of(n: u32, periodic: bool) -> Cells {
        let pts = (0..n).flat_map(move |x| {
            (0..n).flat_map(move |y| {
                (0..n).flat_map(move |z| {
                    (0..8u32).map(move |k| {
                        let o = [k & 1, (k >> 1) & 1, k >> 2].map(|b| 0.25 + 0.5 * b as f64);
                        [x as f64 + o[0], y as f64 + o[1], z as f64 + o[2]]
                    })
                })
            })
        });
        let hi = if periodic { n as f64 } else { n as f64 - 0.001 };
        Cells::bin(pts, CellBox::new([0.0; 3], [hi; 3], 1.0, [periodic; 3]))
    }

    /// A cube of 12 cells a side (no power of two) is cut in two through its middle: the
    /// curve is keyed on the box, not on a 16-cell grid overhanging it, so the halves are the
    /// z halves with one face layer of halo each (keyed on raw cells, the curve's first half
    /// would hold z < 8, two thirds of the cube, and the cut would run jagged inside it).
    #[test]
    fn a_cube_of_any_cell_count_is_cut_through_its_middle() {
        let p = Partition::of(&cube_of(12, false), 2);
        assert_eq!(p.owned, vec![8 * 864, 8 * 864]);
        assert_eq!(p.halo, vec![8 * 144, 8 * 144], "{:?}", p.halo);
    }

    /// Equal counts a little off the middle (extra particles in the first cell, 1 % of a
    /// share) still cut at the middle, between the curve's coarsest blocks, within
    /// [`CUT_SLACK`]; 10 % off, the cut keeps to equal counts.
    #[test]
    fn a_cut_near_the_middle_snaps_to_it_within_the_slack() {
        let share: u32 = 8 * 2048;
        let p = Partition::of(&uniform(16, share / 100), 2);
        assert_eq!(p.owned, vec![(8 * 2048 + share / 100) as u64, 8 * 2048]);
        assert_eq!(p.halo, vec![8 * 256, 8 * 256]);
        let p = Partition::of(&uniform(16, share / 5), 2);
        let (a, b) = (p.owned[0] as f64, p.owned[1] as f64);
        assert!((a - b).abs() < 0.01 * (a + b), "{:?}", p.owned);
    }

    /// Cut by cost, a cube whose particles in z < 4 cost three times the others' is cut into
    /// four ranges of equal cost (within a cell layer's cost), not equal counts: the ranks in
    /// the costly layers own fewer particles. Equal costs cut as equal counts do.
    #[test]
    fn a_cut_by_cost_shares_out_the_cost_not_the_particles() {
        let cells = cube_of(16, false);
        let cost_of = |z: usize| if z < 4 { 3.0 } else { 1.0 };
        let cost: Vec<f64> = (0..cells.count.len())
            .map(|i| cells.count[i] as f64 * cost_of(i / (16 * 16)))
            .collect();
        let by_cost = Partition::of(&cells.clone().with_cost(cost.clone()), 4);
        let mut load = [0.0; 4];
        for (i, &o) in by_cost.owner.iter().enumerate() {
            load[o as usize] += cost[i];
        }
        let share = cost.iter().sum::<f64>() / 4.0;
        let layer = 8.0 * 256.0 * 3.0;
        for l in load {
            assert!((l - share).abs() <= layer, "{load:?} against {share}");
        }
        assert!(
            by_cost.owned[0] < by_cost.owned[3],
            "{:?}: the costly layers' rank owns as many particles",
            by_cost.owned
        );
        let even = (cells.count.iter()).map(|&c| c as f64).collect();
        let by_count = Partition::of(&cells.clone().with_cost(even), 4);
        assert_eq!(by_count.owner, Partition::of(&cells, 4).owner);
    }

    /// A halo two cells deep: the halves receive two face layers each (four when periodic,
    /// two across the cut and two across the period), and a ring wider than a short period
    /// counts each cell once.
    #[test]
    fn a_ring_of_two_cells_sends_two_face_layers() {
        let p = Partition::with_ring(&cube(false), 2, 2);
        assert_eq!(p.halo, vec![2 * 8 * 256, 2 * 8 * 256]);
        let p = Partition::with_ring(&cube(true), 2, 2);
        assert_eq!(p.halo, vec![4 * 8 * 256, 4 * 8 * 256]);
        // 16 cells per period, ring 20: every cell of the other half, once.
        let p = Partition::with_ring(&cube(true), 2, 20);
        assert_eq!(p.halo, vec![8 * 2048, 8 * 2048]);
    }
}
