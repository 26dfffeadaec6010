//! SPH pair terms (method.md §2): density summation, pressure force with Monaghan
//! artificial viscosity, and the compressional / viscous heating rate.
//!
//! Only particles of the same phase interact through these terms; gas and dust couple solely
//! through the IDIC drag of [`crate::drag`].
use crate::{dot, kernel, Real, Vec3};

/// Monaghan artificial viscosity parameters: Π_ab with ν² = `nu2_factor` · h².
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Viscosity<R> {
    pub alpha: R,
    pub beta: R,
    pub nu2_factor: R,
    /// The disc form (`sph.alpha_ss`): α set per pair for a target Shakura–Sunyaev α and the
    /// linear term on receding pairs too; `None`: the shock form.
    pub disc: Option<DiscViscosity>,
}

/// The disc viscosity (method.md §D, "Disc viscosity"): the linear term on every pair, which
/// in the continuum limit is a shear viscosity ν = α_AV c_s h/κ (κ = 10 in 3D, 8 in 2D for
/// the M4 kernel; Lodato & Price 2010, Meglicki et al. 1993), with α_AV per pair such that
/// ν = α_SS c_s H, H = c_s/Ω_K at the pair's mid-point: α_AV = κ α_SS H/h̄.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiscViscosity {
    /// κ α_SS.
    pub kappa_alpha_ss: f64,
    /// The point mass the disc orbits (Ω_K from its GM about its z axis).
    pub gm: f64,
    pub centre: Vec3<f64>,
}

impl DiscViscosity {
    /// κ of ν = α_AV c_s h/κ: the M4 kernel's continuum limit of the linear term on every
    /// pair, 10 in 3D and 8 in 2D (Lodato & Price 2010; Murray 1996).
    pub fn kappa(dim: u32) -> f64 {
        if dim == 3 {
            10.0
        } else {
            8.0
        }
    }

    /// α_AV of a pair at x_a, x_b with mean sound speed `cbar` and mean h `h`.
    #[inline(always)]
    pub fn alpha<R: Real>(&self, xa: Vec3<f64>, xb: Vec3<f64>, cbar: R, h: R) -> R {
        let x = 0.5 * (xa[0] + xb[0]) - self.centre[0];
        let y = 0.5 * (xa[1] + xb[1]) - self.centre[1];
        let r2 = x * x + y * y;
        // Ω_K = √(GM/R³); H = c̄/Ω_K.
        let omega = Real::sqrt(self.gm / (r2 * Real::sqrt(r2)));
        if omega.is_finite() && omega > 0.0 {
            R::from_f64(self.kappa_alpha_ss / omega) * cbar / h
        } else {
            R::ZERO
        }
    }
}

/// State of one gas particle as the pair loop sees it.
#[derive(Clone, Copy, Debug)]
pub struct GasState<R> {
    pub x: Vec3<f64>,
    pub v: Vec3<R>,
    pub m: R,
    pub rho: R,
    pub p: R,
    pub c: R,
}

/// Contribution of a neighbour b at separation r_ab (|r_ab| = r) to the continuity-equation
/// density rate of a: m_b (v_a − v_b)·∇_a W_ab (zero for b = a, where ∇W = 0).
#[inline(always)]
pub fn density_rate_term<R: Real>(
    m_b: R,
    v_a: Vec3<R>,
    v_b: Vec3<R>,
    dx: Vec3<R>,
    r: R,
    k: &kernel::KernelAt<R>,
) -> R {
    m_b * dot(crate::sub(v_a, v_b), dx) * k.grad_factor(r)
}

/// μ_ab = h (v_ab·r_ab)/(|r_ab|² + ν²).
#[inline(always)]
pub fn mu<R: Real>(vr: R, r2: R, h: R, nu2_factor: R) -> R {
    h * vr / (r2 + nu2_factor * h * h)
}

/// Monaghan Π_ab = (−α c̄ μ + β μ²)/ρ̄: the shock form on approaching pairs only
/// (v_ab·r_ab < 0), `alpha` the pair's α; with `receding` (the disc form) the linear term on
/// receding pairs too, the quadratic one still on approaching pairs only.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn viscosity_pi<R: Real>(
    av: &Viscosity<R>,
    alpha: R,
    receding: bool,
    vr: R,
    r2: R,
    h: R,
    cbar: R,
    rhobar: R,
) -> R {
    if (vr >= R::ZERO && !receding) || rhobar <= R::ZERO {
        return R::ZERO;
    }
    let m = mu(vr, r2, h, av.nu2_factor);
    let quad = if vr < R::ZERO {
        av.beta * m * m
    } else {
        R::ZERO
    };
    (-alpha * cbar * m + quad) / rhobar
}

/// What one gas neighbour b adds to gas particle a.
#[derive(Clone, Copy, Debug)]
pub struct GasPair<R> {
    /// Contribution to the non-drag acceleration A_a.
    pub acc: Vec3<R>,
    /// Contribution to de_a/dt (compression + viscous heating).
    pub dedt: R,
    /// Signal speed of the pair, for the time-step limit.
    pub vsig: R,
}

