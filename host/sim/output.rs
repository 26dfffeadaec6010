//! The run's outputs: a snapshot (HDF5, with its XDMF sidecar) at every output time, the error
//! norms against the exact solution at each, the XDMF time series; and for the ball the checks
//! of docs/method.md §6.1 (the undisturbed core at each output, the Lagrange–Jacobi identity
//! after every step).
use super::{Flow, Observer, RunError, Simulation};
use crate::analysis::{self, ExactErrors};
use crate::dist::comm::{Comm, World};
use crate::io::chunks::{ChunkFilter, OnCores};
use crate::io::{self, PhaseView, SnapshotView};
use crate::scene::{LoadedScene, OutputSchedule, Problem};
use crate::step::timestep::Taken;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The times a scene writes snapshots at: t = 0, every `output_dt` or the `output_times`, and
/// t_end.
pub fn output_times(loaded: &LoadedScene, start: f64) -> Vec<f64> {
    let t = &loaded.scene.time;
    let mut v = vec![start];
    match &t.output {
        OutputSchedule::Every { output_dt: dt } => {
            let n = (t.t_end / dt + 1e-9).floor() as usize;
            v.extend((1..=n).map(|i| i as f64 * dt));
        }
        OutputSchedule::At { output_times } => v.extend(output_times.iter().copied()),
        OutputSchedule::EndOnly => {}
    }
    v.push(t.t_end);
    // A run that starts later (initial conditions at the file's time) writes what is after.
    v.retain(|&x| x >= start);
    v.sort_by(|a, b| a.total_cmp(b));
    v.dedup_by(|a, b| (*a - *b).abs() <= 1e-12 * t.t_end);
    v
}

/// What the outputs have written so far (a checkpoint keeps it).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct OutputRecord {
    /// Index into the output times of the next snapshot.
    pub next_output: usize,
    pub snapshots: Vec<String>,
    /// Time of each snapshot (for the XDMF time series).
    pub snapshot_times: Vec<f64>,
    /// Error norms at every snapshot time (scenes with an exact solution).
    pub errors: Vec<ExactErrors>,
    /// The ball: the undisturbed core at each snapshot time (docs/method.md §6.1).
    #[serde(default)]
    pub ball_core: Vec<analysis::ball::CoreCheck>,
    /// The time bins individual steps would give each snapshot's state after the first
    /// (`analysis::bins`; CFL steps on a whole state only).
    #[serde(default)]
    pub time_bins: Vec<analysis::bins::BinCensus>,
    /// The sums at each output (`DIR/evolution.csv`).
    #[serde(default)]
    pub evolution: Vec<super::evolution::Row>,
    /// The time the run started at: 0, or an initial-conditions file's `Header/Time`.
    #[serde(default)]
    pub start_time: f64,
    /// Initial conditions from a file: which, and its SHA-256.
    #[serde(default)]
    pub initial_conditions: Option<crate::setup::file::IcSource>,
    /// Wall seconds of the snapshot writer: each snapshot's files, error norms and the ball's
    /// core (on a thread of its own beside the steps, where the run writes in the background).
    #[serde(default)]
    pub writer_seconds: f64,
}

/// Writes the snapshots of a run (rank 0 over MPI ranks).
pub struct Outputs {
    pub loaded: LoadedScene,
    pub dir: PathBuf,
    times: Vec<f64>,
    pub record: OutputRecord,
    verbose: bool,
    /// Write each snapshot before the run steps on (else on the writer thread, [`Pending`]).
    pub inline: bool,
    /// The snapshot being written beside the steps: at most one.
    pending: Option<Pending>,
}

/// A snapshot written on a thread of its own from a copy of the state while the run steps on
/// (one process: the engine's launcher, CPU or GPU, goes on with the next steps). The run
/// waits for it at the next output, a checkpoint and its end ([`Outputs::settle`]); the
/// record lists the snapshot only once its files are whole.
struct Pending {
    name: String,
    t: f64,
    job: std::thread::JoinHandle<Result<Written, RunError>>,
}

