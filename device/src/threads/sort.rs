//! The grid rebuild: bounds, keys, the counting sort by cell, gathers and copies.
use super::*;

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct BoundsArgs {
    /// Positions: f64 in every precision of the step.
    pub x: *const Vec3<f64>,
    pub n: u32,
    /// Particles per thread.
    pub chunk: u32,
    /// [min x, min y, min z, max x, max y, max z] as [`kernels::ordered_bits`]; initialise to
    /// (u64::MAX ×3, 0 ×3).
    pub out: *mut u64,
}

pub unsafe fn bounds(t: usize, a: &BoundsArgs) {
    let x = sl(a.x, a.n as usize);
    let lo = t * a.chunk as usize;
    if lo >= x.len() {
        return;
    }
    let hi = (lo + a.chunk as usize).min(x.len());
    let mut mn = [u64::MAX; 3];
    let mut mx = [0u64; 3];
    for p in &x[lo..hi] {
        for k in 0..3 {
            // A NaN maps above +∞ (positive NaN) or below −∞ (negative NaN); the host's
            // finiteness check of the decoded bounds then reports it.
            let b = kernels::ordered_bits(p[k]);
            mn[k] = mn[k].min(b);
            mx[k] = mx[k].max(b);
        }
    }
    for k in 0..3 {
        AtomicU64::from_ptr(a.out.add(k)).fetch_min(mn[k], Ordering::Relaxed);
        AtomicU64::from_ptr(a.out.add(3 + k)).fetch_max(mx[k], Ordering::Relaxed);
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct KeysArgs<R> {
    pub ph: PhaseBufs<R>,
    pub p: Params<R>,
    /// groups · stride + 1 counters (one per search cell of each group), zeroed.
    pub counts: *mut u32,
}

pub unsafe fn keys<R: Real>(t: usize, a: &KeysArgs<R>) {
    let ph = &a.ph;
    if t >= ph.len() {
        return;
    }
    let key = (ph.group_of(t) * a.p.key_stride()) as u64 + a.p.geom.key(ph.x()[t]);
    *ph.keys.add(t) = key;
    // Sparse mode sorts on the host: no counters.
    if !a.counts.is_null() {
        atomic_add_u32(a.counts.add(a.p.bucket_of(key)), 1);
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct ScanArgs {
    pub data: *mut u32,
    pub len: u32,
    pub chunk: u32,
    /// One entry per chunk (+1 for the total).
    pub sums: *mut u32,
}

impl ScanArgs {
    pub fn chunks(&self) -> usize {
        (self.len as usize).div_ceil(self.chunk as usize)
    }
    #[inline(always)]
    unsafe fn chunk_of<'a>(&self, t: usize) -> Option<&'a mut [u32]> {
        let lo = t * self.chunk as usize;
        if lo >= self.len as usize {
            return None;
        }
        let hi = (lo + self.chunk as usize).min(self.len as usize);
        // Only this thread's chunk is borrowed: threads never alias one another's slices.
        Some(sl_mut(self.data.add(lo), hi - lo))
    }
}

/// Scan pass 1: thread t sums chunk t.
pub unsafe fn scan_sums(t: usize, a: &ScanArgs) {
    if let Some(c) = a.chunk_of(t) {
        *a.sums.add(t) = c.iter().sum();
    }
}

/// Scan pass 2 (one thread): exclusive scan of the chunk sums; sums[chunks] = total.
pub unsafe fn scan_totals(t: usize, a: &ScanArgs) {
    if t == 0 {
        let n = a.chunks();
        let s = sl_mut(a.sums, n + 1);
        s[n] = kernels::scan_exclusive(&mut s[..n], 0);
    }
}

/// Scan pass 3: thread t turns chunk t into its exclusive prefix sums.
pub unsafe fn scan_chunks(t: usize, a: &ScanArgs) {
    if let Some(c) = a.chunk_of(t) {
        kernels::scan_exclusive(c, *a.sums.add(t));
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct ScatterArgs<R> {
    pub keys: *const u64,
    pub n: u32,
    pub dense: *const u32,
    /// One zeroed counter per dense-table slot.
    pub cursor: *mut u32,
    /// New → old particle index.
    pub perm: *mut u32,
    pub p: Params<R>,
}

pub unsafe fn scatter<R: Real>(t: usize, a: &ScatterArgs<R>) {
    if t >= a.n as usize {
        return;
    }
    let k = a.p.bucket_of(*a.keys.add(t));
    let pos = *a.dense.add(k) + atomic_add_u32(a.cursor.add(k), 1);
    *a.perm.add(pos as usize) = t as u32;
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct SegmentArgs {
    pub dense: *const u32,
    /// Number of dense-table slots.
    pub nkeys: u32,
    pub perm: *mut u32,
    /// Combined keys by old particle index (before the gathers).
    pub keys: *const u64,
    pub n: u32,
}

/// Thread t sorts the segment of search cell t by (key, old index): the order of a stable sort by cell.
pub unsafe fn sort_segments(t: usize, a: &SegmentArgs) {
    if t >= a.nkeys as usize {
        return;
    }
    let (lo, hi) = (*a.dense.add(t) as usize, *a.dense.add(t + 1) as usize);
    if hi > lo + 1 {
        kernels::sort_segment_by_key(sl_mut(a.perm.add(lo), hi - lo), sl(a.keys, a.n as usize));
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct GatherArgs<T> {
    pub src: *const T,
    pub dst: *mut T,
    pub perm: *const u32,
    pub n: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct CopyArgs<T> {
    pub src: *const T,
    pub dst: *mut T,
    pub n: u32,
}

/// dst[t] = src[t] (one kernel per element type).
pub unsafe fn copy<T: Copy>(t: usize, a: &CopyArgs<T>) {
    if t < a.n as usize {
        *a.dst.add(t) = *a.src.add(t);
    }
}

/// dst[t] = src[perm[t]] (one kernel per element type).
pub unsafe fn gather<T: Copy>(t: usize, a: &GatherArgs<T>) {
    if t < a.n as usize {
        *a.dst.add(t) = *a.src.add(*a.perm.add(t) as usize);
    }
}

/// Rows of a halo refresh (docs/scaling.md, "Named refreshes"): one field of a phase, `width`
/// bytes per particle, packed into (or unpacked from) rows of `stride` bytes at `offset`, row
/// t belonging to slot `slots[t]` (`u32::MAX`: a row no slot here takes).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct RowsArgs {
    pub field: *mut u8,
    pub rows: *mut u8,
    pub slots: *const u32,
    pub n: u32,
    pub width: u32,
    pub stride: u32,
    pub offset: u32,
}

/// Row t's bytes of the field and its slot's value (`None`: past the rows, or a row no slot
/// takes).
#[inline(always)]
unsafe fn row_and_value(t: usize, a: &RowsArgs) -> Option<(*mut u8, *mut u8)> {
    if t >= a.n as usize {
        return None;
    }
    let s = *a.slots.add(t);
    if s == u32::MAX {
        return None;
    }
    let row = a.rows.add(t * a.stride as usize + a.offset as usize);
    Some((row, a.field.add(s as usize * a.width as usize)))
}

/// Row t of a refresh's send table takes its slot's value of the field.
pub unsafe fn pack_rows(t: usize, a: &RowsArgs) {
    if let Some((row, value)) = row_and_value(t, a) {
        core::ptr::copy_nonoverlapping(value, row, a.width as usize);
    }
}

/// Row t of a refresh's arriving table overwrites its slot's value of the field.
pub unsafe fn unpack_rows(t: usize, a: &RowsArgs) {
    if let Some((row, value)) = row_and_value(t, a) {
        core::ptr::copy_nonoverlapping(row, value, a.width as usize);
    }
}

pub type GatherV3Args<R> = GatherArgs<[R; 3]>;
pub type CopyV3Args<R> = CopyArgs<[R; 3]>;

// The element types the step copies and gathers, one kernel each (crate::kernel_table).
pub unsafe fn gather_u64(t: usize, a: &GatherArgs<u64>) {
    gather(t, a)
}
pub unsafe fn gather_u8(t: usize, a: &GatherArgs<u8>) {
    gather(t, a)
}
pub unsafe fn gather_x(t: usize, a: &GatherArgs<[f64; 3]>) {
    gather(t, a)
}
pub unsafe fn gather_v3<R: Copy>(t: usize, a: &GatherArgs<[R; 3]>) {
    gather(t, a)
}
pub unsafe fn gather_real<R: Copy>(t: usize, a: &GatherArgs<R>) {
    gather(t, a)
}
pub unsafe fn copy_v3<R: Copy>(t: usize, a: &CopyArgs<[R; 3]>) {
    copy(t, a)
}
pub unsafe fn copy_real<R: Copy>(t: usize, a: &CopyArgs<R>) {
    copy(t, a)
}
