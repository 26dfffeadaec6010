//! PNG figures of snapshots and profiles, after Figures 1–3 of the source report (the 3D
//! gas–dust ball expanding into vacuum):
//! - [`fig_scatter_xy`]: particles in a slab |z| < s, gas and dust side by side (Fig. 1);
//! - [`fig_profiles`]: radial profiles of ρ_g and ρ_d, p, e and the speeds (Fig. 2);
//! - [`fig_speed_tstop`]: particle speed and dust stopping time against radius (Fig. 3).
//!
//! Text is drawn with DejaVu Sans embedded in the binary (`DejaVuSans.ttf`, licence in
//! `DejaVuSans-LICENSE.txt` beside it), so no system font is needed. Every figure is rendered in
//! memory, encoded as PNG and written atomically (temporary in the same directory + rename).

use std::error::Error;
use std::ops::Range;
use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use crate::analysis::profiles::Profiles;
use crate::analysis::radial::RadialCurve;
use crate::io::{write_bytes_atomic, IoError, PhaseData, SnapshotData};

pub mod loglog;
pub use loglog::{fig_loglog, LogLogSeries};

/// The embedded font (Bitstream Vera licence, see `DejaVuSans-LICENSE.txt`).
const FONT_TTF: &[u8] = include_bytes!("DejaVuSans.ttf");
/// The family plotters asks for by default; the embedded font is registered under it.
const FONT: &str = "sans-serif";

/// Most points drawn in one scatter panel; larger sets are subsampled deterministically.
pub const MAX_SCATTER_POINTS: usize = 50_000;

const GAS: RGBColor = RGBColor(31, 119, 180);
const DUST: RGBColor = RGBColor(214, 39, 40);
const GAS_REF: RGBColor = RGBColor(0, 30, 90);
const DUST_REF: RGBColor = RGBColor(110, 0, 0);

type DrawResult = Result<(), Box<dyn Error>>;
/// A labelled reference line: label, points, colour.
type RefLine = (&'static str, Vec<(f64, f64)>, RGBColor);

/// Registers the embedded font with plotters (once per process).
fn ensure_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        if register_font(FONT, FontStyle::Normal, FONT_TTF).is_err() {
            panic!("the embedded DejaVu Sans font does not parse");
        }
    });
}

/// Renders a `w`×`h` RGB picture with `draw` and writes it to `path` as PNG, atomically.
fn render_png(
    path: &Path,
    (w, h): (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> DrawResult,
) -> Result<(), IoError> {
    ensure_font();
    let mut rgb = vec![255u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
        root.fill(&WHITE)
            .map_err(Box::<dyn Error>::from)
            .and_then(|()| draw(&root))
            .and_then(|()| root.present().map_err(Box::<dyn Error>::from))
            .map_err(|e| IoError::invalid(path, format!("drawing the figure failed: {e}")))?;
    }
    let mut png_bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut png_bytes, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .and_then(|mut wr| wr.write_image_data(&rgb))
            .map_err(|e| IoError::invalid(path, format!("PNG encoding failed: {e}")))?;
    }
    write_bytes_atomic(path, &png_bytes)
}

/// Smallest and largest finite value, if any.
fn finite_span(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((f64::min(lo, v), f64::max(hi, v))),
        })
}

/// A linear axis range around `span` with 5 % room each side; something sensible when the span
/// is empty or a single value.
fn padded(span: Option<(f64, f64)>) -> Range<f64> {
    match span {
        None => 0.0..1.0,
        Some((lo, hi)) if hi > lo => {
            let pad = 0.05 * (hi - lo);
            (lo - pad)..(hi + pad)
        }
        Some((0.0, _)) => -1.0..1.0,
        Some((v, _)) => {
            let pad = 0.1 * v.abs();
            (v - pad)..(v + pad)
        }
    }
}

/// Tick labels for a linear axis over `range`: as many decimals as the tick spacing needs, and
/// no "-0.0".
fn linear_ticks(range: &Range<f64>) -> impl Fn(&f64) -> String {
    let step = (range.end - range.start).abs() / 10.0;
    let decimals = if step > 0.0 && step.is_finite() {
        (-step.log10().floor()).clamp(0.0, 12.0) as usize
    } else {
        1
    };
    move |&v| {
        let s = format!("{v:.decimals$}");
        match s.strip_prefix('-') {
            Some(rest) if rest.bytes().all(|b| b == b'0' || b == b'.') => rest.to_string(),
            _ => s,
        }
    }
}