/// What the writer thread owns: the state's copy and what its files say of the run.
struct SnapshotJob {
    path: PathBuf,
    loaded: LoadedScene,
    ics: Option<crate::setup::file::IcSource>,
    phys: crate::step::Physics,
    state: crate::particles::State,
    t_stop: Vec<Vec<f64>>,
    /// Each gas particle's |A| and signal speed, for the time bins' census (CFL steps after
    /// the first snapshot).
    limits: Option<(Vec<[f64; 3]>, Vec<f64>)>,
    /// The XDMF time series with this snapshot, written once the snapshot is.
    series: Vec<(f64, String)>,
}

impl SnapshotJob {
    /// The snapshot's files (its HDF5 file, its XDMF sidecar, the series), then the analyses
    /// of the state's copy; the seconds taken.
    fn write(self) -> Result<Written, RunError> {
        let t0 = std::time::Instant::now();
        let SnapshotJob {
            path,
            loaded,
            ics,
            phys,
            state,
            t_stop,
            limits,
            series,
        } = self;
        let c = &crate::dist::Alone;
        write_snapshot_of(
            &path,
            (&loaded, ics.as_ref()),
            &phys,
            (&state, &t_stop),
            c,
            &OnCores,
        )?;
        let dir = path.parent().unwrap_or(Path::new("."));
        io::write_xdmf_series(dir, &series).map_err(|e| RunError::Io(e.to_string()))?;
        let (errors, core) = analyses(&loaded, &state, &phys);
        let time = &loaded.scene.time;
        let bins = limits.and_then(|(a, v)| analysis::bins::census(&state, &phys, time, (&a, &v)));
        Ok(Written {
            seconds: t0.elapsed().as_secs_f64(),
            errors,
            core,
            bins,
        })
    }
}

/// What the writer thread hands back: its seconds and the analyses of the state's copy.
struct Written {
    seconds: f64,
    errors: Vec<ExactErrors>,
    core: Option<analysis::ball::CoreCheck>,
    bins: Option<analysis::bins::BinCensus>,
}

/// A snapshot's analyses of the whole state: the error norms against the exact solution, the
/// ball's undisturbed core.
fn analyses(
    loaded: &LoadedScene,
    state: &crate::particles::State,
    phys: &crate::step::Physics,
) -> (Vec<ExactErrors>, Option<analysis::ball::CoreCheck>) {
    let fixed_dt = loaded.scene.time.fixed_dt();
    let errors = analysis::exact_errors(&loaded.scene, state, fixed_dt);
    (errors, ball_core(loaded, state, phys, &crate::dist::Alone))
}

impl Outputs {
    pub fn new(loaded: &LoadedScene, dir: &Path, record: OutputRecord, verbose: bool) -> Outputs {
        Outputs {
            times: output_times(loaded, record.start_time),
            loaded: loaded.clone(),
            dir: dir.to_path_buf(),
            record,
            verbose,
            inline: false,
            pending: None,
        }
    }

    /// Wait for the snapshot being written beside the steps, if any, and enter it in the
    /// record (its failure is the run's: the error names the file).
    pub fn settle(&mut self) -> Result<(), RunError> {
        let Some(p) = self.pending.take() else {
            return Ok(());
        };
        let written = p.job.join().unwrap_or_else(|_| {
            Err(RunError::Io(format!(
                "{}: the snapshot writer stopped (panicked)",
                self.dir.join(&p.name).display()
            )))
        })?;
        self.record.writer_seconds += written.seconds;
        self.record.errors.extend(written.errors);
        self.record.ball_core.extend(written.core);
        self.record.time_bins.extend(written.bins);
        self.record.snapshots.push(p.name);
        self.record.snapshot_times.push(p.t);
        Ok(())
    }

