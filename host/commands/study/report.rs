//! A study's report: results.csv, results.md and the plots of error against run time.
use super::*;

impl Study {
    fn series_label(&self, p: &Point) -> String {
        if self.series_axes.is_empty() {
            "all points".into()
        } else {
            self.describe(p, &self.series_axes, true)
        }
    }

    /// Distinct series in order of first appearance, with the points (indices) on each.
    fn series(&self) -> Vec<(String, Vec<usize>)> {
        let mut out: Vec<(String, Vec<usize>)> = Vec::new();
        for (i, p) in self.points.iter().enumerate() {
            let l = self.series_label(p);
            match out.iter_mut().find(|s| s.0 == l) {
                Some(s) => s.1.push(i),
                None => out.push((l, vec![i])),
            }
        }
        out
    }

    /// Write results.csv, results.md and the plots into `dir` (already prepared).
    pub fn write(
        &self,
        dir: &Path,
        results: &[PointResult],
        command: &str,
    ) -> Result<Vec<PathBuf>, IoError> {
        let mut files = vec![self.write_csv(dir, results)?];
        files.extend(self.write_plots(dir, results)?);
        // Markdown
        let p = dir.join("results.md");
        io::write_bytes_atomic(&p, self.markdown(results, command, &files).as_bytes())?;
        files.push(p);
        Ok(files)
    }

    /// results.csv: one row per point (the csv crate quotes what needs quoting).
    fn write_csv(&self, dir: &Path, results: &[PointResult]) -> Result<PathBuf, IoError> {
        let mut csv = csv::Writer::from_writer(Vec::new());
        let csv_err = |e: csv::Error| IoError::invalid(dir.join("results.csv"), e.to_string());
        let mut head: Vec<String> = vec!["series".into()];
        head.extend(self.axes.iter().map(|a| a.key.clone()));
        head.extend(
            [
                "status",
                "steps",
                "drag_limited_steps",
                "dt_min",
                "dt_max",
                "runs",
                "step_seconds",
                "step_cpu_seconds",
                "total_seconds",
            ]
            .map(String::from),
        );
        head.extend(self.metrics.iter().map(|m| m.name()));
        head.push("momentum_drift".into());
        csv.write_record(&head).map_err(csv_err)?;
        for (p, r) in self.points.iter().zip(results) {
            let mut row = vec![self.series_label(p)];
            row.extend(
                self.axes
                    .iter()
                    .zip(&p.index)
                    // Strings bare (the CSV quotes what needs quoting), numbers in full.
                    .map(|(a, &i)| match &a.values[i] {
                        toml::Value::String(s) => s.clone(),
                        v => v.to_string(),
                    }),
            );
            row.push(r.status.text(self.cfg.max_steps));
            row.push(r.steps.to_string());
            row.push(r.drag_limited_steps.to_string());
            for v in [r.dt_min, r.dt_max] {
                row.push(if r.steps > 0 {
                    format!("{v:e}")
                } else {
                    String::new()
                });
            }
            row.push(r.runs.to_string());
            row.push(format!("{:.6}", r.step_seconds));
            row.push(if r.step_cpu_seconds.is_finite() {
                format!("{:.6}", r.step_cpu_seconds)
            } else {
                String::new()
            });
            row.push(format!("{:.6}", r.total_seconds));
            for m in &r.metrics {
                row.push(if m.is_finite() {
                    format!("{m:e}")
                } else {
                    String::new()
                });
            }
            row.push(if r.momentum_drift.is_finite() {
                format!("{:e}", r.momentum_drift)
            } else {
                String::new()
            });
            csv.write_record(&row).map_err(csv_err)?;
        }
        let p = dir.join("results.csv");
        let bytes = csv
            .into_inner()
            .map_err(|e| csv_err(e.into_error().into()))?;
        io::write_bytes_atomic(&p, &bytes)?;
        Ok(p)
    }

