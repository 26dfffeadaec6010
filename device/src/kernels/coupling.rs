//! Kernel coupling (docs/method.md §K): the IDIC cell solve with the gas particles as the cells.
//! Every particle q (gas or dust) spreads itself over the gas particles a around it with the
//! weights w_qa = W(r_qa, h_a)/S_q, S_q = Σ_b W(r_qb, h_b): a partition of unity, so the deposit
//! and the return of the increments conserve momentum exactly, and a uniform increment reaches
//! every particle unchanged. Gas and dust are smoothed by the same operator at the same point, so
//! the relative velocity the drag sees is a property of the flow, not of where particles sit.
use super::*;

/// The gas kernel of particle b: one shared kernel (fixed h, `k.len() == 1`) or one per particle.
#[inline(always)]
pub fn kernel_of<R: Real>(k: &[KernelAt<R>], b: usize) -> KernelAt<R> {
    if k.len() == 1 {
        k[0]
    } else {
        k[b]
    }
}

/// The raw coupling weights of a particle at x: `f(a, W(|x − x_a|, h_a))` for every free gas
/// particle a within reach, in the neighbour walk's order. Their sum is the particle's
/// normaliser S (0: no gas within reach, the particle does not couple).
#[inline(always)]
pub fn coupling_row_at<R: Real>(
    gas: &Sorted<'_, R>,
    k: &[KernelAt<R>],
    gas_fixed: &[bool],
    x: Centre,
    mut f: impl FnMut(usize, R),
) {
    gas.walk_at(x, |b, _, r2| {
        if !is_fixed(gas_fixed, b) {
            let w = kernel_of(k, b).w(r2.sqrt());
            if w > R::ZERO {
                f(b, w);
            }
        }
    });
}

/// What one phase deposits on gas particle a: Σ w m, Σ w m ṽ, and the mass-weighted sums of
/// the density and of sqrt(p/ρ) (gas) that the stopping-time laws read.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Deposit<R> {
    pub mass: R,
    pub mom: Vec3<R>,
    pub rho: R,
    pub cs: R,
}

impl<R: Real> Deposit<R> {
    /// Add one particle's share: `wm` = w_qa m_q, its velocity, density and sqrt(p/ρ).
    #[inline(always)]
    pub fn add(&mut self, wm: R, vel: Vec3<R>, rho: R, cs: R) {
        self.mass += wm;
        self.mom = axpy(self.mom, wm, vel);
        self.rho += wm * rho;
        self.cs += wm * cs;
    }
}

/// Deposit of one phase on a gas particle from its stored row ([`crate::threads::PairBufs`]):
/// the depositing particles `idx` and their weights `w` (w_qa = W(r_qa, h_a)/S_q), with masses
/// `m`, velocities `vel(q)`, densities `rho`, sqrt(p/ρ) `cs(q)`.
#[inline(always)]
pub fn deposit_rows<R: Real>(
    idx: &[u32],
    w: &[R],
    m: &[R],
    rho: &[R],
    vel: impl Fn(usize) -> Vec3<R>,
    cs: impl Fn(usize) -> R,
) -> Deposit<R> {
    let mut d = Deposit {
        mass: R::ZERO,
        mom: [R::ZERO; 3],
        rho: R::ZERO,
        cs: R::ZERO,
    };
    for (&q, &w) in idx.iter().zip(w) {
        let q = q as usize;
        d.add(w * m[q], vel(q), rho[q], cs(q));
    }
    d
}

