//! A 2D razor-thin dusty disc about the `[gravity]` point mass (method.md §D): Σ(R) = Σ_ref
//! (R/r_ref)^(−p) (1 − √(r_in/R))/(1 − √(r_in/r_ref)) between r_in and r_out, locally
//! isothermal gas, and every phase placed on the steady drift of gas and N species
//! (host/exact/drift.rs) from its local ε, St and pressure gradient, so the run starts in
//! equilibrium.
//!
//! Particles sit on rings: each ring is one local spacing Δ(R) = √(m/Σ(R)) wide, holds
//! round(2πR/Δ) gas particles at its mid-radius (alternate rings turned by half a spacing),
//! and its particles share the ring's mass ∫2πRΣ dR; each dust fraction the same rings, turned
//! by half a spacing from the gas, with ε_k times the gas's masses.
use super::*;
use crate::exact::drift::steady_drift;
use crate::scene::{DiscCfg, DustStart, GasEos};
use dustsph_device::sub;

pub(super) fn build(scene: &Scene, d: &DiscCfg) -> Result<Setup, SetupError> {
    let p = Profile::of(scene, d)?;
    let size = Sizing::of(&p)?;
    let rings = rings(d, &|r| p.sigma(r), &|r| p.local_spacing(size.m, r));
    if rings.is_empty() {
        return Err(SetupError {
            key: "sph.n".into(),
            msg: "no ring of particles fits between dustydisc.r_in and r_out; raise sph.n".into(),
        });
    }
    let (lattice, gas) = Lattice::lay(&p, &rings, size.m);
    let h = smoothing_length(scene, size.spacing);
    let res = Resolution {
        p: &p,
        m: size.m,
        h,
    };
    let unresolved = res.unresolved(&rings, size.key)?;
    let domain = crate::grid::Domain {
        dim: p.dim,
        periodic: [None; 3],
    };
    let (mut gas, pull, relax_note) = balance(&p, gas, &lattice, h, domain, size.spacing)?;
    // The leapfrog's circular orbit at its synchronised times is slower than the continuous
    // balance by (Ωτ)²/8 (method.md §D, "The set-up's ringing"): started on the continuous
    // one, every ring would ring at 2 (Ωτ)²/8 v_K. Every particle starts on the discrete orbit
    // of the run's first step τ (`orbit_factor`).
    let tau = match scene.time.integrator {
        crate::scene::Integrator::Kdk => first_step(scene, &gas, h, domain)?,
        crate::scene::Integrator::FirstOrder => 0.0,
    };
    let sums = lattice.sums(&gas, &pull, p.centre);
    let unstable = rayleigh_unstable(&lattice.layers, &sums, p.gm);
    let (mut dust, layer_drift) = place_dust(&p, &lattice.layers, &sums, tau);
    gas.v = gas_velocities(&p, &gas, &lattice, &sums, &layer_drift, tau);
    let ng = gas.len() as u64;
    let mut next = ng;
    for ph in &mut dust {
        ph.id = (next..next + ph.len() as u64).collect();
        next += ph.len() as u64;
    }
    let report = Report {
        rings: &rings,
        layers: lattice.layers.len(),
        ng,
        size: &size,
        unresolved,
        relax_note,
        tau,
        unstable,
    };
    let notes = report.notes(&res);
    let mut su = Setup::at_start(
        gas_phase(gas, None),
        dust,
        h,
        domain,
        size.spacing,
        2.0 * d.r_out,
    );
    su.notes.extend(notes);
    Ok(su)
}

/// The disc's analytic profile about its point mass: Σ, c_s, Ω, H and the gas's density.
struct Profile<'a> {
    scene: &'a Scene,
    d: &'a DiscCfg,
    cs0: f64,
    q: f64,
    r_ref: f64,
    gm: f64,
    centre: [f64; 3],
    dim: u32,
}

