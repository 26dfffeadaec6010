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
use crate::scene::{DiscCfg, GasEos};

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
    let gm = grav.central_mass;
    let centre = grav.position;
    let sigma_norm = d.sigma_ref / taper(r_ref, d.r_in);
    let sigma = |r: f64| sigma_norm * (r / r_ref).powf(-d.p) * taper(r, d.r_in);
    // Spacing 1/n at r_ref: particle mass Σ_ref / n².
    let spacing = 1.0 / scene.sph.n as f64;
    let m = d.sigma_ref * spacing * spacing;
    let est = std::f64::consts::PI * (d.r_out * d.r_out - d.r_in * d.r_in) * d.sigma_ref / m;
    super::check_size(est, 1 + scene.n_fractions(), "sph.n", &["dustydisc.r_out"])?;
    let rings = rings(d, &sigma, m);
    if rings.is_empty() {
        return Err(SetupError {
            key: "sph.n".into(),
            msg: "no ring of particles fits between dustydisc.r_in and r_out; raise sph.n".into(),
        });
    }
    let cs = |r: f64| cs0 * (r / r_ref).powf(-q);
    // dln P/dln R of P = c_s² Σ: −2q − p plus the inner taper's ½√(r_in/R)/(1 − √(r_in/R)).
    let dlnp = |r: f64| {
        let s = (d.r_in / r).sqrt();
        -2.0 * q - d.p + 0.5 * s / (1.0 - s)
    };
    let fr = scene.fractions();
    let eps: Vec<f64> = fr.iter().map(|f| f.eps).collect();
    let mut gas = Phase::default();
    let mut dust: Vec<Phase> = fr.iter().map(|_| Phase::default()).collect();
    for (i, ring) in rings.iter().enumerate() {
        let r = ring.r;
        let omega = (gm / (r * r * r)).sqrt();
        let vk = omega * r;
        let c = cs(r);
        let eta_vk = -0.5 * c * c / vk * dlnp(r);
        let st: Vec<f64> = fr
            .iter()
            .map(|f| omega * f.law.stopping_time(sigma(r), f.eps * sigma(r), c))
            .collect();
        let drift = if fr.is_empty() {
            None
        } else {
            steady_drift(&eps, &st)
        };
        let (gvr, gvp) = drift.as_ref().map_or((0.0, -1.0), |s| s.gas);
        let turn = if i % 2 == 0 { 0.0 } else { 0.5 };
        let place = |ph: &mut Phase, shift: f64, vr: f64, vphi: f64, mass: f64, rho: f64| {
            for j in 0..ring.count {
                let phi =
                    2.0 * std::f64::consts::PI * (j as f64 + turn + shift) / ring.count as f64;
                let (s, c) = phi.sin_cos();
                ph.x.push([centre[0] + r * c, centre[1] + r * s, 0.0]);
                ph.v.push([vr * c - vphi * s, vr * s + vphi * c, 0.0]);
                ph.m.push(mass);
                ph.rho.push(rho);
            }
        };
        let mg = ring.mass / ring.count as f64;
        place(&mut gas, 0.0, gvr * eta_vk, vk + gvp * eta_vk, mg, sigma(r));
        if let Some(s) = &drift {
            for (k, ph) in dust.iter_mut().enumerate() {
                let (ur, up) = s.dust[k];
                place(
                    ph,
                    0.5,
                    ur * eta_vk,
                    vk + up * eta_vk,
                    eps[k] * mg,
                    eps[k] * sigma(r),
                );
            }
        }
    }
    let ng = gas.len() as u64;
    gas.id = (0..ng).collect();
    let mut next = ng;
    for ph in &mut dust {
        ph.id = (next..next + ph.len() as u64).collect();
        next += ph.len() as u64;
    }
    let h = smoothing_length(scene, spacing);
    let n_rings = rings.len();
    let mut su = Setup::at_start(
        gas_phase(gas, None),
        dust,
        h,
        crate::grid::Domain {
            dim: 2,
            periodic: [None; 3],
        },
        spacing,
        2.0 * d.r_out,
    );
    su.notes.push(format!(
        "disc: {n_rings} rings, {ng} gas particles between R = {} and {}, H/R = {:.4} at r_ref = {r_ref}",
        d.r_in,
        d.r_out,
        cs0 / (gm / r_ref).sqrt()
    ));
    Ok(su)
}

/// 1 − √(r_in/R): Σ's inner taper (0 at r_in).
fn taper(r: f64, r_in: f64) -> f64 {
    1.0 - (r_in / r).sqrt()
}

/// One ring of particles: its mid-radius, particle count and mass.
struct Ring {
    r: f64,
    count: usize,
    mass: f64,
}

/// Rings from r_in outward, each as wide as the local spacing √(m/Σ) at its middle, up to
/// r_out; its mass is ∫ 2πRΣ dR over its width.
fn rings(d: &DiscCfg, sigma: &impl Fn(f64) -> f64, m: f64) -> Vec<Ring> {
    let mut out = Vec::new();
    let mut lo = d.r_in;
    let widest = 0.25 * (d.r_out - d.r_in);
    while lo < d.r_out {
        // w = √(m/Σ(lo + w/2)) by bisection (w minus the right side grows with w: near r_in
        // Σ climbs with R, beyond it falls slowly), capped at a quarter of the disc.
        let gap = |w: f64| w - (m / sigma(lo + 0.5 * w)).sqrt();
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
