//! M4 cubic-spline kernel with support 2h (method.md §2), for 1, 2 and 3 dimensions.
use crate::Real;

/// Support radius in units of h.
pub const SUPPORT: f64 = 2.0;

/// Normalisation σ_d of the M4 spline with support 2h.
#[inline(always)]
pub fn sigma<R: Real>(dim: u32) -> R {
    match dim {
        1 => R::from_f64(2.0 / 3.0),
        2 => R::from_f64(10.0 / (7.0 * core::f64::consts::PI)),
        _ => R::from_f64(1.0 / core::f64::consts::PI),
    }
}

#[inline(always)]
fn pow_dim<R: Real>(h: R, dim: u32) -> R {
    match dim {
        1 => h,
        2 => h * h,
        _ => h * h * h,
    }
}

/// Shape function f(q), q = r/h.
#[inline(always)]
pub fn shape<R: Real>(q: R) -> R {
    let one = R::ONE;
    let two = R::from_f64(2.0);
    if q <= one {
        one - R::from_f64(1.5) * q * q + R::from_f64(0.75) * q * q * q
    } else if q <= two {
        let t = two - q;
        R::from_f64(0.25) * t * t * t
    } else {
        R::ZERO
    }
}

/// Derivative f'(q).
#[inline(always)]
pub fn dshape<R: Real>(q: R) -> R {
    let one = R::ONE;
    let two = R::from_f64(2.0);
    if q <= one {
        R::from_f64(-3.0) * q + R::from_f64(2.25) * q * q
    } else if q <= two {
        let t = two - q;
        R::from_f64(-0.75) * t * t
    } else {
        R::ZERO
    }
}

/// h^d (for the variable-h density ρ = m (hfact/h)^d).
#[inline(always)]
pub fn h_pow_dim<R: Real>(h: R, dim: u32) -> R {
    pow_dim(h, dim)
}

/// The variable-h smoothing length of a particle of mass m at density ρ: h = hfact (m/ρ)^(1/d),
/// the relation `kernels::solve_h_at` solves (ρ = m (hfact/h)^d). `guess`, a length of the
/// right scale (the reference h), starts the 3D root. Output's h and the dust's warm start.
#[inline(always)]
pub fn h_of_density<R: Real>(m: R, rho: R, hfact: R, dim: u32, guess: R) -> R {
    hfact * root_dim(m / rho, dim, guess / hfact)
}

/// x^(1/d) for x > 0: x, √x, or the cube root by Newton's iteration y ← (2y + x/y²)/3 from
/// `y0` until it stops improving (no libm root: the GPU build links none; the same operations
/// on the CPU and the GPU). From any y0 > 0 it converges (monotonically after the first step).
#[inline(always)]
pub fn root_dim<R: Real>(x: R, dim: u32, y0: R) -> R {
    match dim {
        1 => x,
        2 => x.sqrt(),
        _ => {
            let three = R::from_f64(3.0);
            let mut y = if y0 > R::ZERO && y0.is_finite() {
                y0
            } else {
                R::ONE
            };
            let mut last = R::from_f64(f64::INFINITY);
            for _ in 0..200 {
                let next = (y + y + x / (y * y)) / three;
                let step = (next - y).abs();
                if step >= last {
                    break;
                }
                y = next;
                last = step;
                if step == R::ZERO {
                    break;
                }
            }
            y
        }
    }
}

/// f'(q)/q, finite at q = 0 (so that ∇W = f'(q)/q · σ/h^(d+2) · r_ab needs no 1/r).
#[inline(always)]
pub fn dshape_over_q<R: Real>(q: R) -> R {
    let one = R::ONE;
    let two = R::from_f64(2.0);
    if q <= one {
        R::from_f64(-3.0) + R::from_f64(2.25) * q
    } else if q <= two {
        let t = two - q;
        R::from_f64(-0.75) * t * t / q
    } else {
        R::ZERO
    }
}

/// The kernel at one smoothing length with its constants computed once, so that a pair costs
/// no division in the inner region (q ≤ 1) and one in the outer shell. `repr(C)`: GPU buffers
/// hold one per particle.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KernelAt<R> {
    pub h: R,
    pub inv_h: R,
    /// σ_d / h^d.
    pub w_norm: R,
    /// σ_d / h^(d+2): ∇_a W_ab = grad_norm · f'(q)/q · r_ab.
    pub grad_norm: R,
    pub dim: u32,
}

impl<R: Real> KernelAt<R> {
    #[inline(always)]
    pub fn new(h: R, dim: u32) -> Self {
        let inv_h = R::ONE / h;
        let w_norm = sigma::<R>(dim) * pow_dim(inv_h, dim);
        KernelAt {
            h,
            inv_h,
            w_norm,
            grad_norm: w_norm * inv_h * inv_h,
            dim,
        }
    }

    /// W(r).
    #[inline(always)]
    pub fn w(&self, r: R) -> R {
        self.w_norm * shape(r * self.inv_h)
    }

    /// F with ∇_a W_ab = F · r_ab, from r = |r_ab| (0 beyond the support).
    #[inline(always)]
    pub fn grad_factor(&self, r: R) -> R {
        self.grad_norm * dshape_over_q(r * self.inv_h)
    }

    /// ∂W/∂h at r: −σ/h^(d+1) (d f(q) + q f'(q)).
    #[inline(always)]
    pub fn dw_dh(&self, r: R) -> R {
        let q = r * self.inv_h;
        -(self.w_norm * self.inv_h) * (R::from_f64(self.dim as f64) * shape(q) + q * dshape(q))
    }
}
