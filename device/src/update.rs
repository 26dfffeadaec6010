//! Explicit particle updates of the step (method.md §3.6, items 6–7).
use crate::{axpy, Real, Vec3};

/// x^{n+1} = x^n + τ w, with w = v^n (the authors' forward Euler) or v^{n+1} (symplectic).
#[inline(always)]
pub fn drift<R: Real>(x: Vec3<R>, w: Vec3<R>, tau: R) -> Vec3<R> {
    axpy(x, tau, w)
}

/// e^{n+1} = e^n + τ (de/dt)^n (+ drag heat per unit mass, when enabled).
#[inline(always)]
pub fn energy<R: Real>(e: R, dedt: R, tau: R) -> R {
    e + tau * dedt
}

/// Wrap a coordinate into the periodic interval [lo, lo + len).
#[inline(always)]
pub fn wrap<R: Real>(x: R, lo: R, len: R) -> R {
    let s = (x - lo) / len;
    let mut y = x - len * s.floor();
    // Guard against y == lo + len from rounding.
    if y >= lo + len {
        y -= len;
    }
    y
}

/// Minimum-image separation along one periodic axis.
#[inline(always)]
pub fn min_image<R: Real>(d: R, len: R) -> R {
    let half = R::from_f64(0.5) * len;
    if d > half {
        d - len
    } else if d < -half {
        d + len
    } else {
        d
    }
}
