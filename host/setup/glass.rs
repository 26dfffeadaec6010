//! Periodic glasses (`lattice = "glass"`): a disordered arrangement whose SPH density is nearly
//! uniform, the usual initial condition of SPH codes for a uniform medium (White 1994; Phantom's
//! and SWIFT's relaxed glasses). Made here by the problem's own SPH: the points of a lattice are
//! first scattered at random (±½ spacing per axis), then moved down the pressure forces of an
//! isothermal gas with the problem's kernel, h (fixed or variable) and gradient (standard or
//! IAD), so that the glass is force-free for the forces the run will use,
//! x ← x + κ h² A/c_s² with the velocities reset
//! every iteration (a damped relaxation), until the summed density stops getting smoother;
//! then FIRE (damped dynamics steered along the forces, Bitzek et al. 2006) until the
//! accelerations vanish (rms below 5e-5 c_s²/h), so that a glass at rest stays at rest. Each phase is relaxed from its own draw. The result is cached by a digest of everything it
//! depends on, so a scene, a resume or a test pays for it once per machine.
use super::{disorder, gas_phase, SetupError};
use crate::grid::Domain;
use crate::particles::{Phase, State};
use crate::step::backend::{Backend, DeviceChoice};
use crate::step::Physics;
use dustsph_device::eos::Eos;
use std::path::PathBuf;

/// Bumped whenever the relaxation changes, so that no cache entry outlives its algorithm.
const VERSION: u64 = 3;

/// The problem's SPH that a glass is relaxed with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlassSph {
    /// Variable h at this hfact (`None`: the fixed h).
    pub variable_hfact: Option<f64>,
    pub iad: bool,
}
/// The relaxation's step, as a share of h·(δρ/ρ): with A ≈ c_s² ∇ρ/ρ over a scale h,
/// κ h² A/c_s² moves a point by ≈ κ h δρ/ρ.
const KAPPA: f64 = 0.25;
/// No point moves more than this share of a spacing in one iteration.
const MAX_MOVE: f64 = 0.1;
const MAX_ITERATIONS: usize = 400;
/// Stop when the density noise fell by less than this share over the last `WINDOW` iterations.
const STALL: f64 = 0.005;
const WINDOW: usize = 20;
/// FIRE after the descent ([`settle`]): its first and largest step (h/c_s), its mixing
/// (Bitzek et al.'s α_start), the steps of positive power before the step grows, the rms
/// acceleration it stops at (c_s²/h) and its most steps.
const DT: f64 = 0.1;
const DT_MAX: f64 = 0.5;
const FIRE_ALPHA: f64 = 0.1;
const FIRE_WAIT: usize = 5;
const FORCE_TOL: f64 = 5e-5;
const MAX_SETTLE: usize = 3000;

/// Everything a glass depends on besides its starting lattice: the periodic box [0, len) on
/// the first `dim` axes, the lattice spacing, h, the draw (`seed`, `phase`) and the SPH.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlassSpec {
    pub dim: u32,
    pub len: [f64; 3],
    pub spacing: f64,
    pub h: f64,
    pub seed: u64,
    pub phase: u64,
    pub sph: GlassSph,
}

/// A relaxed glass: the points, and the rms relative deviation of their summed SPH density
/// from its mean before and after the relaxation.
#[derive(Debug, Clone)]
pub struct Glass {
    pub x: Vec<[f64; 3]>,
    pub start_noise: f64,
    pub noise: f64,
    pub iterations: usize,
}

/// The glass made from the lattice `start` (in the box [0, len) on the first `dim` axes, all
/// periodic) at smoothing length `h`, drawn by (`seed`, `phase`): from the cache when it is
/// there, else relaxed and cached.
pub(crate) fn glass(start: &[[f64; 3]], g: &GlassSpec) -> Result<Glass, SetupError> {
    let key = digest(start, g);
    let file = cache_dir().map(|d| d.join(format!("glass-{key:016x}.bin")));
    if let Some(g) = file.as_ref().and_then(|f| read(f, start.len())) {
        return Ok(g);
    }
    // A large glass takes minutes: say what is happening, and where it will be kept.
    let kept = file
        .as_ref()
        .map_or("not cached: no cache folder".into(), |f| {
            format!("cached as {}", f.display())
        });
    eprintln!(
        "dustsph: relaxing a glass of {} particles (phase {}; {kept})",
        start.len(),
        g.phase
    );
    let glass = relax(start, g)?;
    if let Some(f) = file {
        // The cache only saves time: a machine that cannot write it relaxes again next time.
        let _ = write(&f, &glass);
    }
    Ok(glass)
}

