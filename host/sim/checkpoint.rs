//! Checkpoints of a run (`DIR/checkpoint.h5`: the whole state, the scene as run and the run's
//! progress) and what resume checks before it continues one.
use super::output::{output_times, BallRecord, OutputRecord};
use super::{Checkpointer, Diagnostics, RunError, Simulation};
use crate::io;
use crate::particles::State;
use crate::scene::LoadedScene;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Everything besides the particles that a resumed run must know.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Progress {
    pub diagnostics: Diagnostics,
    pub outputs: OutputRecord,
    #[serde(default)]
    pub ball: BallRecord,
    /// Wall seconds of the run's earlier sessions.
    pub wall_before: f64,
    /// What the set-up gave the run's physics (None in checkpoints written before it was kept):
    /// a resume takes it from here instead of setting the scene up again, so a run from a file
    /// resumes without the file.
    #[serde(default)]
    pub layout: Option<Layout>,
}

/// The set-up's part of a run's physics: the reference h and the periodic axes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Layout {
    pub h: f64,
    pub periodic: [Option<(f64, f64)>; 3],
}

/// Writes the run's checkpoint into its output directory (rank 0 over ranks).
pub struct RunCheckpoints {
    pub loaded: LoadedScene,
    pub dir: PathBuf,
    /// Wall seconds of earlier sessions, and when this one started.
    pub wall_before: f64,
    pub started: Instant,
    /// The step count of the last checkpoint written in this session.
    pub last_step: Option<u64>,
}