/// The gas–gas pair term for particle a from neighbour b, with r_ab = `dx` (minimum image for
/// periodic boundaries) and the kernel `k` at the global h. Momentum: −m_b (p_a/ρ_a² + p_b/ρ_b² +
/// Π_ab) ∇_a W_ab, antisymmetric in a↔b, so total momentum is conserved to round-off. Energy:
/// (p_a/ρ_a²) m_b v_ab·∇W + ½ m_b Π_ab v_ab·∇W. `pa` = p_a/ρ_a², `pb` = p_b/ρ_b².
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn gas_pair<R: Real>(
    a: &GasState<R>,
    b: &GasState<R>,
    pa: R,
    pb: R,
    dx: Vec3<R>,
    r2: R,
    k: &kernel::KernelAt<R>,
    av: Option<&Viscosity<R>>,
) -> GasPair<R> {
    let f = k.grad_factor(r2.sqrt());
    let dv = crate::sub(a.v, b.v);
    let vr = dot(dv, dx);
    let (pi, vsig) = viscous(a, b, vr, r2, k.h, av);
    let coef = -b.m * (pa + pb + pi) * f;
    let vgrad = vr * f;
    GasPair {
        acc: [coef * dx[0], coef * dx[1], coef * dx[2]],
        dedt: b.m * (pa + R::from_f64(0.5) * pi) * vgrad,
        vsig,
    }
}

/// Monaghan Π_ab and the pair signal speed (c_a without viscosity).
#[inline(always)]
fn viscous<R: Real>(
    a: &GasState<R>,
    b: &GasState<R>,
    vr: R,
    r2: R,
    h: R,
    av: Option<&Viscosity<R>>,
) -> (R, R) {
    match av {
        Some(av) => {
            let cbar = R::from_f64(0.5) * (a.c + b.c);
            let rhobar = R::from_f64(0.5) * (a.rho + b.rho);
            let (alpha, receding) = match &av.disc {
                Some(d) => (d.alpha(a.x, b.x, cbar, h), true),
                None => (av.alpha, false),
            };
            let pi = viscosity_pi(av, alpha, receding, vr, r2, h, cbar, rhobar);
            let m = if vr < R::ZERO {
                mu(vr, r2, h, av.nu2_factor).abs()
            } else {
                R::ZERO
            };
            // Monaghan (1989) signal speed with the viscous terms.
            (pi, a.c + R::from_f64(1.2) * (alpha * cbar + av.beta * m))
        }
        None => (R::ZERO, a.c),
    }
}

/// [`gas_pair`] with variable smoothing lengths (kernels `ka`, `kb` at h_a, h_b) and grad-h
/// terms folded into `pa` = p_a/(Ω_a ρ_a²), `pb` = p_b/(Ω_b ρ_b²) (Price 2012, eqs. 35–36):
/// each side's pressure term uses its own kernel gradient; the artificial viscosity uses the
/// mean gradient and the mean h.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn gas_pair_vh<R: Real>(
    a: &GasState<R>,
    b: &GasState<R>,
    pa: R,
    pb: R,
    dx: Vec3<R>,
    r2: R,
    ka: &kernel::KernelAt<R>,
    kb: &kernel::KernelAt<R>,
    av: Option<&Viscosity<R>>,
) -> GasPair<R> {
    let r = r2.sqrt();
    let ga = crate::scale(ka.grad_factor(r), dx);
    let gb = crate::scale(kb.grad_factor(r), dx);
    let hbar = R::from_f64(0.5) * (ka.h + kb.h);
    gas_pair_two_sided(a, b, pa, pb, dx, r2, hbar, ga, gb, av)
}

/// The pair term with one kernel gradient per side: `ga` stands for ∇_a W_ab(h_a), `gb` for
/// ∇_a W_ab(h_b). Momentum −m_b (p̂_a ga + p̂_b gb + Π_ab ḡ), energy m_b (p̂_a v_ab·ga +
/// ½ Π_ab v_ab·ḡ), ḡ = (ga + gb)/2, Π_ab at the mean h `hbar`. Shared by the variable-h and the
/// IAD forms, which differ only in the gradients.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn gas_pair_two_sided<R: Real>(
    a: &GasState<R>,
    b: &GasState<R>,
    pa: R,
    pb: R,
    dx: Vec3<R>,
    r2: R,
    hbar: R,
    ga: Vec3<R>,
    gb: Vec3<R>,
    av: Option<&Viscosity<R>>,
) -> GasPair<R> {
    let dv = crate::sub(a.v, b.v);
    let half = R::from_f64(0.5);
    let (pi, vsig) = viscous(a, b, dot(dv, dx), r2, hbar, av);
    let gbar = crate::scale(half, crate::add(ga, gb));
    let acc = crate::scale(
        -b.m,
        crate::add(
            crate::add(crate::scale(pa, ga), crate::scale(pb, gb)),
            crate::scale(pi, gbar),
        ),
    );
    GasPair {
        acc,
        dedt: b.m * (pa * dot(dv, ga) + half * pi * dot(dv, gbar)),
        vsig,
    }
}

