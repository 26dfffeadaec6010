//! The auxiliary grid: IDIC cells and neighbour search share it (method.md §3.1, §3.6).
//!
//! The grid is rebuilt every step over the particles' current bounding box, anchored to a
//! fixed global lattice (cells are [iΔ, (i+1)Δ) for integer i), so the partition of space never
//! changes while the domain follows the particles. No particle is ever dropped: a position that
//! cannot be placed (NaN, or an extent too large for 64-bit keys) is an error.
use dustsph_device::grid::{CellLookup, GridGeom};
use rayon::prelude::*;
use std::ops::Range;

/// Periodicity of the domain along each axis: `Some((lo, len))` for periodic axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Domain {
    pub dim: u32,
    pub periodic: [Option<(f64, f64)>; 3],
}

impl Domain {
    /// |a − b|² with the minimum image on periodic axes (`update::min_image`, as the step's
    /// neighbour walk takes it).
    pub fn distance2(&self, a: [f64; 3], b: [f64; 3]) -> f64 {
        let mut s = 0.0;
        for k in 0..3 {
            let mut d = a[k] - b[k];
            if let Some((_, len)) = self.periodic[k] {
                d = dustsph_device::update::min_image(d, len);
            }
            s += d * d;
        }
        s
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct GridError(pub String);

impl std::fmt::Display for GridError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for GridError {}

/// Axis-aligned bounds (lo, hi) of a set of positions; empty sets give (+∞, −∞).
pub type Bounds = ([f64; 3], [f64; 3]);
pub const EMPTY_BOUNDS: Bounds = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);

/// Merge two bounding boxes; a NaN wins, so the finiteness check of [`Grid::from_bounds`]
/// catches it.
pub fn merge_bounds((l0, h0): Bounds, (l1, h1): Bounds) -> Bounds {
    let mut out = (l0, h0);
    for k in 0..3 {
        if l1[k] < out.0[k] || l1[k].is_nan() {
            out.0[k] = l1[k];
        }
        if h1[k] > out.1[k] || h1[k].is_nan() {
            out.1[k] = h1[k];
        }
    }
    out
}

/// The grid of one step: the shared geometry of `dustsph-device` built from the bounds.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    pub geom: GridGeom<f64>,
}

impl Grid {
    /// Build the grid with nominal cell size `cell` covering the positions of `phases`.
    /// `support` is the kernel support radius (2h) that neighbour searches must reach.
    pub fn build(
        domain: &Domain,
        cell_size: f64,
        support: f64,
        phases: &[&[[f64; 3]]],
    ) -> Result<Grid, GridError> {
        let b = phases
            .iter()
            .map(|x| {
                x.par_iter()
                    .map(|&p| (p, p))
                    .reduce(|| EMPTY_BOUNDS, merge_bounds)
            })
            .fold(EMPTY_BOUNDS, merge_bounds);
        Grid::from_bounds(domain, cell_size, support, b)
    }

