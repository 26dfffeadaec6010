//! Post-processing of one snapshot: radial profiles (CSV), the report-style figures (PNG), and
//! for the ball the comparison with the 1D reference and the spherical-symmetry check.
//! Used by `dustsph profile SNAPSHOT` and at the end of ball runs.
use crate::analysis::profiles::{
    directional_profile, radial_profiles, write_profiles_csv, ProfileOptions,
};
use crate::analysis::{ball_reference, exact_errors, ExactErrors};
use crate::io::{read_snapshot, IoError, SnapshotData};
use crate::particles::{Gas, Phase, State};
use crate::plot;
use crate::scene::{Problem, Scene};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Spherical symmetry: gas density profiles in cones along the 6 axis directions vs the 8 cube
/// diagonals (method.md §6.1).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Symmetry {
    pub t: f64,
    /// Cone half-angle (rad).
    pub half_angle: f64,
    /// Σ|ρ̄_axes − ρ̄_diagonals| / Σ ρ̄ over bins where both hold particles, r < r_max.
    pub rho_g_relative_l1: f64,
    /// The same for |v|.
    pub speed_relative_l1: f64,
    pub r_max: f64,
}

/// What post-processing produced.
#[derive(Debug, Clone)]
pub struct PostReport {
    pub files: Vec<PathBuf>,
    pub errors: Vec<ExactErrors>,
    pub symmetry: Option<Symmetry>,
    /// What the user should know about how it was made (fewer disc bins than asked, and why).
    pub notes: Vec<String>,
}

/// Particle state back from a snapshot (for the error norms, which work on a [`State`]).
pub fn state_from_snapshot(s: &SnapshotData) -> State {
    let phase = |p: &crate::io::PhaseData, sel: &dyn Fn(usize) -> bool| Phase {
        x: (0..p.x.len()).filter(|&i| sel(i)).map(|i| p.x[i]).collect(),
        v: (0..p.x.len()).filter(|&i| sel(i)).map(|i| p.v[i]).collect(),
        m: (0..p.x.len()).filter(|&i| sel(i)).map(|i| p.m[i]).collect(),
        rho: (0..p.x.len())
            .filter(|&i| sel(i))
            .map(|i| p.rho[i])
            .collect(),
        id: (0..p.x.len())
            .filter(|&i| sel(i))
            .map(|i| p.id[i])
            .collect(),
        fixed: None,
    };
    let gas = s.gas.as_ref().map_or_else(Gas::default, |g| Gas {
        ph: phase(g, &|_| true),
        p: g.p.clone().unwrap_or_else(|| vec![0.0; g.x.len()]),
        c: vec![0.0; g.x.len()],
        e: g.e.clone(),
        h: None,
        omega: None,
        closing_forces: None,
    });
    let dust = s.dust.as_ref().map_or_else(Vec::new, |d| {
        let fr = d.fraction.clone().unwrap_or_else(|| vec![0; d.x.len()]);
        let nf = fr.iter().max().map_or(0, |&m| m as usize + 1);
        (0..nf)
            .map(|k| phase(d, &|i| fr[i] as usize == k))
            .collect()
    });
    State {
        t: s.time,
        step: 0,
        gas,
        dust,
    }
}