/// Symmetric 3×3 matrix stored as (xx, xy, xz, yy, yz, zz).
pub type Sym3<R> = [R; 6];

/// Contribution of neighbour b to the IAD moment matrix of a (García-Senz, Cabezón &
/// Escartín 2012): τ_a = Σ_b V_b r_ab ⊗ r_ab W_ab(h_a), V_b = m_b/ρ_b.
#[inline(always)]
pub fn iad_moment_term<R: Real>(v_b: R, dx: Vec3<R>, w: R) -> Sym3<R> {
    let s = v_b * w;
    [
        s * dx[0] * dx[0],
        s * dx[0] * dx[1],
        s * dx[0] * dx[2],
        s * dx[1] * dx[1],
        s * dx[1] * dx[2],
        s * dx[2] * dx[2],
    ]
}

/// C_a = τ_a⁻¹ in `dim` dimensions (the inactive axes are decoupled; their separations are
/// zero). A particle whose neighbours do not span space (det τ ≲ 0) gets the
/// isotropic estimate C = (dim / tr τ) I: the trace of C τ is then still dim.
#[inline(always)]
pub fn iad_inverse<R: Real>(mut t: Sym3<R>, dim: u32) -> Sym3<R> {
    // Inactive axes: decoupled, with the active axes' scale so the conditioning test is fair.
    if dim < 2 {
        t[1] = R::ZERO;
        t[3] = t[0];
    }
    if dim < 3 {
        t[2] = R::ZERO;
        t[4] = R::ZERO;
        t[5] = R::from_f64(0.5) * (t[0] + t[3]);
    }
    let [xx, xy, xz, yy, yz, zz] = t;
    let cxx = yy * zz - yz * yz;
    let cxy = xz * yz - xy * zz;
    let cxz = xy * yz - xz * yy;
    let det = xx * cxx + xy * cxy + xz * cxz;
    let tr = xx + yy + zz;
    let scale3 = tr * tr * tr;
    if det > R::from_f64(1e-9) * scale3 {
        let inv = R::ONE / det;
        return [
            cxx * inv,
            cxy * inv,
            cxz * inv,
            (xx * zz - xz * xz) * inv,
            (xy * xz - xx * yz) * inv,
            (xx * yy - xy * xy) * inv,
        ];
    }
    let d = R::from_f64(dim as f64);
    let tr_active = match dim {
        1 => xx,
        2 => xx + yy,
        _ => tr,
    };
    let c = if tr_active > R::ZERO {
        d / tr_active
    } else {
        R::ZERO
    };
    [c, R::ZERO, R::ZERO, c, R::ZERO, c]
}

/// C · r.
#[inline(always)]
pub fn sym_mul<R: Real>(c: &Sym3<R>, r: Vec3<R>) -> Vec3<R> {
    [
        c[0] * r[0] + c[1] * r[1] + c[2] * r[2],
        c[1] * r[0] + c[3] * r[1] + c[4] * r[2],
        c[2] * r[0] + c[4] * r[1] + c[5] * r[2],
    ]
}

/// [`gas_pair_vh`] with the integral approach to derivatives (IAD; García-Senz et al. 2012,
/// the gradient of SPHYNX and SPH-EXA): each side's kernel gradient ∇_a W_ab(h_s) is replaced
/// by −C_s r_ab W_ab(h_s), which differentiates linear fields exactly on any particle
/// arrangement. Antisymmetric in a↔b (momentum and energy conserved like the standard form);
/// `pa` = p_a/ρ_a², `pb` = p_b/ρ_b² (no grad-h factors). On the close-packed lattice at
/// h = 1.2 (m/ρ)^(1/3) the standard gradient's long-wave sound speed is 1.2% fast at every
/// resolution; with IAD the error falls as (kh)² (docs/phantom_comparison.md).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn gas_pair_iad<R: Real>(
    a: &GasState<R>,
    b: &GasState<R>,
    pa: R,
    pb: R,
    dx: Vec3<R>,
    r2: R,
    ka: &kernel::KernelAt<R>,
    kb: &kernel::KernelAt<R>,
    ca: &Sym3<R>,
    cb: &Sym3<R>,
    av: Option<&Viscosity<R>>,
) -> GasPair<R> {
    let r = r2.sqrt();
    let ga = crate::scale(-ka.w(r), sym_mul(ca, dx));
    let gb = crate::scale(-kb.w(r), sym_mul(cb, dx));
    let hbar = R::from_f64(0.5) * (ka.h + kb.h);
    gas_pair_two_sided(a, b, pa, pb, dx, r2, hbar, ga, gb, av)
}