    /// The grid over given particle bounds (the engine reduces them with a kernel).
    pub fn from_bounds(
        domain: &Domain,
        cell_size: f64,
        support: f64,
        (lo, hi): Bounds,
    ) -> Result<Grid, GridError> {
        let dim = domain.dim as usize;
        let mut g = GridGeom {
            origin: [0.0; 3],
            cell: [1.0; 3],
            inv: [1.0; 3],
            period: [0.0; 3],
            n: [1; 3],
            sub: [1; 3],
            search: [1.0; 3],
            reach: [0; 3],
            support,
            dim: domain.dim,
            periodic: [0; 3],
        };
        let mut total: u128 = 1;
        // IDIC cells per search cell: search cells of about h (docs/performance.md, "search grid").
        let sub_target = ((support / SEARCH_CELLS_PER_SUPPORT) / cell_size + 1e-9)
            .floor()
            .clamp(1.0, 64.0) as u64;
        for k in 0..dim {
            if let Some((plo, len)) = domain.periodic[k] {
                let nf = (len / cell_size).floor();
                if nf.is_nan() || nf >= (1u64 << 40) as f64 {
                    return Err(GridError(format!(
                        "{nf} cells of size {cell_size} along periodic axis {k}: too many"
                    )));
                }
                let n = (nf as u64).max(1);
                // The search cells must tile the period: the largest divisor of n within reach.
                g.sub[k] = (1..=sub_target.min(n))
                    .rev()
                    .find(|s| n % s == 0)
                    .unwrap_or(1);
                g.origin[k] = plo;
                g.cell[k] = len / n as f64;
                g.period[k] = len;
                g.n[k] = n;
                g.periodic[k] = 1;
            } else {
                if !lo[k].is_finite() || !hi[k].is_finite() {
                    if lo[k] > hi[k] {
                        continue; // no particles at all
                    }
                    return Err(GridError(format!(
                        "a particle position along axis {k} is not finite (min {}, max {}): the run has blown up",
                        lo[k], hi[k]
                    )));
                }
                let i0 = (lo[k] / cell_size).floor();
                let i1 = (hi[k] / cell_size).floor();
                // Checked in f64 before any integer cast can saturate or wrap.
                if (i1 - i0 + 1.0).is_nan() || i1 - i0 + 1.0 >= (1u64 << 40) as f64 {
                    return Err(GridError(format!(
                        "particles span [{}, {}] along axis {k}: {} cells of size {cell_size}, too many \
                         (the cloud has spread too far for this cell size)",
                        lo[k],
                        hi[k],
                        i1 - i0 + 1.0
                    )));
                }
                // Anchored to the global lattice of search cells, so the partition of space
                // never changes while the box follows the particles.
                let s = sub_target as f64;
                let (b0, b1) = ((i0 / s).floor(), (i1 / s).floor());
                g.sub[k] = sub_target;
                g.origin[k] = b0 * s * cell_size;
                g.cell[k] = cell_size;
                g.n[k] = ((b1 - b0) as u64 + 1) * sub_target;
            }
            g.inv[k] = 1.0 / g.cell[k];
            g.search[k] = g.sub[k] as f64 * g.cell[k];
            g.reach[k] = (support / g.search[k] - 1e-12).ceil().max(1.0) as u64;
            total *= g.n[k] as u128;
        }
        if total > (1u128 << 62) {
            return Err(GridError(format!(
                "particles span {:?} cells of size {cell_size}: too many for 64-bit cell keys \
                 (the cloud has spread too far for this cell size)",
                &g.n[..dim]
            )));
        }
        Ok(Grid { geom: g })
    }

    /// The same cells with another search radius (neighbour reach); keys are unchanged.
    pub fn with_support(&self, support: f64) -> Grid {
        let mut g = self.geom;
        g.support = support;
        for k in 0..g.dim as usize {
            g.reach[k] = (support / g.search[k] - 1e-12).ceil().max(1.0) as u64;
        }
        Grid { geom: g }
    }

    #[inline(always)]
    pub fn key(&self, x: [f64; 3]) -> u64 {
        self.geom.key(x)
    }

    /// Total number of cells in the grid box.
    pub fn total_cells(&self) -> u64 {
        self.geom.total_cells()
    }
}

/// Search cells per kernel support (2h): search cells of about h. Measured on the seed ball at
/// ≈57 neighbours (docs/performance.md): the walk over 0.5h IDIC cells cost 8× the pair work.
pub const SEARCH_CELLS_PER_SUPPORT: f64 = 2.0;

/// Whether a phase of `n` particles gets a dense start table over a box of `total` cells:
/// up to 8 cells per particle (+ a floor for small runs), i.e. 32 bytes per particle at most.
pub fn dense_table_fits(total: u64, n: usize) -> bool {
    total <= (8 * n as u64).max(1 << 20)
}

/// The occupied cells of one phase, with particles sorted by cell key.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CellIndex {
    /// Sorted, unique keys of occupied cells.
    pub keys: Vec<u64>,
    /// Particle range of cell i: start[i]..start[i+1].
    pub start: Vec<u32>,
    /// Cell index (into `keys`) of every particle.
    pub cell_of: Vec<u32>,
    /// Dense start table over every search cell of the grid box (first particle with key ≥
    /// `dense_stride`·i), when the box is small enough; makes a row lookup O(1) instead of two
    /// binary searches.
    dense: Vec<u32>,
    dense_stride: u64,
}