impl<'a> Profile<'a> {
    /// The scene's disc: its gas must be locally isothermal, about a point mass.
    fn of(scene: &'a Scene, d: &'a DiscCfg) -> Result<Profile<'a>, SetupError> {
        let GasEos::LocallyIsothermal { cs0, q, r_ref, .. } = scene.gas.eos else {
            return Err(SetupError {
                key: "gas.eos".into(),
                msg: "the disc's gas is locally isothermal".into(),
            });
        };
        let grav = scene.gravity.ok_or_else(|| SetupError {
            key: "gravity".into(),
            msg: "the disc needs a point mass".into(),
        })?;
        Ok(Profile {
            scene,
            d,
            cs0,
            q,
            r_ref,
            gm: grav.central_mass,
            centre: grav.position,
            dim: scene.dim(),
        })
    }

    /// The surface density Σ(R).
    fn sigma(&self, r: f64) -> f64 {
        self.d.sigma_ref * self.d.sigma_shape(r, self.r_ref)
    }

    /// The locally isothermal sound speed c_s(R).
    fn cs(&self, r: f64) -> f64 {
        self.cs0 * (r / self.r_ref).powf(-self.q)
    }

    /// The Keplerian angular speed Ω(R) in the midplane.
    fn omega(&self, r: f64) -> f64 {
        (self.gm / (r * r * r)).sqrt()
    }

    /// The scale height H = c_s/Ω of the 3D disc.
    fn height(&self, r: f64) -> f64 {
        self.cs(r) / self.omega(r)
    }

    /// The midplane density Σ/(√(2π) H) of the 3D disc.
    fn rho_mid(&self, r: f64) -> f64 {
        self.sigma(r) / ((2.0 * std::f64::consts::PI).sqrt() * self.height(r))
    }

    /// The gas's density at a layer's (R, z): Σ in 2D, the Gaussian in 3D.
    fn rho_at(&self, r: f64, z: f64) -> f64 {
        if self.dim == 3 {
            self.rho_mid(r) * (-0.5 * z * z / (self.height(r) * self.height(r))).exp()
        } else {
            self.sigma(r)
        }
    }

    /// The local spacing of particles of mass `m` at R: √(m/Σ) in 2D, the midplane's
    /// (m/ρ)^{1/3} in 3D.
    fn local_spacing(&self, m: f64, r: f64) -> f64 {
        if self.dim == 3 {
            (m / self.rho_mid(r)).cbrt()
        } else {
            (m / self.sigma(r)).sqrt()
        }
    }

    /// [`kepler_and_slope`] at (R, z) with this disc's H(R) and Σ's slope.
    fn kepler(&self, r: f64, z: f64) -> (f64, f64) {
        kepler_and_slope(self.gm, r, z, self.height(r), self.q, |r: f64| {
            self.d.dln_sigma(r)
        })
    }
}

/// The particle mass, the disc's mass and reference spacing, and the key that sets them.
struct Sizing {
    disc_mass: f64,
    m: f64,
    spacing: f64,
    key: &'static str,
}

impl Sizing {
    /// The particle mass: the disc's over `dustydisc.particles`, or from spacing 1/n at r_ref
    /// (in the midplane in 3D): Σ_ref/n² or ρ_mid,ref/n³; refused when it makes too many.
    fn of(p: &Profile) -> Result<Sizing, SetupError> {
        let (scene, d) = (p.scene, p.d);
        let disc_mass = d.mass_between(d.r_in, d.r_out, p.r_ref, d.sigma_ref);
        let m = match d.particles {
            Some(n) => disc_mass / n as f64,
            None => {
                let s = 1.0 / scene.sph.n as f64;
                if p.dim == 3 {
                    p.rho_mid(p.r_ref) * s.powi(3)
                } else {
                    d.sigma_ref * s * s
                }
            }
        };
        // The reference spacing (for h): the local one at r_ref.
        let spacing = p.local_spacing(m, p.r_ref);
        let key = match d.particles {
            Some(_) => "dustydisc.particles",
            None => "sph.n",
        };
        super::check_size(
            disc_mass / m,
            1 + scene.n_fractions(),
            key,
            &["dustydisc.r_out"],
        )?;
        Ok(Sizing {
            disc_mass,
            m,
            spacing,
            key,
        })
    }
}

/// The rings' layers, and each gas particle's layer by its id (the relaxation's engine sorts
/// the particles).
struct Lattice {
    layers: Vec<Layer>,
    layer_of: Vec<usize>,
}

impl Lattice {
    /// The layers and the gas on them: each ring holds columns of n_z particles at the
    /// Gaussian's quantiles (one layer, at z = 0, in 2D), alternate rings turned by half a
    /// spacing.
    fn lay(p: &Profile, rings: &[Ring], m: f64) -> (Lattice, Phase) {
        let mut layers: Vec<Layer> = Vec::new();
        for (i, ring) in rings.iter().enumerate() {
            let (r, hz) = (ring.r, p.height(ring.r));
            let n_z = if p.dim == 3 {
                ((ring.mass / (ring.count as f64 * m)).round() as usize).max(1)
            } else {
                1
            };
            for k in 0..n_z {
                layers.push(Layer {
                    r,
                    z: if p.dim == 3 {
                        hz * normal_quantile((k as f64 + 0.5) / n_z as f64)
                    } else {
                        0.0
                    },
                    count: ring.count,
                    turn: if i % 2 == 0 { 0.0 } else { 0.5 },
                    mass: ring.mass / (ring.count * n_z) as f64,
                });
            }
        }
        let mut gas = Phase::default();
        let mut layer_of: Vec<usize> = Vec::new();
        for (l, ly) in layers.iter().enumerate() {
            place(
                &mut gas,
                ly,
                0.0,
                p.centre,
                [0.0; 3],
                ly.mass,
                p.rho_at(ly.r, ly.z),
            );
            layer_of.extend(std::iter::repeat_n(l, ly.count));
        }
        gas.id = (0..gas.len() as u64).collect();
        (Lattice { layers, layer_of }, gas)
    }