    /// Write the next snapshot from the simulation's (synced) state: its file, its errors, the
    /// series. Over ranks every rank goes on, or none.
    pub fn write_next(&mut self, sim: &mut Simulation) -> Result<(), RunError> {
        // At most one snapshot pending: the last one is whole (and named in the record) before
        // the next is copied.
        self.settle()?;
        let name = io::snapshot_name(self.record.snapshots.len());
        // The sums of the output (collective where the ranks hold shares); rank 0 writes them.
        let totals = sim.stepper.totals(&sim.state);
        if sim.is_root() {
            let when = (sim.state.t, sim.state.step);
            let pm = sim.phys.gravity.is_on();
            let row = super::evolution::Row::of(when, &totals, &sim.diagnostics, pm);
            self.record.evolution.push(row);
            super::evolution::write(&self.dir, &self.record.evolution)
                .map_err(|e| RunError::Io(e.to_string()))?;
        }
        if self.write_by_share(sim, &name)? {
            return Ok(());
        }
        // Over ranks the others deflate a share of rank 0's chunks while it writes.
        let helpers = sim.stepper.output_world();
        let written = match (sim.is_root(), helpers) {
            (true, None) if !self.inline => {
                // Entered in the record once whole ([`Outputs::settle`]).
                self.write_files(sim, &name, None)?;
                self.record.next_output += 1;
                return Ok(());
            }
            (true, None) => self.write_files(sim, &name, Some(&OnCores)),
            (true, Some(w)) => {
                let farm = crate::dist::farm::Farm::new(w);
                let written = self.write_files(sim, &name, Some(&farm));
                farm.finish();
                written
            }
            (false, Some(w)) => {
                if let Err(e) = crate::dist::farm::serve(&w) {
                    // Rank 0 waits for this rank's chunks: the job cannot go on.
                    eprintln!("dustsph: rank {}: {e}", w.rank());
                    w.abort(1);
                }
                Ok(())
            }
            (false, None) => Ok(()),
        };
        // No rank may wait on one that stopped.
        if sim.any(written.is_err()) {
            written.clone()?;
            return Err(RunError::Io("rank 0 could not write the output".into()));
        }
        self.record.snapshots.push(name);
        self.record.snapshot_times.push(sim.state.t);
        self.record.next_output += 1;
        sim.shed_gathered();
        Ok(())
    }

    /// Over ranks whose outputs are written by share: the next snapshot, each rank its own
    /// particles ([`write_snapshot_of`]; collective). False (nothing written) elsewhere.
    fn write_by_share(&mut self, sim: &mut Simulation, name: &str) -> Result<bool, RunError> {
        let step_err = |e: crate::step::StepError| RunError::Step(e.to_string());
        let ics = self.record.initial_conditions.as_ref();
        let path = self.dir.join(name);
        let phys = sim.stepper.phys().clone();
        let loaded = &self.loaded;
        let fixed_dt = loaded.scene.time.fixed_dt();
        let write = |own: &crate::particles::State, t_stop: &[Vec<f64>], w: &World| {
            let c: &dyn crate::dist::Comm = w;
            let written =
                write_snapshot_of(&path, (loaded, ics), &phys, (own, t_stop), c, &OnCores);
            // The errors and the ball's core reduced over the ranks (whatever the write said:
            // every rank takes part).
            let errors = analysis::exact_errors_over(c, &loaded.scene, own, fixed_dt);
            let core = ball_core(loaded, own, &phys, c);
            (written, errors, core, w.rank())
        };
        let own = sim.stepper.own_output(&sim.state, write);
        let Some((written, errors, core, rank)) = own.map_err(step_err)? else {
            // The ranks step on the deep halo (a rank holds no gas): the output is gathered.
            sim.sync().map_err(step_err)?;
            return Ok(false);
        };
        let written = written.and_then(|()| match rank {
            0 => {
                self.record.errors.extend(errors);
                self.record.ball_core.extend(core);
                self.write_series((sim.state.t, sim.state.step), name)
            }
            _ => Ok(()),
        });
        // No rank may wait on one that stopped.
        if sim.any(written.is_err()) {
            written.clone()?;
            return Err(RunError::Io(
                "another rank could not write the output".into(),
            ));
        }
        self.record.snapshots.push(name.to_string());
        self.record.snapshot_times.push(sim.state.t);
        self.record.next_output += 1;
        Ok(true)
    }

