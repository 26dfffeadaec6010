//! Mass-weighted radial profiles of a snapshot about the origin (the 3D gas–dust ball of the
//! source report, Fig. 2), in all directions or in a cone around one direction (the
//! spherical-symmetry check: axes against diagonals).
//!
//! Bins are equal in r on [0, r_max]; a particle exactly at r_max falls in the last bin, one
//! beyond it in none. In each bin:
//! - `rho_g`, `p`, `e`, `v`: mass-weighted means over gas particles of ρ, p, e and |v|;
//! - `rho_d`: the dust density of all fractions together, Σ_k of the mass-weighted mean SPH
//!   density of fraction k's particles in the bin (a fraction absent from the bin adds 0);
//! - `u`: mass-weighted mean |v| over all dust particles;
//! - `t_stop`: mass-weighted mean of the finite stopping times of dust particles.
//!
//! A bin with no particle of a phase has NaN in that phase's fields, as does a field the snapshot
//! does not hold (gas pressure, energy, dust stopping time).

use std::path::Path;

use super::radial::RadialCurve;
use crate::io::{write_bytes_atomic, IoError, PhaseData, SnapshotData};

/// How to bin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProfileOptions {
    /// Number of equal-width bins on [0, r_max] (at least 1).
    pub n_bins: usize,
    /// Outer radius; default: the largest radius of any particle in the snapshot (also for
    /// [`directional_profile`], so that profiles along different directions share their bins).
    pub r_max: Option<f64>,
}

impl Default for ProfileOptions {
    fn default() -> Self {
        ProfileOptions {
            n_bins: 100,
            r_max: None,
        }
    }
}

/// Radial profiles of one snapshot.
#[derive(Debug, Clone, PartialEq)]
pub struct Profiles {
    pub time: f64,
    /// Bin centres in `r`; fields as described in the module documentation.
    pub curve: RadialCurve,
    /// Mass-weighted mean dust stopping time per bin (NaN where the bin has no dust particle
    /// with a finite stopping time).
    pub t_stop: Vec<f64>,
    /// Gas particles per bin.
    pub n_gas: Vec<usize>,
    /// Dust particles per bin (all fractions).
    pub n_dust: Vec<usize>,
}

/// Column names of [`write_profiles_csv`], in order.
pub const CSV_COLUMNS: [&str; 10] = [
    "r", "rho_g", "rho_d", "p", "e", "v_g", "u_d", "t_stop", "n_gas", "n_dust",
];

/// Profiles in all directions about the origin.
///
/// # Panics
/// If `opt.n_bins` is 0, or `opt.r_max` is given and not finite and positive.
pub fn radial_profiles(snap: &SnapshotData, opt: &ProfileOptions) -> Profiles {
    bin(snap, opt, |_| true)
}

/// Profile of the particles within a cone of half-angle `half_angle` (radians) about the
/// direction `dir` (need not be normalised). A particle at the origin lies in every cone.
///
/// # Panics
/// As [`radial_profiles`]; also if `dir` is zero or not finite.
pub fn directional_profile(
    snap: &SnapshotData,
    dir: [f64; 3],
    half_angle: f64,
    opt: &ProfileOptions,
) -> Profiles {
    let len = norm(dir);
    assert!(
        len.is_finite() && len > 0.0,
        "directional_profile: direction {dir:?} must be finite and non-zero"
    );
    let d = dir.map(|c| c / len);
    let cos_half = half_angle.cos();
    bin(snap, opt, move |x| {
        let r = norm(x);
        r == 0.0 || dot(x, d) >= r * cos_half
    })
}