    /// The layer of the gas's particle `i` (by its id).
    fn layer(&self, gas: &Phase, i: usize) -> usize {
        self.layer_of[gas.id[i] as usize]
    }

    /// Each layer's (Σ height above the centre, Σ pull, particles): the layers' mean height
    /// and, from the mean pull, η v_K = (v_K² − v_φ²)/(2 v_K) of the balance.
    fn sums(&self, gas: &Phase, pull: &[f64], centre: [f64; 3]) -> Vec<(f64, f64, usize)> {
        let mut sums = vec![(0.0, 0.0, 0usize); self.layers.len()];
        for i in 0..gas.len() {
            let s = &mut sums[self.layer(gas, i)];
            s.0 += gas.x[i][2] - centre[2];
            s.1 += pull[i];
            s.2 += 1;
        }
        sums
    }
}

/// The kernel's resolution of the scale height, h/H.
struct Resolution<'a> {
    p: &'a Profile<'a>,
    m: f64,
    h: f64,
}

impl Resolution<'_> {
    /// h/H of the midplane at R (variable h: the h of the set-up's density).
    fn h_over_h(&self, r: f64) -> f64 {
        let p = self.p;
        let hr = match p.scene.sph.smoothing.variable_hfact() {
            Some(hf) => {
                dustsph_device::kernel::h_of_density(self.m, p.rho_at(r, 0.0), hf, p.dim, self.h)
            }
            None => self.h,
        };
        hr / p.height(r)
    }

    /// The share of the disc's mass in rings with h/H > 1: refused over half (a disc whose
    /// scale height the kernel does not resolve is no disc: its pressure support, drift and
    /// settling are set by h, not by H).
    fn unresolved(&self, rings: &[Ring], size_key: &str) -> Result<f64, SetupError> {
        let unresolved: f64 = rings
            .iter()
            .filter(|g| self.h_over_h(g.r) > 1.0)
            .map(|g| g.mass)
            .fold(0.0, |a, m| a + m) // from +0: an empty f64 sum is −0
            / rings.iter().map(|g| g.mass).sum::<f64>();
        if unresolved > 0.5 {
            return Err(SetupError {
                key: size_key.into(),
                msg: format!(
                    "h/H > 1 over {:.0} % of the disc's mass (h/H {:.2} at r_ref): the kernel \
                     does not resolve the scale height; raise {size_key}",
                    100.0 * unresolved,
                    self.h_over_h(self.p.r_ref)
                ),
            });
        }
        Ok(unresolved)
    }
}

/// Each gas particle's radial pull −A_R (gravity and pressure) per unit R, v_φ² = R·(−A_R)
/// at balance: from the run's own SPH forces when relaxed (the gas returned relaxed, with the
/// relaxation's note), else from the analytic profile.
fn balance(
    p: &Profile,
    gas: Phase,
    lattice: &Lattice,
    h: f64,
    domain: crate::grid::Domain,
    spacing: f64,
) -> Result<(Phase, Vec<f64>, String), SetupError> {
    if p.d.relax {
        let (gas, acc, note) = relax(p.scene, gas, h, domain, spacing)?;
        let pull = (0..gas.len())
            .map(|i| {
                let x = sub(gas.x[i], p.centre);
                let r = x[0].hypot(x[1]);
                -(x[0] * acc[i][0] + x[1] * acc[i][1]) / (r * r)
            })
            .collect();
        Ok((gas, pull, note))
    } else {
        let pull = (0..gas.len())
            .map(|i| {
                let ly = &lattice.layers[lattice.layer(&gas, i)];
                let (vk, dlnp) = p.kepler(ly.r, ly.z);
                (vk * vk + p.cs(ly.r).powi(2) * dlnp) / (ly.r * ly.r)
            })
            .collect();
        Ok((gas, pull, String::new()))
    }
}

/// The factor the leapfrog's circular orbit at its synchronised times, for the first step τ,
/// is below the continuous balance's v_φ: 1 − (Ωτ)²/8.
fn orbit_factor(tau: f64, r: f64, vphi: f64) -> f64 {
    let w = vphi * tau / r;
    1.0 - w * w / 8.0
}