    /// The plots: the plotted metric against the step loop's wall time, and against each
    /// `plot_against` axis.
    fn write_plots(&self, dir: &Path, results: &[PointResult]) -> Result<Vec<PathBuf>, IoError> {
        let mut files = Vec::new();
        let series = self.series();
        let styles = self.styles(&series);
        let pm = self.plot_metric;
        let title = self.cfg.title.clone().unwrap_or(self.cfg.name.clone());
        let mk = |x: &dyn Fn(usize) -> f64| -> Vec<LogLogSeries> {
            series
                .iter()
                .zip(&styles)
                .map(|((label, idx), &(color, style))| LogLogSeries {
                    label: label.clone(),
                    points: idx
                        .iter()
                        .filter(|&&i| results[i].status == Status::Ok)
                        .map(|&i| (x(i), results[i].metrics[pm]))
                        .collect(),
                    color,
                    style,
                })
                .collect()
        };
        let p = dir.join("error_vs_time.png");
        let x_desc = format!(
            "wall time of the step loop, {} thread{} [s]",
            self.cfg.threads,
            if self.cfg.threads == 1 { "" } else { "s" }
        );
        let mut lines = mk(&|i| results[i].cost());
        let n_lines = lines.len();
        lines.extend(
            self.references
                .iter()
                .enumerate()
                .map(|(k, r)| LogLogSeries {
                    label: r.label.clone(),
                    points: vec![(r.wall_s, r.error)],
                    color: n_lines + k,
                    style: 2,
                }),
        );
        fig_loglog(
            &p,
            &format!("{title}: error against run time"),
            &x_desc,
            &self.metrics[pm].in_words(self.t_end()),
            &lines,
        )?;
        files.push(p);
        for &a in &self.plot_against {
            let key = &self.axes[a].key;
            let p = dir.join(format!("error_vs_{}.png", key.replace('.', "_")));
            fig_loglog(
                &p,
                &format!("{title}: error against {key}"),
                key,
                &self.metrics[pm].in_words(self.t_end()),
                &mk(&|i| {
                    as_number(&self.axes[a].values[self.points[i].index[a]]).unwrap_or(f64::NAN)
                }),
            )?;
            files.push(p);
        }

        Ok(files)
    }

    /// Colour and marker of each series: the first series axis picks the marker/dash, the
    /// others the colour (one axis: colour and marker both follow it).
    fn styles(&self, series: &[(String, Vec<usize>)]) -> Vec<(usize, usize)> {
        let mut colors: Vec<String> = Vec::new();
        series
            .iter()
            .map(|(_, idx)| {
                let p = &self.points[idx[0]];
                let style = self.series_axes.first().map_or(0, |&a| p.index[a]);
                let rest = if self.series_axes.len() > 1 {
                    self.describe(p, &self.series_axes[1..], true)
                } else {
                    self.describe(p, &self.series_axes, true)
                };
                let color = match colors.iter().position(|c| *c == rest) {
                    Some(c) => c,
                    None => {
                        colors.push(rest);
                        colors.len() - 1
                    }
                };
                (color, style)
            })
            .collect()
    }