fn norm(x: [f64; 3]) -> f64 {
    dot(x, x).sqrt()
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Σ w and Σ w·f of one mean.
#[derive(Debug, Clone, Copy, Default)]
struct Mean {
    w: f64,
    wf: f64,
}

impl Mean {
    fn add(&mut self, w: f64, f: f64) {
        self.w += w;
        self.wf += w * f;
    }

    /// The mean, NaN without weight.
    fn get(self) -> f64 {
        if self.w > 0.0 {
            self.wf / self.w
        } else {
            f64::NAN
        }
    }
}

#[derive(Debug, Clone, Default)]
struct Bin {
    n_gas: usize,
    rho_g: Mean,
    p: Mean,
    e: Mean,
    v: Mean,
    n_dust: usize,
    /// Per fraction.
    rho_d: Vec<Mean>,
    u: Mean,
    t_stop: Mean,
}

fn max_radius(snap: &SnapshotData) -> f64 {
    [&snap.gas, &snap.dust]
        .into_iter()
        .flatten()
        .flat_map(|ph| ph.x.iter())
        .map(|&x| norm(x))
        .fold(0.0, f64::max)
}

/// The bin of radius `r`, if any.
fn bin_index(r: f64, r_max: f64, n: usize) -> Option<usize> {
    if r.is_nan() || r > r_max {
        return None;
    }
    Some((((r / r_max) * n as f64) as usize).min(n - 1))
}

fn bin(snap: &SnapshotData, opt: &ProfileOptions, select: impl Fn([f64; 3]) -> bool) -> Profiles {
    let n = opt.n_bins;
    assert!(n > 0, "profiles need at least one bin");
    let r_max = match opt.r_max {
        Some(r) => {
            assert!(
                r.is_finite() && r > 0.0,
                "profile radius r_max = {r} must be finite and > 0"
            );
            r
        }
        // All particles at the origin (or none): one nominal unit so the bins stay defined.
        None => Some(max_radius(snap)).filter(|&r| r > 0.0).unwrap_or(1.0),
    };
    let n_frac = snap
        .dust
        .as_ref()
        .and_then(|d| d.fraction.as_ref())
        .and_then(|f| f.iter().max())
        .map_or(1, |&k| k as usize + 1);
    let mut bins = vec![
        Bin {
            rho_d: vec![Mean::default(); n_frac],
            ..Bin::default()
        };
        n
    ];
    let selected = |ph: &PhaseData| {
        ph.x.iter()
            .enumerate()
            .filter(|&(_, &x)| select(x))
            .filter_map(|(i, &x)| bin_index(norm(x), r_max, n).map(|b| (i, b)))
            .collect::<Vec<_>>()
    };
    if let Some(g) = &snap.gas {
        for (i, b) in selected(g) {
            let (m, bin) = (g.m[i], &mut bins[b]);
            bin.n_gas += 1;
            bin.rho_g.add(m, g.rho[i]);
            bin.v.add(m, norm(g.v[i]));
            bin.p.add(m, g.p.as_ref().map_or(f64::NAN, |p| p[i]));
            bin.e.add(m, g.e.as_ref().map_or(f64::NAN, |e| e[i]));
        }
    }
    if let Some(d) = &snap.dust {
        for (i, b) in selected(d) {
            let (m, bin) = (d.m[i], &mut bins[b]);
            let k = d.fraction.as_ref().map_or(0, |f| f[i] as usize);
            bin.n_dust += 1;
            bin.rho_d[k].add(m, d.rho[i]);
            bin.u.add(m, norm(d.v[i]));
            if let Some(t) = d.t_stop.as_ref().map(|t| t[i]).filter(|t| t.is_finite()) {
                bin.t_stop.add(m, t);
            }
        }
    }
    let width = r_max / n as f64;
    let mut curve = RadialCurve::default();
    let mut out = Profiles {
        time: snap.time,
        curve: RadialCurve::default(),
        t_stop: Vec::with_capacity(n),
        n_gas: Vec::with_capacity(n),
        n_dust: Vec::with_capacity(n),
    };
    for (j, b) in bins.into_iter().enumerate() {
        curve.r.push((j as f64 + 0.5) * width);
        curve.rho_g.push(b.rho_g.get());
        curve.p.push(b.p.get());
        curve.e.push(b.e.get());
        curve.v.push(b.v.get());
        curve.rho_d.push(if b.n_dust > 0 {
            b.rho_d.iter().filter(|m| m.w > 0.0).map(|m| m.get()).sum()
        } else {
            f64::NAN
        });
        curve.u.push(b.u.get());
        out.t_stop.push(b.t_stop.get());
        out.n_gas.push(b.n_gas);
        out.n_dust.push(b.n_dust);
    }
    out.curve = curve;
    out
}

/// Writes the profiles as CSV: one header line with [`CSV_COLUMNS`], then one row per bin
/// (floats in Rust's shortest round-trip exponent form, empty bins as `NaN`). Atomic (temporary
/// + rename).
pub fn write_profiles_csv(path: &Path, p: &Profiles) -> Result<(), IoError> {
    let c = &p.curve;
    let n = c.len();
    let lens = [
        c.rho_g.len(),
        c.rho_d.len(),
        c.p.len(),
        c.e.len(),
        c.v.len(),
        c.u.len(),
        p.t_stop.len(),
        p.n_gas.len(),
        p.n_dust.len(),
    ];
    if lens.iter().any(|&l| l != n) {
        return Err(IoError::invalid(
            path,
            format!("profile columns have different lengths: r has {n}, others {lens:?}"),
        ));
    }
    let mut w = csv::Writer::from_writer(Vec::new());
    let err = |e: csv::Error| IoError::invalid(path, e.to_string());
    w.write_record(CSV_COLUMNS).map_err(err)?;
    for j in 0..n {
        let floats = [
            c.r[j],
            c.rho_g[j],
            c.rho_d[j],
            c.p[j],
            c.e[j],
            c.v[j],
            c.u[j],
            p.t_stop[j],
        ];
        let mut row: Vec<String> = floats.iter().map(|x| format!("{x:e}")).collect();
        row.push(p.n_gas[j].to_string());
        row.push(p.n_dust[j].to_string());
        w.write_record(&row).map_err(err)?;
    }
    let bytes = w.into_inner().map_err(|e| err(e.into_error().into()))?;
    write_bytes_atomic(path, &bytes)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A phase from positions, masses, densities and speeds along x; gas gets p = ρ and
    /// e = 2.5, dust a stopping time of 1e-3 and fraction 0.
    pub(crate) fn phase(x: Vec<[f64; 3]>, m: Vec<f64>, rho: Vec<f64>, gas: bool) -> PhaseData {
        let n = x.len();
        PhaseData {
            v: x.clone(),
            h: vec![0.1; n],
            id: (0..n as u64).collect(),
            e: gas.then(|| vec![2.5; n]),
            p: gas.then(|| rho.clone()),
            t_stop: (!gas).then(|| vec![1e-3; n]),
            fraction: (!gas).then(|| vec![0; n]),
            x,
            m,
            rho,
        }
    }

    pub(crate) fn snapshot(gas: Option<PhaseData>, dust: Option<PhaseData>) -> SnapshotData {
        SnapshotData {
            time: 0.2,
            dim: 3,
            box_size: [4.0; 3],
            offset: [-2.0; 3],
            scene_text: String::new(),
            num_part: [
                gas.as_ref().map_or(0, |g| g.x.len() as u64),
                0,
                0,
                dust.as_ref().map_or(0, |d| d.x.len() as u64),
                0,
                0,
            ],
            gas,
            dust,
        }
    }

    /// Lattice points of spacing `dx` inside the unit ball, offset by half a cell.
    pub(crate) fn ball(dx: f64) -> Vec<[f64; 3]> {
        let k = (1.0 / dx).ceil() as i64;
        let mut out = Vec::new();
        for i in -k..k {
            for j in -k..k {
                for l in -k..k {
                    let x = [i, j, l].map(|c| (c as f64 + 0.5) * dx);
                    if norm(x) <= 1.0 {
                        out.push(x);
                    }
                }
            }
        }
        out
    }

    #[test]
    fn uniform_ball_gives_flat_profiles() {
        let x = ball(0.05);
        let n = x.len();
        let gas = phase(x.clone(), vec![1e-4; n], vec![1.0; n], true);
        let mut dust = phase(x, vec![5e-5; n], vec![0.5; n], false);
        dust.v = dust.x.iter().map(|_| [0.0, 0.3, 0.4]).collect();
        let s = snapshot(Some(gas), Some(dust));
        let p = radial_profiles(
            &s,
            &ProfileOptions {
                n_bins: 10,
                r_max: None,
            },
        );
        assert_eq!(p.time, 0.2);
        assert_eq!(p.curve.len(), 10);
        let r_max = max_radius(&s);
        assert!((p.curve.r[0] - 0.05 * r_max).abs() < 1e-12);
        assert!((p.curve.r[9] - 0.95 * r_max).abs() < 1e-12);
        assert_eq!(p.n_gas.iter().sum::<usize>(), n);
        assert_eq!(p.n_dust, p.n_gas);
        for j in 0..10 {
            assert!(p.n_gas[j] > 0, "bin {j}");
            assert!((p.curve.rho_g[j] - 1.0).abs() < 1e-12);
            assert!((p.curve.rho_d[j] - 0.5).abs() < 1e-12);
            assert!((p.curve.p[j] - 1.0).abs() < 1e-12);
            assert!((p.curve.e[j] - 2.5).abs() < 1e-12);
            assert!((p.curve.u[j] - 0.5).abs() < 1e-12);
            assert!((p.t_stop[j] - 1e-3).abs() < 1e-15);
            // Gas moves radially at |v| = r: the bin mean lies inside the bin.
            let (lo, hi) = (j as f64 * 0.1 * r_max, (j + 1) as f64 * 0.1 * r_max);
            assert!(p.curve.v[j] >= lo && p.curve.v[j] <= hi, "bin {j}");
        }
        // Shell volume ∝ r²: particle counts grow outward.
        assert!(p.n_gas[8] > 10 * p.n_gas[1]);
    }

    #[test]
    fn means_are_mass_weighted_and_fractions_add_up() {
        // One bin, two gas particles of different mass and density.
        let gas = PhaseData {
            e: Some(vec![1.0, 4.0]),
            p: Some(vec![2.0, 8.0]),
            v: vec![[3.0, 4.0, 0.0], [0.0, 0.0, 10.0]],
            ..phase(
                vec![[0.1, 0.0, 0.0], [0.0, 0.2, 0.0]],
                vec![3.0, 1.0],
                vec![1.0, 5.0],
                true,
            )
        };
        // Dust: fraction 0 (two particles), fraction 2 (one), an uncoupled particle (t = inf)
        // and one without a value (NaN).
        let dust = PhaseData {
            fraction: Some(vec![0, 0, 2, 2, 2]),
            t_stop: Some(vec![1.0, 2.0, 4.0, f64::INFINITY, f64::NAN]),
            v: vec![[1.0, 0.0, 0.0]; 5],
            ..phase(
                vec![[0.0, 0.0, 0.3]; 5],
                vec![1.0, 3.0, 2.0, 2.0, 2.0],
                vec![0.2, 0.6, 0.1, 0.1, 0.1],
                false,
            )
        };
        let s = snapshot(Some(gas), Some(dust));
        let p = radial_profiles(
            &s,
            &ProfileOptions {
                n_bins: 2,
                r_max: Some(1.0),
            },
        );
        assert_eq!(p.curve.r, vec![0.25, 0.75]);
        assert_eq!(
            (p.n_gas.clone(), p.n_dust.clone()),
            (vec![2, 0], vec![5, 0])
        );
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(p.curve.rho_g[0], (3.0 * 1.0 + 1.0 * 5.0) / 4.0));
        assert!(close(p.curve.p[0], (3.0 * 2.0 + 8.0) / 4.0));
        assert!(close(p.curve.e[0], (3.0 * 1.0 + 4.0) / 4.0));
        assert!(close(p.curve.v[0], (3.0 * 5.0 + 10.0) / 4.0));
        // Fraction 0: (1·0.2 + 3·0.6)/4 = 0.5; fraction 2: 0.1; fraction 1 is absent.
        assert!(close(p.curve.rho_d[0], 0.6));
        assert!(close(p.curve.u[0], 1.0));
        // Only finite stopping times: (1·1 + 3·2 + 2·4)/6.
        assert!(close(p.t_stop[0], 15.0 / 6.0));
        // The empty outer bin: NaN fields, zero counts, but a centre.
        let c = &p.curve;
        for f in [
            c.rho_g[1],
            c.rho_d[1],
            c.p[1],
            c.e[1],
            c.v[1],
            c.u[1],
            p.t_stop[1],
        ] {
            assert!(f.is_nan());
        }
    }

    #[test]
    fn missing_fields_and_particles_outside_r_max() {
        // Isothermal-like gas without pressure, dust without stopping times; one particle on
        // the outer edge (kept) and one beyond it (dropped).
        let mut gas = phase(
            vec![[1.0, 0.0, 0.0], [0.0, 1.5, 0.0]],
            vec![1.0; 2],
            vec![1.0; 2],
            true,
        );
        gas.p = None;
        let mut dust = phase(vec![[0.0, 0.0, 0.0]], vec![1.0], vec![2.0], false);
        dust.t_stop = None;
        dust.fraction = None;
        let s = snapshot(Some(gas), Some(dust));
        let p = radial_profiles(
            &s,
            &ProfileOptions {
                n_bins: 4,
                r_max: Some(1.0),
            },
        );
        assert_eq!(p.n_gas, vec![0, 0, 0, 1]);
        assert_eq!(p.n_dust, vec![1, 0, 0, 0]);
        assert!(p.curve.p[3].is_nan() && (p.curve.e[3] - 2.5).abs() < 1e-15);
        assert_eq!(p.curve.rho_d[0], 2.0);
        assert!(p.t_stop[0].is_nan());
        // The default r_max is the largest radius, 1.5.
        let d = radial_profiles(
            &s,
            &ProfileOptions {
                n_bins: 3,
                r_max: None,
            },
        );
        assert_eq!(d.n_gas, vec![0, 0, 2]);
        // No particles at all: all bins empty.
        let e = radial_profiles(&snapshot(None, None), &ProfileOptions::default());
        assert!(e.n_gas.iter().chain(&e.n_dust).all(|&c| c == 0));
        assert!(e.curve.rho_g.iter().all(|x| x.is_nan()));
    }

    #[test]
    fn directional_profile_selects_the_cone() {
        // Gas on the +x axis, on the diagonal (1,1,1), slightly off +x (5°), on −x, and at the
        // origin; densities tell them apart.
        let s5 = 5f64.to_radians();
        let x = vec![
            [0.5, 0.0, 0.0],
            [0.5, 0.5, 0.5],
            [0.8 * s5.cos(), 0.8 * s5.sin(), 0.0],
            [-0.5, 0.0, 0.0],
            [0.0, 0.0, 0.0],
        ];
        let gas = phase(x, vec![1.0; 5], vec![1.0, 2.0, 3.0, 4.0, 5.0], true);
        let s = snapshot(Some(gas), None);
        let opt = ProfileOptions {
            n_bins: 10,
            r_max: Some(1.0),
        };
        let narrow = directional_profile(&s, [2.0, 0.0, 0.0], 3f64.to_radians(), &opt);
        assert_eq!(narrow.n_gas.iter().sum::<usize>(), 2);
        assert_eq!((narrow.n_gas[0], narrow.n_gas[5]), (1, 1));
        assert_eq!((narrow.curve.rho_g[0], narrow.curve.rho_g[5]), (5.0, 1.0));
        let wide = directional_profile(&s, [1.0, 0.0, 0.0], 10f64.to_radians(), &opt);
        assert_eq!(wide.n_gas.iter().sum::<usize>(), 3);
        assert_eq!(wide.curve.rho_g[8], 3.0);
        let diag = directional_profile(&s, [1.0, 1.0, 1.0], 0.1, &opt);
        assert_eq!(diag.n_gas.iter().sum::<usize>(), 2);
        assert_eq!(diag.curve.rho_g[8], 2.0);
        let back = directional_profile(&s, [-1.0, 0.0, 0.0], 0.1, &opt);
        assert_eq!(back.curve.rho_g[5], 4.0);
        // Half-angle π: everything.
        let all = directional_profile(&s, [0.0, 0.0, 1.0], std::f64::consts::PI, &opt);
        // (Debug text: NaN fields compare equal there.)
        assert_eq!(
            format!("{all:?}"),
            format!("{:?}", radial_profiles(&s, &opt))
        );
    }

    #[test]
    fn directional_profiles_of_a_uniform_ball_agree_with_the_full_one() {
        let x = ball(0.04);
        let n = x.len();
        let s = snapshot(Some(phase(x, vec![1.0; n], vec![1.0; n], true)), None);
        let opt = ProfileOptions {
            n_bins: 8,
            r_max: None,
        };
        let full = radial_profiles(&s, &opt);
        for dir in [[1.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, -1.0, 1.0]] {
            let p = directional_profile(&s, dir, 0.3, &opt);
            assert_eq!(p.curve.r, full.curve.r);
            // Cone solid angle 2π(1 − cos 0.3) of 4π: about 2.2 % of the particles.
            let frac = p.n_gas.iter().sum::<usize>() as f64 / n as f64;
            assert!((frac - 0.5 * (1.0 - 0.3f64.cos())).abs() < 0.005, "{frac}");
            for j in 1..8 {
                assert_eq!(p.curve.rho_g[j], 1.0, "{dir:?} bin {j}");
            }
        }
    }

    #[test]
    #[should_panic(expected = "non-zero")]
    fn zero_direction_panics() {
        directional_profile(
            &snapshot(None, None),
            [0.0; 3],
            0.1,
            &ProfileOptions::default(),
        );
    }

    #[test]
    fn csv_has_a_header_and_one_row_per_bin_and_is_written_atomically() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("profiles_0003.csv");
        std::fs::write(dir.path().join(".profiles_0003.csv.tmp"), b"stale").unwrap();
        let gas = phase(vec![[0.1, 0.0, 0.0]], vec![1.0], vec![1.25], true);
        let s = snapshot(Some(gas), None);
        let p = radial_profiles(
            &s,
            &ProfileOptions {
                n_bins: 3,
                r_max: Some(0.3),
            },
        );
        write_profiles_csv(&path, &p).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], "r,rho_g,rho_d,p,e,v_g,u_d,t_stop,n_gas,n_dust");
        assert_eq!(lines.len(), 4);
        let row: Vec<&str> = lines[2].split(',').collect();
        assert_eq!(row.len(), 10);
        let num = |s: &str| s.parse::<f64>().unwrap();
        assert!((num(row[0]) - 0.15).abs() < 1e-15);
        assert_eq!(num(row[1]), 1.25);
        assert!(num(row[2]).is_nan());
        assert_eq!((row[8], row[9]), ("1", "0"));
        assert!(lines[1].ends_with(",0,0"));
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec!["profiles_0003.csv"]);

        let mut bad = p.clone();
        bad.n_dust.pop();
        let err = write_profiles_csv(&path, &bad).unwrap_err();
        assert!(err.to_string().contains("profiles_0003.csv"), "{err}");
    }
}
