//! `dustsph study STUDY.toml`: one scene over a grid of parameters, run in this process, with
//! error norms against the exact solution and wall times; writes `results.csv`, `results.md`
//! and log–log plots of error against run time (one line per series).
//!
//! A study file (`configs/studies/`):
//!
//! ```toml
//! [study]
//! name = "dustywave_n1"
//! scene = "../dustywave.toml"        # relative to the study file
//! set = ["time.output_dt="]          # fixed --set overrides for every point
//! series = ["drag.method"]           # axes whose values make the lines (the rest are points on them)
//! metrics = ["max.l1", "rho_g.l1"]   # FIELD.NORM (l1, l2, linf) of the exact-solution errors at
//!                                    # t_end; FIELD "max" is the largest over all fields
//! plot = "max.l1"                    # the metric plotted (default: the first)
//! repeat = 3                         # runs per point (median times) ...
//! repeat_below = 2.0                 # ... when the first run's stepping took less (seconds)
//! max_steps = 200000                 # points that would need more steps are skipped, with a row
//! targets = [1e-2, 1e-3]             # "cheapest run reaching this error" table, per series
//! plot_against = ["sph.n"]           # extra plots of the error against these (numeric) axes
//! [[axis]]
//! key = "drag.method"                # any scene key, as for --set
//! values = ["idic", "explicit"]      # TOML values
//! ```
//!
//! Every point's scene is built and validated before anything runs or is written.
use crate::analysis::{self, ExactErrors};
use crate::io::{self, IoError};
use crate::plot::{fig_loglog, LogLogSeries};
use crate::scene::{self, Scene};
use crate::setup;
use crate::sim::{Flow, Observer, RunError, Simulation};
use crate::step::backend::DeviceChoice;
use serde::Deserialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

mod command;
mod point;
mod report;

pub use command::{execute, StudyArgs};
use std::time::Instant;

fn one() -> usize {
    1
}
fn default_max_steps() -> u64 {
    200_000
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct StudyFile {
    study: StudyCfg,
    #[serde(default)]
    axis: Vec<AxisCfg>,
    #[serde(default)]
    reference: Vec<ReferenceCfg>,
}

/// A figure measured elsewhere (another code, a paper), drawn into the error-against-time plot
/// as its own marker and listed in results.md; never run by the study.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceCfg {
    /// Legend label, e.g. "Phantom two-fluid implicit, K = 1e5".
    pub label: String,
    /// Its wall time [s] and its error in the plotted metric.
    pub wall_s: f64,
    pub error: f64,
    /// Conditions and source (machine, steps, time of the error, ...).
    #[serde(default)]
    pub note: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudyCfg {
    pub name: String,
    /// Heading of results.md and the plots (default: the name).
    pub title: Option<String>,
    /// A paragraph for results.md.
    pub description: Option<String>,
    /// Base scene, relative to the study file.
    pub scene: PathBuf,
    #[serde(default)]
    pub set: Vec<String>,
    #[serde(default)]
    pub series: Vec<String>,
    pub metrics: Vec<String>,
    pub plot: Option<String>,
    #[serde(default = "one")]
    pub repeat: usize,
    #[serde(default)]
    pub repeat_below: f64,
    #[serde(default = "default_max_steps")]
    pub max_steps: u64,
    #[serde(default)]
    pub targets: Vec<f64>,
    #[serde(default)]
    pub plot_against: Vec<String>,
    /// Threads of the runs (default 1: on a shared machine one thread's CPU time is a stable
    /// measure of cost, and the points are small).
    #[serde(default = "one")]
    pub threads: usize,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisCfg {
    /// A scene key (`--set` style), or with `sets` just the axis name.
    pub key: String,
    pub values: Vec<toml::Value>,
    /// Instead of `key=value`: the overrides of each value (one list per value), for an axis
    /// that moves several keys together (e.g. every fraction's t_stop by one scale).
    pub sets: Option<Vec<Vec<String>>>,
}

/// A bad study file: which file, which key, what is wrong (as scene errors).
#[derive(Debug, Clone)]
pub struct StudyError {
    pub file: PathBuf,
    pub key: Option<String>,
    pub msg: String,
}

impl std::fmt::Display for StudyError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.key {
            Some(k) => write!(f, "{}: key `{}`: {}", self.file.display(), k, self.msg),
            None => write!(f, "{}: {}", self.file.display(), self.msg),
        }
    }
}
impl std::error::Error for StudyError {}