/// The dust phases on the gas's layers at their mean heights (turned by half a spacing, with
/// ε_k times the gas's masses), each on the layer's steady drift of gas and species from its
/// local ε and St (Keplerian without `dust_velocity = "drift"`); and each layer's drift, for
/// the gas's back-reaction.
fn place_dust(
    p: &Profile,
    layers: &[Layer],
    sums: &[(f64, f64, usize)],
    tau: f64,
) -> (Vec<Phase>, Vec<Option<(f64, f64)>>) {
    let (gm, centre) = (p.gm, p.centre);
    let fr = p.scene.fractions();
    let eps: Vec<f64> = fr.iter().map(|f| f.eps).collect();
    let drift_start = p.d.dust_velocity == DustStart::Drift;
    let mut dust: Vec<Phase> = fr.iter().map(|_| Phase::default()).collect();
    let mut layer_drift = Vec::with_capacity(layers.len());
    for (l, ly) in layers.iter().enumerate() {
        let (r, c) = (ly.r, p.cs(ly.r));
        let (z, mean_pull) = (sums[l].0 / sums[l].2 as f64, sums[l].1 / sums[l].2 as f64);
        let (vk, _) = p.kepler(r, z);
        let eta_vk = (vk * vk - r * r * mean_pull) / (2.0 * vk);
        let rho_g = p.rho_at(r, z);
        let st: Vec<f64> = fr
            .iter()
            .map(|f| p.omega(r) * f.law.stopping_time(rho_g, f.eps * rho_g, c))
            .collect();
        let drift = (!fr.is_empty() && drift_start)
            .then(|| steady_drift(&eps, &st))
            .flatten();
        for (j, ph) in dust.iter_mut().enumerate() {
            let v = match &drift {
                Some(s) => {
                    let (ur, up) = s.dust[j];
                    // The slow root of z̈ = −Ω_z² z − ż/t: the settling mode, ż ≈ −z Ω St for
                    // St ≪ 1; none for St ≥ 1/2 (the grains oscillate about the midplane).
                    let t = st[j] / p.omega(r);
                    let omega_z2 = gm / (r * r + z * z).powf(1.5);
                    let disc = 1.0 - 4.0 * omega_z2 * t * t;
                    let vz = if disc > 0.0 {
                        z * (disc.sqrt() - 1.0) / (2.0 * t)
                    } else {
                        0.0
                    };
                    let vphi = vk + up * eta_vk;
                    [ur * eta_vk, vphi * orbit_factor(tau, r, vphi), vz]
                }
                None => [0.0, vk * orbit_factor(tau, r, vk), 0.0],
            };
            let at = Layer { z, ..*ly };
            place(ph, &at, 0.5, centre, v, eps[j] * ly.mass, eps[j] * rho_g);
        }
        layer_drift.push(drift.map(|s| s.gas));
    }
    (dust, layer_drift)
}

/// The gas's velocities: its layer's balance v_φ = √(R² ⟨pull⟩) (a layer is one ring at one
/// height: axisymmetric, so its mean is the balance without the lattice's particle noise),
/// plus the dust's back-reaction (the steady drift's gas velocities less the pressure support
/// −η v_K they contain), on the leapfrog's orbit.
fn gas_velocities(
    p: &Profile,
    gas: &Phase,
    lattice: &Lattice,
    sums: &[(f64, f64, usize)],
    layer_drift: &[Option<(f64, f64)>],
    tau: f64,
) -> Vec<[f64; 3]> {
    (0..gas.len())
        .map(|i| {
            // The layer by particle id: the relaxation's engine sorted the particles.
            let l = lattice.layer(gas, i);
            let x = sub(gas.x[i], p.centre);
            let r = x[0].hypot(x[1]);
            let mean_pull = sums[l].1 / sums[l].2 as f64;
            let (vk, _) = p.kepler(lattice.layers[l].r, x[2]);
            let vphi_p = (r * r * mean_pull).max(0.0).sqrt();
            let eta_vk = (vk * vk - vphi_p * vphi_p) / (2.0 * vk);
            let (vr, vphi) = match layer_drift[l] {
                Some((gr, gp)) => (gr * eta_vk, vphi_p + (gp + 1.0) * eta_vk),
                None => (0.0, vphi_p),
            };
            let vphi = vphi * orbit_factor(tau, r, vphi);
            let (s, co) = (x[1] / r, x[0] / r);
            [vr * co - vphi * s, vr * s + vphi * co, 0.0]
        })
        .collect()
}

/// What the set-up measured, for the run's log.
struct Report<'a> {
    rings: &'a [Ring],
    layers: usize,
    ng: u64,
    size: &'a Sizing,
    unresolved: f64,
    relax_note: String,
    tau: f64,
    unstable: Vec<(f64, f64)>,
}

