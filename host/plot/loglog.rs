//! Log–log line plots of studies (error against run time or resolution): one line per series,
//! colour by one part of the series label and marker/dash by another, legend beside the chart.
use super::*;

/// One line of a log–log plot.
#[derive(Debug, Clone)]
pub struct LogLogSeries {
    pub label: String,
    /// (x, y); points that are not finite and positive are left out.
    pub points: Vec<(f64, f64)>,
    /// Colour index (into a fixed palette of 10, cycling).
    pub color: usize,
    /// Marker and line style: 0 filled circle + solid, 1 open triangle + dashed,
    /// 2 filled square + dotted-dashed, then cycling.
    pub style: usize,
}

const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
];

/// Tick values for a log axis over `r`: 1, 2, 5 × 10^k inside it (only 1 × 10^k when that gives
/// more than 14; every 1…9 × 10^k when it gives fewer than 3), light lines at 1…9 × 10^k.
fn log_key_points(r: &std::ops::Range<f64>) -> (Vec<f64>, Vec<f64>) {
    let (lo, hi) = (r.start, r.end);
    let mut bold = Vec::new();
    let mut light = Vec::new();
    let mut k = lo.log10().floor() as i32;
    while 10f64.powi(k) <= hi {
        for m in 1..=9 {
            let v = f64::from(m) * 10f64.powi(k);
            if v >= lo && v <= hi {
                light.push(v);
                if [1, 2, 5].contains(&m) {
                    bold.push(v);
                }
            }
        }
        k += 1;
    }
    if bold.len() < 3 {
        // Less than a decade: label every 1…9 × 10^k.
        bold = light.clone();
    }
    if bold.len() > 14 {
        bold.retain(|v| {
            let m = v / 10f64.powf(v.log10().floor());
            (m - 1.0).abs() < 1e-9
        });
    }
    (bold, light)
}

fn usable(p: &(f64, f64)) -> bool {
    p.0.is_finite() && p.1.is_finite() && p.0 > 0.0 && p.1 > 0.0
}

/// Draws a marker of `style` at `c` (backend or chart coordinates alike).
fn marker<DB: DrawingBackend, CT: plotters::coord::CoordTranslate>(
    chart_area: &DrawingArea<DB, CT>,
    c: CT::From,
    style: usize,
    color: RGBColor,
) -> DrawResult
where
    DB::ErrorType: 'static,
    CT::From: Clone,
{
    match style % 3 {
        0 => chart_area.draw(&Circle::new(c, 5, color.filled()))?,
        1 => chart_area.draw(&TriangleMarker::new(c, 7, color.stroke_width(2)))?,
        _ => chart_area.draw(
            &(plotters::element::EmptyElement::at(c)
                + Rectangle::new([(-5, -5), (5, 5)], color.filled())),
        )?,
    }
    Ok(())
}

/// A log–log figure of `series` (1500×950 px): the chart on the left, the legend on the right.
/// Series with no usable point are listed in the legend as "(no data)".
pub fn fig_loglog(
    path: &Path,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[LogLogSeries],
) -> Result<(), IoError> {
    let xs = log_range(
        series
            .iter()
            .flat_map(|s| s.points.iter().filter(|p| usable(p)).map(|p| p.0)),
    );
    let ys = log_range(
        series
            .iter()
            .flat_map(|s| s.points.iter().filter(|p| usable(p)).map(|p| p.1)),
    );
    render_png(path, (1500, 950), |root| {
        let area = root.titled(title, (FONT, 26))?;
        let (left, right) = area.split_horizontally(1130);
        let mut chart = ChartBuilder::on(&left)
            .margin(15)
            .x_label_area_size(50)
            .y_label_area_size(85)
            .build_cartesian_2d(
                {
                    let (b, l) = log_key_points(&xs);
                    xs.clone()
                        .log_scale()
                        .with_key_points(b)
                        .with_light_points(l)
                },
                {
                    let (b, l) = log_key_points(&ys);
                    ys.clone()
                        .log_scale()
                        .with_key_points(b)
                        .with_light_points(l)
                },
            )?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .x_label_formatter(&log_ticks)
            .y_label_formatter(&log_ticks)
            .label_style((FONT, 16))
            .axis_desc_style((FONT, 19))
            .draw()?;
        for s in series {
            let color = PALETTE[s.color % PALETTE.len()];
            let mut pts: Vec<(f64, f64)> = s.points.iter().copied().filter(usable).collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            let line = color.stroke_width(2);
            match s.style % 3 {
                0 => {
                    chart.draw_series(LineSeries::new(pts.iter().copied(), line))?;
                }
                1 => {
                    chart.draw_series(DashedLineSeries::new(pts.iter().copied(), 10, 6, line))?;
                }
                _ => {
                    chart.draw_series(DashedLineSeries::new(pts.iter().copied(), 4, 4, line))?;
                }
            }
            let plot_area = chart.plotting_area();
            for p in &pts {
                marker(plot_area, *p, s.style, color)?;
            }
        }
        // Legend: one row per series.
        let row = 28.min(880 / series.len().max(1) as i32).max(14);
        let font = (FONT, (row - 8).clamp(12, 18));
        for (i, s) in series.iter().enumerate() {
            let color = PALETTE[s.color % PALETTE.len()];
            let y = 40 + i as i32 * row;
            right.draw(&PathElement::new(
                vec![(8, y), (48, y)],
                color.stroke_width(2),
            ))?;
            marker(&right, (28, y), s.style, color)?;
            let text = if s.points.iter().any(usable) {
                s.label.clone()
            } else {
                format!("{} (no data)", s.label)
            };
            right.draw(&Text::new(
                text,
                (58, y - 9),
                font.into_font().color(&BLACK),
            ))?;
        }
        Ok(())
    })
}