/// The least-squares fit of the gas's velocity about gas particle a over its deposit row
/// (method.md §K, "Sampling offsets"): with the weights ω_b = w_ba m_b, offsets d_b = x_b − x_a
/// (`dx`) and velocities `dv(b)` (relative to a's, against cancellation), the gradient
/// G = C_vx C_xx⁻¹ of the centred moments C_xx = Σ ω (d − d̄)(d − d̄)ᵀ,
/// C_vx = Σ ω (v − v̄)(d − d̄)ᵀ over the first `dim` axes, and the row's first moment Σ ω d.
/// Exact for a linear field on any arrangement. `None` where the row's offsets do not span
/// `dim` axes (det C_xx below 1e-6 of (tr C_xx/dim)^dim: a row on a line or a point).
#[inline(always)]
pub fn row_gradient<R: Real>(
    idx: &[u32],
    w: &[R],
    m: &[R],
    dx: impl Fn(usize) -> Vec3<R>,
    dv: impl Fn(usize) -> Vec3<R>,
    dim: usize,
) -> Option<([Vec3<R>; 3], Vec3<R>)> {
    let (mut mass, mut d1, mut v1) = (R::ZERO, [R::ZERO; 3], [R::ZERO; 3]);
    let (mut dd, mut vd) = ([[R::ZERO; 3]; 3], [[R::ZERO; 3]; 3]);
    for (&q, &wq) in idx.iter().zip(w) {
        let q = q as usize;
        let om = wq * m[q];
        let (d, v) = (dx(q), dv(q));
        mass += om;
        d1 = axpy(d1, om, d);
        v1 = axpy(v1, om, v);
        for i in 0..3 {
            dd[i] = axpy(dd[i], om * d[i], d);
            vd[i] = axpy(vd[i], om * v[i], d);
        }
    }
    if mass <= R::ZERO {
        return None;
    }
    let inv_m = R::ONE / mass;
    let mut c = [[R::ZERO; 3]; 3];
    let mut cv = [[R::ZERO; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = dd[i][j] - d1[i] * d1[j] * inv_m;
            cv[i][j] = vd[i][j] - v1[i] * d1[j] * inv_m;
        }
    }
    let inv = inverse_leading(&c, dim)?;
    let mut g = [[R::ZERO; 3]; 3];
    for i in 0..3 {
        for j in 0..dim {
            let mut s = R::ZERO;
            for k in 0..dim {
                s += cv[i][k] * inv[k][j];
            }
            g[i][j] = s;
        }
    }
    Some((g, d1))
}

/// Σ ω d over a deposit row: the first moment of a phase's offsets from the gas particle.
#[inline(always)]
pub fn row_moment<R: Real>(
    idx: &[u32],
    w: &[R],
    m: &[R],
    dx: impl Fn(usize) -> Vec3<R>,
) -> Vec3<R> {
    let mut d1 = [R::ZERO; 3];
    for (&q, &wq) in idx.iter().zip(w) {
        let q = q as usize;
        d1 = axpy(d1, wq * m[q], dx(q));
    }
    d1
}

/// A deposit read at the gas particle instead of at its particles' centroid: Σ ω ṽ less
/// G · Σ ω d (the fit's value at d = 0, times the mass).
#[inline(always)]
pub fn read_at_centre<R: Real>(dep: &mut Deposit<R>, g: &[Vec3<R>; 3], first: Vec3<R>) {
    for (i, gi) in g.iter().enumerate() {
        dep.mom[i] -= crate::dot(*gi, first);
    }
}

/// The inverse of the leading `dim` × `dim` block of a symmetric matrix (zeros elsewhere);
/// `None` when it is singular to 1e-6 of its scale.
#[inline(always)]
fn inverse_leading<R: Real>(c: &[Vec3<R>; 3], dim: usize) -> Option<[Vec3<R>; 3]> {
    let mut inv = [[R::ZERO; 3]; 3];
    let scale = match dim {
        1 => c[0][0],
        2 => R::from_f64(0.5) * (c[0][0] + c[1][1]),
        _ => R::from_f64(1.0 / 3.0) * (c[0][0] + c[1][1] + c[2][2]),
    };
    if scale <= R::ZERO {
        return None;
    }
    let tiny = R::from_f64(1e-6);
    match dim {
        1 => inv[0][0] = R::ONE / c[0][0],
        2 => {
            let det = c[0][0] * c[1][1] - c[0][1] * c[1][0];
            if det <= tiny * scale * scale {
                return None;
            }
            let r = R::ONE / det;
            inv[0][0] = c[1][1] * r;
            inv[1][1] = c[0][0] * r;
            inv[0][1] = -c[0][1] * r;
            inv[1][0] = -c[1][0] * r;
        }
        _ => {
            let a = [
                c[1][1] * c[2][2] - c[1][2] * c[2][1],
                c[0][2] * c[2][1] - c[0][1] * c[2][2],
                c[0][1] * c[1][2] - c[0][2] * c[1][1],
            ];
            let det = c[0][0] * a[0] + c[1][0] * a[1] + c[2][0] * a[2];
            if det <= tiny * scale * scale * scale {
                return None;
            }
            let r = R::ONE / det;
            inv[0] = [a[0] * r, a[1] * r, a[2] * r];
            inv[1] = [
                (c[1][2] * c[2][0] - c[1][0] * c[2][2]) * r,
                (c[0][0] * c[2][2] - c[0][2] * c[2][0]) * r,
                (c[0][2] * c[1][0] - c[0][0] * c[1][2]) * r,
            ];
            inv[2] = [
                (c[1][0] * c[2][1] - c[1][1] * c[2][0]) * r,
                (c[0][1] * c[2][0] - c[0][0] * c[2][1]) * r,
                (c[0][0] * c[1][1] - c[0][1] * c[1][0]) * r,
            ];
        }
    }
    Some(inv)
}