impl Report<'_> {
    /// The disc's lines for the run's log: its rings and resolution, the first step's orbit,
    /// the midplane Stokes numbers and any Rayleigh-unstable rings.
    fn notes(&self, res: &Resolution) -> Vec<String> {
        let p = res.p;
        let mut notes = vec![self.summary(res)];
        if self.tau > 0.0 {
            notes.push(format!(
                "disc: every particle on the leapfrog's circular orbit for the first step τ = {:.4e} \
                 ((Ωτ)²/8 below the continuous balance: {:.2e} of v_φ at r_ref)",
                self.tau,
                1.0 - orbit_factor(self.tau, p.r_ref, (p.gm / p.r_ref).sqrt())
            ));
        }
        if let Some(stokes) = self.stokes(p) {
            notes.push(stokes);
        }
        if !self.unstable.is_empty() {
            notes.push(self.rayleigh(p));
        }
        notes
    }

    /// The disc's rings, layers, particles, H/R and h/H (and the relaxation's note).
    fn summary(&self, res: &Resolution) -> String {
        let (p, d, rings) = (res.p, res.p.d, self.rings);
        let n_rings = rings.len();
        let resolution = format!(
            "; h/H {:.2} at the inner ring, {:.2} at r_ref, {:.2} at the outer, > 1 over {:.0} % \
             of the mass; disc mass {:.4e}, gas particle mass {:.4e}",
            res.h_over_h(rings[0].r),
            res.h_over_h(p.r_ref),
            res.h_over_h(rings[n_rings - 1].r),
            100.0 * self.unresolved,
            self.size.disc_mass,
            self.size.m
        );
        let drift_start = d.dust_velocity == DustStart::Drift;
        format!(
            "disc: {n_rings} rings, {} layers, {} gas particles between R = {} and {}, H/R = {:.4} at r_ref = {}{resolution}{}{}",
            self.layers,
            self.ng,
            d.r_in,
            d.r_out,
            p.cs0 / (p.gm / p.r_ref).sqrt(),
            p.r_ref,
            self.relax_note,
            if drift_start { "" } else { "; dust on Keplerian orbits (no drift)" }
        )
    }

    /// Each grain's Stokes number in the midplane at the inner ring, r_ref and the outer ring
    /// (none without dust).
    fn stokes(&self, p: &Profile) -> Option<String> {
        let (rings, r_ref) = (self.rings, p.r_ref);
        let n_rings = rings.len();
        let stokes: Vec<String> = p
            .scene
            .fractions()
            .iter()
            .enumerate()
            .map(|(k, f)| {
                let st = |r: f64| {
                    let rho = p.rho_at(r, 0.0);
                    p.omega(r) * f.law.stopping_time(rho, f.eps * rho, p.cs(r))
                };
                format!(
                    "fraction {k} (ε {:.3e}): St {:.3e} / {:.3e} / {:.3e}",
                    f.eps,
                    st(rings[0].r),
                    st(r_ref),
                    st(rings[n_rings - 1].r)
                )
            })
            .collect();
        (!stokes.is_empty()).then(|| {
            format!(
                "disc: midplane Stokes numbers at R = {:.4} / {r_ref} / {:.4}: {}",
                rings[0].r,
                rings[n_rings - 1].r,
                stokes.join("; ")
            )
        })
    }

    /// The Rayleigh-unstable rings. Rings inside an edge damping zone have their radial
    /// motion damped: said per ring, and the line is a note, not a warning, when every such
    /// ring is in a zone.
    fn rayleigh(&self, p: &Profile) -> String {
        let pm = p.scene.gravity.map(|g| g.point_mass()).unwrap_or_default();
        let at: Vec<String> = self
            .unstable
            .iter()
            .map(|(r, g)| match pm.damp_weight(*r) {
                0.0 => format!("{r:.4} ({g:.2})"),
                w => format!("{r:.4} ({g:.2}; in a damping zone, weight {w:.2})"),
            })
            .collect();
        let held = self.unstable.iter().all(|(r, _)| pm.damp_weight(*r) > 0.0);
        format!(
            "{}: disc: R v_φ falls outward at R = {} (in brackets the growth rate of a \
             displacement there over Ω: Rayleigh-unstable rings, an SPH edge's pressure gradient \
             acting over h; method.md §D, \"The discs' edges\")",
            if held { "note" } else { "warning" },
            at.join(", ")
        )
    }
}

/// The rings where the specific angular momentum of the balance falls outward (Rayleigh:
/// (R v_φ)² must grow with R), each as (R, γ/Ω): R the outer ring of a falling pair, γ the
/// growth rate of a displacement there, γ² = −κ² = −d(R v_φ)²/dR / R³, over Ω² = GM/R³. A
/// ring's (R v_φ)² is the mean over its layers of R⁴ ⟨pull⟩. An SPH edge has a pressure
/// gradient of c_s²/h over one h, not over H, and where h < H the rotation that balances it
/// breaks this (method.md §D, "The discs' edges").
fn rayleigh_unstable(layers: &[Layer], sums: &[(f64, f64, usize)], gm: f64) -> Vec<(f64, f64)> {
    let mut rings: Vec<(f64, f64, usize)> = Vec::new(); // (R, Σ (R v_φ)², layers)
    for (ly, s) in layers.iter().zip(sums) {
        let j2 = ly.r.powi(4) * s.1 / s.2 as f64;
        match rings.last_mut() {
            Some(last) if last.0 == ly.r => {
                last.1 += j2;
                last.2 += 1;
            }
            _ => rings.push((ly.r, j2, 1)),
        }
    }
    rings
        .windows(2)
        .filter_map(|w| {
            let fall = w[0].1 / w[0].2 as f64 - w[1].1 / w[1].2 as f64;
            (fall > 0.0).then(|| (w[1].0, (fall / (w[1].0 - w[0].0) / gm).sqrt()))
        })
        .collect()
}