/// A metric: FIELD.NORM.
#[derive(Debug, Clone, PartialEq)]
pub struct Metric {
    pub field: String,
    pub norm: Norm,
    /// Which comparison of the scene (`FIELD.NORM@k`; 0, the first, by default): the ball has
    /// 0 = inside r < R0 − 2h, 1 = the whole ball.
    pub reference: usize,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Norm {
    L1,
    L2,
    Linf,
}

impl Metric {
    fn parse(s: &str) -> Option<Metric> {
        let (s, reference) = match s.split_once('@') {
            Some((m, k)) => (m, k.parse().ok()?),
            None => (s, 0),
        };
        let (field, norm) = s.rsplit_once('.')?;
        let norm = match norm {
            "l1" => Norm::L1,
            "l2" => Norm::L2,
            "linf" => Norm::Linf,
            _ => return None,
        };
        (!field.is_empty()).then(|| Metric {
            field: field.to_string(),
            norm,
            reference,
        })
    }

    pub fn name(&self) -> String {
        let n = match self.norm {
            Norm::L1 => "l1",
            Norm::L2 => "l2",
            Norm::Linf => "linf",
        };
        if self.reference == 0 {
            format!("{}.{n}", self.field)
        } else {
            format!("{}.{n}@{}", self.field, self.reference)
        }
    }

    /// The metric in words, for a plot's axis: "gas velocity error (L2) at t = 1", with the
    /// comparison when it is not the first ("… (comparison 1)").
    pub fn in_words(&self, t_end: f64) -> String {
        let field = self.field.as_str();
        let what = match field {
            "max" => "largest error over the fields".to_string(),
            "rho_g" => "gas density error".to_string(),
            "v_g" => "gas velocity error".to_string(),
            "p" => "pressure error".to_string(),
            "e" => "internal energy error".to_string(),
            f => match (f.strip_prefix("rho_d"), f.strip_prefix("u_d")) {
                (Some(k), _) => format!("dust {k} density error"),
                (_, Some(k)) => format!("dust {k} velocity error"),
                _ => format!("{f} error"),
            },
        };
        let norm = match self.norm {
            Norm::L1 => "L1",
            Norm::L2 => "L2",
            Norm::Linf => "L∞",
        };
        let cmp = match self.reference {
            0 => String::new(),
            k => format!(" (comparison {k})"),
        };
        format!("{what} ({norm}) at t = {}{cmp}", scene::num(t_end))
    }

    /// The value in its reference among `all` (NaN if missing).
    fn of_all(&self, all: &[ExactErrors]) -> f64 {
        all.get(self.reference).map_or(f64::NAN, |e| self.of(e))
    }