/// Tick labels for a log axis: shortest scientific form ("1e-3", "2.5e-3").
fn log_ticks(v: &f64) -> String {
    let s = format!("{v:.3e}");
    match s.split_once('e') {
        Some((mant, exp)) => {
            let mant = if mant.contains('.') {
                mant.trim_end_matches('0').trim_end_matches('.')
            } else {
                mant
            };
            format!("{mant}e{exp}")
        }
        None => s,
    }
}

/// Marker radius for a scatter of `n` points: bigger when few.
fn dot_size(n: usize) -> i32 {
    if n <= 5000 {
        2
    } else {
        1
    }
}

/// A log axis range around the positive finite values.
fn log_range(values: impl IntoIterator<Item = f64>) -> Range<f64> {
    match finite_span(values.into_iter().filter(|&v| v > 0.0)) {
        None => 1e-3..1.0,
        Some((lo, hi)) if hi > lo => (lo / 1.3)..(hi * 1.3),
        Some((v, _)) => (v / 2.0)..(v * 2.0),
    }
}

/// A deterministic, evenly spread choice of at most `limit` indices out of `0..n`, in increasing
/// order: the `limit` indices with the smallest hash (so no lattice ordering is aliased).
fn subsample(n: usize, limit: usize) -> Vec<usize> {
    if n <= limit {
        return (0..n).collect();
    }
    let mut keyed: Vec<(u64, usize)> = (0..n).map(|i| (splitmix64(i as u64), i)).collect();
    if limit > 0 {
        keyed.select_nth_unstable(limit - 1);
    }
    let mut out: Vec<usize> = keyed[..limit].iter().map(|&(_, i)| i).collect();
    out.sort_unstable();
    out
}

/// SplitMix64's finaliser: a fixed, well-mixing hash of an index.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Indices of gas and dust particles to draw: at most `limit` in all, chosen over the joint
/// index space so both phases keep their share.
fn joint_subsample(n_gas: usize, n_dust: usize, limit: usize) -> (Vec<usize>, Vec<usize>) {
    let pick = subsample(n_gas + n_dust, limit);
    let split = pick.partition_point(|&i| i < n_gas);
    (
        pick[..split].to_vec(),
        pick[split..].iter().map(|&i| i - n_gas).collect(),
    )
}

fn speed(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

fn radius(x: [f64; 3]) -> f64 {
    speed(x)
}

/// How a curve is drawn.
#[derive(Clone, Copy, PartialEq)]
enum Style {
    /// SPH bins: markers joined by a thin line (broken at empty bins).
    Points,
    /// Reference solution: a solid line.
    Line,
}

struct Curve<'a> {
    label: &'a str,
    r: &'a [f64],
    y: Vec<f64>,
    color: RGBColor,
    style: Style,
}

/// The runs of consecutive finite points of a curve.
fn finite_runs(r: &[f64], y: &[f64]) -> Vec<Vec<(f64, f64)>> {
    let mut runs = vec![Vec::new()];
    for (&x, &v) in r.iter().zip(y) {
        if x.is_finite() && v.is_finite() {
            runs.last_mut().expect("never empty").push((x, v));
        } else if !runs.last().expect("never empty").is_empty() {
            runs.push(Vec::new());
        }
    }
    runs.retain(|r| !r.is_empty());
    runs
}

/// One panel of curves against r.
fn curve_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    caption: &str,
    y_desc: &str,
    x_range: Range<f64>,
    curves: &[Curve],
    legend_at: SeriesLabelPosition,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let y_range = padded(finite_span(curves.iter().flat_map(|c| {
        c.r.iter()
            .zip(&c.y)
            .filter(|(&r, _)| x_range.contains(&r))
            .map(|(_, &y)| y)
    })));
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FONT, 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(75)
        .build_cartesian_2d(x_range.clone(), y_range.clone())?;
    chart
        .configure_mesh()
        .x_desc("r")
        .y_desc(y_desc)
        .x_label_formatter(&linear_ticks(&x_range))
        .y_label_formatter(&linear_ticks(&y_range))
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 18))
        .max_light_lines(4)
        .draw()?;
    for c in curves {
        let color = c.color;
        let runs = finite_runs(c.r, &c.y);
        match c.style {
            Style::Line => {
                for (k, run) in runs.into_iter().enumerate() {
                    let s = chart.draw_series(LineSeries::new(run, color.stroke_width(2)))?;
                    if k == 0 {
                        s.label(c.label).legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(2))
                        });
                    }
                }
            }
            Style::Points => {
                for run in &runs {
                    chart.draw_series(LineSeries::new(run.iter().copied(), color.mix(0.5)))?;
                }
                let points = runs.into_iter().flatten();
                chart
                    .draw_series(points.map(|p| Circle::new(p, 3, color.filled())))?
                    .label(c.label)
                    .legend(move |(x, y)| Circle::new((x + 12, y), 4, color.filled()));
            }
        }
    }
    if !curves.is_empty() {
        chart
            .configure_series_labels()
            .position(legend_at)
            .label_font((FONT, 16))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
    }
    Ok(())
}