impl CellIndex {
    /// Sorting permutation (new → old) of positions `x` by cell key, and the index built on it.
    pub fn sort(grid: &Grid, x: &[[f64; 3]]) -> (Vec<u32>, CellIndex) {
        let mut kp: Vec<(u64, u32)> = x
            .par_iter()
            .enumerate()
            .map(|(i, &p)| (grid.key(p), i as u32))
            .collect();
        // (key, old index) pairs are unique, so the order is deterministic.
        kp.par_sort_unstable();
        let perm: Vec<u32> = kp.iter().map(|&(_, i)| i).collect();
        let mut idx = CellIndex::default();
        idx.cell_of.reserve(kp.len());
        for (i, &(k, _)) in kp.iter().enumerate() {
            if idx.keys.last() != Some(&k) {
                idx.keys.push(k);
                idx.start.push(i as u32);
            }
            idx.cell_of.push(idx.keys.len() as u32 - 1);
        }
        idx.start.push(kp.len() as u32);
        let stride = grid.geom.sub.iter().product::<u64>();
        let total = grid.total_cells() / stride;
        idx.dense_stride = stride;
        if dense_table_fits(total, kp.len()) {
            let mut dense = Vec::with_capacity(total as usize + 1);
            for (c, &k) in idx.keys.iter().enumerate() {
                // Entry i: the first particle of search cell i or later.
                dense.resize((k / stride) as usize + 1, idx.start[c]);
            }
            dense.resize(total as usize + 1, kp.len() as u32);
            idx.dense = dense;
        }
        (perm, idx)
    }

    pub fn n_cells(&self) -> usize {
        self.keys.len()
    }

    #[inline(always)]
    pub fn cell_range(&self, c: usize) -> Range<usize> {
        self.start[c] as usize..self.start[c + 1] as usize
    }