    /// The value in `e` (NaN if the field is missing).
    fn of(&self, e: &ExactErrors) -> f64 {
        let pick = |n: &analysis::norms::Norms| match self.norm {
            Norm::L1 => n.l1,
            Norm::L2 => n.l2,
            Norm::Linf => n.linf,
        };
        if self.field == "max" {
            e.fields
                .iter()
                .map(|f| pick(&f.norms))
                .fold(f64::NAN, f64::max)
        } else {
            e.get(&self.field).map_or(f64::NAN, pick)
        }
    }
}

/// One point of the grid: a value index per axis, and its validated scene.
#[derive(Debug, Clone)]
pub struct Point {
    pub index: Vec<usize>,
    pub overrides: Vec<String>,
    pub scene: Scene,
}

/// A loaded, fully validated study.
#[derive(Debug, Clone)]
pub struct Study {
    pub file: PathBuf,
    pub cfg: StudyCfg,
    pub axes: Vec<AxisCfg>,
    pub scene_file: PathBuf,
    pub metrics: Vec<Metric>,
    /// Index into `metrics` of the plotted one.
    pub plot_metric: usize,
    /// Axis indices of the series keys, and of the other axes.
    pub series_axes: Vec<usize>,
    pub point_axes: Vec<usize>,
    pub plot_against: Vec<usize>,
    pub points: Vec<Point>,
    /// Figures from elsewhere, drawn into the error-against-time plot.
    pub references: Vec<ReferenceCfg>,
}

/// How a point ended.
#[derive(Debug, Clone, PartialEq)]
pub enum Status {
    Ok,
    /// Not run: the first step's size says it would need this many steps (> max_steps).
    Skipped(u64),
    /// The run stopped (blow-up, bad time step, or more than max_steps steps).
    Failed(String),
}

impl Status {
    pub fn text(&self, max_steps: u64) -> String {
        match self {
            Status::Ok => "ok".into(),
            Status::Skipped(n) => format!("skipped: would need ≈{n} steps (max_steps {max_steps})"),
            Status::Failed(m) => format!("failed: {m}"),
        }
    }
}

/// Result of one point (times are medians over `runs`).
#[derive(Debug, Clone)]
pub struct PointResult {
    pub status: Status,
    pub steps: u64,
    pub drag_limited_steps: u64,
    pub dt_min: f64,
    pub dt_max: f64,
    pub runs: usize,
    pub step_seconds: f64,
    /// CPU seconds of the step loop (single-threaded studies; NaN otherwise).
    pub step_cpu_seconds: f64,
    pub total_seconds: f64,
    pub metrics: Vec<f64>,
    /// |P(t_end) − P(0)| / max_t Σ m|v|.
    pub momentum_drift: f64,
    /// The reference of the errors (first entry of the exact-solution comparison).
    pub reference: String,
}

impl PointResult {
    /// The cost plotted and ranked: the wall seconds of the step loop (single-threaded by
    /// default; the CPU seconds beside them show whether other load inflated them — the CPU
    /// clock here is too coarse, a few ms, to rank the shortest runs).
    pub fn cost(&self) -> f64 {
        self.step_seconds
    }
}

/// A TOML value as a label: strings bare, numbers short.
pub fn label_value(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        toml::Value::Float(f) => scene::num(*f),
        toml::Value::Integer(i) => i.to_string(),
        other => other.to_string(),
    }
}

/// The last segment of a dotted key (`dust.fractions.0.t_stop` → `t_stop`).
fn short_key(k: &str) -> &str {
    k.rsplit('.')
        .find(|s| s.parse::<usize>().is_err())
        .unwrap_or(k)
}

/// Read and validate a study file, building every point's scene.
pub fn load(path: &Path) -> Result<Study, StudyError> {
    let err = |key: Option<String>, msg: String| StudyError {
        file: path.to_path_buf(),
        key,
        msg,
    };
    let f = read_study_file(path, &err)?;
    let (metrics, plot_metric) = check_settings(&f, &err)?;
    let (series_axes, plot_against, point_axes) = check_axes(&f, &err)?;
    let (scene_file, points) = build_points(path, &f, &err)?;
    check_metric_fields(&points[0].scene, &metrics, &err)?;
    Ok(Study {
        file: path.to_path_buf(),
        cfg: f.study,
        axes: f.axis,
        scene_file,
        metrics,
        plot_metric,
        series_axes,
        point_axes,
        plot_against,
        points,
        references: f.reference,
    })
}

/// The study file, parsed (keys named as `a.0.b` in errors).
fn read_study_file(
    path: &Path,
    err: &dyn Fn(Option<String>, String) -> StudyError,
) -> Result<StudyFile, StudyError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| err(None, format!("cannot read study file: {e}")))?;
    let value: toml::Value = text
        .parse::<toml::Table>()
        .map(toml::Value::Table)
        .map_err(|e| err(None, format!("not valid TOML: {e}")))?;
    let f: StudyFile = serde_path_to_error::deserialize(value).map_err(|e| {
        let key = e.path().to_string().replace('[', ".").replace(']', "");
        let msg = e.into_inner().to_string();
        let msg = match msg.find("\nin `").or_else(|| msg.find(" in `")) {
            Some(i) => msg[..i].trim_end().to_string(),
            None => msg,
        };
        err((key != "." && !key.is_empty()).then_some(key), msg)
    })?;
    Ok(f)
}

