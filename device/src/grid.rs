//! Geometry of the auxiliary grid and the neighbour walk over it (method.md §3.1, §3.6).
//!
//! The host builds a [`GridGeom`] each step from the particles' bounding box; the CPU loops and
//! the GPU kernels then use the very same cell arithmetic and the same walk, so both backends
//! visit neighbours in the same order and produce the same sums.
use crate::{cell, dot, update, Real, Vec3};

/// One step's grid: cells [origin + iΔ, origin + (i+1)Δ) along each axis, `n` cells per axis.
/// Plain data (`repr(C)`), so it travels to a GPU kernel by value.
///
/// Two levels share one key: the IDIC cells (Δ), and search cells of `sub` IDIC cells along
/// each axis, so that the neighbour walk visits few, well-filled cells while the IDIC cells stay
/// small. The key is hierarchical (search cell, then IDIC cell inside it): a phase sorted by key
/// has every IDIC cell and every search cell as one contiguous range (docs/performance.md,
/// "search grid").
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridGeom<R> {
    pub origin: [R; 3],
    pub cell: [R; 3],
    pub inv: [R; 3],
    /// Period length on periodic axes (the periodic interval starts at `origin`); 0 on open axes.
    pub period: [R; 3],
    pub n: [u64; 3],
    /// IDIC cells per search cell along each axis (`n` is a multiple of it; 1 on unused axes).
    pub sub: [u64; 3],
    /// Search cell size along each axis: `sub` × `cell`.
    pub search: [R; 3],
    /// Neighbour reach in search cells along each axis: ceil(support / search).
    pub reach: [u64; 3],
    /// Kernel support radius (2h).
    pub support: R,
    pub dim: u32,
    /// 1 on periodic axes.
    pub periodic: [u32; 3],
}

impl<R: Real> GridGeom<R> {
    #[inline(always)]
    pub fn is_periodic(&self, k: usize) -> bool {
        self.periodic[k] != 0
    }

    /// Integer cell coordinates of a position (clamped against rounding at the edges).
    #[inline(always)]
    pub fn coord(&self, x: Vec3<R>) -> [u64; 3] {
        let mut c = [0u64; 3];
        let mut k = 0;
        while k < self.dim as usize {
            let i = cell::cell_coord(x[k], self.origin[k], self.inv[k]);
            let top = self.n[k] as i64 - 1;
            c[k] = if i < 0 {
                0
            } else if i > top {
                top as u64
            } else {
                i as u64
            };
            k += 1;
        }
        c
    }

    /// Search cells per axis.
    #[inline(always)]
    fn ns(&self, k: usize) -> u64 {
        self.n[k] / self.sub[k]
    }

    /// IDIC cells per search cell.
    #[inline(always)]
    fn sub_cells(&self) -> u64 {
        self.sub[0] * self.sub[1] * self.sub[2]
    }

    /// Key of an IDIC cell: the row-major index of its search cell, times the IDIC cells per
    /// search cell, plus its row-major index inside the search cell.
    #[inline(always)]
    pub fn key_of_coord(&self, c: [u64; 3]) -> u64 {
        let s = self.sub;
        let block = cell::key(
            c[0] / s[0],
            c[1] / s[1],
            c[2] / s[2],
            self.ns(0),
            self.ns(1),
        );
        block * self.sub_cells() + cell::key(c[0] % s[0], c[1] % s[1], c[2] % s[2], s[0], s[1])
    }

    #[inline(always)]
    pub fn key(&self, x: Vec3<R>) -> u64 {
        self.key_of_coord(self.coord(x))
    }

    #[inline(always)]
    pub fn coord_of_key(&self, key: u64) -> [u64; 3] {
        let s = self.sub;
        let (block, inner) = (key / self.sub_cells(), key % self.sub_cells());
        let (n0, n1) = (self.ns(0), self.ns(1));
        let b = [block % n0, (block / n0) % n1, block / n0 / n1];
        let i = [inner % s[0], (inner / s[0]) % s[1], inner / s[0] / s[1]];
        [b[0] * s[0] + i[0], b[1] * s[1] + i[1], b[2] * s[2] + i[2]]
    }

