//! DUSTYWAVE (method.md §7.2–7.3): a linear sound wave in a periodic 1D box, any number of
//! fractions, isothermal or adiabatic. Particles are placed so that the SPH density follows
//! the perturbation exactly in mass coordinates.
use super::*;
use crate::exact::complex::C;
use crate::exact::dustywave::{LinearWave, WaveAmplitudes, WaveGas};
use crate::scene::{LawKind, WaveMode};

/// The linear model of the scene (background state, linear stopping times).
pub fn model(scene: &Scene) -> LinearWave {
    let w = scene.dustywave.as_ref().expect("validated");
    let rho_g0 = scene.gas.rho.expect("validated");
    let (gas, cs0) = match scene.gas.eos {
        EosKind::Isothermal => {
            let cs = scene.gas.cs.expect("validated");
            (WaveGas::Isothermal { cs }, cs)
        }
        EosKind::Adiabatic => {
            let (gamma, p0) = (
                scene.gas.gamma.expect("validated"),
                scene.gas.p.expect("validated"),
            );
            (
                WaveGas::Adiabatic { gamma, p0 },
                (gamma * p0 / rho_g0).sqrt(),
            )
        }
    };
    let (rho_d0, t_stop) = match &scene.dust {
        Some(d) => d
            .fractions
            .iter()
            .map(|f| {
                let rho = f.eps * rho_g0;
                // Linear theory: drag perturbations of t are second order.
                let t = match d.law {
                    LawKind::ConstantT => f.t_stop.or(d.t_stop).expect("validated"),
                    LawKind::ConstantK => rho / f.k.expect("validated"),
                    LawKind::Epstein => f.s_rho.expect("validated") / (rho_g0 * cs0),
                };
                (rho, t)
            })
            .unzip(),
        None => (Vec::new(), Vec::new()),
    };
    LinearWave {
        rho_g0,
        gas,
        rho_d0,
        t_stop,
        k: 2.0 * std::f64::consts::PI / w.length,
    }
}

/// Initial complex amplitudes for the scene's mode, normalised so that `amplitude` is relative:
/// δρ_g = A ρ_g0 (eigenmode), or δρ = A ρ0 and δv = A c_s in every phase (sine).
pub fn initial_amplitudes(scene: &Scene, lw: &LinearWave) -> WaveAmplitudes {
    let w = scene.dustywave.as_ref().expect("validated");
    match w.mode {
        WaveMode::Eigen => lw.eigenmode().1.scale(C::new(lw.rho_g0, 0.0)),
        WaveMode::Sine => {
            // f = f0 + A sin(kx) = f0 + A Re[−i e^{ikx}] for densities (× ρ0) and velocities (× c_s).
            let mi = C::new(0.0, -1.0);
            let cs = lw.sound_speed();
            let e = match lw.gas {
                WaveGas::Isothermal { .. } => None,
                WaveGas::Adiabatic { p0, .. } => Some(mi * (p0 / lw.rho_g0)),
            };
            WaveAmplitudes {
                rho_g: mi * lw.rho_g0,
                v_g: mi * cs,
                e,
                rho_d: lw.rho_d0.iter().map(|&r| mi * r).collect(),
                v_d: vec![mi * cs; lw.rho_d0.len()],
            }
        }
    }
}

/// Evaluate f0 + A Re[f̂ e^{ikx}].
pub fn field(f0: f64, amp: f64, fhat: C, k: f64, x: f64) -> f64 {
    f0 + amp * (fhat * C::new(0.0, k * x).exp()).re
}

/// Positions of `n` equal-mass particles whose density is ρ0 + A Re[ρ̂ e^{ikx}] on [0, L).
fn place(n: usize, length: f64, rho0: f64, amp: f64, rho_hat: C, k: f64) -> Vec<[f64; 3]> {
    let dx = length / n as f64;
    let ik = C::new(0.0, k);
    (0..n)
        .map(|i| {
            let target = (i as f64 + 0.5) * dx * rho0;
            let mut x = (i as f64 + 0.5) * dx;
            for _ in 0..50 {
                let e = C::new(0.0, k * x).exp();
                let mass = rho0 * x + amp * (rho_hat * (e - C::ONE) / ik).re;
                let rho = rho0 + amp * (rho_hat * e).re;
                let step = (mass - target) / rho;
                x -= step;
                if step.abs() < 1e-15 * length {
                    break;
                }
            }
            [x, 0.0, 0.0]
        })
        .collect()
}

pub(super) fn build(scene: &Scene) -> Result<Setup, SetupError> {
    let w = scene.dustywave.as_ref().expect("validated");
    let n = ((scene.sph.n as f64 * w.length).round() as usize).max(2);
    let dx = w.length / n as f64;
    let h = smoothing_length(scene, dx);
    check_periodic_fits(w.length, h, "dustywave.length")?;
    let lw = model(scene);
    let y = initial_amplitudes(scene, &lw);
    let (a, k) = (w.amplitude, lw.k);
    let x = place(n, w.length, lw.rho_g0, a, y.rho_g, k);
    let v: Vec<[f64; 3]> = x
        .iter()
        .map(|p| [field(0.0, a, y.v_g, k, p[0]), 0.0, 0.0])
        .collect();
    let e = match (lw.gas, y.e) {
        (WaveGas::Adiabatic { gamma, p0 }, Some(eh)) => {
            let e0 = p0 / ((gamma - 1.0) * lw.rho_g0);
            Some(x.iter().map(|p| field(e0, a, eh, k, p[0])).collect())
        }
        _ => None,
    };
    let gas = Phase {
        x,
        v,
        m: vec![lw.rho_g0 * dx; n],
        rho: vec![lw.rho_g0; n],
        id: (0..n as u64).collect(),
        fixed: None,
    };
    let dust = (0..lw.rho_d0.len())
        .map(|kf| {
            let rho0 = lw.rho_d0[kf];
            let x = place(n, w.length, rho0, a, y.rho_d[kf], k);
            let v = x
                .iter()
                .map(|p| [field(0.0, a, y.v_d[kf], k, p[0]), 0.0, 0.0])
                .collect();
            Phase {
                x,
                v,
                m: vec![rho0 * dx; n],
                rho: vec![rho0; n],
                id: ((kf as u64 + 1) * n as u64..(kf as u64 + 2) * n as u64).collect(),
                fixed: None,
            }
        })
        .collect();
    Ok(Setup::at_start(
        gas_phase(gas, e),
        dust,
        h,
        Domain {
            dim: 1,
            periodic: [Some((0.0, w.length)), None, None],
        },
        dx,
        w.length,
    ))
}