    /// The snapshot `name` of the simulation's (synced) state, its chunks filtered by
    /// `chunks` before the run goes on, or (`None`) on the writer thread from a copy of the
    /// state, each with its error norms and the ball's core; then the time bins of the state.
    fn write_files(
        &mut self,
        sim: &mut Simulation,
        name: &str,
        chunks: Option<&dyn ChunkFilter>,
    ) -> Result<(), RunError> {
        let ics = self.record.initial_conditions.as_ref();
        let path = self.dir.join(name);
        let when = (sim.state.t, sim.state.step);
        match chunks {
            Some(chunks) => {
                let t0 = std::time::Instant::now();
                write_snapshot(&path, &self.loaded, ics, sim, chunks)?;
                self.write_series(when, name)?;
                let (errors, core) = analyses(&self.loaded, &sim.state, &sim.phys);
                self.record.errors.extend(errors);
                self.record.ball_core.extend(core);
                self.record.writer_seconds += t0.elapsed().as_secs_f64();
            }
            None => {
                self.say_written(when, name);
                let Simulation { stepper, state, .. } = &mut *sim;
                let step_err = |e: crate::step::StepError| RunError::Step(e.to_string());
                let t_stop = stepper.output_fields(state).map_err(step_err)?;
                // One process: the state is in the engine's order, which the limits follow.
                let limits = (self.census_due(state))
                    .then(|| stepper.particle_limits(state))
                    .transpose()
                    .map_err(step_err)?;
                let job = SnapshotJob {
                    path,
                    loaded: self.loaded.clone(),
                    ics: ics.cloned(),
                    phys: stepper.phys().clone(),
                    state: state.clone(),
                    t_stop,
                    limits,
                    series: self.series_with(when.0, name),
                };
                let job = std::thread::Builder::new()
                    .name("snapshot writer".into())
                    .spawn(move || job.write())
                    .map_err(|e| RunError::Io(format!("{}: {e}", self.dir.display())))?;
                self.pending = Some(Pending {
                    name: name.to_string(),
                    t: when.0,
                    job,
                });
                return Ok(());
            }
        }
        // Last: it brings the state into the engine's order, which the stopping times the
        // snapshot took over ranks do not follow.
        if self.census_due(&sim.state) {
            let limits = (sim.stepper.particle_limits(&mut sim.state))
                .map_err(|e| RunError::Step(e.to_string()))?;
            let time = &self.loaded.scene.time;
            let lim = (limits.0.as_slice(), limits.1.as_slice());
            self.record
                .time_bins
                .extend(analysis::bins::census(&sim.state, &sim.phys, time, lim));
        }
        Ok(())
    }

    /// Whether this output gets a census of the time bins: CFL steps, after the first.
    fn census_due(&self, state: &crate::particles::State) -> bool {
        state.step > 0 && self.loaded.scene.time.fixed_dt().is_none()
    }

    fn say_written(&self, (t, step): (f64, u64), name: &str) {
        if self.verbose {
            eprintln!("  t = {t:.6}  step {step:>7}  → {name}");
        }
    }

    /// The XDMF time series of the record with the snapshot `name` at time `t` added.
    fn series_with(&self, t: f64, name: &str) -> Vec<(f64, String)> {
        (self.record.snapshot_times.iter().copied())
            .chain([t])
            .zip(
                self.record
                    .snapshots
                    .iter()
                    .cloned()
                    .chain([name.to_string()]),
            )
            .collect()
    }

    /// The XDMF time series with the snapshot `name` at time `t` added, written now.
    fn write_series(&self, when: (f64, u64), name: &str) -> Result<(), RunError> {
        self.say_written(when, name);
        let series = self.series_with(when.0, name);
        io::write_xdmf_series(&self.dir, &series).map_err(|e| RunError::Io(e.to_string()))
    }

    /// Whether every output time has been written.
    pub fn done(&self) -> bool {
        self.record.next_output >= self.times.len()
    }
}

