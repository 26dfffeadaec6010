//! A disc snapshot in radial bins (method.md §D): each phase's surface density, mass-weighted
//! radial velocity and azimuthal velocity relative to Keplerian, beside the exact steady drift
//! computed from the bins' own ε, Stokes numbers and pressure gradient.
use crate::exact::drift::steady_drift_viscous;
use crate::io::{PhaseData, SnapshotData};
use crate::scene::{GasEos, ProblemCfg, Scene};

/// One phase in the bins: Σ (its particles' SPH density: Σ in 2D), ⟨v_R⟩, ⟨v_φ⟩ − v_K
/// (mass-weighted), and the exact steady
/// (v_R, v_φ − v_K) at the bin (NaN where it cannot be computed).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PhaseBins {
    pub name: String,
    pub sigma: Vec<f64>,
    pub v_r: Vec<f64>,
    pub dv_phi: Vec<f64>,
    pub exact_v_r: Vec<f64>,
    pub exact_dv_phi: Vec<f64>,
}

/// The disc in `r.len()` bins (bin centres `r`): the gas first, then each fraction.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DiscBins {
    pub r: Vec<f64>,
    pub phases: Vec<PhaseBins>,
}

/// The bins of a snapshot of a scene with a point mass and locally isothermal gas (`None`
/// otherwise), between the disc's edges (`[dustydisc]`) or the gas's extent.
pub fn disc_bins(snap: &SnapshotData, scene: &Scene, n_bins: usize) -> Option<DiscBins> {
    let a = Annuli::of(snap, scene, n_bins)?;
    let gas = snap.gas.as_ref()?;
    let mut phases = vec![PhaseBins {
        name: "gas".into(),
        ..a.bins(&gas.x, &gas.v, &gas.m, &gas.rho, &|_| true)
    }];
    let fractions = scene.fractions();
    if let Some(d) = &snap.dust {
        for k in 0..fractions.len() {
            let fr = d.fraction.as_deref();
            let keep = |i: usize| fr.is_none_or(|f| f[i] as usize == k);
            phases.push(PhaseBins {
                name: format!("dust fraction {k}"),
                ..a.bins(&d.x, &d.v, &d.m, &d.rho, &keep)
            });
        }
    }
    let exact = a.exact_drift(scene, gas, &phases);
    for (p, (vr, vp)) in phases.iter_mut().zip(exact) {
        p.exact_v_r = vr;
        p.exact_dv_phi = vp;
    }
    Some(DiscBins { r: a.r, phases })
}

/// The annuli a disc snapshot is binned in (centres `r`, `width` wide from `lo`), about the
/// point mass, with the locally isothermal gas's c_s and H.
struct Annuli {
    centre: [f64; 3],
    gm: f64,
    cs0: f64,
    q: f64,
    r_ref: f64,
    dim3: bool,
    lo: f64,
    width: f64,
    n_bins: usize,
    r: Vec<f64>,
}

impl Annuli {
    /// The annuli of a scene with a point mass and locally isothermal gas (`None` otherwise)
    /// between the disc's edges (`[dustydisc]`) or the gas's extent.
    fn of(snap: &SnapshotData, scene: &Scene, n_bins: usize) -> Option<Annuli> {
        let g = scene.gravity?;
        let GasEos::LocallyIsothermal { cs0, q, r_ref, .. } = scene.gas.eos else {
            return None;
        };
        let gas = snap.gas.as_ref()?;
        let mut a = Annuli {
            centre: g.position,
            gm: g.central_mass,
            cs0,
            q,
            r_ref,
            dim3: scene.dim() == 3,
            lo: 0.0,
            width: 0.0,
            n_bins: 0,
            r: Vec::new(),
        };
        let (lo, hi) = match &scene.problem {
            ProblemCfg::Dustydisc(d) => (d.r_in, d.r_out),
            _ => gas
                .x
                .iter()
                .map(|x| a.radius(x))
                .fold((f64::INFINITY, 0.0f64), |a, r| (a.0.min(r), a.1.max(r))),
        };
        // Bins at least two kernel supports wide (4 h, the median gas h): narrower ones alias
        // with the particles' rings and each bin's Σ jumps with the number of rings it holds.
        let mut hs: Vec<f64> = gas.h.iter().copied().filter(|h| h.is_finite()).collect();
        hs.sort_by(f64::total_cmp);
        let h_med = hs.get(hs.len() / 2).copied().unwrap_or(0.0);
        let n_bins = n_bins
            .min(((hi - lo) / (4.0 * h_med)).floor() as usize)
            .max(3);
        let width = (hi - lo) / n_bins as f64;
        a.r = (0..n_bins).map(|i| lo + (i as f64 + 0.5) * width).collect();
        (a.lo, a.width, a.n_bins) = (lo, width, n_bins);
        Some(a)
    }

