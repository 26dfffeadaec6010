//! Diagnostics: the momentum reduction.
use super::*;

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MomentumArgs<R> {
    pub ph: PhaseBufs<R>,
    /// Particles per thread.
    pub chunk: u32,
    /// Per thread: Σ m v_x, Σ m v_y, Σ m v_z, Σ m |v| over its chunk, in f64.
    pub out: *mut f64,
}

/// Thread t sums the momentum and the momentum scale Σ m|v| of particles
/// [t·chunk, (t+1)·chunk) in f64, in particle order; the host adds the chunks in order, so the
/// sums are the same on every launcher.
pub unsafe fn momentum<R: Real>(t: usize, a: &MomentumArgs<R>) {
    let n = a.ph.n as usize;
    let lo = t * a.chunk as usize;
    if lo >= n {
        return;
    }
    let hi = (lo + a.chunk as usize).min(n);
    let (v, m) = (sl(a.ph.v, n), sl(a.ph.m, n));
    let mut s = [0.0f64; 4];
    for i in lo..hi {
        let mi = m[i].to_f64();
        let vi = [v[i][0].to_f64(), v[i][1].to_f64(), v[i][2].to_f64()];
        for k in 0..3 {
            s[k] += mi * vi[k];
        }
        s[3] += mi * Real::sqrt(dot(vi, vi));
    }
    for (k, x) in s.iter().enumerate() {
        *a.out.add(4 * t + k) = *x;
    }
}