/// One layer of a ring: `count` particles of mass `mass` at radius `r`, height `z`, angles
/// 2π(j + turn)/count.
#[derive(Debug, Clone, Copy)]
struct Layer {
    r: f64,
    z: f64,
    count: usize,
    turn: f64,
    mass: f64,
}

/// Append a layer's particles to `ph` (turned by `shift` spacings more), moving with the
/// cylindrical velocity `v` = (v_R, v_φ, v_z).
fn place(ph: &mut Phase, ly: &Layer, shift: f64, c: [f64; 3], v: [f64; 3], m: f64, rho: f64) {
    for j in 0..ly.count {
        let phi = 2.0 * std::f64::consts::PI * (j as f64 + ly.turn + shift) / ly.count as f64;
        let (s, co) = phi.sin_cos();
        ph.x.push([c[0] + ly.r * co, c[1] + ly.r * s, c[2] + ly.z]);
        ph.v.push([v[0] * co - v[1] * s, v[0] * s + v[1] * co, v[2]]);
        ph.m.push(m);
        ph.rho.push(rho);
    }
}

/// The Keplerian speed at (R, z) about the point mass, and d ln P/d ln R there for P = c_s² ρ
/// with ρ ∝ Σ/H e^{−z²/2H²}, H ∝ R^{3/2−q} (at z = 0 in 2D: d ln Σ/d ln R − 2q).
fn kepler_and_slope(
    gm: f64,
    r: f64,
    z: f64,
    hz: f64,
    q: f64,
    dln_sigma: impl Fn(f64) -> f64,
) -> (f64, f64) {
    let vk = (gm * r * r / (r * r + z * z).powf(1.5)).sqrt();
    let vertical = if hz > 0.0 && z != 0.0 {
        (1.5 - q) * (z * z / (hz * hz) - 1.0)
    } else {
        0.0
    };
    (vk, dln_sigma(r) - 2.0 * q + vertical)
}

/// The run's first step τ for this gas (at rest, as the balance was measured): the step
/// planner's rule on the gas's own forces with the scene's physics (edge zones included). The
/// dust adds no limit the gas has not (the same pull; IDIC no drag limit).
fn first_step(
    scene: &Scene,
    gas: &Phase,
    h: f64,
    domain: crate::grid::Domain,
) -> Result<f64, SetupError> {
    let fail = |e: String| SetupError {
        key: "dustydisc".into(),
        msg: format!("the disc's first step could not be measured: {e}"),
    };
    let mut st = State {
        t: 0.0,
        step: 0,
        gas: gas_phase(gas.clone(), None),
        dust: Vec::new(),
    };
    let forces = crate::step::backend::Backend::new(
        crate::step::backend::DeviceChoice::Cpu,
        gas_physics(scene, h, domain),
        &mut st,
    )
    .and_then(|mut eng| eng.forces())
    .map_err(|e| fail(e.to_string()))?;
    crate::step::timestep::StepPlanner::new(&scene.time, h)
        .plan(&forces, f64::INFINITY, 0.0, 0, scene.time.t_end)
        .map(|plan| plan.dt_free)
        .map_err(|e| fail(format!("{e:?}")))
}

/// The scene's physics for the gas alone (no drag, no accretion): the set-up's measurements.
fn gas_physics(scene: &Scene, h: f64, domain: crate::grid::Domain) -> crate::step::Physics {
    let mut phys = crate::step::Physics::from_scene(scene, h, domain);
    phys.laws.clear();
    phys.accretion_radius = 0.0;
    phys
}

/// Iterations of the vertical relaxation at most, and when it has converged: the rms of the
/// gas's vertical acceleration below this share of the rms of the star's vertical pull.
const RELAX_ITERATIONS: usize = 200;
const RELAX_TOL: f64 = 0.02;
/// Seconds between the balance's progress lines.
const RELAX_REPORT_SECONDS: f64 = 10.0;
/// A relaxation move: κ h² A_z/c_s² (at most a tenth of a spacing).
const RELAX_KAPPA: f64 = 0.25;
/// The share of its last move a particle keeps (heavy-ball momentum).
const RELAX_MOMENTUM: f64 = 0.6;