/// Radial profiles as in the report's Fig. 2: ρ_g and ρ_d, p, e and the speeds against r, SPH
/// bins as markers, the reference (if given) as solid lines. 1400×1000 px.
pub fn fig_profiles(
    path: &Path,
    prof: &Profiles,
    reference: Option<&RadialCurve>,
    title: &str,
) -> Result<(), IoError> {
    let c = &prof.curve;
    let r_hi = finite_span(
        c.r.iter()
            .chain(reference.map_or(&[][..], |rc| &rc.r[..]))
            .copied(),
    )
    .map_or(1.0, |(_, hi)| hi);
    // The last bin centre is half a bin inside r_max.
    let half_bin = if c.len() > 1 {
        0.5 * (c.r[1] - c.r[0])
    } else {
        0.0
    };
    let x_range = 0.0..(r_hi + half_bin) * 1.02;
    let sph = |label, y: &[f64], color| Curve {
        label,
        r: &c.r,
        y: y.to_vec(),
        color,
        style: Style::Points,
    };
    let abs = |y: &[f64]| -> Vec<f64> { y.iter().map(|v| v.abs()).collect() };
    let mut rho = vec![
        sph("SPH gas", &c.rho_g, GAS),
        sph("SPH dust", &c.rho_d, DUST),
    ];
    let mut p = vec![sph("SPH gas", &c.p, GAS)];
    let mut e = vec![sph("SPH gas", &c.e, GAS)];
    let mut v = vec![sph("SPH gas", &c.v, GAS), sph("SPH dust", &c.u, DUST)];
    if let Some(rc) = reference {
        let exact = |label, y: &[f64], color| Curve {
            label,
            r: &rc.r,
            y: y.to_vec(),
            color,
            style: Style::Line,
        };
        rho.push(exact("reference gas", &rc.rho_g, GAS_REF));
        rho.push(exact("reference dust", &rc.rho_d, DUST_REF));
        p.push(exact("reference", &rc.p, GAS_REF));
        e.push(exact("reference", &rc.e, GAS_REF));
        v.push(exact("reference gas", &abs(&rc.v), GAS_REF));
        v.push(exact("reference dust", &abs(&rc.u), DUST_REF));
    }
    render_png(path, (1400, 1000), |root| {
        let area = root.titled(title, (FONT, 28))?;
        let panels = area.split_evenly((2, 2));
        use SeriesLabelPosition::{UpperLeft, UpperRight};
        let r = x_range.clone();
        curve_panel(&panels[0], "density", "ρ", r.clone(), &rho, UpperRight)?;
        curve_panel(&panels[1], "gas pressure", "p", r.clone(), &p, UpperRight)?;
        curve_panel(
            &panels[2],
            "gas internal energy",
            "e",
            r.clone(),
            &e,
            UpperRight,
        )?;
        curve_panel(&panels[3], "mean speed", "|v|", r, &v, UpperLeft)?;
        Ok(())
    })
}