/// The `[study]` settings and reference points; the metrics parsed, and the plotted one.
fn check_settings(
    f: &StudyFile,
    err: &dyn Fn(Option<String>, String) -> StudyError,
) -> Result<(Vec<Metric>, usize), StudyError> {
    for (i, r) in f.reference.iter().enumerate() {
        for (key, v) in [("wall_s", r.wall_s), ("error", r.error)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(err(
                    Some(format!("reference.{i}.{key}")),
                    "must be a finite number > 0 (it is drawn on log axes)".into(),
                ));
            }
        }
    }
    let c = &f.study;
    if c.name.trim().is_empty() {
        return Err(err(Some("study.name".into()), "must not be empty".into()));
    }
    // The default output folder is output/studies/<name>: a name must not lead anywhere else.
    if c.name.contains(['/', '\\', '\0']) || c.name == "." || c.name.contains("..") {
        return Err(err(
            Some("study.name".into()),
            format!(
                "{:?} is not a plain name: no path separators or \"..\" (it names the output \
                 folder output/studies/<name>; use --out for another place)",
                c.name
            ),
        ));
    }
    if c.repeat == 0 {
        return Err(err(Some("study.repeat".into()), "must be ≥ 1".into()));
    }
    if !(c.repeat_below.is_finite() && c.repeat_below >= 0.0) {
        return Err(err(
            Some("study.repeat_below".into()),
            "must be a finite number ≥ 0 (seconds)".into(),
        ));
    }
    if c.threads == 0 {
        return Err(err(Some("study.threads".into()), "must be ≥ 1".into()));
    }
    if c.max_steps == 0 {
        return Err(err(Some("study.max_steps".into()), "must be ≥ 1".into()));
    }
    for (i, t) in c.targets.iter().enumerate() {
        if !(t.is_finite() && *t > 0.0) {
            return Err(err(
                Some(format!("study.targets.{i}")),
                "must be a finite number > 0".into(),
            ));
        }
    }
    if c.metrics.is_empty() {
        return Err(err(
            Some("study.metrics".into()),
            "list at least one metric, e.g. \"max.l1\" or \"rho_g.l1\"".into(),
        ));
    }
    let mut metrics = Vec::new();
    for (i, m) in c.metrics.iter().enumerate() {
        metrics.push(Metric::parse(m).ok_or_else(|| {
            err(
                Some(format!("study.metrics.{i}")),
                format!("`{m}` is not FIELD.NORM[@k] with NORM one of l1, l2, linf"),
            )
        })?);
    }
    let plot_metric = match &c.plot {
        None => 0,
        Some(p) => c.metrics.iter().position(|m| m == p).ok_or_else(|| {
            err(
                Some("study.plot".into()),
                format!("`{p}` is not one of study.metrics"),
            )
        })?,
    };
    Ok((metrics, plot_metric))
}