/// The relaxation itself (no cache).
pub(crate) fn relax(start: &[[f64; 3]], g: &GlassSpec) -> Result<Glass, SetupError> {
    let fail = |e: String| SetupError {
        key: "lattice".into(),
        msg: format!("the glass could not be relaxed: {e}"),
    };
    let GlassSpec {
        dim,
        len,
        spacing,
        h,
        seed,
        phase,
        sph,
    } = *g;
    let mut x = start.to_vec();
    disorder::jitter(&mut x, dim, &len, spacing, 0.5, seed, phase);
    let volume: f64 = len[..dim as usize].iter().product();
    let mut phys = Physics::open_1d(h, Eos::Isothermal { cs: 1.0 }, Vec::new());
    phys.dim = dim;
    phys.variable_h = sph.variable_hfact;
    if sph.iad {
        phys.gradient = crate::scene::GradientMethod::Iad;
    }
    let mut periodic = [None; 3];
    for (p, l) in periodic.iter_mut().zip(len).take(dim as usize) {
        *p = Some((0.0, l));
    }
    phys.domain = Domain { dim, periodic };
    let mut history: Vec<f64> = Vec::new();
    let mut best: Option<(f64, Vec<[f64; 3]>)> = None;
    for it in 0..=MAX_ITERATIONS {
        let (xs, acc, rho, _) = forces_at(x, volume, &phys).map_err(fail)?;
        let noise = density_noise(&rho);
        history.push(noise);
        x = xs;
        if best.as_ref().is_none_or(|(b, _)| noise < *b) {
            best = Some((noise, x.clone()));
        }
        let stalled = it >= WINDOW && noise > (1.0 - STALL) * history[it - WINDOW];
        if stalled || it == MAX_ITERATIONS {
            break;
        }
        for (p, a) in x.iter_mut().zip(&acc) {
            let mut d = [0.0; 3];
            for k in 0..dim as usize {
                d[k] = KAPPA * h * h * a[k];
            }
            let size = d.iter().map(|c| c * c).sum::<f64>().sqrt();
            let cap = MAX_MOVE * spacing;
            let s = if size > cap { cap / size } else { 1.0 };
            for k in 0..dim as usize {
                p[k] = (p[k] + s * d[k]).rem_euclid(len[k]);
            }
        }
    }
    let (_, x) = best.expect("at least one iteration");
    let (x, noise, steps) = settle(x, g, &phys).map_err(fail)?;
    Ok(Glass {
        x,
        start_noise: history[0],
        noise,
        iterations: history.len() - 1 + steps,
    })
}

/// The SPH forces and densities of the points `x` (isothermal, c_s = 1): the points sorted
/// as the engine sorts them, their accelerations and densities, and where each came from
/// (its index in `x`).
type Forces = (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<f64>, Vec<u64>);

fn forces_at(x: Vec<[f64; 3]>, volume: f64, phys: &Physics) -> Result<Forces, String> {
    let n = x.len();
    let mut st = State {
        t: 0.0,
        step: 0,
        gas: gas_phase(
            Phase {
                x,
                v: vec![[0.0; 3]; n],
                m: vec![volume / n as f64; n],
                rho: vec![1.0; n],
                id: (0..n as u64).collect(),
                fixed: None,
            },
            None,
        ),
        dust: Vec::new(),
    };
    let mut eng =
        Backend::new(DeviceChoice::Cpu, phys.clone(), &mut st).map_err(|e| e.to_string())?;
    eng.forces().map_err(|e| e.to_string())?;
    let acc = eng.accelerations().map_err(|e| e.to_string())?;
    eng.sync(&mut st).map_err(|e| e.to_string())?;
    let ph = st.gas.ph;
    Ok((ph.x, acc, ph.rho, ph.id))
}

