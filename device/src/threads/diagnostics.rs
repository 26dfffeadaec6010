//! Diagnostics: the momentum reduction (with the angular momentum and the particles inside the
//! accretion radius, method.md §1.2, and the ball's Lagrange–Jacobi sums, method.md §6.1).
use super::*;

/// Sums per thread: Σ m v (3), Σ m |v|, Σ m (x − centre) × v (3), particles inside the
/// accretion radius; then the Lagrange–Jacobi terms Σ m |x|², Σ 2 m |v|², Σ m p/ρ.
pub const MOMENTUM_SUMS: usize = 11;

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MomentumArgs<R> {
    pub ph: PhaseBufs<R>,
    /// Particles per thread.
    pub chunk: u32,
    /// The point about which the angular momentum is taken (the star's position, or 0).
    pub centre: Vec3<f64>,
    /// The accretion radius squared (0: none is counted).
    pub r_acc2: f64,
    /// The gas pressure (Σ m p/ρ); null for dust.
    pub p: *const R,
    /// Per thread: [`MOMENTUM_SUMS`] sums over its chunk, in f64.
    pub out: *mut f64,
}

/// Thread t sums the momentum, the momentum scale Σ m|v|, the angular momentum about the
/// centre and the count of particles closer to it than the accretion radius, over particles
/// [t·chunk, (t+1)·chunk) in f64, in particle order; the host adds the chunks in order, so the
/// sums are the same on every launcher.
pub unsafe fn momentum<R: Real>(t: usize, a: &MomentumArgs<R>) {
    let n = a.ph.n as usize;
    let lo = t * a.chunk as usize;
    if lo >= n {
        return;
    }
    let hi = (lo + a.chunk as usize).min(n);
    let (x, v, m, rho) = (sl(a.ph.x, n), sl(a.ph.v, n), sl(a.ph.m, n), sl(a.ph.rho, n));
    let mut s = [0.0f64; MOMENTUM_SUMS];
    for i in lo..hi {
        let mi = m[i].to_f64();
        let vi = [v[i][0].to_f64(), v[i][1].to_f64(), v[i][2].to_f64()];
        let r = [
            x[i][0] - a.centre[0],
            x[i][1] - a.centre[1],
            x[i][2] - a.centre[2],
        ];
        for k in 0..3 {
            s[k] += mi * vi[k];
        }
        s[3] += mi * Real::sqrt(dot(vi, vi));
        let l = crate::cross(r, vi);
        for k in 0..3 {
            s[4 + k] += mi * l[k];
        }
        if dot(r, r) < a.r_acc2 {
            s[7] += 1.0;
        }
        s[8] += mi * dot(x[i], x[i]);
        s[9] += 2.0 * mi * dot(vi, vi);
        if !a.p.is_null() {
            s[10] += mi * (*a.p.add(i)).to_f64() / rho[i].to_f64();
        }
    }
    for (k, x) in s.iter().enumerate() {
        *a.out.add(MOMENTUM_SUMS * t + k) = *x;
    }
}