impl Observer for Outputs {
    fn name(&self) -> &'static str {
        "snapshots (output fields, files, error norms)"
    }

    fn next_time(&self, _t: f64) -> Option<f64> {
        self.times.get(self.record.next_output).copied()
    }

    fn after_step(&mut self, sim: &mut Simulation, taken: &Taken) -> Result<Flow, RunError> {
        if taken.plan.landing && Some(taken.plan.t_target) == self.next_time(sim.state.t) {
            self.write_next(sim)?;
        }
        Ok(Flow::Continue)
    }

    fn settle(&mut self) -> Result<(), RunError> {
        Outputs::settle(self)
    }

    fn save(&self) -> Option<(&'static str, serde_json::Value)> {
        Some(("outputs", serde_json::to_value(&self.record).ok()?))
    }
}

impl Drop for Outputs {
    /// A run dropped on an error still leaves its last snapshot whole (or, failed, no file:
    /// it is written to a temporary name and renamed).
    fn drop(&mut self) {
        if let Some(p) = self.pending.take() {
            let _ = p.job.join();
        }
    }
}

/// Write one snapshot of the simulation's (synced) state: the dust densities and stopping
/// times computed for it, variable h's per-particle h, the effective scene and its provenance;
/// its chunks filtered by `chunks`.
pub fn write_snapshot(
    path: &Path,
    loaded: &LoadedScene,
    ics: Option<&crate::setup::file::IcSource>,
    sim: &mut Simulation,
    chunks: &dyn ChunkFilter,
) -> Result<(), RunError> {
    let step_err = |e: crate::step::StepError| RunError::Step(e.to_string());
    // The state is synced (the loop syncs every process at a landing; over ranks this runs on
    // rank 0 alone, so nothing here may be collective).
    let Simulation { stepper, state, .. } = sim;
    let t_stop = stepper.output_fields(state).map_err(step_err)?;
    let (phys, c) = (stepper.phys(), &crate::dist::Alone);
    write_snapshot_of(path, (loaded, ics), phys, (state, &t_stop), c, chunks)
}

/// The snapshot of `state` with its dust stopping times per fraction, over the processes of
/// `c` that each hold a share of the particles (collective; one process holds them all):
/// process 0 writes the file ([`io::write_snapshot_shared`]) and its XDMF sidecar.
pub fn write_snapshot_of(
    path: &Path,
    (loaded, ics): (&LoadedScene, Option<&crate::setup::file::IcSource>),
    phys: &crate::step::Physics,
    (state, t_stop): (&crate::particles::State, &[Vec<f64>]),
    c: &dyn crate::dist::Comm,
    chunks: &dyn ChunkFilter,
) -> Result<(), RunError> {
    let h = phys.h;
    let g = &state.gas;
    // Variable h: the gas's own h; the dust's from its density (h = hfact (m/ρ)^(1/d), the
    // relation its solve satisfies); the box margin is the largest support.
    let dim = loaded.scene.dim();
    let dust_h: Vec<Option<Vec<f64>>> = state
        .dust
        .iter()
        .map(|d| {
            phys.variable_h.map(|hf| {
                d.m.iter()
                    .zip(&d.rho)
                    .map(|(&m, &r)| dustsph_device::kernel::h_of_density(m, r, hf, dim, h))
                    .collect()
            })
        })
        .collect();
    let gas_h = g.h.as_deref().filter(|_| phys.variable_h.is_some());
    let h_max = gas_h
        .iter()
        .flat_map(|v| v.iter())
        .chain(dust_h.iter().flatten().flatten())
        .fold(h, |a, &b| if b.is_finite() { a.max(b) } else { a });
    // The snapshot contract has InternalEnergy for every gas; isothermal gas solves no energy
    // equation, so it gets p/ρ (= c_s²), made here for output only.
    let e_iso: Option<Vec<f64>> =
        g.e.is_none()
            .then(|| g.p.iter().zip(&g.ph.rho).map(|(p, r)| p / r).collect());
    let scene_file = loaded.path.display().to_string();
    let model = loaded.scene.to_toml();
    let view = SnapshotView {
        time: state.t,
        dim,
        periodic: phys.domain.periodic,
        pad: dustsph_device::kernel::SUPPORT * h_max,
        scene_text: &loaded.effective,
        scene_model: &model,
        source: io::SceneSource {
            file: &scene_file,
            text: &loaded.text,
            overrides: &loaded.overrides,
            initial_conditions: ics.map(|s| (s.path.as_str(), s.sha256.as_str())),
            units: loaded
                .scene
                .units
                .map(|u| [u.length_cm, u.mass_g, u.time_s()]),
        },
        gas: Some(PhaseView {
            x: &g.ph.x,
            v: &g.ph.v,
            m: &g.ph.m,
            rho: &g.ph.rho,
            h,
            h_each: gas_h,
            id: &g.ph.id,
            e: g.e.as_deref().or(e_iso.as_deref()),
            p: Some(&g.p),
            t_stop: None,
        }),
        dust: state
            .dust
            .iter()
            .zip(t_stop)
            .zip(&dust_h)
            .map(|((d, ts), dh)| PhaseView {
                x: &d.x,
                v: &d.v,
                m: &d.m,
                rho: &d.rho,
                h,
                h_each: dh.as_deref(),
                id: &d.id,
                e: None,
                p: None,
                t_stop: Some(ts),
            })
            .collect(),
    };
    let io_err = |e: io::IoError| RunError::Io(e.to_string());
    let rows = io::write_snapshot_shared(path, &view, c, chunks).map_err(io_err)?;
    // ParaView sidecar: gas and dust as two point sets.
    if c.rank() == 0 {
        io::write_xdmf_view_rows(path, &view, rows).map_err(io_err)?;
    }
    Ok(())
}