    /// A position's cylindrical radius about the point mass.
    fn radius(&self, x: &[f64; 3]) -> f64 {
        let centre = self.centre;
        ((x[0] - centre[0]).powi(2) + (x[1] - centre[1]).powi(2)).sqrt()
    }

    /// The bin a position falls in (none outside the annuli).
    fn bin_of(&self, x: &[f64; 3]) -> Option<usize> {
        let b = ((self.radius(x) - self.lo) / self.width).floor();
        (b >= 0.0 && b < self.n_bins as f64).then_some(b as usize)
    }

    /// The locally isothermal sound speed at R.
    fn cs(&self, r: f64) -> f64 {
        self.cs0 * (r / self.r_ref).powf(-self.q)
    }

    /// The scale height H = c_s/Ω at R.
    fn height(&self, r: f64) -> f64 {
        self.cs(r) / (self.gm / r.powi(3)).sqrt()
    }

    /// One phase's Σ, ⟨v_R⟩ and ⟨v_φ⟩ − v_K per bin over its particles that `keep` takes.
    /// Sums per bin: mass, m v_R, m (v_φ − v_K), m ρ, and the mass the velocities are taken
    /// over. In 2D Σ is the mass-weighted mean of the particles' SPH density (a 2D density is
    /// Σ): counting masses per annulus would alias with the rings of the set-up (± a ring per
    /// bin). In 3D Σ is the annulus's mass over its area (bins ≥ 4h wide), and the velocities
    /// are those of the mid-disc, |z| < H/2 (H = c_s/Ω at the particle's R).
    fn bins(
        &self,
        xs: &[[f64; 3]],
        vs: &[[f64; 3]],
        ms: &[f64],
        rho: &[f64],
        keep: &dyn Fn(usize) -> bool,
    ) -> PhaseBins {
        let (centre, dim3) = (self.centre, self.dim3);
        let mut s = vec![[0.0f64; 5]; self.n_bins];
        for i in 0..xs.len() {
            let Some(b) = self.bin_of(&xs[i]).filter(|_| keep(i)) else {
                continue;
            };
            let (x, v) = (xs[i], vs[i]);
            let d = [x[0] - centre[0], x[1] - centre[1], x[2] - centre[2]];
            let rr = (d[0] * d[0] + d[1] * d[1]).sqrt();
            s[b][0] += ms[i];
            s[b][3] += ms[i] * rho[i];
            if dim3 && d[2].abs() >= 0.5 * self.height(rr) {
                continue;
            }
            let vk = (self.gm / rr).sqrt();
            let vr = (d[0] * v[0] + d[1] * v[1]) / rr;
            let vphi = (d[0] * v[1] - d[1] * v[0]) / rr;
            s[b][1] += ms[i] * vr;
            s[b][2] += ms[i] * (vphi - vk);
            s[b][4] += ms[i];
        }
        let per = |b: &[f64; 5], k: usize, of: usize| {
            if b[of] > 0.0 {
                b[k] / b[of]
            } else {
                f64::NAN
            }
        };
        let sigma = s
            .iter()
            .zip(&self.r)
            .map(|(b, rc)| {
                if dim3 {
                    b[0] / (2.0 * std::f64::consts::PI * rc * self.width)
                } else {
                    per(b, 3, 0)
                }
            })
            .collect();
        PhaseBins {
            sigma,
            v_r: s.iter().map(|b| per(b, 1, 4)).collect(),
            dv_phi: s.iter().map(|b| per(b, 2, 4)).collect(),
            ..Default::default()
        }
    }

