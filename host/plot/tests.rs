use super::*;
use crate::analysis::profiles::tests::{ball, phase, snapshot};
use crate::analysis::profiles::{radial_profiles, ProfileOptions};
use std::fs;

const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'];

/// A small expanding ball: v = r x̂_r, ρ falling outward, dust with stopping times (some
/// infinite).
fn small_ball() -> SnapshotData {
    let x = ball(0.1);
    let n = x.len();
    let rho: Vec<f64> = x.iter().map(|&p| 1.0 - 0.5 * radius(p)).collect();
    let mut gas = phase(x.clone(), vec![1e-3; n], rho.clone(), true);
    // Some scatter about the reference speed |v| = r.
    gas.v = (0..n)
        .map(|i| x[i].map(|c| c * (0.9 + 0.2 * (i % 7) as f64 / 6.0)))
        .collect();
    let mut dust = phase(
        x.iter().map(|p| p.map(|c| 1.01 * c)).collect(),
        vec![5e-4; n],
        rho.iter().map(|r| 0.5 * r).collect(),
        false,
    );
    dust.t_stop = Some(
        (0..n)
            .map(|i| {
                if i % 17 == 0 {
                    f64::INFINITY
                } else {
                    8.45e-4 * (1.0 + 3.0 * radius(x[i]))
                }
            })
            .collect(),
    );
    snapshot(Some(gas), Some(dust))
}

fn reference() -> RadialCurve {
    let r: Vec<f64> = (0..=50).map(|i| i as f64 * 0.02).collect();
    RadialCurve {
        rho_g: r.iter().map(|r| 1.0 - 0.5 * r).collect(),
        rho_d: r.iter().map(|r| 0.5 - 0.25 * r).collect(),
        p: r.iter().map(|r| (1.0 - 0.5 * r).powf(1.4)).collect(),
        e: r.iter().map(|r| 2.5 * (1.0 - 0.5 * r).powf(0.4)).collect(),
        v: r.clone(),
        u: r.clone(),
        r,
    }
}

fn assert_png(path: &Path) {
    let bytes = fs::read(path).unwrap();
    assert!(
        bytes.len() > 1000,
        "{}: {} bytes",
        path.display(),
        bytes.len()
    );
    assert_eq!(bytes[..8], PNG_SIGNATURE, "{}", path.display());
    // The temporary is gone (other tests may be writing into the same directory).
    let name = path.file_name().unwrap().to_string_lossy();
    assert!(!path.with_file_name(format!(".{name}.tmp")).exists());
}

/// Figures go to `DUSTSPH_FIGURE_DIR` when set (to look at them), else to a temporary
/// directory.
fn figure_dir() -> (Option<tempfile::TempDir>, std::path::PathBuf) {
    match std::env::var_os("DUSTSPH_FIGURE_DIR") {
        Some(d) => {
            fs::create_dir_all(&d).unwrap();
            (None, d.into())
        }
        None => {
            let t = tempfile::tempdir().unwrap();
            let p = t.path().to_path_buf();
            (Some(t), p)
        }
    }
}

#[test]
fn embedded_font_draws_text() {
    // Registering twice is harmless, and the font then puts ink on the page.
    ensure_font();
    ensure_font();
    let (w, h) = (120u32, 30u32);
    let mut rgb = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
        root.draw_text("dustsph", &(FONT, 20).into_font().color(&BLACK), (2, 2))
            .unwrap();
        root.present().unwrap();
    }
    let ink = rgb.chunks(3).filter(|p| p[0] < 128).count();
    assert!(ink > 50, "the text left {ink} dark pixels");
}

#[test]
fn profile_figure_is_a_png() {
    let (_keep, dir) = figure_dir();
    let s = small_ball();
    let p = radial_profiles(
        &s,
        &ProfileOptions {
            n_bins: 20,
            r_max: None,
        },
    );
    let path = dir.join("profiles.png");
    fig_profiles(&path, &p, Some(&reference()), "ball, t = 0.2").unwrap();
    assert_png(&path);
    // Without a reference, and for a snapshot with no particles at all.
    let path = dir.join("profiles_noref.png");
    fig_profiles(&path, &p, None, "no reference").unwrap();
    assert_png(&path);
    let empty = radial_profiles(&snapshot(None, None), &ProfileOptions::default());
    let path = dir.join("profiles_empty.png");
    fig_profiles(&path, &empty, None, "empty").unwrap();
    assert_png(&path);
}

