//! Cell indices of the auxiliary grid (IDIC cells and neighbour search share it).
use crate::Real;

/// Integer cell coordinate of `x` on a lattice of spacing `dc` anchored at `origin`.
#[inline(always)]
pub fn cell_coord<R: Real>(x: R, origin: R, inv_dc: R) -> i64 {
    // ⌊v⌋ by truncation and a correction (no libm floor); NaN gives 0 as before.
    let v = ((x - origin) * inv_dc).to_f64();
    let t = v as i64;
    if (t as f64) > v {
        t - 1
    } else {
        t
    }
}

/// Row-major key of a cell with non-negative coordinates inside an (nx, ny, nz) box.
/// Consecutive x cells have consecutive keys, so a row of cells is one key range.
#[inline(always)]
pub fn key(ix: u64, iy: u64, iz: u64, nx: u64, ny: u64) -> u64 {
    (iz * ny + iy) * nx + ix
}