    /// Total number of cells in the grid box.
    #[inline(always)]
    pub fn total_cells(&self) -> u64 {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// Separation a − b with the minimum image on periodic axes.
    #[inline(always)]
    pub fn separation(&self, a: Vec3<R>, b: Vec3<R>) -> Vec3<R> {
        let mut d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        for (k, dk) in d.iter_mut().enumerate() {
            if self.is_periodic(k) {
                *dk = update::min_image(*dk, self.period[k]);
            }
        }
        d
    }

    /// Wrap a position into the periodic box.
    #[inline(always)]
    pub fn wrap(&self, mut x: Vec3<R>) -> Vec3<R> {
        for (k, xk) in x.iter_mut().enumerate() {
            if self.is_periodic(k) {
                *xk = update::wrap(*xk, self.origin[k], self.period[k]);
            }
        }
        x
    }

    /// Search-cell ranges within reach `r` along axis k of search coordinate c (one or two
    /// inclusive ranges).
    #[inline(always)]
    fn axis_ranges(&self, k: usize, c: u64, r: u64) -> ([(u64, u64); 2], usize) {
        let n = self.ns(k);
        if self.is_periodic(k) {
            if 2 * r + 1 >= n {
                return ([(0, n - 1), (0, 0)], 1);
            }
            let lo = c as i64 - r as i64;
            let hi = c + r;
            if lo < 0 {
                ([((lo + n as i64) as u64, n - 1), (0, hi)], 2)
            } else if hi >= n {
                ([(lo as u64, n - 1), (0, hi - n)], 2)
            } else {
                ([(lo as u64, hi), (0, 0)], 1)
            }
        } else {
            let lo = c.saturating_sub(r);
            let hi = if c + r < n - 1 { c + r } else { n - 1 };
            ([(lo, hi), (0, 0)], 1)
        }
    }

    /// Lower bound of the distance between search-cell coordinates a and b along axis k.
    #[inline(always)]
    fn gap(&self, k: usize, a: u64, b: u64) -> R {
        let mut d = a.abs_diff(b);
        if self.is_periodic(k) && self.ns(k) - d < d {
            d = self.ns(k) - d;
        }
        // Only cells within reach get here (d ≤ reach): the u32 conversion is exact and cheap.
        R::from_f64(d.saturating_sub(1) as u32 as f64) * self.search[k]
    }

    /// Calls `f(lo_key, hi_key, image)` for every row of search cells (inclusive key range
    /// along x) that may hold a point within the support of some point of the IDIC cell `c`.
    /// Rows are trimmed to the support sphere. Each cell is visited at most once, always in the
    /// same order. `image[k]` is what the minimum image adds to a separation along a periodic
    /// axis k for the points of this row (+L, −L or 0), valid when [`Self::row_images`] holds.
    #[inline(always)]
    pub fn for_each_neighbour_row(&self, c: [u64; 3], f: impl FnMut(u64, u64, Vec3<R>)) {
        self.for_each_row_within(c, self.support, self.reach, f)
    }

    /// [`Self::for_each_neighbour_row`] for a radius `support` with its `reach` in search cells
    /// per axis (at most the grid's). Where the rows' images hold ([`Self::row_images`]), the
    /// rows and cells it visits are those of the grid's own walk that reach within `support`,
    /// in the same order.
    #[inline(always)]
    fn for_each_row_within(
        &self,
        c: [u64; 3],
        support: R,
        reach: [u64; 3],
        mut f: impl FnMut(u64, u64, Vec3<R>),
    ) {
        let c = [c[0] / self.sub[0], c[1] / self.sub[1], c[2] / self.sub[2]];
        let (n0, n1, sc) = (self.ns(0), self.ns(1), self.sub_cells());
        let s2 = support * support;
        let (yr, ny) = self.axis_ranges(1, c[1], reach[1]);
        let (zr, nz) = self.axis_ranges(2, c[2], reach[2]);
        for &(z0, z1) in &zr[..nz] {
            let oz = self.image(2, c[2], z0, z1);
            for iz in z0..=z1 {
                let gz = self.gap(2, iz, c[2]);
                for &(y0, y1) in &yr[..ny] {
                    let oy = self.image(1, c[1], y0, y1);
                    for iy in y0..=y1 {
                        let gy = self.gap(1, iy, c[1]);
                        let g2 = gy * gy + gz * gz;
                        if g2 >= s2 {
                            continue;
                        }
                        // Reach along x for this row: the largest r ≤ reach whose cell gap
                        // (r − 1)Δ is inside the sphere, ((r − 1)Δ)² < s² − g² (= ⌈√(s² − g²)/Δ⌉
                        // without a square root or a float → integer conversion).
                        let d2 = s2 - g2;
                        let mut rx = reach[0];
                        while rx > 1 {
                            let g = R::from_f64((rx - 1) as u32 as f64) * self.search[0];
                            if g * g < d2 {
                                break;
                            }
                            rx -= 1;
                        }
                        let (xr, nx) = self.axis_ranges(0, c[0], rx);
                        let row = (iz * n1 + iy) * n0;
                        for &(x0, x1) in &xr[..nx] {
                            let ox = self.image(0, c[0], x0, x1);
                            f((row + x0) * sc, (row + x1) * sc + sc - 1, [ox, oy, oz]);
                        }
                    }
                }
            }
        }
    }

    /// The minimum image's shift along axis k for the cells lo..=hi of [`Self::axis_ranges`],
    /// seen from search coordinate c: 0 for the piece holding c; a piece wrapped past the top
    /// (above c) holds points at x_j ≈ x_i + L, so + L is added to x_i − x_j; below c, − L.
    #[inline(always)]
    fn image(&self, k: usize, c: u64, lo: u64, hi: u64) -> R {
        if !self.is_periodic(k) || (lo <= c && c <= hi) {
            R::ZERO
        } else if lo > c {
            self.period[k]
        } else {
            -self.period[k]
        }
    }

    /// Whether the rows' image shifts equal the minimum image for every pair within the
    /// support: on every periodic axis the walk reaches less than half the period
    /// (2·reach + 2 ≤ search cells, so points of a row are at most L/2 apart along it before
    /// the shift); else (a box of a few supports) the walk applies the minimum image itself.
    #[inline(always)]
    pub fn row_images(&self) -> bool {
        let mut k = 0;
        while k < 3 {
            if self.is_periodic(k) && 2 * self.reach[k] + 2 > self.ns(k) {
                return false;
            }
            k += 1;
        }
        true
    }
}

/// Where one phase's particles (sorted by cell key) sit: `keys`/`start` list the occupied
/// cells; `dense`, when not empty, is the first particle with key ≥ `dense_stride`·i for every
/// i (an O(1) row lookup instead of two binary searches). A stride of the IDIC cells per search
/// cell keeps the table small (the CPU); the GPU's counting sort builds it per key (stride 1).
#[derive(Clone, Copy, Debug)]
pub struct CellLookup<'a> {
    pub keys: &'a [u64],
    pub start: &'a [u32],
    pub dense: &'a [u32],
    pub dense_stride: u64,
    /// Added to the walk's keys before the binary search of `keys` (the GPU's sparse tables
    /// hold every group's keys back to back, as group · (T + 1) + key).
    pub key_offset: u64,
}