    /// Bin i's Σ over the pressure's: 1 in 2D (P = c_s² Σ_g), the midplane's √(2π) H in 3D
    /// (P = c_s² Σ_g/(√(2π) H)).
    fn mid(&self, i: usize) -> f64 {
        if self.dim3 {
            (2.0 * std::f64::consts::PI).sqrt() * self.height(self.r[i])
        } else {
            1.0
        }
    }

    /// (R, ln R, ln P) of every gas particle (3D: of the mid-disc, |z| < H/2).
    fn pressure_points(&self, gas: &PhaseData) -> Vec<(f64, f64, f64)> {
        gas.x
            .iter()
            .zip(&gas.rho)
            .filter_map(|(x, rho)| {
                let rr = self.radius(x);
                let z = x[2] - self.centre[2];
                (rr > 0.0 && *rho > 0.0 && !(self.dim3 && z.abs() >= 0.5 * self.height(rr)))
                    .then(|| (rr, rr.ln(), (self.cs(rr).powi(2) * rho).ln()))
            })
            .collect()
    }

    /// The gas's viscous inflow per bin with the disc viscosity (`sph.alpha_ss`,
    /// ν = α_SS c_s²/Ω): v_visc = −3/(Σ√R) ∂(νΣ√R)/∂R (Lynden-Bell & Pringle 1974), ∂/∂R by
    /// differences of the bins (central inside, one-sided at the ends); 0 without it.
    fn viscous_inflow(&self, scene: &Scene, sigma: &[f64]) -> Vec<f64> {
        let (r, n_bins) = (&self.r, self.n_bins);
        let alpha_ss = scene.sph.viscosity.and_then(|v| v.alpha_ss).unwrap_or(0.0);
        let torque: Vec<f64> = (0..n_bins)
            .map(|i| {
                let omega = (self.gm / r[i].powi(3)).sqrt();
                alpha_ss * self.cs(r[i]).powi(2) / omega * sigma[i] * r[i].sqrt()
            })
            .collect();
        let v_visc = |i: usize| {
            if alpha_ss == 0.0 || n_bins < 2 {
                return 0.0;
            }
            let (a, b) = (i.saturating_sub(1), (i + 1).min(n_bins - 1));
            let d = (torque[b] - torque[a]) / (r[b] - r[a]);
            -3.0 * d / (sigma[i] * r[i].sqrt())
        };
        (0..n_bins).map(v_visc).collect()
    }