/// Particle speed of gas and dust against radius, and the dust stopping time against radius on
/// a log scale, as in the report's Fig. 3. Scatter panels show at most
/// [`MAX_SCATTER_POINTS`] particles (a deterministic subsample); stopping times that are not
/// finite and positive are left out. The reference (if given) adds |v| and |u| as lines.
/// 1400×1000 px.
pub fn fig_speed_tstop(
    path: &Path,
    snap: &SnapshotData,
    reference: Option<&RadialCurve>,
    title: &str,
) -> Result<(), IoError> {
    let (gas, dust) = (snap.gas.as_ref(), snap.dust.as_ref());
    let n = |ph: Option<&PhaseData>| ph.map_or(0, |p| p.x.len());
    let (ig, id) = joint_subsample(n(gas), n(dust), MAX_SCATTER_POINTS);
    let pts = |ph: Option<&PhaseData>, idx: &[usize]| -> Vec<(f64, f64)> {
        ph.map_or(Vec::new(), |p| {
            idx.iter()
                .map(|&i| (radius(p.x[i]), speed(p.v[i])))
                .collect()
        })
    };
    let (vg, vd) = (pts(gas, &ig), pts(dust, &id));
    let ts = stopping_times(dust);
    let ref_r = reference.map_or(&[][..], |rc| &rc.r[..]);
    let r_hi = finite_span(
        vg.iter()
            .chain(&vd)
            .map(|p| p.0)
            .chain(ref_r.iter().copied()),
    )
    .map_or(1.0, |(_, hi)| hi);
    let x_range = 0.0..r_hi * 1.03;
    let ref_speeds = reference_speeds(reference);
    let n_shown = vg.len() + vd.len();
    let n_all = n(gas) + n(dust);
    render_png(path, (1400, 1000), |root| {
        let area = root.titled(title, (FONT, 28))?;
        let (top, bottom) = area.split_vertically(area.dim_in_pixel().1 / 2);
        let y_range = padded(
            finite_span(
                vg.iter()
                    .chain(&vd)
                    .map(|p| p.1)
                    .chain(ref_speeds.iter().flat_map(|l| l.1.iter().map(|p| p.1))),
            )
            .map(|(_, hi)| (0.0, hi)),
        );
        let caption = if n_shown < n_all {
            format!("particle speed ({n_shown} of {n_all} particles shown)")
        } else {
            "particle speed".to_string()
        };
        let mut chart = ChartBuilder::on(&top)
            .caption(caption, (FONT, 22))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(75)
            .build_cartesian_2d(x_range.clone(), y_range.clone())?;
        chart
            .configure_mesh()
            .x_desc("r")
            .y_desc("|v|")
            .x_label_formatter(&linear_ticks(&x_range))
            .y_label_formatter(&linear_ticks(&y_range))
            .label_style((FONT, 15))
            .axis_desc_style((FONT, 18))
            .max_light_lines(4)
            .draw()?;
        let dot = dot_size(vg.len() + vd.len());
        for (label, p, color) in [("gas", &vg, GAS), ("dust", &vd, DUST)] {
            if p.is_empty() {
                continue;
            }
            chart
                .draw_series(
                    p.iter()
                        .map(|&q| Circle::new(q, dot, color.mix(0.6).filled())),
                )?
                .label(label)
                .legend(move |(x, y)| Circle::new((x + 12, y), 4, color.filled()));
        }
        for (label, line, color) in &ref_speeds {
            let color = *color;
            chart
                .draw_series(LineSeries::new(line.iter().copied(), color.stroke_width(2)))?
                .label(*label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font((FONT, 16))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;

        tstop_panel(&bottom, x_range.clone(), &ts)
    })
}

/// The stopping-time panel's points (radius, t_s): a subsample of the dust particles with
/// usable (finite, positive) values.
fn stopping_times(dust: Option<&PhaseData>) -> Vec<(f64, f64)> {
    dust.map_or(Vec::new(), |d| {
        let t = d.t_stop.as_deref().unwrap_or(&[]);
        let usable: Vec<usize> = (0..t.len())
            .filter(|&i| t[i].is_finite() && t[i] > 0.0)
            .collect();
        subsample(usable.len(), MAX_SCATTER_POINTS)
            .into_iter()
            .map(|k| (radius(d.x[usable[k]]), t[usable[k]]))
            .collect()
    })
}

/// The reference's |v| and |u| against radius, as lines (none without a reference).
fn reference_speeds(reference: Option<&RadialCurve>) -> Vec<RefLine> {
    reference.map_or(Vec::new(), |rc| {
        let line = |y: &[f64]| -> Vec<(f64, f64)> {
            rc.r.iter()
                .zip(y)
                .filter(|(r, y)| r.is_finite() && y.is_finite())
                .map(|(&r, &y)| (r, y.abs()))
                .collect()
        };
        vec![
            ("reference gas", line(&rc.v), GAS_REF),
            ("reference dust", line(&rc.u), DUST_REF),
        ]
    })
}

/// The dust stopping time against radius on a log scale (the lower panel of
/// [`fig_speed_tstop`]).
fn tstop_panel<DB: DrawingBackend>(
    bottom: &DrawingArea<DB, Shift>,
    x_range: Range<f64>,
    ts: &[(f64, f64)],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let caption = if ts.is_empty() {
        "dust stopping time (no finite values)".to_string()
    } else {
        "dust stopping time".to_string()
    };
    let mut chart = ChartBuilder::on(bottom)
        .caption(caption, (FONT, 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(75)
        .build_cartesian_2d(
            x_range.clone(),
            log_range(ts.iter().map(|p| p.1)).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("r")
        .y_desc("t_stop")
        .x_label_formatter(&linear_ticks(&x_range))
        .y_label_formatter(&log_ticks)
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 18))
        .draw()?;
    chart.draw_series(
        ts.iter()
            .map(|&q| Circle::new(q, dot_size(ts.len()), DUST.mix(0.6).filled())),
    )?;
    Ok(())
}

/// Gas and dust particles in the slab |z| < `slab` (1D/2D snapshots: all particles) in the x–y
/// plane, side by side with the same axes at equal aspect, as in the report's Fig. 1. At most
/// [`MAX_SCATTER_POINTS`] particles are drawn (a deterministic subsample). 1700×900 px.
pub fn fig_scatter_xy(
    path: &Path,
    snap: &SnapshotData,
    slab: f64,
    title: &str,
) -> Result<(), IoError> {
    let in_slab = |x: &[f64; 3]| snap.dim < 3 || x[2].abs() < slab;
    let pick = |ph: Option<&PhaseData>| -> Vec<(f64, f64)> {
        ph.map_or(Vec::new(), |p| {
            p.x.iter()
                .filter(|x| in_slab(x))
                .map(|x| (x[0], x[1]))
                .collect()
        })
    };
    let (g_all, d_all) = (pick(snap.gas.as_ref()), pick(snap.dust.as_ref()));
    let (ig, id) = joint_subsample(g_all.len(), d_all.len(), MAX_SCATTER_POINTS);
    let g: Vec<(f64, f64)> = ig.iter().map(|&i| g_all[i]).collect();
    let d: Vec<(f64, f64)> = id.iter().map(|&i| d_all[i]).collect();
    let bx = finite_span(g_all.iter().chain(&d_all).map(|p| p.0));
    let by = finite_span(g_all.iter().chain(&d_all).map(|p| p.1));
    let where_ = if snap.dim < 3 {
        "all particles".to_string()
    } else {
        format!("|z| < {slab}")
    };
    render_png(path, (1700, 900), |root| {
        let area = root.titled(title, (FONT, 28))?;
        let (left, right) = area.split_horizontally(area.dim_in_pixel().0 / 2);
        for (panel, name, pts, total, color) in [
            (&left, "gas", &g, g_all.len(), GAS),
            (&right, "dust", &d, d_all.len(), DUST),
        ] {
            let caption = if pts.len() < total {
                format!("{name}, {where_}: {} of {total} particles", pts.len())
            } else {
                format!("{name}, {where_}: {total} particles")
            };
            let panel = panel.titled(&caption, (FONT, 22))?;
            let build = |x: Range<f64>, y: Range<f64>| {
                ChartBuilder::on(&panel)
                    .margin(15)
                    .x_label_area_size(45)
                    .y_label_area_size(70)
                    .build_cartesian_2d(x, y)
            };
            // Measure the plotting area, then widen one range so a unit is as long in x as in y.
            let (pw, ph) = build(0.0..1.0, 0.0..1.0)?.plotting_area().dim_in_pixel();
            let (xr, yr) = equal_aspect(bx, by, pw.max(1), ph.max(1));
            let mut chart = build(xr.clone(), yr.clone())?;
            chart
                .configure_mesh()
                .x_desc("x")
                .y_desc("y")
                .x_label_formatter(&linear_ticks(&xr))
                .y_label_formatter(&linear_ticks(&yr))
                .label_style((FONT, 15))
                .axis_desc_style((FONT, 18))
                .max_light_lines(4)
                .draw()?;
            let dot = dot_size(pts.len());
            chart.draw_series(pts.iter().map(|&q| Circle::new(q, dot, color.filled())))?;
        }
        Ok(())
    })
}

/// Axis ranges covering both spans (with 5 % room) whose data-per-pixel ratio is the same in x
/// and y for a plotting area of `pw`×`ph` pixels.
fn equal_aspect(
    bx: Option<(f64, f64)>,
    by: Option<(f64, f64)>,
    pw: u32,
    ph: u32,
) -> (Range<f64>, Range<f64>) {
    let centre_half =
        |b: Option<(f64, f64)>| b.map_or((0.0, 0.0), |(lo, hi)| (0.5 * (lo + hi), 0.5 * (hi - lo)));
    let ((cx, hx), (cy, hy)) = (centre_half(bx), centre_half(by));
    let (pw, ph) = (f64::from(pw), f64::from(ph));
    // Data units per pixel: enough for both extents; a single point gets a unit square.
    let mut s = (2.0 * hx / pw).max(2.0 * hy / ph) * 1.05;
    if !(s.is_finite() && s > 0.0) {
        s = 2.0 / pw.min(ph);
    }
    (
        (cx - 0.5 * s * pw)..(cx + 0.5 * s * pw),
        (cy - 0.5 * s * ph)..(cy + 0.5 * s * ph),
    )
}

#[cfg(test)]
mod tests;

/// A disc snapshot in radial bins (`analysis::disc`): Σ of every phase, and its ⟨v_R⟩ and
/// ⟨v_φ⟩ − v_K as markers beside the exact steady drift from the bins' own ε, St and pressure
/// gradient as lines. 1400×1000 px.
pub fn fig_disc(
    path: &Path,
    d: &crate::analysis::disc::DiscBins,
    title: &str,
) -> Result<(), IoError> {
    // Gas, then the fractions: a colour per phase, its exact line darker.
    const PALETTE: [(RGBColor, RGBColor); 5] = [
        (GAS, GAS_REF),
        (DUST, DUST_REF),
        (RGBColor(44, 160, 44), RGBColor(0, 80, 0)),
        (RGBColor(255, 127, 14), RGBColor(140, 60, 0)),
        (RGBColor(148, 103, 189), RGBColor(70, 40, 110)),
    ];
    let pick = |k: usize| PALETTE[k % PALETTE.len()];
    let labels: Vec<(String, String)> = d
        .phases
        .iter()
        .map(|p| (p.name.clone(), format!("{} exact", p.name)))
        .collect();
    let mut sigma = Vec::new();
    let (mut vr, mut vp) = (Vec::new(), Vec::new());
    // Each fraction's Σ over the gas's, on its own axis (on Σ's, beside the gas, the dust's
    // is a line at zero).
    let gas_sigma = d
        .phases
        .first()
        .map(|g| g.sigma.clone())
        .unwrap_or_default();
    let mut ratio = Vec::new();
    for (k, p) in d.phases.iter().enumerate().skip(1) {
        ratio.push(Curve {
            label: &labels[k].0,
            r: &d.r,
            y: (p.sigma.iter().zip(&gas_sigma))
                .map(|(s, g)| if *g > 0.0 { s / g } else { f64::NAN })
                .collect(),
            color: pick(k).0,
            style: Style::Points,
        });
    }
    for (k, p) in d.phases.iter().enumerate() {
        let (c, c_ref) = pick(k);
        sigma.push(Curve {
            label: &labels[k].0,
            r: &d.r,
            y: p.sigma.clone(),
            color: c,
            style: Style::Points,
        });
        for (out, y, y_ref) in [
            (&mut vr, &p.v_r, &p.exact_v_r),
            (&mut vp, &p.dv_phi, &p.exact_dv_phi),
        ] {
            out.push(Curve {
                label: &labels[k].0,
                r: &d.r,
                y: y.clone(),
                color: c,
                style: Style::Points,
            });
            out.push(Curve {
                label: &labels[k].1,
                r: &d.r,
                y: y_ref.clone(),
                color: c_ref,
                style: Style::Line,
            });
        }
    }
    let span = finite_span(d.r.iter().copied()).unwrap_or((0.0, 1.0));
    let half = if d.r.len() > 1 {
        0.5 * (d.r[1] - d.r[0])
    } else {
        0.0
    };
    let x_range = (span.0 - half)..(span.1 + half);
    render_png(path, (1400, 1000), |root| {
        let area = root.titled(title, (FONT, 28))?;
        let panels = area.split_evenly((2, 2));
        use SeriesLabelPosition::{LowerRight, UpperRight};
        let r = x_range.clone();
        curve_panel(
            &panels[0],
            "surface density",
            "Σ",
            r.clone(),
            &sigma,
            UpperRight,
        )?;
        curve_panel(
            &panels[1],
            "radial velocity",
            "v_R",
            r.clone(),
            &vr,
            LowerRight,
        )?;
        curve_panel(
            &panels[2],
            "azimuthal velocity − v_K",
            "v_φ − v_K",
            r.clone(),
            &vp,
            LowerRight,
        )?;
        if !ratio.is_empty() {
            curve_panel(
                &panels[3],
                "dust-to-gas ratio",
                "Σ_k / Σ_gas",
                r,
                &ratio,
                UpperRight,
            )?;
        }
        Ok(())
    })
}