    /// The lookup the shared neighbour walk uses.
    #[inline(always)]
    pub fn lookup(&self) -> CellLookup<'_> {
        CellLookup {
            keys: &self.keys,
            start: &self.start,
            dense: &self.dense,
            dense_stride: self.dense_stride.max(1),
            key_offset: 0,
        }
    }

    /// Particles whose cells have keys in [lo, hi].
    #[inline(always)]
    pub fn particles_in_keys(&self, lo: u64, hi: u64) -> Range<usize> {
        let (a, b) = self.lookup().particles_in_keys(lo, hi);
        a..b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expanding_cloud_keeps_every_particle() {
        let dom = Domain {
            dim: 3,
            periodic: [None; 3],
        };
        let x: Vec<[f64; 3]> = (0..1000)
            .map(|i| {
                let f = i as f64;
                [f.sin() * 1e3, (f * 0.7).cos() * 1e-3, f * 0.01 - 5.0]
            })
            .collect();
        let g = Grid::build(&dom, 0.05, 0.2, &[&x]).unwrap();
        let (perm, idx) = CellIndex::sort(&g, &x);
        assert_eq!(perm.len(), x.len());
        let mut seen = vec![false; x.len()];
        for &p in &perm {
            seen[p as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
        // Each particle's cell contains it.
        for (new, &old) in perm.iter().enumerate() {
            let c = g.geom.coord(x[old as usize]);
            assert_eq!(idx.keys[idx.cell_of[new] as usize], g.geom.key_of_coord(c));
        }
    }

    #[test]
    fn sparse_and_dense_lookups_find_all_3d_neighbours() {
        // Two clusters far apart: the grid box has ~1e9 cells, so the sparse path is used;
        // a compact cloud uses the dense table. Both must match brute force.
        for spread in [1.0, 2000.0] {
            let dom = Domain {
                dim: 3,
                periodic: [None; 3],
            };
            let x: Vec<[f64; 3]> = (0..600)
                .map(|i| {
                    let f = i as f64 * 0.618_033_988_7;
                    let off = if i % 2 == 0 { 0.0 } else { spread };
                    [f.fract() + off, (f * 1.37).fract(), (f * 2.11).fract()]
                })
                .collect();
            let support = 0.2;
            let g = Grid::build(&dom, 0.05, support, &[&x]).unwrap();
            let (perm, idx) = CellIndex::sort(&g, &x);
            assert_eq!(idx.dense.is_empty(), spread > 1.0);
            let xs: Vec<[f64; 3]> = perm.iter().map(|&p| x[p as usize]).collect();
            let within = |a: [f64; 3], b: [f64; 3]| {
                let d = g.geom.separation(a, b);
                d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < support * support
            };
            for (i, &xi) in xs.iter().enumerate() {
                let mut found = Vec::new();
                g.geom
                    .for_each_neighbour_row(g.geom.coord(xi), |lo, hi, _| {
                        found.extend(idx.particles_in_keys(lo, hi).filter(|&j| within(xi, xs[j])));
                    });
                found.sort();
                let brute: Vec<usize> = (0..xs.len()).filter(|&j| within(xi, xs[j])).collect();
                assert_eq!(found, brute, "particle {i}, spread {spread}");
            }
        }
    }

    #[test]
    fn a_huge_extent_is_an_error_not_an_overflow() {
        let dom = Domain {
            dim: 1,
            periodic: [None; 3],
        };
        let x = vec![[0.0; 3], [1e20, 0.0, 0.0]];
        assert!(Grid::build(&dom, 0.05, 0.2, &[&x]).is_err());
        let dom = Domain {
            dim: 3,
            periodic: [None; 3],
        };
        let x = vec![[0.0; 3], [1e5, 1e5, 1e5]];
        assert!(
            Grid::build(&dom, 1e-3, 0.2, &[&x]).is_err(),
            "1e24 cells overflow 64-bit keys"
        );
    }

    #[test]
    fn nan_position_is_an_error_not_a_drop() {
        let dom = Domain {
            dim: 1,
            periodic: [None; 3],
        };
        let x = vec![[0.0; 3], [f64::NAN, 0.0, 0.0]];
        assert!(Grid::build(&dom, 0.1, 0.2, &[&x]).is_err());
    }

    #[test]
    fn neighbour_rows_find_all_pairs_within_support_periodic_and_open() {
        for periodic in [false, true] {
            let len = 1.0;
            let dom = Domain {
                dim: 2,
                periodic: if periodic {
                    [Some((0.0, len)), Some((0.0, len)), None]
                } else {
                    [None; 3]
                },
            };
            let x: Vec<[f64; 3]> = (0..400)
                .map(|i| {
                    let f = i as f64 * 0.618_033_988_7;
                    [f.fract(), (f * 1.37).fract(), 0.0]
                })
                .collect();
            let support = 0.13;
            let g = Grid::build(&dom, 0.031, support, &[&x]).unwrap();
            let (perm, idx) = CellIndex::sort(&g, &x);
            let xs: Vec<[f64; 3]> = perm.iter().map(|&p| x[p as usize]).collect();
            for (i, &xi) in xs.iter().enumerate() {
                let mut found = Vec::new();
                g.geom
                    .for_each_neighbour_row(g.geom.coord(xi), |lo, hi, _| {
                        for j in idx.particles_in_keys(lo, hi) {
                            let d = g.geom.separation(xi, xs[j]);
                            if d[0] * d[0] + d[1] * d[1] < support * support {
                                found.push(j);
                            }
                        }
                    });
                found.sort();
                let brute: Vec<usize> = (0..xs.len())
                    .filter(|&j| {
                        let d = g.geom.separation(xi, xs[j]);
                        d[0] * d[0] + d[1] * d[1] < support * support
                    })
                    .collect();
                assert_eq!(found, brute, "particle {i}, periodic {periodic}");
            }
        }
    }

    /// The walk's row images (one add per axis) give exactly the minimum image's separations:
    /// the same pairs, and dx and r² equal to the bit, against brute force with
    /// `GridGeom::separation`; on boxes wide enough for them and on ones too narrow (where the
    /// walk applies the minimum image itself), fully and partly periodic, points on the edges.
    #[test]
    fn row_images_give_the_minimum_image_to_the_bit() {
        use dustsph_device::grid::for_neighbours;
        let mut narrow_seen = [false; 2];
        let cases = [0.05, 0.07, 0.09, 0.11, 0.13, 0.15, 0.17, 0.2, 0.25, 0.3]
            .map(|s| ([true; 3], s))
            .into_iter()
            .chain([([true, true, false], 0.13), ([false, true, true], 0.07)]);
        for (periodic, support) in cases {
            let len = [1.0, 0.7, 0.45];
            let dom = Domain {
                dim: 3,
                periodic: [0, 1, 2].map(|k| periodic[k].then_some((-0.2, len[k]))),
            };
            let mut x: Vec<[f64; 3]> = (0..900)
                .map(|i| {
                    let f = i as f64 * 0.618_033_988_7;
                    [0, 1, 2].map(|k| -0.2 + len[k] * (f * [1.0, 1.37, 2.11][k]).fract())
                })
                .collect();
            // Points on the lower edges and just inside the upper ones.
            x.push([-0.2, -0.2, -0.2]);
            x.push([0.8 - 1e-15, 0.5 - 1e-15, 0.25 - 1e-15]);
            let g = Grid::build(&dom, support / 4.0, support, &[&x]).unwrap();
            narrow_seen[g.geom.row_images() as usize] = true;
            let (perm, idx) = CellIndex::sort(&g, &x);
            let xs: Vec<[f64; 3]> = perm.iter().map(|&p| x[p as usize]).collect();
            let s2 = support * support;
            for &xi in &xs {
                let mut found = Vec::new();
                for_neighbours(&g.geom, &idx.lookup(), &xs, xi, |j, dx, r2| {
                    found.push((j, dx.map(f64::to_bits), r2.to_bits()))
                });
                found.sort();
                let brute: Vec<_> = (0..xs.len())
                    .filter_map(|j| {
                        let d = g.geom.separation(xi, xs[j]);
                        let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                        (r2 < s2).then(|| (j, d.map(f64::to_bits), r2.to_bits()))
                    })
                    .collect();
                assert_eq!(found, brute, "periodic {periodic:?}, support {support}");
            }
        }
        assert_eq!(
            narrow_seen,
            [true, true],
            "both forms of the walk were checked"
        );
    }

    /// A walk within a radius below the grid's support visits exactly the particles of the
    /// whole walk within that radius, in the same order and with the same dx and r² to the bit
    /// (the h solve's sums are then those of the whole walk); on open, periodic and too-narrow
    /// periodic boxes (the whole walk itself there), for radii from a fraction of a search cell
    /// to the support.
    #[test]
    fn a_walk_within_a_radius_is_the_whole_walks_particles_within_it_in_order() {
        use dustsph_device::grid::{for_neighbours, for_neighbours_within};
        let cases = [([false; 3], 0.2), ([true; 3], 0.07), ([true; 3], 0.3)]
            .into_iter()
            .chain([([true, false, true], 0.11)]);
        for (periodic, support) in cases {
            let len = [1.0, 0.7, 0.45];
            let dom = Domain {
                dim: 3,
                periodic: [0, 1, 2].map(|k| periodic[k].then_some((-0.2, len[k]))),
            };
            let x: Vec<[f64; 3]> = (0..900)
                .map(|i| {
                    let f = i as f64 * 0.618_033_988_7;
                    [0, 1, 2].map(|k| -0.2 + len[k] * (f * [1.0, 1.37, 2.11][k]).fract())
                })
                .collect();
            // Cells of a quarter of the reference support, the search radius 3× it (variable h).
            let g = Grid::build(&dom, support / 4.0, support, &[&x]).unwrap();
            let g = g.with_support(3.0 * support);
            let (perm, idx) = CellIndex::sort(&g, &x);
            let xs: Vec<[f64; 3]> = perm.iter().map(|&p| x[p as usize]).collect();
            for (n, &xi) in xs.iter().enumerate().step_by(7) {
                let radius = support * [0.1, 0.6, 1.0, 2.2, 3.0, 3.5][n % 6];
                let mut within = Vec::new();
                for_neighbours_within(&g.geom, &idx.lookup(), &xs, xi, radius, |j, dx, r2| {
                    if r2 < radius * radius {
                        within.push((j, dx.map(f64::to_bits), r2.to_bits()))
                    }
                });
                let mut whole = Vec::new();
                for_neighbours(&g.geom, &idx.lookup(), &xs, xi, |j, dx, r2| {
                    if r2 < radius * radius {
                        whole.push((j, dx.map(f64::to_bits), r2.to_bits()))
                    }
                });
                assert_eq!(within, whole, "periodic {periodic:?}, radius {radius}");
            }
        }
    }
}