/// FIRE (Bitzek et al. 2006, PRL 97, 170201) after the descent: the descent stops when the
/// density noise stops falling, not when the forces vanish, and left a glass that set itself
/// moving at 0.03–0.04 c_s. Damped dynamics whose velocity is steered along the force, the
/// step grown while the power F·v stays positive and the motion stopped when it turns, until
/// the rms acceleration is below `FORCE_TOL` c_s²/h: the glass, at rest, then stays at rest.
/// Returns the points, their density noise and the steps taken.
fn settle(
    mut x: Vec<[f64; 3]>,
    g: &GlassSpec,
    phys: &Physics,
) -> Result<(Vec<[f64; 3]>, f64, usize), String> {
    let dim = g.dim as usize;
    let volume: f64 = g.len[..dim].iter().product();
    let mut v = vec![[0.0f64; 3]; x.len()];
    let (mut dt, mut alpha, mut positive) = (DT * g.h, FIRE_ALPHA, 0usize);
    let dt_max = DT_MAX * g.h;
    let norm = |w: &[[f64; 3]]| {
        w.iter()
            .map(|u| u.iter().map(|c| c * c).sum::<f64>())
            .sum::<f64>()
    };
    for step in 0..=MAX_SETTLE {
        let (xs, acc, rho, id) = forces_at(x, volume, phys)?;
        // The engine sorted the points: the velocities follow them.
        v = id.iter().map(|&i| v[i as usize]).collect();
        x = xs;
        let rms = (norm(&acc) / acc.len().max(1) as f64).sqrt();
        if rms * g.h < FORCE_TOL || step == MAX_SETTLE {
            return Ok((x, density_noise(&rho), step));
        }
        let power: f64 = (acc.iter().zip(&v))
            .map(|(a, u)| (0..dim).map(|k| a[k] * u[k]).sum::<f64>())
            .sum();
        let (vn, an) = (norm(&v).sqrt(), norm(&acc).sqrt());
        if power > 0.0 {
            for (u, a) in v.iter_mut().zip(&acc) {
                for k in 0..dim {
                    u[k] = (1.0 - alpha) * u[k] + alpha * vn / an * a[k];
                }
            }
            positive += 1;
            if positive > FIRE_WAIT {
                dt = (dt * 1.1).min(dt_max);
                alpha *= 0.99;
            }
        } else {
            v.iter_mut().for_each(|u| *u = [0.0; 3]);
            (dt, alpha, positive) = (dt * 0.5, FIRE_ALPHA, 0);
        }
        for ((p, u), a) in x.iter_mut().zip(v.iter_mut()).zip(&acc) {
            for k in 0..dim {
                u[k] += dt * a[k];
                p[k] = (p[k] + dt * u[k]).rem_euclid(g.len[k]);
            }
        }
    }
    unreachable!("the loop returns at its last step")
}

/// rms of ρ/⟨ρ⟩ − 1.
pub fn density_noise(rho: &[f64]) -> f64 {
    let n = rho.len().max(1) as f64;
    let mean = rho.iter().sum::<f64>() / n;
    (rho.iter().map(|r| (r / mean - 1.0).powi(2)).sum::<f64>() / n).sqrt()
}

/// FNV-1a over the bytes of everything the glass depends on.
fn digest(start: &[[f64; 3]], g: &GlassSpec) -> u64 {
    let mut hsh: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |v: u64| {
        for b in v.to_le_bytes() {
            hsh ^= b as u64;
            hsh = hsh.wrapping_mul(0x0100_0000_01b3);
        }
    };
    let hfact = g.sph.variable_hfact.map_or(0, f64::to_bits);
    let iad = g.sph.iad as u64;
    for v in [
        VERSION,
        g.dim as u64,
        g.seed,
        g.phase,
        start.len() as u64,
        hfact,
        iad,
    ] {
        eat(v);
    }
    for v in g.len.iter().chain([g.spacing, g.h].iter()) {
        eat(v.to_bits());
    }
    for p in start {
        for c in p {
            eat(c.to_bits());
        }
    }
    hsh
}

