//! One point of a study: its scene run to t_end without output (up to `repeat` times for the
//! median of its times), its errors and diagnostics.
use super::*;

/// One run of a scene without output: (status, steps, drag-limited steps, dt range, stepping
/// seconds, total seconds, errors at t_end, momentum drift).
struct Once {
    status: Status,
    steps: u64,
    drag_limited: u64,
    dt: (f64, f64),
    step_s: f64,
    /// CPU seconds of the step loop on this thread (single-threaded runs on Linux).
    step_cpu: f64,
    total_s: f64,
    errors: Vec<ExactErrors>,
    momentum_drift: f64,
}

fn run_once(scene: &Scene, max_steps: u64) -> Once {
    let t0 = Instant::now();
    let mut out = Once {
        status: Status::Ok,
        steps: 0,
        drag_limited: 0,
        dt: (f64::INFINITY, 0.0),
        step_s: 0.0,
        step_cpu: f64::NAN,
        total_s: 0.0,
        errors: Vec::new(),
        momentum_drift: f64::NAN,
    };
    let fail = |mut o: Once, m: String| {
        o.status = Status::Failed(m);
        o.total_s = t0.elapsed().as_secs_f64();
        o
    };
    let mut sim = match Simulation::of_scene(scene, DeviceChoice::Cpu) {
        Ok((s, _)) => s,
        Err(e) => return fail(out, e),
    };
    let t_end = scene.time.t_end;
    // A point whose first step says it needs more than max_steps steps is skipped unrun.
    match sim.plan_next(t_end) {
        Ok(first) => {
            let need = (t_end / first.plan.dt_free).ceil();
            if need > max_steps as f64 {
                out.status = Status::Skipped(need as u64);
                out.total_s = t0.elapsed().as_secs_f64();
                return out;
            }
        }
        Err(e) => return fail(out, e.to_string()),
    }
    let ts = Instant::now();
    let cpu0 = thread_cpu_seconds();
    let ran = sim.run(t_end, &mut [&mut StepBudget(max_steps)], None);
    out.step_s = ts.elapsed().as_secs_f64();
    if let (Some(a), Some(b)) = (cpu0, thread_cpu_seconds()) {
        out.step_cpu = b - a;
    }
    let d = &sim.diagnostics;
    out.steps = d.steps;
    out.drag_limited = d.drag_limited_steps;
    out.dt = (d.dt_min, d.dt_max);
    if let Err(e) = ran {
        return fail(out, e.to_string());
    }
    if let Err(e) = sim.refresh_dust_density() {
        return fail(out, e.to_string());
    }
    out.errors = analysis::exact_errors(scene, &sim.state, scene.time.fixed_dt());
    out.momentum_drift = sim.diagnostics.momentum_drift();
    out.total_s = t0.elapsed().as_secs_f64();
    out
}

/// Stops a point that would take more than its study's `max_steps` steps.
struct StepBudget(u64);

impl Observer for StepBudget {
    fn before_step(&mut self, sim: &mut Simulation) -> Result<Flow, RunError> {
        if sim.diagnostics.steps >= self.0 {
            return Err(RunError::Step(format!(
                "more than max_steps = {} steps",
                self.0
            )));
        }
        Ok(Flow::Continue)
    }
}

/// CPU time of the calling thread (Linux: /proc/thread-self/schedstat, nanoseconds).
fn thread_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = s.split_whitespace().next()?.parse().ok()?;
    Some(ns * 1e-9)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

impl Study {
    /// Run one point: once, and again up to `repeat` times while the first stepping took less
    /// than `repeat_below` seconds (times are medians; errors come from the first run, the
    /// runs being deterministic).
    pub fn run_point(&self, p: &Point) -> PointResult {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(self.cfg.threads)
            .build();
        let once = || match &pool {
            Ok(pool) => pool.install(|| run_once(&p.scene, self.cfg.max_steps)),
            Err(_) => run_once(&p.scene, self.cfg.max_steps),
        };
        let single = self.cfg.threads == 1 && pool.is_ok();
        let first = once();
        let mut step = vec![first.step_s];
        let mut cpu = vec![first.step_cpu];
        let mut total = vec![first.total_s];
        if first.status == Status::Ok && first.step_s < self.cfg.repeat_below {
            for _ in 1..self.cfg.repeat {
                let o = once();
                step.push(o.step_s);
                cpu.push(o.step_cpu);
                total.push(o.total_s);
            }
        }
        PointResult {
            runs: step.len(),
            step_cpu_seconds: if single { median(cpu) } else { f64::NAN },
            step_seconds: median(step),
            total_seconds: median(total),
            metrics: self
                .metrics
                .iter()
                .map(|m| m.of_all(&first.errors))
                .collect(),
            reference: first
                .errors
                .iter()
                .enumerate()
                .map(|(k, e)| format!("@{k}: {}", e.reference))
                .collect::<Vec<_>>()
                .join("; "),
            status: first.status,
            steps: first.steps,
            drag_limited_steps: first.drag_limited,
            dt_min: first.dt.0,
            dt_max: first.dt.1,
            momentum_drift: first.momentum_drift,
        }
    }
}