    fn markdown(&self, results: &[PointResult], command: &str, files: &[PathBuf]) -> String {
        let c = &self.cfg;
        let mut s = String::new();
        let title = c.title.clone().unwrap_or(c.name.clone());
        let _ = writeln!(s, "# {title}\n");
        if let Some(d) = &c.description {
            let _ = writeln!(s, "{}\n", d.trim());
        }
        let _ = writeln!(
            s,
            "Generated by `{command}` (dustsph {}, git {}).\n",
            env!("CARGO_PKG_VERSION"),
            env!("DUSTSPH_GIT")
        );
        let _ = writeln!(
            s,
            "- Study file: `{}`; base scene: `{}`; fixed overrides: {}",
            self.file.display(),
            self.scene_file.display(),
            if c.set.is_empty() {
                "none".to_string()
            } else {
                c.set
                    .iter()
                    .map(|x| format!("`{x}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        );
        let _ = writeln!(
            s,
            "- Backend: CPU (rayon, {} thread(s)), {}. **step s** = wall time of the time-step loop, the cost plotted and ranked; **cpu s** = CPU time of that loop on its one thread (single-threaded studies; a cpu s well below step s means other load slowed the run; the CPU clock read here ticks in milliseconds, so it is rough for the shortest runs); **total s** (wall) adds set-up, initial densities and the error evaluation. Times are the median of up to {} runs when the first step loop took < {} s (column *runs*).",
            c.threads,
            {
                let mut p: Vec<&str> = self
                    .points
                    .iter()
                    .map(|p| p.scene.numerics.precision.name())
                    .collect();
                p.sort_unstable();
                p.dedup();
                p.join(" and ")
            },
            c.repeat,
            c.repeat_below
        );
        if let Some(r) = results.iter().find(|r| !r.reference.is_empty()) {
            let _ = writeln!(s, "- Errors at t_end against (FIELD.NORM@k uses comparison k, @0 when not given): {}. `max.*` is the largest norm over all compared fields.", r.reference);
        }
        let _ = writeln!(
            s,
            "- Points whose first step shows they would need more than {} steps are not run (status *skipped*), and say how many they would need.",
            c.max_steps
        );
        let _ = writeln!(
            s,
            "- Momentum drift = max over every step of |P(t) − P(0)|, over the largest Σ m|v| of the run (M c_s for a system at rest; docs/validation.md); scenes with fixed wall particles exchange momentum with the walls: there it is not a conservation check.\n"
        );
        for f in files {
            if f.extension().is_some_and(|e| e == "png") {
                if let Some(n) = f.file_name() {
                    let n = n.to_string_lossy();
                    let _ = writeln!(s, "![{n}]({n})\n");
                }
            }
        }
        if !self.references.is_empty() {
            let _ = writeln!(
                s,
                "Reference points (measured elsewhere, not run by this study; squares in the plot):\n\n| reference | wall time s | {} | note |\n|---|---|---|---|",
                self.metrics[self.plot_metric].name()
            );
            for r in &self.references {
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.3e} | {} |",
                    r.label.replace('|', "\\|"),
                    r.wall_s,
                    r.error,
                    r.note.replace('|', "\\|")
                );
            }
            let _ = writeln!(s);
        }
        s += &self.results_table(results);
        s += &self.targets_table(results);
        s
    }

    /// The table of every point's settings, steps, times, metrics and status (Markdown).
    fn results_table(&self, results: &[PointResult]) -> String {
        let c = &self.cfg;
        let mut s = String::new();
        let mut head: Vec<String> = self.axes.iter().map(|a| format!("`{}`", a.key)).collect();
        head.extend(
            [
                "steps", "dt min", "dt max", "runs", "step s", "cpu s", "total s",
            ]
            .map(String::from),
        );
        head.extend(self.metrics.iter().map(|m| m.name()));
        head.extend(["momentum drift", "status"].map(String::from));
        let _ = writeln!(s, "| {} |", head.join(" | "));
        let _ = writeln!(s, "|{}", "---|".repeat(head.len()));
        let g = |v: f64| {
            if v.is_finite() {
                format!("{v:.3e}")
            } else {
                "–".into()
            }
        };
        for (p, r) in self.points.iter().zip(results) {
            let mut row: Vec<String> = self
                .axes
                .iter()
                .zip(&p.index)
                .map(|(a, &i)| label_value(&a.values[i]).replace('|', "\\|"))
                .collect();
            let ran = r.status == Status::Ok;
            row.push(if r.steps > 0 {
                r.steps.to_string()
            } else {
                "–".into()
            });
            row.push(if r.steps > 0 {
                g(r.dt_min)
            } else {
                "–".into()
            });
            row.push(if r.steps > 0 {
                g(r.dt_max)
            } else {
                "–".into()
            });
            row.push(r.runs.to_string());
            row.push(if ran {
                format!("{:.3}", r.step_seconds)
            } else {
                "–".into()
            });
            row.push(if ran && r.step_cpu_seconds.is_finite() {
                format!("{:.3}", r.step_cpu_seconds)
            } else {
                "–".into()
            });
            row.push(if ran {
                format!("{:.3}", r.total_seconds)
            } else {
                "–".into()
            });
            row.extend(r.metrics.iter().map(|&m| g(m)));
            row.push(g(r.momentum_drift));
            row.push(r.status.text(c.max_steps));
            let _ = writeln!(s, "| {} |", row.join(" | "));
        }
        s
    }

    /// For each series, the cheapest run reaching each target error (Markdown; empty without
    /// targets).
    fn targets_table(&self, results: &[PointResult]) -> String {
        let c = &self.cfg;
        let mut s = String::new();
        if !c.targets.is_empty() {
            let pm = self.plot_metric;
            let _ = writeln!(
                s,
                "\n## Cheapest run reaching a target `{}`\n\nFor each series, the run with the smallest step-loop wall time (step s) among those whose error is at or below the target (no interpolation).\n",
                self.metrics[pm].name()
            );
            let mut head = vec!["series".to_string()];
            head.extend(c.targets.iter().map(|t| format!("≤ {}", scene::num(*t))));
            let _ = writeln!(s, "| {} |", head.join(" | "));
            let _ = writeln!(s, "|{}", "---|".repeat(head.len()));
            for (label, idx) in self.series() {
                let mut row = vec![label];
                for &t in &c.targets {
                    let best = idx
                        .iter()
                        .filter(|&&i| {
                            results[i].status == Status::Ok && results[i].metrics[pm] <= t
                        })
                        .min_by(|&&a, &&b| {
                            results[a].step_seconds.total_cmp(&results[b].step_seconds)
                        });
                    row.push(match best {
                        Some(&i) => format!(
                            "{:.3} s ({}{})",
                            results[i].cost(),
                            self.describe(&self.points[i], &self.point_axes, true),
                            format_args!(", {} steps", results[i].steps)
                        ),
                        None => "not reached".into(),
                    });
                }
                let _ = writeln!(s, "| {} |", row.join(" | "));
            }
        }
        s
    }
}