impl CellLookup<'_> {
    /// Particle index range of the cells with keys in [lo, hi]; with a dense table, lo and
    /// hi + 1 are multiples of its stride (whole search cells, as the walk asks).
    #[inline(always)]
    pub fn particles_in_keys(&self, lo: u64, hi: u64) -> (usize, usize) {
        if !self.dense.is_empty() {
            let s = self.dense_stride;
            return (
                self.dense[(lo / s) as usize] as usize,
                self.dense[((hi + 1) / s) as usize] as usize,
            );
        }
        let (lo, hi) = (lo + self.key_offset, hi + self.key_offset);
        let a = self.keys.partition_point(|&k| k < lo);
        let b = a + self.keys[a..].partition_point(|&k| k <= hi);
        (self.start[a] as usize, self.start[b] as usize)
    }
}

/// Visit the particles j of a sorted phase within the kernel support of the point `xi`:
/// `f(j, xi − x_j, r²)` (minimum image on periodic axes). The one neighbour walk of the code.
#[inline(always)]
pub fn for_neighbours<R: Real>(
    g: &GridGeom<R>,
    look: &CellLookup<'_>,
    x: &[Vec3<R>],
    xi: Vec3<R>,
    f: impl FnMut(usize, Vec3<R>, R),
) {
    for_neighbours_to(g, look, x, xi, (g.support, g.reach), f)
}