/// `DUSTSPH_CACHE`, else `$XDG_CACHE_HOME/dustsph`, else `$HOME/.cache/dustsph`.
fn cache_dir() -> Option<PathBuf> {
    let env = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    (crate::env::var("DUSTSPH_CACHE"))
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| env("XDG_CACHE_HOME").map(|d| d.join("dustsph")))
        .or_else(|| env("HOME").map(|d| d.join(".cache").join("dustsph")))
}

/// Layout: n, iterations (u64), start noise, noise (f64), then 3n f64, little-endian.
fn write(file: &std::path::Path, g: &Glass) -> std::io::Result<()> {
    let mut b = Vec::with_capacity(32 + 24 * g.x.len());
    b.extend((g.x.len() as u64).to_le_bytes());
    b.extend((g.iterations as u64).to_le_bytes());
    b.extend(g.start_noise.to_le_bytes());
    b.extend(g.noise.to_le_bytes());
    for c in g.x.iter().flatten() {
        b.extend(c.to_le_bytes());
    }
    std::fs::create_dir_all(file.parent().unwrap_or(file))?;
    // Written aside and renamed: a reader never sees half a file.
    let tmp = file.with_extension(format!("tmp{}", std::process::id()));
    std::fs::write(&tmp, &b)?;
    std::fs::rename(&tmp, file)
}

fn read(file: &std::path::Path, n: usize) -> Option<Glass> {
    let b = std::fs::read(file).ok()?;
    if b.len() != 32 + 24 * n {
        return None;
    }
    let word = |i: usize| <[u8; 8]>::try_from(&b[8 * i..8 * i + 8]).unwrap();
    if u64::from_le_bytes(word(0)) != n as u64 {
        return None;
    }
    let x: Vec<[f64; 3]> = (0..n)
        .map(|i| std::array::from_fn(|k| f64::from_le_bytes(word(4 + 3 * i + k))))
        .collect();
    if x.iter().flatten().any(|c| !c.is_finite()) {
        return None;
    }
    Some(Glass {
        x,
        iterations: u64::from_le_bytes(word(1)) as usize,
        start_noise: f64::from_le_bytes(word(2)),
        noise: f64::from_le_bytes(word(3)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_relaxed_glass_is_smoother_than_its_random_start_and_reads_back_from_the_cache() {
        let n = 10;
        let start = super::super::lattice(3, n, 1.0);
        let len = [1.0; 3];
        let sph = GlassSph {
            variable_hfact: None,
            iad: false,
        };
        let spec = GlassSpec {
            dim: 3,
            len,
            spacing: 0.1,
            h: 0.12,
            seed: 3,
            phase: 0,
            sph,
        };
        let g = relax(&start, &spec).unwrap();
        assert_eq!(g.x.len(), 1000);
        assert!(g.x.iter().flatten().all(|c| (0.0..1.0).contains(c)));
        // The random start's noise is several %, the glass's a small fraction of it.
        assert!(g.start_noise > 0.02, "start {}", g.start_noise);
        assert!(
            g.noise < 0.2 * g.start_noise,
            "{} → {}",
            g.start_noise,
            g.noise
        );
        // It is no lattice: the points are not where the lattice put them.
        let moved =
            g.x.iter()
                .filter(|p| {
                    start
                        .iter()
                        .all(|q| (0..3).any(|k| (p[k] - q[k]).abs() > 1e-3))
                })
                .count();
        assert!(moved > 900, "{moved}");
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("g.bin");
        write(&f, &g).unwrap();
        let back = read(&f, 1000).unwrap();
        assert_eq!(back.x, g.x);
        assert_eq!(back.noise, g.noise);
        assert!(read(&f, 999).is_none());
        // Another phase is another draw.
        assert_ne!(
            digest(&start, &spec),
            digest(&start, &GlassSpec { phase: 1, ..spec })
        );
    }
}