#[test]
fn speed_figure_is_a_png() {
    let (_keep, dir) = figure_dir();
    let path = dir.join("speed_tstop.png");
    fig_speed_tstop(&path, &small_ball(), Some(&reference()), "ball, t = 0.2").unwrap();
    assert_png(&path);
    // Dust without stopping times, no reference.
    let mut s = small_ball();
    s.dust.as_mut().unwrap().t_stop = None;
    let path = dir.join("speed_no_tstop.png");
    fig_speed_tstop(&path, &s, None, "no t_stop").unwrap();
    assert_png(&path);
}

#[test]
fn scatter_figure_is_a_png() {
    let (_keep, dir) = figure_dir();
    let path = dir.join("scatter_xy.png");
    fig_scatter_xy(&path, &small_ball(), 0.1, "ball, t = 0.2").unwrap();
    assert_png(&path);
    // A 1D snapshot: every particle, on a line.
    let mut s = snapshot(
        Some(phase(
            (0..50).map(|i| [i as f64 * 0.02, 0.0, 0.0]).collect(),
            vec![1.0; 50],
            vec![1.0; 50],
            true,
        )),
        None,
    );
    s.dim = 1;
    let path = dir.join("scatter_1d.png");
    fig_scatter_xy(&path, &s, 0.1, "1D").unwrap();
    assert_png(&path);
}

#[test]
fn a_missing_directory_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope");
    let err = fig_scatter_xy(&missing.join("a.png"), &small_ball(), 0.1, "x").unwrap_err();
    assert!(err.to_string().contains("nope"), "{err}");
    assert!(!missing.exists());
}

#[test]
fn subsampling_is_deterministic_bounded_and_spread() {
    assert_eq!(subsample(5, 10), vec![0, 1, 2, 3, 4]);
    let a = subsample(100_000, 1000);
    assert_eq!(a.len(), 1000);
    assert_eq!(a, subsample(100_000, 1000));
    assert!(a.windows(2).all(|w| w[0] < w[1]));
    // Roughly uniform over the range: each tenth holds about a tenth.
    for k in 0..10 {
        let c = a.iter().filter(|&&i| i / 10_000 == k).count();
        assert!((60..=140).contains(&c), "tenth {k}: {c}");
    }
    // The joint choice keeps the phases' shares and maps back to each phase's indices.
    let (g, d) = joint_subsample(30_000, 90_000, 12_000);
    assert_eq!(g.len() + d.len(), 12_000);
    assert!((2500..3500).contains(&g.len()), "{}", g.len());
    assert!(g.iter().all(|&i| i < 30_000) && d.iter().all(|&i| i < 90_000));
    assert_eq!(joint_subsample(3, 4, 10), (vec![0, 1, 2], vec![0, 1, 2, 3]));
}

#[test]
fn tick_labels_are_tidy() {
    let f = linear_ticks(&(-1.0..1.0));
    assert_eq!(
        (f(&-1e-17), f(&0.4), f(&-0.6)),
        ("0.0".into(), "0.4".into(), "-0.6".into())
    );
    let f = linear_ticks(&(0.0..200.0));
    assert_eq!(f(&40.0), "40");
    assert_eq!(log_ticks(&1e-3), "1e-3");
    assert_eq!(log_ticks(&2.5e-3), "2.5e-3");
    assert_eq!(log_ticks(&0.0020000000000000005), "2e-3");
    assert_eq!(log_ticks(&100.0), "1e2");
}

#[test]
fn equal_aspect_keeps_units_square() {
    let (x, y) = equal_aspect(Some((-1.0, 1.0)), Some((-0.5, 0.5)), 800, 400);
    let sx = (x.end - x.start) / 800.0;
    let sy = (y.end - y.start) / 400.0;
    assert!((sx - sy).abs() < 1e-12 * sx);
    assert!(x.start <= -1.0 && x.end >= 1.0 && y.start <= -0.5 && y.end >= 0.5);
    let (x, y) = equal_aspect(Some((2.0, 2.0)), Some((0.0, 0.0)), 100, 100);
    assert!(x.contains(&2.0) && y.contains(&0.0) && x.end > x.start);
    let (x, _) = equal_aspect(None, None, 100, 50);
    assert!(x.end > x.start);
}