/// The gas alone under the run's own SPH forces (its EOS, kernel, h, gradient and the point
/// mass): in 3D its heights moved down the vertical force until it balances (the radii and
/// angles kept: Σ(R) stays as set), then every particle's acceleration for the rotation.
/// Returns the gas, its accelerations (in its order) and a note for the run's log.
fn relax(
    scene: &Scene,
    gas: Phase,
    h: f64,
    domain: crate::grid::Domain,
    spacing: f64,
) -> Result<(Phase, Vec<[f64; 3]>, String), SetupError> {
    let fail = |e: String| SetupError {
        key: "dustydisc.relax".into(),
        msg: format!("the disc's gas could not be balanced: {e}"),
    };
    let mut phys = gas_physics(scene, h, domain);
    // The balance is measured at rest: no zone damping.
    phys.gravity.damp_per_omega = 0.0;
    let dim = domain.dim;
    let mut moved = vec![0.0; gas.len()];
    let mut g = gas;
    // The best balance so far: (residual, gas, accelerations, iteration).
    let mut best: Option<(f64, Phase, Vec<[f64; 3]>, usize)> = None;
    let done = |best: Option<(f64, Phase, Vec<[f64; 3]>, usize)>, why: &str| {
        let (res, g, acc, it) = best.expect("the first iteration is kept");
        let note = format!(
            "; gas balanced vertically by {it} iterations{why} (rms A_z/g_z within 2H {res:.1e})"
        );
        Ok((g, acc, note))
    };
    // A long balance (a fine 3D disc: minutes) says how it goes every RELAX_REPORT_SECONDS.
    let mut said = std::time::Instant::now();
    for it in 0..=RELAX_ITERATIONS {
        let mut st = State {
            t: 0.0,
            step: 0,
            gas: gas_phase(g, None),
            dust: Vec::new(),
        };
        let built = crate::step::backend::Backend::new(
            crate::step::backend::DeviceChoice::Cpu,
            phys.clone(),
            &mut st,
        )
        .and_then(|mut eng| {
            eng.forces()?;
            let acc = eng.accelerations()?;
            eng.sync(&mut st)?;
            Ok(acc)
        });
        let acc = match (built, &best) {
            (Ok(acc), _) => acc,
            // A column's topmost particle pushed out of reach (SPH's free surface): keep the
            // best balance reached before it.
            (Err(_), Some(_)) => return done(best, ", then a surface particle ran away"),
            (Err(e), None) => return Err(fail(e.to_string())),
        };
        g = st.gas.ph;
        if dim < 3 {
            return Ok((g, acc, String::new()));
        }
        let residual = vertical_residual(&g, &acc, &phys);
        if said.elapsed().as_secs_f64() >= RELAX_REPORT_SECONDS {
            said = std::time::Instant::now();
            eprintln!(
                "dustsph: disc: balancing the gas vertically: iteration {it} of at most \
                 {RELAX_ITERATIONS}, rms A_z/g_z within 2H {residual:.2e} (done below {RELAX_TOL})"
            );
        }
        if best.as_ref().is_none_or(|b| residual < b.0) {
            best = Some((residual, g.clone(), acc.clone(), it));
        }
        if residual < RELAX_TOL {
            return done(best, "");
        }
        if it == RELAX_ITERATIONS {
            return done(best, " (not converged)");
        }
        relax_move(&mut g, &acc, &mut moved, &phys, h, spacing);
    }
    unreachable!("the loop returns at its last iteration")
}

/// The gas's vertical balance within two scale heights: the rms of its A_z (pressure + pull)
/// over the rms of the pull alone (a column's few outermost particles, SPH's free surface,
/// never balance).
fn vertical_residual(g: &Phase, acc: &[[f64; 3]], phys: &crate::step::Physics) -> f64 {
    let (centre, gm) = (phys.gravity.pos, phys.gravity.gm);
    let (mut a2, mut g2) = (0.0, 0.0);
    for (xi, a) in g.x.iter().zip(acc) {
        let x = sub(*xi, centre);
        let r = x[0].hypot(x[1]);
        if x[2].abs() > 2.0 * phys.local_cs.at(*xi) * (r * r * r / gm).sqrt() {
            continue;
        }
        let pull = gm * x[2] / (r * r + x[2] * x[2]).powf(1.5);
        a2 += a[2] * a[2];
        g2 += pull * pull;
    }
    (a2 / g2.max(f64::MIN_POSITIVE)).sqrt()
}

/// One move of the relaxation's heavy-ball descent: each move keeps a share of the particle's
/// last one (`moved`, by id: the engine sorts), which speeds up the slow large-scale mode of
/// the column. Particles beyond 2H stay where the Gaussian put them: SPH's free surface would
/// push a column's outermost ones outward without end.
fn relax_move(
    g: &mut Phase,
    acc: &[[f64; 3]],
    moved: &mut [f64],
    phys: &crate::step::Physics,
    h: f64,
    spacing: f64,
) {
    let (centre, gm) = (phys.gravity.pos, phys.gravity.gm);
    for ((x, a), id) in g.x.iter_mut().zip(acc).zip(&g.id) {
        let id = *id as usize;
        let d = sub(*x, centre);
        let r = d[0].hypot(d[1]);
        let c = phys.local_cs.at(*x);
        if d[2].abs() > 2.0 * c * (r * r * r / gm).sqrt() {
            moved[id] = 0.0;
            continue;
        }
        let dz = (RELAX_KAPPA * h * h * a[2] / (c * c) + RELAX_MOMENTUM * moved[id])
            .clamp(-0.1 * spacing, 0.1 * spacing);
        moved[id] = dz;
        x[2] += dz;
    }
}