/// The ball's undisturbed core (docs/method.md §6.1) against the initial state, for a ball
/// scene (`None` otherwise), of the particles every process of `c` holds a share of.
fn ball_core(
    loaded: &LoadedScene,
    state: &crate::particles::State,
    phys: &crate::step::Physics,
    c: &dyn crate::dist::Comm,
) -> Option<analysis::ball::CoreCheck> {
    let sc = &loaded.scene;
    let b = sc.ball()?;
    let (rho, p) = (b.background.rho, b.background.p);
    let cs = phys.eos.sound_speed(rho, p);
    let eps: f64 = sc.fractions().iter().map(|f| f.eps).sum();
    analysis::ball::core_check(c, state, (b.radius, rho, eps * rho, p, cs, phys.h))
}

/// The ball's Lagrange–Jacobi terms while it runs (a checkpoint keeps them).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct BallRecord {
    /// (t, I, 2Σm|v|² + 2dΣm p/ρ) after every step.
    pub lagrange_jacobi: Vec<(f64, f64, f64)>,
}

/// The ball's Lagrange–Jacobi identity (docs/method.md §6.1): its terms after every step, from
/// the state as the step left it (before an output's engine reorders it).
pub struct BallChecks {
    loaded: LoadedScene,
    pub record: BallRecord,
}

impl BallChecks {
    /// For the ball only (`None` for other scenes).
    pub fn of(loaded: &LoadedScene, record: BallRecord) -> Option<BallChecks> {
        (loaded.scene.kind() == Problem::Dustyball).then(|| BallChecks {
            loaded: loaded.clone(),
            record,
        })
    }

    /// Record the terms of the state as it stands (collective over ranks; rank 0 keeps them).
    pub fn record_now(&mut self, sim: &mut Simulation) -> Result<(), RunError> {
        let (i, rhs) = sim
            .stepper
            .lagrange_jacobi_terms(self.loaded.scene.dim())
            .map_err(|e| RunError::Step(e.to_string()))?;
        if sim.is_root() {
            self.record.lagrange_jacobi.push((sim.state.t, i, rhs));
        }
        Ok(())
    }
}

impl Observer for BallChecks {
    fn name(&self) -> &'static str {
        "ball checks (core, Lagrange–Jacobi)"
    }

    fn after_step(&mut self, sim: &mut Simulation, _: &Taken) -> Result<Flow, RunError> {
        self.record_now(sim)?;
        Ok(Flow::Continue)
    }

    fn save(&self) -> Option<(&'static str, serde_json::Value)> {
        Some(("ball", serde_json::to_value(&self.record).ok()?))
    }
}