    /// Each phase's exact steady drift (v_R, v_φ − v_K) per bin from the bins' own ε, St and
    /// d ln P/d ln R (ε = Σ_k/Σ_g, the column's), NaN where it cannot be computed.
    fn exact_drift(
        &self,
        scene: &Scene,
        gas: &PhaseData,
        phases: &[PhaseBins],
    ) -> Vec<(Vec<f64>, Vec<f64>)> {
        let (r, n_bins, width) = (&self.r, self.n_bins, self.width);
        let fractions = scene.fractions();
        let ln_p: Vec<f64> = (0..n_bins)
            .map(|i| (self.cs(r[i]).powi(2) * phases[0].sigma[i] / self.mid(i)).ln())
            .collect();
        let pressure_points = self.pressure_points(gas);
        let nf = phases.len() - 1;
        let v_visc = self.viscous_inflow(scene, &phases[0].sigma);
        let mut exact = vec![(vec![f64::NAN; n_bins], vec![f64::NAN; n_bins]); nf + 1];
        for i in 0..n_bins {
            // d ln P/d ln R: the least-squares slope of the gas particles' own ln P (c_s² ρ,
            // in 3D of the mid-disc's) against ln R within a bin width of the bin's centre, a
            // local linear fit whose error is second order in the width; the binned profile
            // where no particle is near.
            let dlnp = local_slope(&pressure_points, r[i], width).unwrap_or_else(|| {
                let (a, b) = (i.saturating_sub(2), (i + 2).min(n_bins - 1));
                let pts: Vec<(f64, f64)> = (a..=b)
                    .map(|j| (r[j].ln(), ln_p[j]))
                    .filter(|(_, y)| y.is_finite())
                    .collect();
                slope(&pts).unwrap_or(f64::NAN)
            });
            let sg = phases[0].sigma[i];
            let omega = (self.gm / r[i].powi(3)).sqrt();
            let vk = omega * r[i];
            let c = self.cs(r[i]);
            let eta_vk = -0.5 * c * c / vk * dlnp;
            let eps: Vec<f64> = (1..=nf).map(|k| phases[k].sigma[i] / sg).collect();
            let st: Vec<f64> = fractions
                .iter()
                .zip(&eps)
                .map(|(f, e)| {
                    omega
                        * f.law
                            .stopping_time(sg / self.mid(i), e * sg / self.mid(i), c)
                })
                .collect();
            let drift = steady_drift_viscous(&eps, &st, v_visc[i] / eta_vk);
            if let Some(s) = drift.filter(|_| eta_vk.is_finite()) {
                exact[0].0[i] = s.gas.0 * eta_vk;
                exact[0].1[i] = s.gas.1 * eta_vk;
                for (k, u) in s.dust.iter().enumerate() {
                    exact[k + 1].0[i] = u.0 * eta_vk;
                    exact[k + 1].1[i] = u.1 * eta_vk;
                }
            }
        }
        exact
    }
}

/// The least-squares slope of (x, y) points (`None` below two points or with no spread).
fn slope(pts: &[(f64, f64)]) -> Option<f64> {
    let n = pts.len() as f64;
    if pts.len() < 2 {
        return None;
    }
    let (mx, my) = pts
        .iter()
        .fold((0.0, 0.0), |s, p| (s.0 + p.0 / n, s.1 + p.1 / n));
    let (sxy, sxx) = pts.iter().fold((0.0, 0.0), |s, p| {
        (s.0 + (p.0 - mx) * (p.1 - my), s.1 + (p.0 - mx) * (p.0 - mx))
    });
    (sxx > 0.0).then(|| sxy / sxx)
}

/// d ln P/d ln R at `rc` from the particles' (R, ln R, ln P) within `half` of it.
fn local_slope(points: &[(f64, f64, f64)], rc: f64, half: f64) -> Option<f64> {
    let near: Vec<(f64, f64)> = points
        .iter()
        .filter(|p| (p.0 - rc).abs() < half)
        .map(|p| (p.1, p.2))
        .collect();
    if near.len() < 8 {
        return None;
    }
    slope(&near)
}

/// The bins as CSV: R, then per phase Σ, v_R, v_φ − v_K and the exact pair.
pub fn disc_csv(d: &DiscBins) -> String {
    let mut out = String::from("R");
    for p in &d.phases {
        let n = p.name.replace(' ', "_");
        for c in ["sigma", "v_R", "dv_phi", "v_R_exact", "dv_phi_exact"] {
            out.push_str(&format!(",{n}_{c}"));
        }
    }
    out.push('\n');
    for i in 0..d.r.len() {
        out.push_str(&format!("{:e}", d.r[i]));
        for p in &d.phases {
            for v in [
                p.sigma[i],
                p.v_r[i],
                p.dv_phi[i],
                p.exact_v_r[i],
                p.exact_dv_phi[i],
            ] {
                out.push_str(&format!(",{v:e}"));
            }
        }
        out.push('\n');
    }
    out
}