/// Φ⁻¹(p): the standard normal quantile, by bisection on Φ(x) = ½ erfc(−x/√2) to round-off.
fn normal_quantile(p: f64) -> f64 {
    let cdf = |x: f64| 0.5 * libm::erfc(-x / std::f64::consts::SQRT_2);
    let (mut a, mut b) = (-40.0, 40.0);
    for _ in 0..200 {
        let c = 0.5 * (a + b);
        if cdf(c) < p {
            a = c;
        } else {
            b = c;
        }
    }
    0.5 * (a + b)
}

/// One ring of particles: its mid-radius, particle count and mass.
struct Ring {
    r: f64,
    count: usize,
    mass: f64,
}

/// Rings from r_in outward, each as wide as the local spacing at its middle (√(m/Σ) in 2D,
/// the midplane's (m/ρ)^{1/3} in 3D), up to r_out; its mass is ∫ 2πRΣ dR over its width.
fn rings(d: &DiscCfg, sigma: &impl Fn(f64) -> f64, spacing: &impl Fn(f64) -> f64) -> Vec<Ring> {
    let mut out = Vec::new();
    let mut lo = d.r_in;
    let widest = 0.25 * (d.r_out - d.r_in);
    while lo < d.r_out {
        // w = spacing(lo + w/2) by bisection (w minus the right side grows with w: near r_in
        // Σ climbs with R, beyond it falls slowly), capped at a quarter of the disc.
        let gap = |w: f64| w - spacing(lo + 0.5 * w);
        let w = if gap(widest) <= 0.0 {
            widest
        } else {
            let (mut a, mut b) = (0.0, widest);
            for _ in 0..100 {
                let c = 0.5 * (a + b);
                if gap(c) > 0.0 {
                    b = c;
                } else {
                    a = c;
                }
            }
            b
        };
        let hi = lo + w;
        if hi > d.r_out {
            break;
        }
        let r = lo + 0.5 * w;
        // Composite Simpson over 64 pieces: Σ climbs as √(R − r_in) from the inner edge.
        let f = |x: f64| 2.0 * std::f64::consts::PI * x * sigma(x);
        let k = 64;
        let dx = w / k as f64;
        let mass = dx / 3.0
            * (0..=k)
                .map(|j| {
                    let c = if j == 0 || j == k {
                        1.0
                    } else if j % 2 == 1 {
                        4.0
                    } else {
                        2.0
                    };
                    c * f(lo + j as f64 * dx)
                })
                .sum::<f64>();
        let count = ((2.0 * std::f64::consts::PI * r / w).round() as usize).max(1);
        out.push(Ring { r, count, mass });
        lo = hi;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layer(r: f64, z: f64) -> Layer {
        Layer {
            r,
            z,
            count: 10,
            turn: 0.0,
            mass: 1.0,
        }
    }

    /// Keplerian rings (pull = GM/R³, (R v_φ)² = GM R) are Rayleigh-stable; a ring whose
    /// pull is cut by an edge's pressure is reported, in 2D and, averaged over its layers, 3D.
    #[test]
    fn rayleigh_check_names_the_ring_whose_angular_momentum_falls_outward() {
        let radii = [1.0, 1.1, 1.2, 1.3];
        let kepler = |r: f64| 1.0 / (r * r * r);
        let two_d: Vec<Layer> = radii.iter().map(|&r| layer(r, 0.0)).collect();
        let mut sums: Vec<(f64, f64, usize)> = radii.iter().map(|&r| (0.0, kepler(r), 1)).collect();
        assert!(rayleigh_unstable(&two_d, &sums, 1.0).is_empty());
        // The outer ring held up by its pressure: 0.8 of the Keplerian pull, (R v_φ)² down 20 %.
        sums[3].1 *= 0.8;
        // (R v_φ)² = 1.3 · 0.8 after 1.2: γ² = (1.2 − 1.04)/0.1 = 1.6 (GM = 1).
        let found = rayleigh_unstable(&two_d, &sums, 1.0);
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].0, 1.3);
        assert!((found[0].1 - 1.6f64.sqrt()).abs() < 1e-12, "{found:?}");
        // 3D: two layers per ring; only the ring's mean counts (one layer 30 % down, the other
        // 30 % up, is no fall).
        let three_d: Vec<Layer> = radii
            .iter()
            .flat_map(|&r| [layer(r, -0.1), layer(r, 0.1)])
            .collect();
        let mut s3: Vec<(f64, f64, usize)> = three_d
            .iter()
            .map(|l| (l.z * 10.0, 10.0 * kepler(l.r), 10))
            .collect();
        s3[4].1 *= 0.7;
        s3[5].1 *= 1.3;
        assert!(rayleigh_unstable(&three_d, &s3, 1.0).is_empty());
        s3[5].1 /= 1.3;
        // The ring at 1.2 down to (1.2·0.7 + 1.2)/2 = 1.02 after 1.1: γ² = 0.08/0.1 = 0.8.
        let found = rayleigh_unstable(&three_d, &s3, 1.0);
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].0, 1.2);
        assert!((found[0].1 - 0.8f64.sqrt()).abs() < 1e-12, "{found:?}");
    }
}