/// Axes vs diagonals (3D snapshots only).
pub fn symmetry(snap: &SnapshotData, r_max: f64) -> Option<Symmetry> {
    if snap.dim != 3 {
        return None;
    }
    let half_angle = 0.2;
    let opt = ProfileOptions {
        n_bins: 40,
        r_max: Some(r_max),
    };
    let mean = |dirs: &[[f64; 3]]| -> (Vec<f64>, Vec<f64>) {
        let profs: Vec<_> = dirs
            .iter()
            .map(|&d| directional_profile(snap, d, half_angle, &opt))
            .collect();
        let n = opt.n_bins;
        let avg = |f: &dyn Fn(&crate::analysis::profiles::Profiles, usize) -> f64| -> Vec<f64> {
            (0..n)
                .map(|b| {
                    let v: Vec<f64> = profs
                        .iter()
                        .map(|p| f(p, b))
                        .filter(|x| x.is_finite())
                        .collect();
                    if v.len() == profs.len() {
                        v.iter().sum::<f64>() / v.len() as f64
                    } else {
                        f64::NAN
                    }
                })
                .collect()
        };
        (avg(&|p, b| p.curve.rho_g[b]), avg(&|p, b| p.curve.v[b]))
    };
    let axes: Vec<[f64; 3]> = (0..3)
        .flat_map(|k| {
            [1.0, -1.0].map(|s| {
                let mut d = [0.0; 3];
                d[k] = s;
                d
            })
        })
        .collect();
    let diags: Vec<[f64; 3]> = (0..8)
        .map(|i| {
            [
                if i & 1 == 0 { 1.0 } else { -1.0 },
                if i & 2 == 0 { 1.0 } else { -1.0 },
                if i & 4 == 0 { 1.0 } else { -1.0 },
            ]
        })
        .collect();
    let (ra, va) = mean(&axes);
    let (rd, vd) = mean(&diags);
    let rel = |a: &[f64], b: &[f64]| {
        let (mut num, mut den) = (0.0, 0.0);
        for (x, y) in a.iter().zip(b) {
            if x.is_finite() && y.is_finite() {
                num += (x - y).abs();
                den += 0.5 * (x.abs() + y.abs());
            }
        }
        if den > 0.0 {
            num / den
        } else {
            f64::NAN
        }
    };
    Some(Symmetry {
        t: snap.time,
        half_angle,
        rho_g_relative_l1: rel(&ra, &rd),
        speed_relative_l1: rel(&va, &vd),
        r_max,
    })
}

/// `DIR/snapshot_0004.h5` → `DIR/snapshot_0004_<suffix>`.
fn sibling(path: &Path, suffix: &str) -> PathBuf {
    let stem = path
        .file_stem()
        .map_or_else(|| "snapshot".into(), |s| s.to_string_lossy().into_owned());
    path.with_file_name(format!("{stem}_{suffix}"))
}

/// Profiles CSV and three figures next to the snapshot; for the ball also the reference errors
/// and the symmetry check. `scene` is parsed from the snapshot's own `Scene` attribute.
/// A disc's radial bins at most.
pub const MAX_DISC_BINS: usize = 40;

pub fn post_process(path: &Path, bins: usize) -> Result<PostReport, IoError> {
    let snap = read_snapshot(path)?;
    let scene: Option<Scene> = crate::scene::parse(&snap.scene_text, path, &[]).ok();
    let reference = scene.as_ref().and_then(|s| ball_reference(s, snap.time));
    let prof = radial_profiles(
        &snap,
        &ProfileOptions {
            n_bins: bins,
            r_max: None,
        },
    );
    let name = scene
        .as_ref()
        .map_or("snapshot".to_string(), |s| s.name.clone());
    let title = format!("{name}, t = {:.4}", snap.time);
    let mut files = Vec::new();
    let csv = sibling(path, "profile.csv");
    write_profiles_csv(&csv, &prof)?;
    files.push(csv);
    let f = sibling(path, "profiles.png");
    plot::fig_profiles(&f, &prof, reference.as_ref(), &title)?;
    files.push(f);
    let f = sibling(path, "speed_tstop.png");
    plot::fig_speed_tstop(&f, &snap, reference.as_ref(), &title)?;
    files.push(f);
    let f = sibling(path, "xy.png");
    let h = snap
        .gas
        .as_ref()
        .and_then(|g| g.h.first().copied())
        .unwrap_or(0.05);
    plot::fig_scatter_xy(&f, &snap, h, &title)?;
    files.push(f);
    // A disc (a point mass and locally isothermal gas): its bins against the steady drift.
    let mut notes = Vec::new();
    if let Some(d) = scene
        .as_ref()
        .and_then(|s| crate::analysis::disc::disc_bins(&snap, s, bins.min(MAX_DISC_BINS)))
    {
        if d.r.len() < bins {
            notes.push(format!(
                "disc: {} radial bins, not the {bins} asked: at most {MAX_DISC_BINS}, each at \
                 least 4 h wide (the median gas h; narrower bins alias with the particles' rings)",
                d.r.len()
            ));
        }
        let csv = sibling(path, "disc.csv");
        std::fs::write(&csv, crate::analysis::disc::disc_csv(&d))
            .map_err(|e| IoError::io(&csv, e))?;
        files.push(csv);
        let f = sibling(path, "disc.png");
        plot::fig_disc(&f, &d, &title)?;
        files.push(f);
    }
    let (errors, symmetry) = match &scene {
        Some(s) if s.kind() == Problem::Dustyball => {
            let state = state_from_snapshot(&snap);
            let r0 = s.ball().map_or(1.0, |b| b.radius);
            (exact_errors(s, &state, None), symmetry(&snap, r0))
        }
        _ => (Vec::new(), None),
    };
    Ok(PostReport {
        files,
        errors,
        symmetry,
        notes,
    })
}