/// [`for_neighbours`] within `radius` of `xi` only, for a gather over the particle's own
/// support under variable h (the grid reaches the largest support: a disc's supports differ
/// several-fold, docs/performance.md "Discs"). The particles it visits are those of
/// [`for_neighbours`] within `radius`, in the same order; where that cannot be kept (a
/// periodic axis of a few supports, [`GridGeom::row_images`]) or `radius` is not below the
/// grid's support, it is [`for_neighbours`] itself.
#[inline(always)]
pub fn for_neighbours_within<R: Real>(
    g: &GridGeom<R>,
    look: &CellLookup<'_>,
    x: &[Vec3<R>],
    xi: Vec3<R>,
    radius: R,
    f: impl FnMut(usize, Vec3<R>, R),
) {
    // (NaN compares false: the whole walk.)
    let below = radius < g.support;
    if !below || !g.row_images() {
        return for_neighbours(g, look, x, xi, f);
    }
    let mut reach = g.reach;
    let mut k = 0;
    while k < g.dim as usize {
        // ⌈radius / search⌉ (at least 1) without a float → integer conversion of a ratio
        // that could round past the grid's own reach.
        let mut r = 1u64;
        while r < g.reach[k] && R::from_f64(r as u32 as f64) * g.search[k] < radius {
            r += 1;
        }
        reach[k] = r;
        k += 1;
    }
    for_neighbours_to(g, look, x, xi, (radius, reach), f)
}

#[inline(always)]
fn for_neighbours_to<R: Real>(
    g: &GridGeom<R>,
    look: &CellLookup<'_>,
    x: &[Vec3<R>],
    xi: Vec3<R>,
    (support, reach): (R, [u64; 3]),
    mut f: impl FnMut(usize, Vec3<R>, R),
) {
    let s2 = support * support;
    // Where the walk reaches less than half of every period, a row's image shift is the
    // minimum image of each of its points: one add per axis instead of two comparisons (the
    // same operations, so the same bits: d + L is what `min_image` computes for d < −L/2,
    // d − L = d + (−L) for d > L/2, and d + 0 = d). One loop for both forms: a second copy of
    // `f` would cost registers. The GPU build keeps the minimum image: the row shifts cost
    // its forces kernel 10 registers (ptxas sm_90, 220 → 230), and their gain there is
    // unmeasured.
    #[cfg(target_arch = "nvptx64")]
    let imaged = false;
    #[cfg(not(target_arch = "nvptx64"))]
    let imaged = g.row_images();
    g.for_each_row_within(g.coord(xi), support, reach, |lo, hi, img| {
        let (a, b) = look.particles_in_keys(lo, hi);
        for (o, &xj) in x[a..b].iter().enumerate() {
            let dx = if imaged {
                [
                    (xi[0] - xj[0]) + img[0],
                    (xi[1] - xj[1]) + img[1],
                    (xi[2] - xj[2]) + img[2],
                ]
            } else {
                g.separation(xi, xj)
            };
            let r2 = dot(dx, dx);
            if r2 < s2 {
                f(a + o, dx, r2);
            }
        }
    });
}