/// The axes, and which of them make the series, the extra plots and the points.
#[allow(clippy::type_complexity)]
fn check_axes(
    f: &StudyFile,
    err: &dyn Fn(Option<String>, String) -> StudyError,
) -> Result<(Vec<usize>, Vec<usize>, Vec<usize>), StudyError> {
    let c = &f.study;
    if f.axis.is_empty() {
        return Err(err(
            Some("axis".into()),
            "give at least one [[axis]] with key and values".into(),
        ));
    }
    for (i, a) in f.axis.iter().enumerate() {
        if a.key.trim().is_empty() || (a.sets.is_none() && a.key.contains('=')) {
            return Err(err(
                Some(format!("axis.{i}.key")),
                "must be a scene key such as sph.n".into(),
            ));
        }
        if a.values.is_empty() {
            return Err(err(
                Some(format!("axis.{i}.values")),
                "must list at least one value".into(),
            ));
        }
        if let Some(j) = (1..a.values.len()).find(|&j| a.values[..j].contains(&a.values[j])) {
            return Err(err(
                Some(format!("axis.{i}.values.{j}")),
                format!(
                    "{} is listed twice (each point would run twice)",
                    a.values[j]
                ),
            ));
        }
        if let Some(sets) = &a.sets {
            if sets.len() != a.values.len() {
                return Err(err(
                    Some(format!("axis.{i}.sets")),
                    format!(
                        "needs one list of overrides per value ({}), got {}",
                        a.values.len(),
                        sets.len()
                    ),
                ));
            }
        }
        if f.axis[..i].iter().any(|b| b.key == a.key) {
            return Err(err(
                Some(format!("axis.{i}.key")),
                format!("`{}` is already an axis", a.key),
            ));
        }
    }
    let axis_of = |k: &str, key: String| {
        f.axis
            .iter()
            .position(|a| a.key == k)
            .ok_or_else(|| err(Some(key), format!("`{k}` is not the key of an [[axis]]")))
    };
    let series_axes = c
        .series
        .iter()
        .enumerate()
        .map(|(i, k)| axis_of(k, format!("study.series.{i}")))
        .collect::<Result<Vec<_>, _>>()?;
    let plot_against = c
        .plot_against
        .iter()
        .enumerate()
        .map(|(i, k)| axis_of(k, format!("study.plot_against.{i}")))
        .collect::<Result<Vec<_>, _>>()?;
    for (i, &a) in plot_against.iter().enumerate() {
        if f.axis[a].values.iter().any(|v| as_number(v).is_none()) {
            return Err(err(
                Some(format!("study.plot_against.{i}")),
                format!("axis `{}` has non-numeric values", f.axis[a].key),
            ));
        }
    }
    let point_axes: Vec<usize> = (0..f.axis.len())
        .filter(|a| !series_axes.contains(a))
        .collect();
    Ok((series_axes, plot_against, point_axes))
}

/// Every point of the grid as a validated scene, in axis order (the first axis varies
/// slowest); a bad value names the axis value (or `study.set`) that caused it.
fn build_points(
    path: &Path,
    f: &StudyFile,
    err: &dyn Fn(Option<String>, String) -> StudyError,
) -> Result<(PathBuf, Vec<Point>), StudyError> {
    let c = &f.study;
    let base = path.parent().unwrap_or(Path::new("."));
    let scene_file = base.join(&c.scene);
    let scene_text = std::fs::read_to_string(&scene_file).map_err(|e| {
        err(
            Some("study.scene".into()),
            format!("cannot read {}: {e}", scene_file.display()),
        )
    })?;
    // Every point, in axis order (the first axis varies slowest).
    let mut points = Vec::new();
    let n_points: usize = f.axis.iter().map(|a| a.values.len()).product();
    for p in 0..n_points {
        let mut index = vec![0; f.axis.len()];
        let mut r = p;
        for a in (0..f.axis.len()).rev() {
            index[a] = r % f.axis[a].values.len();
            r /= f.axis[a].values.len();
        }
        let mut overrides = c.set.clone();
        for (a, &v) in index.iter().enumerate() {
            match &f.axis[a].sets {
                Some(sets) => overrides.extend(sets[v].iter().cloned()),
                None => overrides.push(format!("{}={}", f.axis[a].key, f.axis[a].values[v])),
            }
        }
        let scene = scene::parse(&scene_text, &scene_file, &overrides).map_err(|e| {
            let at: Vec<String> = index
                .iter()
                .enumerate()
                .map(|(a, &v)| format!("{}={}", f.axis[a].key, label_value(&f.axis[a].values[v])))
                .collect();
            let key = match &e.key {
                Some(k) => match f.axis.iter().position(|a| &a.key == k) {
                    Some(a) => Some(format!("axis.{a}.values.{}", index[a])),
                    None => c
                        .set
                        .iter()
                        .position(|s| s.split('=').next().map(str::trim) == Some(k.as_str()))
                        .map(|i| format!("study.set.{i}")),
                },
                None => None,
            };
            err(key, format!("at point {}: {e}", at.join(", ")))
        })?;
        points.push(Point {
            index,
            overrides,
            scene,
        });
    }
    Ok((scene_file, points))
}

