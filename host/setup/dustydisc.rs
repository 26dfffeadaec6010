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
    let dim = scene.dim();
    let gm = grav.central_mass;
    let centre = grav.position;
    let sigma = |r: f64| d.sigma_ref * d.sigma_shape(r, r_ref);
    let cs = |r: f64| cs0 * (r / r_ref).powf(-q);
    let omega = |r: f64| (gm / (r * r * r)).sqrt();
    // The scale height H = c_s/Ω and the midplane density Σ/(√(2π) H) of the 3D disc.
    let height = |r: f64| cs(r) / omega(r);
    let rho_mid = |r: f64| sigma(r) / ((2.0 * std::f64::consts::PI).sqrt() * height(r));
    let disc_mass = d.mass_between(d.r_in, d.r_out, r_ref, d.sigma_ref);
    // The particle mass: the disc's over `dustydisc.particles`, or from spacing 1/n at r_ref
    // (in the midplane in 3D): Σ_ref/n² or ρ_mid,ref/n³.
    let m = match d.particles {
        Some(n) => disc_mass / n as f64,
        None => {
            let s = 1.0 / scene.sph.n as f64;
            if dim == 3 {
                rho_mid(r_ref) * s.powi(3)
            } else {
                d.sigma_ref * s * s
            }
        }
    };
    let local_spacing = |r: f64| {
        if dim == 3 {
            (m / rho_mid(r)).cbrt()
        } else {
            (m / sigma(r)).sqrt()
        }
    };
    // The reference spacing (for h): the local one at r_ref.
    let spacing = local_spacing(r_ref);
    let size_key = match d.particles {
        Some(_) => "dustydisc.particles",
        None => "sph.n",
    };
    super::check_size(
        disc_mass / m,
        1 + scene.n_fractions(),
        size_key,
        &["dustydisc.r_out"],
    )?;
    let rings = rings(d, &sigma, &local_spacing);
    if rings.is_empty() {
        return Err(SetupError {
            key: "sph.n".into(),
            msg: "no ring of particles fits between dustydisc.r_in and r_out; raise sph.n".into(),
        });
    }
    let dln_sigma = |r: f64| d.dln_sigma(r);
    // The layers: each ring holds columns of n_z particles at the Gaussian's quantiles (one
    // layer, at z = 0, in 2D), alternate rings turned by half a spacing.
    let mut layers: Vec<Layer> = Vec::new();
    for (i, ring) in rings.iter().enumerate() {
        let (r, hz) = (ring.r, height(ring.r));
        let n_z = if dim == 3 {
            ((ring.mass / (ring.count as f64 * m)).round() as usize).max(1)
        } else {
            1
        };
        for k in 0..n_z {
            layers.push(Layer {
                r,
                z: if dim == 3 {
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
    // The gas's density at a layer's (R, z): Σ in 2D, the Gaussian in 3D.
    let rho_at = |r: f64, z: f64| {
        if dim == 3 {
            rho_mid(r) * (-0.5 * z * z / (height(r) * height(r))).exp()
        } else {
            sigma(r)
        }
    };
    let mut gas = Phase::default();
    let mut layer_of: Vec<usize> = Vec::new();
    for (l, ly) in layers.iter().enumerate() {
        place(
            &mut gas,
            ly,
            0.0,
            centre,
            [0.0; 3],
            ly.mass,
            rho_at(ly.r, ly.z),
        );
        layer_of.extend(std::iter::repeat_n(l, ly.count));
    }
    gas.id = (0..gas.len() as u64).collect();
    let h = smoothing_length(scene, spacing);
    // The resolution of the scale height: h/H of the midplane at the inner and outer rings and
    // at r_ref (variable h: the h of the set-up's density).
    let h_over_h = |r: f64| {
        let hr = match scene.sph.smoothing.variable_hfact() {
            Some(hf) => dustsph_device::kernel::h_of_density(m, rho_at(r, 0.0), hf, dim, h),
            None => h,
        };
        hr / height(r)
    };
    // A disc whose scale height the kernel does not resolve over most of its mass is no disc
    // (its pressure support, drift and settling are set by h, not by H).
    let unresolved: f64 = rings
        .iter()
        .filter(|g| h_over_h(g.r) > 1.0)
        .map(|g| g.mass)
        .fold(0.0, |a, m| a + m) // from +0: an empty f64 sum is −0
        / rings.iter().map(|g| g.mass).sum::<f64>();
    if unresolved > 0.5 {
        return Err(SetupError {
            key: size_key.into(),
            msg: format!(
                "h/H > 1 over {:.0} % of the disc's mass (h/H {:.2} at r_ref): the kernel does \
                 not resolve the scale height; raise {size_key}",
                100.0 * unresolved,
                h_over_h(r_ref)
            ),
        });
    }
    let domain = crate::grid::Domain {
        dim,
        periodic: [None; 3],
    };
    // Each gas particle's radial pull −A_R (gravity and pressure) per unit R, v_φ² = R·(−A_R)
    // at balance: from the run's own SPH forces when relaxed, else from the analytic profile.
    let mut relax_note = String::new();
    let pull: Vec<f64> = if d.relax {
        let (relaxed, acc, note) = relax(scene, gas, h, domain, spacing)?;
        gas = relaxed;
        relax_note = note;
        (0..gas.len())
            .map(|i| {
                let x = sub(gas.x[i], centre);
                let r = x[0].hypot(x[1]);
                -(x[0] * acc[i][0] + x[1] * acc[i][1]) / (r * r)
            })
            .collect()
    } else {
        (0..gas.len())
            .map(|i| {
                let ly = &layers[layer_of[gas.id[i] as usize]];
                let (vk, dlnp) = kepler_and_slope(gm, ly.r, ly.z, height(ly.r), q, dln_sigma);
                (vk * vk + cs(ly.r).powi(2) * dlnp) / (ly.r * ly.r)
            })
            .collect()
    };
    // The leapfrog's circular orbit at its synchronised times is slower than the continuous
    // balance by (Ωτ)²/8 (method.md §D, "The set-up's ringing"): started on the continuous
    // one, every ring would ring at 2 (Ωτ)²/8 v_K. Every particle starts on the discrete orbit
    // of the run's first step τ (`orbit_factor`).
    let tau = match scene.time.integrator {
        crate::scene::Integrator::Kdk => first_step(scene, &gas, h, domain)?,
        crate::scene::Integrator::FirstOrder => 0.0,
    };
    let orbit_factor = |r: f64, vphi: f64| {
        let w = vphi * tau / r;
        1.0 - w * w / 8.0
    };
    // The layers' mean height and η v_K = (v_K² − v_φ²)/(2 v_K) from the balance.
    let mut sums = vec![(0.0, 0.0, 0usize); layers.len()];
    for i in 0..gas.len() {
        let s = &mut sums[layer_of[gas.id[i] as usize]];
        s.0 += gas.x[i][2] - centre[2];
        s.1 += pull[i];
        s.2 += 1;
    }
    let unstable = rayleigh_unstable(&layers, &sums, gm);
    let fr = scene.fractions();
    let eps: Vec<f64> = fr.iter().map(|f| f.eps).collect();
    let drift_start = d.dust_velocity == DustStart::Drift;
    let mut dust: Vec<Phase> = fr.iter().map(|_| Phase::default()).collect();
    let mut gas_v = vec![[0.0; 3]; gas.len()];
    let mut layer_drift = Vec::with_capacity(layers.len());
    for (l, ly) in layers.iter().enumerate() {
        let (r, c) = (ly.r, cs(ly.r));
        let (z, mean_pull) = (sums[l].0 / sums[l].2 as f64, sums[l].1 / sums[l].2 as f64);
        let (vk, _) = kepler_and_slope(gm, r, z, height(r), q, dln_sigma);
        let eta_vk = (vk * vk - r * r * mean_pull) / (2.0 * vk);
        let rho_g = rho_at(r, z);
        let st: Vec<f64> = fr
            .iter()
            .map(|f| omega(r) * f.law.stopping_time(rho_g, f.eps * rho_g, c))
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
                    let t = st[j] / omega(r);
                    let omega_z2 = gm / (r * r + z * z).powf(1.5);
                    let disc = 1.0 - 4.0 * omega_z2 * t * t;
                    let vz = if disc > 0.0 {
                        z * (disc.sqrt() - 1.0) / (2.0 * t)
                    } else {
                        0.0
                    };
                    let vphi = vk + up * eta_vk;
                    [ur * eta_vk, vphi * orbit_factor(r, vphi), vz]
                }
                None => [0.0, vk * orbit_factor(r, vk), 0.0],
            };
            let at = Layer { z, ..*ly };
            place(ph, &at, 0.5, centre, v, eps[j] * ly.mass, eps[j] * rho_g);
        }
        layer_drift.push(drift.map(|s| s.gas));
    }
    // The gas: its layer's balance v_φ = √(R² ⟨pull⟩) (a layer is one ring at one height:
    // axisymmetric, so its mean is the balance without the lattice's particle noise), plus
    // the dust's back-reaction (the steady drift's gas velocities less the pressure support
    // −η v_K they contain).
    for i in 0..gas.len() {
        // The layer by particle id: the relaxation's engine sorted the particles.
        let l = layer_of[gas.id[i] as usize];
        let x = sub(gas.x[i], centre);
        let r = x[0].hypot(x[1]);
        let mean_pull = sums[l].1 / sums[l].2 as f64;
        let (vk, _) = kepler_and_slope(gm, layers[l].r, x[2], height(layers[l].r), q, dln_sigma);
        let vphi_p = (r * r * mean_pull).max(0.0).sqrt();
        let eta_vk = (vk * vk - vphi_p * vphi_p) / (2.0 * vk);
        let (vr, vphi) = match layer_drift[l] {
            Some((gr, gp)) => (gr * eta_vk, vphi_p + (gp + 1.0) * eta_vk),
            None => (0.0, vphi_p),
        };
        let vphi = vphi * orbit_factor(r, vphi);
        let (s, co) = (x[1] / r, x[0] / r);
        gas_v[i] = [vr * co - vphi * s, vr * s + vphi * co, 0.0];
    }
    gas.v = gas_v;
    let ng = gas.len() as u64;
    let mut next = ng;
    for ph in &mut dust {
        ph.id = (next..next + ph.len() as u64).collect();
        next += ph.len() as u64;
    }
    let n_rings = rings.len();
    let resolution = format!(
        "; h/H {:.2} at the inner ring, {:.2} at r_ref, {:.2} at the outer, > 1 over {:.0} % of \
         the mass; disc mass {disc_mass:.4e}, gas particle mass {m:.4e}",
        h_over_h(rings[0].r),
        h_over_h(r_ref),
        h_over_h(rings[n_rings - 1].r),
        100.0 * unresolved
    );
    // Each grain's Stokes number in the midplane at the inner ring, r_ref and the outer ring.
    let stokes: Vec<String> = fr
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let st = |r: f64| {
                let rho = rho_at(r, 0.0);
                omega(r) * f.law.stopping_time(rho, f.eps * rho, cs(r))
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
    let mut su = Setup::at_start(
        gas_phase(gas, None),
        dust,
        h,
        domain,
        spacing,
        2.0 * d.r_out,
    );
    su.notes.push(format!(
        "disc: {n_rings} rings, {} layers, {ng} gas particles between R = {} and {}, H/R = {:.4} at r_ref = {r_ref}{resolution}{}{}",
        layers.len(),
        d.r_in,
        d.r_out,
        cs0 / (gm / r_ref).sqrt(),
        relax_note,
        if drift_start { "" } else { "; dust on Keplerian orbits (no drift)" }
    ));
    if tau > 0.0 {
        su.notes.push(format!(
            "disc: every particle on the leapfrog's circular orbit for the first step τ = {tau:.4e} \
             ((Ωτ)²/8 below the continuous balance: {:.2e} of v_φ at r_ref)",
            1.0 - orbit_factor(r_ref, (gm / r_ref).sqrt())
        ));
    }
    if !stokes.is_empty() {
        su.notes.push(format!(
            "disc: midplane Stokes numbers at R = {:.4} / {r_ref} / {:.4}: {}",
            rings[0].r,
            rings[n_rings - 1].r,
            stokes.join("; ")
        ));
    }
    if !unstable.is_empty() {
        // Rings inside an edge damping zone have their radial motion damped: said per ring,
        // and the line is a note, not a warning, when every such ring is in a zone.
        let pm = scene.gravity.map(|g| g.point_mass()).unwrap_or_default();
        let at: Vec<String> = unstable
            .iter()
            .map(|(r, g)| match pm.damp_weight(*r) {
                0.0 => format!("{r:.4} ({g:.2})"),
                w => format!("{r:.4} ({g:.2}; in a damping zone, weight {w:.2})"),
            })
            .collect();
        let held = unstable.iter().all(|(r, _)| pm.damp_weight(*r) > 0.0);
        su.notes.push(format!(
            "{}: disc: R v_φ falls outward at R = {} (in brackets the growth rate of a \
             displacement there over Ω: Rayleigh-unstable rings, an SPH edge's pressure gradient \
             acting over h; method.md §D, \"The discs' edges\")",
            if held { "note" } else { "warning" },
            at.join(", ")
        ));
    }
    Ok(su)
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
    let centre = phys.gravity.pos;
    let gm = phys.gravity.gm;
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
        // Vertical balance within two scale heights: the gas's A_z (pressure + pull) against
        // the pull alone (a column's few outermost particles, SPH's free surface, never balance).
        let (mut a2, mut g2) = (0.0, 0.0);
        for (xi, a) in g.x.iter().zip(&acc) {
            let x = sub(*xi, centre);
            let r = x[0].hypot(x[1]);
            if x[2].abs() > 2.0 * phys.local_cs.at(*xi) * (r * r * r / gm).sqrt() {
                continue;
            }
            let pull = gm * x[2] / (r * r + x[2] * x[2]).powf(1.5);
            a2 += a[2] * a[2];
            g2 += pull * pull;
        }
        let residual = (a2 / g2.max(f64::MIN_POSITIVE)).sqrt();
        if best.as_ref().is_none_or(|b| residual < b.0) {
            best = Some((residual, g.clone(), acc.clone(), it));
        }
        if residual < RELAX_TOL {
            return done(best, "");
        }
        if it == RELAX_ITERATIONS {
            return done(best, " (not converged)");
        }
        // Heavy-ball descent: each move keeps a share of the particle's last one (by id: the
        // engine sorts), which speeds up the slow large-scale mode of the column.
        // Particles beyond 2H stay where the Gaussian put them: SPH's free surface would push
        // a column's outermost ones outward without end.
        for ((x, a), id) in g.x.iter_mut().zip(&acc).zip(&g.id) {
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
    unreachable!("the loop returns at its last iteration")
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
