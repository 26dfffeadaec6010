//! DUSTYWAVE (method.md §7.2–7.3): a linear sound wave along x in a periodic box (1D line, 2D
//! or 3D slab), any number of fractions, isothermal or adiabatic. Particles are placed so that
//! the density follows the perturbation exactly in mass coordinates.
use super::*;
use crate::exact::complex::C;
use crate::exact::dustywave::{LinearWave, WaveAmplitudes, WaveGas};
use crate::scene::{GasEos, Lattice, WaveCfg, WaveMode};

/// The linear model of the scene (background state, linear stopping times).
pub fn model(scene: &Scene, w: &WaveCfg) -> LinearWave {
    let bg = w.background;
    let rho_g0 = bg.rho;
    let gas = match scene.gas.eos {
        GasEos::Isothermal { cs } => WaveGas::Isothermal { cs },
        GasEos::Adiabatic { gamma } => WaveGas::Adiabatic { gamma, p0: bg.p },
        // Refused for the built-in problems (scene checks); the reference c_s stands in.
        GasEos::LocallyIsothermal { cs0, .. } => WaveGas::Isothermal { cs: cs0 },
    };
    let cs0 = scene.gas.eos.sound_speed(bg);
    let (rho_d0, t_stop) = scene
        .fractions()
        .iter()
        .map(|f| {
            let rho = f.eps * rho_g0;
            // Linear theory: drag perturbations of t are second order.
            (rho, f.law.stopping_time(rho_g0, rho, cs0))
        })
        .unzip();
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
pub fn initial_amplitudes(w: &WaveCfg, lw: &LinearWave) -> WaveAmplitudes {
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

/// The unperturbed lattice of the wave: points in [0, Lx) × [0, Ly) × [0, Lz) and the box
/// lengths (1 on unused axes). `nx` points per row along x with spacing Δ = length/nx; in 2D/3D `layers`
/// rows along y (and layers along z).
///
/// Close-packed (Phantom's `set_unifdis('closepacked')`, written from its geometry): rows of
/// spacing Δ along x, rows Δ√3/2 apart along y with every other row shifted by Δ/2 (a hexagonal
/// layer), layers Δ√(2/3) apart along z, each shifted by (Δ/2, Δ√3/6) from the one below (ABC
/// stacking, so every particle has 12 neighbours at distance Δ: face-centred cubic). Periodic
/// when the row count is even and the layer count a multiple of 3. Cubic: spacing Δ on every axis.
pub fn lattice(
    dim: u32,
    lattice: Lattice,
    nx: usize,
    length: f64,
    layers: usize,
) -> (Vec<[f64; 3]>, [f64; 3]) {
    let dx = length / nx as f64;
    if dim == 1 {
        let x = (0..nx).map(|i| [(i as f64 + 0.5) * dx, 0.0, 0.0]).collect();
        return (x, [length, 1.0, 1.0]);
    }
    let (ny, nz) = (layers, if dim == 3 { layers } else { 1 });
    let (dy, dz) = match lattice {
        Lattice::Closepacked => (dx * 0.75f64.sqrt(), dx * 6f64.sqrt() / 3.0),
        Lattice::Cubic | Lattice::Glass => (dx, dx),
    };
    let mut x = Vec::with_capacity(nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            // Layer k of the ABC stack shifts rows by k/3 of a row spacing along y, and the
            // half-spacing x offset alternates with the row parity of the shifted layer.
            let (ox, oy) = match lattice {
                Lattice::Closepacked if dim == 2 => (0.25 + 0.5 * (j % 2) as f64, 0.5),
                Lattice::Closepacked => (
                    0.25 + 0.5 * ((j + k % 3) % 2) as f64,
                    1.0 / 6.0 + (k % 3) as f64 / 3.0,
                ),
                Lattice::Cubic | Lattice::Glass => (0.5, 0.5),
            };
            let y = (j as f64 + oy) * dy;
            let z = if dim == 3 { (k as f64 + 0.5) * dz } else { 0.0 };
            for i in 0..nx {
                x.push([(i as f64 + ox) * dx, y, z]);
            }
        }
    }
    let len = [
        length,
        ny as f64 * dy,
        if dim == 3 { nz as f64 * dz } else { 1.0 },
    ];
    (x, len)
}

/// Stretch unperturbed points along x (uniform density ρ0 on [0, L)) so that the density
/// becomes ρ0 + A Re[ρ̂ e^{ikx}]: each point moves to the x whose mass coordinate
/// ∫₀ˣ ρ dx' equals ρ0 x₀ (Newton iteration; exact in mass coordinates).
fn stretch(x0: &[[f64; 3]], length: f64, rho0: f64, amp: f64, rho_hat: C, k: f64) -> Vec<[f64; 3]> {
    let ik = C::new(0.0, k);
    x0.iter()
        .map(|p| {
            let target = p[0] * rho0;
            let mut x = p[0];
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
            [x, p[1], p[2]]
        })
        .collect()
}

/// The wave's particles, of those `keep` says are this process's (every one alone): each
/// phase's positions are laid out whole, one phase at a time, and only this process's
/// particles are made of them.
pub(super) fn build(scene: &Scene, w: &WaveCfg, keep: Keep) -> Result<Setup, SetupError> {
    let dim = scene.dim();
    let n_f = (scene.sph.n as f64 * w.length).round().max(2.0);
    let rows = (w.layers as f64).powi(dim as i32 - 1);
    super::check_size(
        n_f * rows,
        1 + scene.n_fractions(),
        "sph.n",
        &["dustywave.length", "dustywave.layers"],
    )?;
    let n = n_f as usize;
    let dx = w.length / n as f64;
    let (x0, len) = lattice(dim, w.lattice, n, w.length, w.layers);
    // A glass or jitter replaces the unperturbed points (gas: phase 0, fraction k: k + 1,
    // each its own draw); the stretch then puts the wave on them in mass coordinates.
    let mut notes = Vec::new();
    let np = x0.len();
    let volume: f64 = len[..dim as usize].iter().product();
    // h = hfact × the mean spacing (V/N)^(1/d), Phantom's convention (h = hfact (m/ρ)^(1/d));
    // in 1D that is Δx.
    let spacing = if dim == 1 {
        dx
    } else {
        (volume / np as f64).powf(1.0 / dim as f64)
    };
    let h = smoothing_length(scene, spacing);
    for (a, key) in ["dustywave.length", "dustywave.layers", "dustywave.layers"]
        .iter()
        .enumerate()
        .take(dim as usize)
    {
        check_periodic_fits(len[a], h, key)?;
    }
    let lw = model(scene, w);
    let y = initial_amplitudes(w, &lw);
    let (a, k) = (w.amplitude, lw.k);
    let order = (w.lattice, w.jitter, w.seed);
    let xg = arrange(x0.clone(), dim, &len, dx, h, order, 0, scene, &mut notes)?;
    let x = stretch(&xg, w.length, lw.rho_g0, a, y.rho_g, k);
    drop(xg);
    // Equal masses giving the background density exactly: m = ρ0 V / N. The exact initial
    // density (summation replaces it; the continuity equation starts from it).
    let cell_volume = if dim == 1 { dx } else { volume / np as f64 };
    let gas = phase_kept(x, (0, 0), keep, |_, p| {
        let v = [field(0.0, a, y.v_g, k, p[0]), 0.0, 0.0];
        (
            v,
            lw.rho_g0 * cell_volume,
            field(lw.rho_g0, a, y.rho_g, k, p[0]),
        )
    });
    let e = match (lw.gas, y.e) {
        (WaveGas::Adiabatic { gamma, p0 }, Some(eh)) => {
            let e0 = p0 / ((gamma - 1.0) * lw.rho_g0);
            Some(gas.x.iter().map(|p| field(e0, a, eh, k, p[0])).collect())
        }
        _ => None,
    };
    let npu = np as u64;
    let x0_dust: Vec<[f64; 3]> = x0
        .iter()
        .map(|p| {
            let mut q = *p;
            for (c, l) in q.iter_mut().zip(&len).take(dim as usize) {
                *c = (*c + w.dust_shift * dx).rem_euclid(*l);
            }
            q
        })
        .collect();
    let mut dust = Vec::new();
    for kf in 0..lw.rho_d0.len() {
        let x0 = arrange(
            x0_dust.clone(),
            dim,
            &len,
            dx,
            h,
            order,
            kf as u64 + 1,
            scene,
            &mut notes,
        )?;
        let rho0 = lw.rho_d0[kf];
        let x = stretch(&x0, w.length, rho0, a, y.rho_d[kf], k);
        drop(x0);
        let first = (kf as u64 + 1) * npu;
        dust.push(phase_kept(x, (kf as u64 + 1, first), keep, |_, p| {
            let v = [field(0.0, a, y.v_d[kf], k, p[0]), 0.0, 0.0];
            (v, rho0 * cell_volume, field(rho0, a, y.rho_d[kf], k, p[0]))
        }));
    }
    let mut periodic = [None; 3];
    for (p, &l) in periodic.iter_mut().zip(&len).take(dim as usize) {
        *p = Some((0.0, l));
    }
    let mut su = Setup::at_start(
        gas_phase(gas, e),
        dust,
        h,
        Domain { dim, periodic },
        spacing,
        w.length,
    );
    su.notes = notes;
    su.share = keep.shared();
    Ok(su)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Minimum-image distances from particle i to every other.
    fn distances(x: &[[f64; 3]], len: [f64; 3], i: usize) -> Vec<f64> {
        x.iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(_, p)| {
                (0..3)
                    .map(|k| {
                        let d = p[k] - x[i][k];
                        let d = d - len[k] * (d / len[k]).round();
                        d * d
                    })
                    .sum::<f64>()
                    .sqrt()
            })
            .collect()
    }

    #[test]
    fn close_packed_lattices_are_periodic_fcc_and_hexagonal() {
        // 3D: every particle has 12 nearest neighbours at Δ, across the periodic boundaries too;
        // the box is nx Δ × ny Δ√3/2 × nz Δ√(2/3) and the volume per particle Δ³/√2.
        let (nx, dx) = (16, 1.0 / 16.0);
        let (x, len) = lattice(3, Lattice::Closepacked, nx, 1.0, 6);
        assert_eq!(x.len(), nx * 6 * 6);
        assert!((len[1] - 6.0 * dx * 0.75f64.sqrt()).abs() < 1e-15);
        assert!((len[2] - 6.0 * dx * (2.0f64 / 3.0).sqrt()).abs() < 1e-15);
        let vol = len[0] * len[1] * len[2] / x.len() as f64;
        assert!((vol - dx.powi(3) / 2f64.sqrt()).abs() < 1e-15);
        for i in [0, 17, 100, 311, x.len() - 1] {
            let d = distances(&x, len, i);
            let near = d.iter().filter(|&&r| (r - dx).abs() < 1e-12).count();
            assert_eq!(near, 12, "particle {i}");
            assert!(d.iter().all(|&r| r > dx - 1e-12));
        }
        // 2D: six neighbours at Δ.
        let (x, len) = lattice(2, Lattice::Closepacked, nx, 1.0, 6);
        for i in [0, 21, x.len() - 1] {
            let d = distances(&x, len, i);
            assert_eq!(d.iter().filter(|&&r| (r - dx).abs() < 1e-12).count(), 6);
        }
    }
}