/// Metric fields must exist in the scene's exact-solution comparison (names from t = 0).
fn check_metric_fields(
    first: &Scene,
    metrics: &[Metric],
    err: &dyn Fn(Option<String>, String) -> StudyError,
) -> Result<(), StudyError> {
    let su = setup::build(first).map_err(|e| err(Some("study.scene".into()), e.to_string()))?;
    let refs = analysis::exact_errors(first, &su.state, None);
    let names: Vec<String> = refs
        .first()
        .map(|e| e.fields.iter().map(|f| f.field.clone()).collect())
        .unwrap_or_default();
    if names.is_empty() {
        return Err(err(
            Some("study.scene".into()),
            format!(
                "problem `{}` has no exact solution to measure errors against",
                first.kind().name()
            ),
        ));
    }
    for (i, m) in metrics.iter().enumerate() {
        if m.reference >= refs.len() {
            return Err(err(
                Some(format!("study.metrics.{i}")),
                format!(
                    "@{}: this scene has {} comparison(s) (@0 … @{})",
                    m.reference,
                    refs.len(),
                    refs.len() - 1
                ),
            ));
        }
        let names: Vec<String> = refs[m.reference]
            .fields
            .iter()
            .map(|f| f.field.clone())
            .collect();
        if m.field != "max" && !names.contains(&m.field) {
            return Err(err(
                Some(format!("study.metrics.{i}")),
                format!(
                    "field `{}` is not compared for this scene (fields: max, {})",
                    m.field,
                    names.join(", ")
                ),
            ));
        }
    }
    Ok(())
}

fn as_number(v: &toml::Value) -> Option<f64> {
    match v {
        toml::Value::Float(f) => Some(*f),
        toml::Value::Integer(i) => Some(*i as f64),
        _ => None,
    }
}

impl Study {
    /// The points' end time (every point of a study ends at the same t_end unless an axis
    /// sets it; the first point's then).
    fn t_end(&self) -> f64 {
        self.points.first().map_or(f64::NAN, |p| p.scene.time.t_end)
    }

    /// `key=value, ...` of a point over the given axes.
    pub fn describe(&self, p: &Point, axes: &[usize], short: bool) -> String {
        axes.iter()
            .map(|&a| {
                let k = &self.axes[a].key;
                let k = if short { short_key(k) } else { k.as_str() };
                let v = &self.axes[a].values[p.index[a]];
                match v {
                    toml::Value::String(s) if short => s.clone(),
                    _ => format!("{k}={}", label_value(v)),
                }
            })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// The names `dustsph study` writes into its output directory.
pub fn is_study_output(name: &str) -> bool {
    io::owned_or_temporary(name, |n| {
        n == "results.csv"
            || n == "results.md"
            || (n.starts_with("error_vs_") && n.ends_with(".png"))
    })
}

/// Run a loaded study into `out` (prepared with the `--out`/`--force` policy of `run`); prints a
/// line per point on stderr unless `quiet`. Returns the results and the files written.
pub fn run(
    study: &Study,
    out: &Path,
    force: bool,
    quiet: bool,
    command: &str,
) -> Result<(Vec<PointResult>, Vec<PathBuf>), IoError> {
    let dir = io::prepare_dir(out, force, is_study_output)?;
    let n = study.points.len();
    let mut results = Vec::with_capacity(n);
    for (i, p) in study.points.iter().enumerate() {
        let r = study.run_point(p);
        if !quiet {
            let all: Vec<usize> = (0..study.axes.len()).collect();
            eprintln!(
                "[{}/{n}] {}: {} steps, {:.3} s (cpu {:.3} s), {} = {:.3e}  {}",
                i + 1,
                study.describe(p, &all, true),
                r.steps,
                r.step_seconds,
                r.step_cpu_seconds,
                study.metrics[study.plot_metric].name(),
                r.metrics[study.plot_metric],
                r.status.text(study.cfg.max_steps)
            );
        }
        results.push(r);
    }
    let files = study.write(&dir, &results, command)?;
    Ok((results, files))
}