/// The implicit solve on gas particle a from the deposits (method.md §3.3 closed form, with the
/// cell means replaced by the deposit means): ε_k = M_k/M_g, t_k* from each law with the
/// mass-weighted mean densities and sound speed (`gamma_root` · mean sqrt(p/ρ)).
/// `CellCoupling::u_new`/`v_new` are the new means; `old` returns the old means (ũ_k).
#[inline(always)]
pub fn kernel_couple<R: Real>(
    gas: &Deposit<R>,
    dust: &[Deposit<R>],
    laws: &[StoppingLaw<R>],
    tau: R,
    gamma_root: R,
    old: &mut [Vec3<R>; MAX_FRACTIONS],
) -> CellCoupling<R> {
    let nf = dust.len().min(laws.len()).min(MAX_FRACTIONS);
    if gas.mass <= R::ZERO {
        return solve_coupling([R::ZERO; 3], &[], tau, |_| None);
    }
    let inv_g = R::ONE / gas.mass;
    for k in 0..nf {
        if dust[k].mass > R::ZERO {
            old[k] = scale(R::ONE / dust[k].mass, dust[k].mom);
        }
    }
    solve_coupling(scale(inv_g, gas.mom), &old[..nf], tau, |k| {
        let d = &dust[k];
        if d.mass <= R::ZERO {
            return None;
        }
        let means = CellMeans {
            rho_dust: d.rho / d.mass,
            rho_gas: gas.rho * inv_g,
            cs_gas: gamma_root * gas.cs * inv_g,
        };
        Some((drag::cell_eps(d.mass, gas.mass), laws[k].cell_time(&means)))
    })
}

/// What the solve on one gas particle hands back under the kernel coupling: the increment
/// (new − old mean) of its gas mean and of each fraction's mean — zero for a phase that
/// deposited nothing there — and each fraction's t_k* (+∞ where uncoupled).
#[derive(Clone, Copy, Debug)]
pub struct KernelIncrements<R> {
    pub dv: Vec3<R>,
    pub du: [Vec3<R>; MAX_FRACTIONS],
    pub t_stop: [R; MAX_FRACTIONS],
}

/// [`kernel_couple`] turned into the increments the particles receive (CPU and GPU alike).
#[inline(always)]
pub fn kernel_increments<R: Real>(
    gas: &Deposit<R>,
    dust: &[Deposit<R>],
    laws: &[StoppingLaw<R>],
    tau: R,
    gamma_root: R,
) -> KernelIncrements<R> {
    let zero = [R::ZERO; 3];
    let mut old = [zero; MAX_FRACTIONS];
    let c = kernel_couple(gas, dust, laws, tau, gamma_root, &mut old);
    let mut out = KernelIncrements {
        dv: zero,
        du: [zero; MAX_FRACTIONS],
        t_stop: c.t_stop,
    };
    if gas.mass > R::ZERO {
        out.dv = sub(c.v_new, scale(R::ONE / gas.mass, gas.mom));
    }
    let nf = dust.len().min(laws.len()).min(MAX_FRACTIONS);
    for f in 0..nf {
        if dust[f].mass > R::ZERO {
            out.du[f] = sub(c.u_new[f], old[f]);
        }
    }
    out
}

/// Σ_a w_qa Δ_a for a particle q from its stored row (gas particles `idx`, raw kernel values
/// `w` = W(r_qa, h_a)) and its normaliser `s` (0 when `s` = 0): the share of the gas particles'
/// increments `delta(a)` (new − old mean) that q receives.
#[inline(always)]
pub fn gather_rows<R: Real>(
    idx: &[u32],
    w: &[R],
    s: R,
    delta: impl Fn(usize) -> Vec3<R>,
) -> Vec3<R> {
    let mut acc = [R::ZERO; 3];
    if s <= R::ZERO {
        return acc;
    }
    for (&a, &w) in idx.iter().zip(w) {
        acc = axpy(acc, w / s, delta(a as usize));
    }
    acc
}