impl Checkpointer for RunCheckpoints {
    fn write(
        &mut self,
        sim: &mut Simulation,
        parts: Vec<(&'static str, serde_json::Value)>,
    ) -> Result<(), RunError> {
        let part = |name: &str| {
            parts
                .iter()
                .find(|p| p.0 == name)
                .map_or(serde_json::Value::Null, |p| p.1.clone())
        };
        let io_err = |e: serde_json::Error| RunError::Io(e.to_string());
        let progress = Progress {
            diagnostics: sim.diagnostics.clone(),
            outputs: serde_json::from_value(part("outputs")).map_err(io_err)?,
            ball: serde_json::from_value(part("ball")).unwrap_or_default(),
            wall_before: self.wall_before + self.started.elapsed().as_secs_f64(),
            layout: Some(Layout {
                h: sim.phys.h,
                periodic: sim.phys.domain.periodic,
            }),
        };
        let meta = io::checkpoint::CheckpointMeta {
            scene_text: self.loaded.text.clone(),
            scene_file: self.loaded.path.display().to_string(),
            overrides_json: serde_json::to_string(&self.loaded.overrides).map_err(io_err)?,
            progress_json: serde_json::to_string(&progress).map_err(io_err)?,
        };
        let path = self.dir.join(io::checkpoint::CHECKPOINT_NAME);
        let io_err = |e: io::IoError| RunError::Io(e.to_string());
        // Over ranks whose outputs are written by share, each rank writes its own particles
        // into the one file; elsewhere rank 0 writes the whole state, gathered.
        let shared = (sim.stepper).with_own(&sim.state, |own, w| {
            io::checkpoint::write_checkpoint_shared(&path, own, &meta, w).map_err(io_err)
        });
        let written = match shared {
            Some(w) => w,
            None => {
                sim.sync().map_err(|e| RunError::Step(e.to_string()))?;
                match sim.is_root() {
                    true => {
                        io::checkpoint::write_checkpoint(&path, &sim.state, &meta).map_err(io_err)
                    }
                    false => Ok(()),
                }
            }
        };
        if sim.any(written.is_err()) {
            written.clone()?;
            return Err(RunError::Io("rank 0 could not write the checkpoint".into()));
        }
        self.last_step = Some(sim.state.step);
        written
    }
}

/// A checkpoint read back: its state, its scene as run, its progress. Everything wrong with it
/// is input (resume exits 2 and changes nothing).
pub fn read(dir: &Path) -> Result<(State, LoadedScene, Progress), RunError> {
    read_on(dir, &crate::dist::Alone)
}

/// [`read`] as one of the processes of `c` (collective): the state is this process's share of
/// the checkpoint's rows ([`io::checkpoint::read_checkpoint_on`]), and every process returns
/// the same verdict.
pub fn read_on(
    dir: &Path,
    c: &dyn crate::dist::Comm,
) -> Result<(State, LoadedScene, Progress), RunError> {
    let ck = dir.join(io::checkpoint::CHECKPOINT_NAME);
    let io::checkpoint::CheckpointShare {
        state,
        meta,
        counts,
    } = io::checkpoint::read_checkpoint_on(&ck, c).map_err(|e| RunError::Input(e.to_string()))?;
    let bad = |e: String| RunError::Input(format!("{}: {e}", ck.display()));
    let overrides: Vec<String> =
        serde_json::from_str(&meta.overrides_json).map_err(|e| bad(e.to_string()))?;
    let file = PathBuf::from(&meta.scene_file);
    let loaded = LoadedScene::from_text(&meta.scene_text, &file, &overrides)
        .map_err(|e| bad(e.to_string()))?;
    let progress: Progress = serde_json::from_str(&meta.progress_json).map_err(|e| {
        bad(format!(
            "its progress does not read ({e}): a checkpoint of an older dustsph?"
        ))
    })?;
    verify_resume(
        dir,
        (&state, &counts, c),
        &loaded,
        &progress.outputs,
        &progress.diagnostics.accreted,
    )
    .map_err(bad)?;
    Ok((state, loaded, progress))
}

/// A checkpoint may continue only the run it was written by, in its own directory: its
/// particles agree with its own scene (counts per phase, unused coordinates zero), every
/// snapshot its progress lists is there and was written by the same effective scene with the
/// same particle counts no later than the checkpoint, and no other snapshot would be
/// overwritten. Particles the star accreted (its record in `accreted`) count as the run's: the
/// set-up's counts are the state's plus those, and a snapshot holds between the two.
/// `state` is this process's share of the checkpoint, `whole` every process's counts (the
/// gas's, then each fraction's); collective over `c`.
fn verify_resume(
    dir: &Path,
    (state, whole, c): (&State, &[usize], &dyn crate::dist::Comm),
    loaded: &LoadedScene,
    outputs: &OutputRecord,
    accreted: &super::accretion::Accreted,
) -> Result<(), String> {
    let scene = &loaded.scene;
    let have = (whole[0], whole[1..].to_vec());
    let taken_dust = |k: usize| accreted.dust_particles.get(k).copied().unwrap_or(0);
    let with_accreted = (
        have.0 + accreted.gas_particles,
        have.1
            .iter()
            .enumerate()
            .map(|(k, n)| n + taken_dust(k))
            .collect::<Vec<_>>(),
    );
    // A run from a file is not set up again (the file may have moved): its counts are held to
    // its own snapshots below.
    if !matches!(scene.problem, crate::scene::ProblemCfg::File(_)) {
        verify_scene_counts(scene, c, (&have, &with_accreted), accreted)?;
    }
    verify_dim(state, scene, c)?;
    if let Some(&t_end) = output_times(loaded, outputs.start_time).last() {
        if state.t >= t_end {
            return Err(format!(
                "its run already reached t_end = {t_end} (t = {}): nothing to resume, and the \
                 output stays as it is (to run further, start a new run with a later \
                 time.t_end)",
                state.t
            ));
        }
    }
    verify_listed_snapshots(dir, state, loaded, outputs, (&have, &with_accreted))?;
    verify_no_other_snapshot(dir, state, loaded, outputs)
}

/// Particle counts: the gas's, then each fraction's.
type Counts = (usize, Vec<usize>);

/// The checkpoint's counts, with the accreted particles (`with_accreted`), are those its
/// scene sets up (by share where the scene allows: each process its share, counted
/// together; collective over `c`).
fn verify_scene_counts(
    scene: &crate::scene::Scene,
    c: &dyn crate::dist::Comm,
    (have, with_accreted): (&Counts, &Counts),
    accreted: &super::accretion::Accreted,
) -> Result<(), String> {
    let counts =
        |s: &State| -> Counts { (s.gas.ph.len(), s.dust.iter().map(|d| d.len()).collect()) };
    let su =
        crate::setup::build_on(scene, c).map_err(|e| format!("its scene cannot be set up: {e}"))?;
    let mut want = counts(&su.state);
    if su.share {
        let mut n: Vec<u64> = std::iter::once(want.0)
            .chain(want.1.iter().copied())
            .map(|n| n as u64)
            .collect();
        c.sum_u64(&mut n);
        want = (n[0] as usize, n[1..].iter().map(|&n| n as usize).collect());
    }
    if want != *with_accreted {
        return Err(format!(
            "its particles (gas {}, dust {:?}, with {} gas and {:?} dust accreted) do not \
             match its own scene (gas {}, dust {:?})",
            have.0, have.1, accreted.gas_particles, accreted.dust_particles, want.0, want.1
        ));
    }
    Ok(())
}

/// No process's particle has a coordinate the scene's dimension leaves unused (collective
/// over `c`).
fn verify_dim(
    state: &State,
    scene: &crate::scene::Scene,
    c: &dyn crate::dist::Comm,
) -> Result<(), String> {
    let dim = scene.dim() as usize;
    let phases = std::iter::once(&state.gas.ph).chain(&state.dust);
    let mut off_axis = [(dim < 3
        && phases
            .flat_map(|p| &p.x)
            .any(|x| x[dim..].iter().any(|c| *c != 0.0))) as u8 as f64];
    c.max_f64(&mut off_axis);
    if off_axis[0] > 0.0 {
        return Err(format!(
            "its particles are not {dim}-dimensional as its scene (scene.dim = {dim}) says"
        ));
    }
    Ok(())
}

/// Every snapshot the checkpoint's progress lists is in `dir`, written by the same effective
/// scene with the same particle counts (between the state's and those with the accreted),
/// no later than the checkpoint and at the time the run wrote it.
fn verify_listed_snapshots(
    dir: &Path,
    state: &State,
    loaded: &LoadedScene,
    outputs: &OutputRecord,
    (have, with_accreted): (&Counts, &Counts),
) -> Result<(), String> {
    let dim = loaded.scene.dim() as usize;
    let n_dust: usize = have.1.iter().sum();
    for (k, name) in outputs.snapshots.iter().enumerate() {
        let p = dir.join(name);
        let h = io::snapshot::read_header(&p).map_err(|e| {
            format!("the snapshot {name} its run wrote is missing or unreadable ({e})")
        })?;
        let same_scene = same_run_scene(&h, loaded);
        let (ng, nd) = (
            h.num_part[io::snapshot::GAS_TYPE] as usize,
            h.num_part[io::snapshot::DUST_TYPE] as usize,
        );
        let same_counts = (have.0..=with_accreted.0).contains(&ng)
            && (n_dust..=with_accreted.1.iter().sum::<usize>()).contains(&nd);
        if !same_scene || !same_counts || h.dim as usize != dim {
            return Err(format!(
                "{name} in {} was written by another run (scene {}, particles {:?}): the \
                 checkpoint belongs elsewhere",
                dir.display(),
                if same_scene { "the same" } else { "different" },
                h.num_part
            ));
        }
        if h.time > state.t {
            return Err(format!(
                "{name} is at t = {} after the checkpoint's t = {}: the checkpoint is older \
                 than the run's output",
                h.time, state.t
            ));
        }
        // The run wrote this snapshot at a known time: another one copied over it is not it.
        if let Some(&t) = outputs.snapshot_times.get(k) {
            if h.time != t {
                return Err(format!(
                    "{name} in {} is at t = {}, but the checkpoint's run wrote it at t = {t}: \
                     it was replaced; put the run's own file back",
                    dir.display(),
                    h.time
                ));
            }
        }
    }
    Ok(())
}

/// No snapshot in `dir` but those the checkpoint's run wrote: resuming would overwrite it.
fn verify_no_other_snapshot(
    dir: &Path,
    state: &State,
    loaded: &LoadedScene,
    outputs: &OutputRecord,
) -> Result<(), String> {
    let listed: std::collections::HashSet<&str> =
        outputs.snapshots.iter().map(|s| s.as_str()).collect();
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        if io::output_dir::is_snapshot_name(&name) && !listed.contains(name.as_str()) {
            // The same run, written after the checkpoint was: say so.
            if let Ok(h) = io::snapshot::read_header(&e.path()) {
                if same_run_scene(&h, loaded) && h.time > state.t {
                    return Err(format!(
                        "{name} in {} (t = {}) was written after the checkpoint (t = {}); \
                         resuming would overwrite it (move it and the later snapshots away \
                         to continue from the checkpoint)",
                        dir.display(),
                        h.time,
                        state.t
                    ));
                }
            }
            return Err(format!(
                "{name} in {} is not one the checkpoint's run wrote; resuming would overwrite \
                 it (move it away, or resume in the run's own directory)",
                dir.display()
            ));
        }
    }
    Ok(())
}

/// Whether a snapshot was written from the scene a run is made of: the same effective scene
/// (file and overrides). A snapshot from before the Header recorded the effective scene holds
/// the file's text alone, which is the run's only if it had no overrides.
fn same_run_scene(h: &io::snapshot::SnapshotHeader, loaded: &LoadedScene) -> bool {
    match &h.source_text {
        Some(_) => h.scene_text == loaded.effective,
        None => loaded.overrides.is_empty() && h.scene_text == loaded.text,
    }
}