// ---------------------------------------------------------------------------------------------
// The command line.

/// One table of error norms, headed by what it compares against, in words: the reference and,
/// wrapped below it, how the errors are measured (the reference's further clauses).
pub fn print_errors(e: &ExactErrors) {
    let mut clauses = e.reference.split("; ");
    println!(
        "  errors at t = {} against the {}",
        e.t,
        clauses.next().unwrap_or("exact solution")
    );
    let rest: Vec<&str> = clauses.collect();
    if !rest.is_empty() {
        for line in wrap(&rest.join("; "), 88) {
            println!("    {line}");
        }
    }
    for f in &e.fields {
        print_field(f);
    }
}

/// `text` in lines of at most `width` characters, broken at spaces.
fn wrap(text: &str, width: usize) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    for word in text.split_whitespace() {
        match lines.last_mut() {
            Some(l) if l.chars().count() + 1 + word.chars().count() <= width => {
                l.push(' ');
                l.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    lines
}

/// One line of an error table; a constant offset (one number) reads as one.
pub fn print_field(f: &crate::analysis::FieldError) {
    if f.field.ends_with(" offset") {
        println!(
            "  {:>8}: {:.3e} (constant, removed from the errors above)",
            f.field, f.norms.l1
        );
    } else {
        println!(
            "  {:>8}: L1 {:.3e}  L2 {:.3e}  Linf {:.3e}",
            f.field, f.norms.l1, f.norms.l2, f.norms.linf
        );
    }
}

#[derive(clap::Args)]
pub struct ProfileArgs {
    snapshot: PathBuf,
    /// Number of radial bins
    #[arg(long, default_value_t = 100)]
    bins: usize,
}

/// More radial bins than this would hold fewer than one particle each in any snapshot that fits
/// in memory.
const MAX_BINS: usize = 1_000_000;

pub fn execute(a: ProfileArgs) -> u8 {
    let ProfileArgs { snapshot, bins } = a;
    if !(1..=MAX_BINS).contains(&bins) {
        eprintln!("error: --bins must be between 1 and {MAX_BINS} (got {bins})");
        return 2;
    }
    // The usual mistakes, said plainly (not as HDF5's errno text), as bad input.
    if snapshot.is_dir() {
        eprintln!(
            "error: {} is a directory; give one of its snapshot_NNNN.h5 files",
            snapshot.display()
        );
        return 2;
    }
    if !snapshot.is_file() {
        eprintln!("error: {}: no such file", snapshot.display());
        return 2;
    }
    match crate::commands::profile::post_process(&snapshot, bins) {
        Ok(r) => {
            for f in &r.files {
                println!("wrote {}", f.display());
            }
            for n in &r.notes {
                eprintln!("dustsph: note: {n}");
            }
            for e in &r.errors {
                print_errors(e);
            }
            if let Some(s) = &r.symmetry {
                println!(
                    "symmetry (axes vs diagonals, r < {}): rho_g {:.3e}, |v| {:.3e} (relative L1)",
                    s.r_max, s.rho_g_relative_l1, s.speed_relative_l1
                );
            }
            0
        }
        Err(e) => {
            eprintln!("error: {e}");
            1
        }
    }
}
