//! `dustsph` command line.
use clap::{Parser, Subcommand};
use dustsph::commands::run::{Run, RunOptions};
use dustsph::scene::{ListChoice, Precision};
use dustsph::sim::summary::Summary;
use dustsph::sim::{RunError, Stop};
use dustsph::step::backend::DeviceChoice;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "dustsph",
    version = concat!(env!("CARGO_PKG_VERSION"), " (git ", env!("DUSTSPH_GIT"), ")"),
    about = "Gas + polydisperse dust by SPH-IDIC"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run a scene: snapshots at the scene's output times and summary.json in the output directory.
    Run(RunArgs),
    /// The GPU path: how its kernels were built, whether a device is usable; optionally write
    /// the embedded PTX (for `ptxas`).
    Gpu(GpuArgs),
    /// Run each scene kind for a few steps on a one-thread CPU reference and on a device, and
    /// compare every array after every step (bit for bit expected).
    Parity(ParityArgs),
    /// CPU speed: a uniform 3D box at ≈60 neighbours and the 3D ball, on 1 and 2 threads.
    Bench(BenchArgs),
    /// Radial profiles (CSV) and figures (PNG) of a snapshot, written next to it; for the ball
    /// also the errors against the 1D reference and the spherical-symmetry check.
    Profile(ProfileArgs),
    /// Run a study (configs/studies/*.toml): a scene over a grid of parameters, in this process;
    /// writes results.csv, results.md and error-against-run-time plots (PNG).
    Study(StudyArgs),
    /// The stiffness and extremes matrix (IDIC): every case must stay finite, conserve momentum
    /// to 1e-12, keep densities positive and match the exact wave/box solutions. Prints a line
    /// per case; exit code 1 if any fails.
    Stiffness(StiffnessArgs),
    /// Continue an interrupted run from DIR/checkpoint.h5, bit for bit.
    Resume(ResumeArgs),
    /// The multi-rank model (docs/scaling.md): the Morton decomposition of a ball and a slab of
    /// N particles over R ranks, its halo and what exchanging it costs; no physics, no MPI.
    Scaling(ScalingArgs),
    /// Under `mpirun -n R` (a build with the mpi feature): the decomposition, migration and
    /// halo exchange of a scene's particles over the ranks, checked on every rank (no physics;
    /// exit 1 on every rank if any rank's check fails).
    MpiCheck(MpiCheckArgs),
}

#[derive(clap::Args)]
struct MpiCheckArgs {
    /// Scene file (TOML)
    scene: PathBuf,
    /// Override a scene key (repeatable)
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Halo depth in kernel supports (2h): 1 for the exchange check (default); with `--steps`,
    /// step with a deep halo this many supports deep, its chain of passes recomputed on every
    /// rank (default: the thin halo a run uses, refreshed between the step's passes)
    #[arg(long)]
    depth: Option<f64>,
    /// Make this rank report a failure (checks that every rank then stops)
    #[arg(long, hide = true)]
    fail_rank: Option<u32>,
    /// Then step the scene N times over the ranks (the run's thin halo, or `--depth`'s deep
    /// one) and compare every particle with one process on rank 0 (exit 1 above 1e-12 of a
    /// field's scale)
    #[arg(long, default_value_t = 0)]
    steps: u64,
}

#[derive(clap::Args)]
struct RunArgs {
    /// Scene file (TOML), e.g. configs/dustywave.toml
    scene: PathBuf,
    /// Override a scene key, e.g. --set dust.fractions.0.t_stop=1e-6 (repeatable)
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Output directory (default: output/<scene name>)
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write into a non-empty output directory (replaces only dustsph's own files)
    #[arg(long)]
    force: bool,
    /// Write DIR/checkpoint.h5 every N steps (Ctrl-C always writes one)
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    checkpoint_every: Option<u64>,
    /// Stop as if interrupted after N steps (with --checkpoint-every N: a checkpoint to resume
    /// from; for tests)
    #[arg(long, value_name = "N", hide = true)]
    stop_after: Option<u64>,
    /// No progress output
    #[arg(long, short)]
    quiet: bool,
    /// Where to step: a CUDA GPU if usable, else the CPU (auto); the CPU's cores (cpu); a
    /// CUDA GPU (cuda). The same step and kernels on either.
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
    /// The float type of the step: f64 (the reference) or f32 (docs/accuracy.md); the
    /// same as --set numerics.precision=…
    #[arg(long, value_enum)]
    precision: Option<Precision>,
}

#[derive(clap::Args)]
struct GpuArgs {
    /// Write the embedded PTX to this file
    #[arg(long, value_name = "FILE")]
    write_ptx: Option<PathBuf>,
    /// Replace FILE if it exists
    #[arg(long)]
    force: bool,
}

#[derive(clap::Args)]
struct ParityArgs {
    /// The device to check against the one-thread CPU reference (cuda; or cpu: every core)
    #[arg(long, value_enum, default_value_t = DeviceChoice::Cuda)]
    device: DeviceChoice,
    /// Check the f32 kernels instead of the f64 ones
    #[arg(long, value_enum, default_value_t = Precision::F64)]
    precision: Precision,
}

#[derive(clap::Args)]
struct BenchArgs {
    /// Steps to time per case
    #[arg(long, default_value_t = 10)]
    steps: u64,
    /// Thread counts to run, e.g. 1,2
    #[arg(long, value_delimiter = ',', default_values_t = vec![1usize, 2])]
    threads: Vec<usize>,
    /// Also the full seed ball (2 × 248 439 particles, ≈2000 neighbours; minutes per step count)
    #[arg(long)]
    full: bool,
    /// Particles per side of the uniform 3D box (per phase), e.g. 32,100,160,215 for
    /// 3.3e4 … 1e7
    #[arg(long, value_delimiter = ',', default_values_t = vec![32usize])]
    box_n: Vec<usize>,
    /// Where to run: cpu (default) or cuda
    #[arg(long, value_enum, default_value_t = DeviceChoice::Cpu)]
    device: DeviceChoice,
    /// The float type of the step (f64 or f32)
    #[arg(long, value_enum, default_value_t = Precision::F64)]
    precision: Precision,
    /// Per-particle neighbour lists (auto: on the CPU, off on CUDA; numerics.neighbour_list)
    #[arg(long, value_enum, default_value_t = ListChoice::Auto)]
    neighbour_list: ListChoice,
}

#[derive(clap::Args)]
struct ProfileArgs {
    snapshot: PathBuf,
    /// Number of radial bins
    #[arg(long, default_value_t = 100)]
    bins: usize,
}

#[derive(clap::Args)]
struct StudyArgs {
    /// Study file (TOML), e.g. configs/studies/dustywave_n1.toml
    study: PathBuf,
    /// Output directory (default: output/studies/<study name>)
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write into a non-empty output directory (replaces only the study's own files)
    #[arg(long)]
    force: bool,
    /// No line per point
    #[arg(long, short)]
    quiet: bool,
    /// Validate the study and list its points; run nothing, write nothing
    #[arg(long)]
    dry_run: bool,
}

#[derive(clap::Args)]
struct StiffnessArgs {
    /// The full grid (default: the reduced CI grid)
    #[arg(long)]
    full: bool,
    /// Write the Markdown table to this file (e.g. docs/stiffness.md)
    #[arg(long)]
    out: Option<PathBuf>,
    /// Replace an existing --out file
    #[arg(long)]
    force: bool,
}

#[derive(clap::Args)]
struct ScalingArgs {
    /// Particles per cloud
    #[arg(long, default_value_t = 1e8)]
    particles: f64,
    /// Rank counts
    #[arg(long, value_delimiter = ',', default_values_t = vec![1u32, 2, 4, 8, 16, 64, 256, 1024, 4096])]
    ranks: Vec<u32>,
    /// Interconnect bandwidth per rank, Gb/s
    #[arg(long, default_value_t = 200.0)]
    gbps: f64,
    /// Measured step throughput of one rank, particle-steps/s (default: this code's CPU bench,
    /// 3D box at 56 neighbours on 2 cores)
    #[arg(long, default_value_t = 1.95e6)]
    rate: f64,
    /// Halo depth in kernel supports: 1 for an exchange before each neighbour pass; the length
    /// of the step's chain of neighbour passes for one exchange per step (then halo/owned is
    /// also the redundant compute)
    #[arg(long, default_value_t = 1.0)]
    depth: f64,
}

#[derive(clap::Args)]
struct ResumeArgs {
    dir: PathBuf,
    /// Write DIR/checkpoint.h5 every N steps (Ctrl-C always writes one)
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    checkpoint_every: Option<u64>,
    #[arg(long, short)]
    quiet: bool,
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
}

fn report(s: &Summary, out: &std::path::Path) {
    println!(
        "{}: {} steps to t = {} in {:.2} s ({:.3e} particle-steps/s); summary: {}",
        s.scene,
        s.steps,
        s.t_final,
        s.wall_seconds,
        s.particle_steps_per_second,
        out.join("summary.json").display()
    );
    for last in s.errors.iter().filter(|e| e.t == s.t_final) {
        let r = &last.reference;
        println!("  vs {}", r.split(';').next().unwrap_or(r));
        for f in &last.fields {
            print_field(f);
        }
    }
}

/// One line of an error table; a constant offset (one number) reads as one.
fn print_field(f: &dustsph::analysis::FieldError) {
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

/// Start the run (`start`: set-up and the first snapshot) and step it to the end. Ctrl-C is
/// caught from before the start: pressed during the set-up, the run stops at its first step
/// with a checkpoint (exit 130), as later.
fn drive(
    start: impl FnOnce() -> Result<Run, RunError>,
    checkpoint_every: Option<u64>,
    stop_after: Option<u64>,
) -> ExitCode {
    let fail = |e: RunError| {
        if !matches!(e, RunError::InputReported) {
            eprintln!("error: {e}");
        }
        ExitCode::from(match e {
            RunError::Input(_) | RunError::InputReported => 2,
            _ => 1,
        })
    };
    // Ctrl-C asks the loop to stop after the current step and write a checkpoint; a second one
    // stops at once (files are written to a temporary name and renamed, so none is left torn).
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    if let Err(e) = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::Relaxed) {
            eprintln!("dustsph: second interrupt: stopping now, without a checkpoint");
            std::process::exit(130);
        }
    }) {
        eprintln!("warning: Ctrl-C will not checkpoint ({e})");
    }
    let mut r = match start() {
        Ok(r) => r,
        Err(e) => return fail(e),
    };
    match r.advance(stop_after, checkpoint_every, Some(&stop)) {
        Ok(Stop::Finished) => {}
        Ok(Stop::Interrupted { .. }) if !r.is_root() => return ExitCode::from(130),
        Ok(Stop::Interrupted { .. }) => {
            let (step, t) = (r.sim.state.step, r.sim.state.t);
            if r.checkpointed_now() {
                eprintln!(
                    "interrupted at step {step}, t = {t}: checkpoint written; continue with \
                     `dustsph resume {}`",
                    r.out_dir().display()
                );
            } else {
                eprintln!("stopped at step {step}, t = {t}, without a checkpoint of this state");
            }
            return ExitCode::from(130);
        }
        Err(e) => return fail(e),
    }
    let out = r.out_dir().to_path_buf();
    let root = r.is_root();
    match r.finish() {
        Ok((s, _)) => {
            if root {
                report(&s, &out);
            }
            ExitCode::SUCCESS
        }
        Err(e) => fail(e),
    }
}

fn main() -> ExitCode {
    let cmd = Cli::parse().cmd;
    // One process per job, except for the MPI check: several ranks would each run the whole
    // command into the same output.
    let over_ranks = cfg!(feature = "mpi") && matches!(cmd, Cmd::Run(_) | Cmd::Resume(_));
    if !matches!(cmd, Cmd::MpiCheck(_)) && !over_ranks {
        if let Err(e) = dustsph::dist::refuse_many_ranks("this dustsph command") {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    }
    match cmd {
        Cmd::MpiCheck(a) => mpi_check(a),
        Cmd::Run(a) => run(a),
        Cmd::Bench(a) => bench(a),
        Cmd::Profile(a) => profile(a),
        Cmd::Study(a) => study(a),
        Cmd::Stiffness(a) => stiffness(a),
        Cmd::Resume(a) => resume(a),
        Cmd::Scaling(a) => scaling(a),
        Cmd::Parity(a) => parity(a),
        Cmd::Gpu(a) => gpu(a),
    }
}

fn run(a: RunArgs) -> ExitCode {
    let RunArgs {
        scene,
        set,
        out,
        force,
        checkpoint_every,
        stop_after,
        quiet,
        device,
        precision,
    } = a;
    let mut set = set;
    if let Some(p) = precision {
        set.push(format!("numerics.precision=\"{}\"", p.name()));
    }
    let loaded = match dustsph::scene::load(&scene, &set) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let out = out.unwrap_or_else(|| PathBuf::from("output").join(&loaded.scene.scene.name));
    // Over MPI ranks only rank 0 speaks (and writes).
    let quiet = quiet || dustsph::dist::launched().is_some_and(|(r, _)| r != 0);
    if !quiet {
        eprintln!("dustsph: {} → {}", scene.display(), out.display());
    }
    let opts = RunOptions {
        out,
        force,
        verbose: !quiet,
        device,
    };
    // Started as one of several MPI ranks: the run is split over them (docs/scaling.md).
    #[cfg(feature = "mpi")]
    if let Some(world) = ranks_world() {
        let start = || world.and_then(|w| Run::start_over_ranks(&loaded, &opts, w));
        return drive(start, checkpoint_every, stop_after);
    }
    drive(|| Run::start(&loaded, &opts), checkpoint_every, stop_after)
}

fn bench(a: BenchArgs) -> ExitCode {
    let BenchArgs {
        steps,
        threads,
        full,
        box_n,
        device,
        precision,
        neighbour_list,
    } = a;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let bad = if steps == 0 {
        Some("--steps must be at least 1".to_string())
    } else if let Some(t) = threads.iter().find(|&&t| t == 0 || t > 16 * cores) {
        Some(format!(
            "--threads {t}: each count must be between 1 and {} (16 × the {cores} cores here)",
            16 * cores
        ))
    } else {
        box_n
            .iter()
            .find(|&&n| n < 2)
            .map(|n| format!("--box-n {n}: at least 2 particles per side"))
    };
    if let Some(m) = bad {
        eprintln!("error: {m}");
        return ExitCode::from(2);
    }
    let mut cases: Vec<(String, &str, Vec<String>)> = box_n
        .iter()
        .map(|n| {
            (
                format!("box 3D n={n}, ~60 nb"),
                "configs/dustybox.toml",
                vec![
                    "scene.dim=3".to_string(),
                    format!("sph.n={n}"),
                    "sph.hfact=1.215".into(),
                    "dust.fractions=[{eps=0.5, t_stop=0.1}]".into(),
                    "dustybox.u_dust=[1.0]".into(),
                ],
            )
        })
        .collect();
    cases.push((
        "ball 3D, n=20, h=0.1".into(),
        "configs/dusty_ball.toml",
        vec!["sph.n=20".into()],
    ));
    if full {
        cases.push((
            "ball 3D seed (n=39, h=0.1)".into(),
            "configs/dusty_ball.toml",
            vec![],
        ));
    }
    println!(
        "{:<28} {:>7} {:>9} {:>9} {:>10} {:>6} {:>9} {:>14} {:>14} {:>9}",
        "case",
        "threads",
        "gas",
        "dust",
        "neighbours",
        "steps",
        "seconds",
        "particle-st/s",
        "interact./s",
        "B/part."
    );
    let mut where_ = String::new();
    for (name, file, sets) in cases {
        let name = name.as_str();
        let mut sets = sets;
        sets.push(format!("numerics.precision=\"{}\"", precision.name()));
        sets.push(format!(
            "numerics.neighbour_list=\"{}\"",
            neighbour_list.name()
        ));
        let loaded = match dustsph::scene::load_shipped(file, &sets) {
            Ok(l) => l,
            Err(e) => {
                eprintln!("error: {e}");
                return ExitCode::from(2);
            }
        };
        for &t in &threads {
            match dustsph::bench::bench(name, &loaded.scene, steps, t, device) {
                Ok(r) => {
                    println!(
                        "{:<28} {:>7} {:>9} {:>9} {:>10.1} {:>6} {:>9.3} {:>14.3e} {:>14.3e} {:>9}",
                        r.case,
                        r.threads,
                        r.gas,
                        r.dust,
                        r.mean_neighbours,
                        r.steps,
                        r.seconds,
                        r.particle_steps_per_s(),
                        r.interactions_per_s(),
                        r.bytes_per_particle
                            .map_or("-".into(), |b| format!("{b:.0}"))
                    );
                    where_ = r.device;
                }
                Err(e) => {
                    eprintln!("error: {name}: {e}");
                    return ExitCode::from(1);
                }
            }
        }
    }
    println!("device: {where_}");
    ExitCode::SUCCESS
}

/// More radial bins than this would hold fewer than one particle each in any snapshot that fits
/// in memory.
const MAX_BINS: usize = 1_000_000;

fn profile(a: ProfileArgs) -> ExitCode {
    let ProfileArgs { snapshot, bins } = a;
    if !(1..=MAX_BINS).contains(&bins) {
        eprintln!("error: --bins must be between 1 and {MAX_BINS} (got {bins})");
        return ExitCode::from(2);
    }
    // The usual mistakes, said plainly (not as HDF5's errno text), as bad input.
    if snapshot.is_dir() {
        eprintln!(
            "error: {} is a directory; give one of its snapshot_NNNN.h5 files",
            snapshot.display()
        );
        return ExitCode::from(2);
    }
    if !snapshot.is_file() {
        eprintln!("error: {}: no such file", snapshot.display());
        return ExitCode::from(2);
    }
    match dustsph::post::post_process(&snapshot, bins) {
        Ok(r) => {
            for f in &r.files {
                println!("wrote {}", f.display());
            }
            for e in &r.errors {
                println!("errors against {}", e.reference);
                for f in &e.fields {
                    print_field(f);
                }
            }
            if let Some(s) = &r.symmetry {
                println!(
                    "symmetry (axes vs diagonals, r < {}): rho_g {:.3e}, |v| {:.3e} (relative L1)",
                    s.r_max, s.rho_g_relative_l1, s.speed_relative_l1
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}

fn study(a: StudyArgs) -> ExitCode {
    let StudyArgs {
        study,
        out,
        force,
        quiet,
        dry_run,
    } = a;
    let st = match dustsph::study::load(&study) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    if dry_run {
        let all: Vec<usize> = (0..st.axes.len()).collect();
        for (i, p) in st.points.iter().enumerate() {
            println!("{:>4}  {}", i + 1, st.describe(p, &all, false));
        }
        return ExitCode::SUCCESS;
    }
    let out = out.unwrap_or_else(|| PathBuf::from("output/studies").join(&st.cfg.name));
    let command = format!(
        "dustsph study {} --out {} --force",
        study.display(),
        out.display()
    );
    if !quiet {
        eprintln!(
            "dustsph: study {} ({} points) → {}",
            study.display(),
            st.points.len(),
            out.display()
        );
    }
    match dustsph::study::run(&st, &out, force, quiet, &command) {
        Ok((results, files)) => {
            for f in &files {
                println!("wrote {}", f.display());
            }
            let failed = results
                .iter()
                .filter(|r| matches!(r.status, dustsph::study::Status::Failed(_)))
                .count();
            if failed > 0 {
                eprintln!("error: {failed} point(s) failed (see results.md)");
                return ExitCode::from(1);
            }
            // Every point skipped (over max_steps): the tables and plots hold no measurement.
            if !results.is_empty()
                && results
                    .iter()
                    .all(|r| matches!(r.status, dustsph::study::Status::Skipped(_)))
            {
                eprintln!(
                    "error: every point was skipped (each would need more than study.max_steps \
                     steps; see results.md): raise study.max_steps or coarsen the grid"
                );
                return ExitCode::from(1);
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}

fn stiffness(a: StiffnessArgs) -> ExitCode {
    let StiffnessArgs { full, out, force } = a;
    if let Some(o) = &out {
        if o.exists() && !force {
            eprintln!("error: {} exists; give --force to replace it", o.display());
            return ExitCode::from(2);
        }
        // Where the report goes must be writable before the matrix runs (minutes with --full).
        let dir = match o.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let probe = dir.join(format!(".dustsph-write-check-{}.tmp", std::process::id()));
        if o.is_dir() {
            eprintln!(
                "error: {} is a directory; --out names the report file",
                o.display()
            );
            return ExitCode::from(2);
        }
        if let Err(e) = std::fs::write(&probe, b"") {
            eprintln!(
                "error: {}: cannot write the report there ({e})",
                o.display()
            );
            return ExitCode::from(2);
        }
        let _ = std::fs::remove_file(&probe);
    }
    let reports = dustsph::stiffness::run(full, |r| {
        eprintln!(
            "{:<6} {} — {}: {} steps (explicit would need {:.0}), momentum drift {:.1e}",
            if r.passed() { "pass" } else { "FAIL" },
            r.group,
            r.name,
            r.steps,
            r.explicit_steps,
            r.momentum_drift
        );
        for f in &r.failures {
            eprintln!("       {f}");
        }
    });
    let failed = reports.iter().filter(|r| !r.passed()).count();
    if let Some(o) = &out {
        let command = format!(
            "dustsph stiffness{} --out {} --force",
            if full { " --full" } else { "" },
            o.display()
        );
        let md = dustsph::stiffness::markdown(&reports, full, &command);
        if let Err(e) = dustsph::io::write_bytes_atomic(o, md.as_bytes()) {
            eprintln!("error: {e}");
            return ExitCode::from(1);
        }
        println!("wrote {}", o.display());
    }
    println!("{} of {} cases pass", reports.len() - failed, reports.len());
    if failed > 0 {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    }
}

fn resume(a: ResumeArgs) -> ExitCode {
    let ResumeArgs {
        dir,
        checkpoint_every,
        quiet,
        device,
    } = a;
    let quiet = quiet || dustsph::dist::launched().is_some_and(|(r, _)| r != 0);
    if !quiet {
        eprintln!("dustsph: resuming {}", dir.display());
    }
    // Started as one of several MPI ranks: the rest of the run is split over them.
    #[cfg(feature = "mpi")]
    if let Some(world) = ranks_world() {
        let start = || world.and_then(|w| Run::resume_over_ranks(&dir, !quiet, device, w));
        return drive(start, checkpoint_every, None);
    }
    drive(|| Run::resume(&dir, !quiet, device), checkpoint_every, None)
}

fn parity(a: ParityArgs) -> ExitCode {
    let ParityArgs { device, precision } = a;
    // A device that is not there is bad input (exit 2), said once, before any case runs.
    if let Err(e) = dustsph::step::backend::select(device) {
        eprintln!("error: {e}");
        return ExitCode::from(2);
    }
    let mut all_ok = true;
    for (label, file, sets, steps) in dustsph::parity::CASES {
        let mut sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        sets.push(format!("numerics.precision=\"{}\"", precision.name()));
        let loaded = match dustsph::scene::load_shipped(file, &sets) {
            Ok(l) => l,
            Err(e) => {
                eprintln!("error: {e}");
                return ExitCode::from(2);
            }
        };
        match dustsph::parity::compare(&loaded, *steps, device) {
            Ok(p) => {
                let worst = p.fields.iter().filter(|f| !f.bitwise).count();
                println!(
                    "{label:<44} {steps:>3} steps on {}: {} of {} fields bit-identical, max relative difference {:.3e}",
                    p.device,
                    p.fields.len() - worst,
                    p.fields.len(),
                    p.max_relative()
                );
                for f in p.fields.iter().filter(|f| !f.bitwise) {
                    println!("    {:<28} {:.3e}", f.field, f.max_relative);
                }
                all_ok &= p.max_relative() <= 1e-10;
            }
            Err(e) => {
                eprintln!("error: {label}: {e}");
                return ExitCode::from(1);
            }
        }
    }
    if all_ok {
        ExitCode::SUCCESS
    } else {
        eprintln!("parity: some array differs by more than 1e-10 (relative)");
        ExitCode::from(1)
    }
}

fn gpu(a: GpuArgs) -> ExitCode {
    let GpuArgs { write_ptx, force } = a;
    if let Some(f) = &write_ptx {
        if f.exists() && !force {
            eprintln!(
                "error: {} exists: not replaced (--force replaces it)",
                f.display()
            );
            return ExitCode::from(2);
        }
    }
    use dustsph::launch;
    use std::io::Write as _;
    // A reader that closes the pipe early (`dustsph gpu | head -1`) is not an error.
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "kernels: {} ({} bytes of PTX, {} entry points)",
        launch::PTX_NOTE,
        launch::PTX.len(),
        launch::PTX.matches(".entry ").count()
    );
    let _ = match launch::probe() {
        Ok(name) => writeln!(out, "device: {name}"),
        Err(why) => writeln!(out, "device: none ({why})"),
    };
    if let Some(f) = write_ptx {
        if launch::PTX.is_empty() {
            eprintln!(
                "error: this binary has no PTX to write ({})",
                launch::PTX_NOTE
            );
            return ExitCode::from(1);
        }
        if let Err(e) = std::fs::write(&f, launch::PTX) {
            eprintln!("error: {}: {e}", f.display());
            return ExitCode::from(1);
        }
        let _ = writeln!(out, "wrote {}", f.display());
    }
    ExitCode::SUCCESS
}

fn scaling(a: ScalingArgs) -> ExitCode {
    use dustsph::commands::scaling;
    if !(a.particles.is_finite() && a.particles >= 1.0 && a.particles <= 2e9) {
        eprintln!("error: --particles must be in [1, 2e9]");
        return ExitCode::from(2);
    }
    if a.ranks.is_empty()
        || a.ranks.contains(&0)
        || !(a.gbps > 0.0 && a.rate > 0.0 && a.depth >= 1.0 && a.depth <= 64.0)
    {
        eprintln!("error: --ranks must be ≥ 1, --gbps and --rate > 0, --depth in [1, 64]");
        return ExitCode::from(2);
    }
    let bw = a.gbps * 1e9 / 8.0;
    for kind in ["ball", "slab"] {
        let t0 = std::time::Instant::now();
        let (n, rows) = scaling::model(kind, a.particles, &a.ranks, bw, a.depth);
        println!(
            "\n{kind}: {n} particles, h = 1.2 Δ, halo {} × 2h deep ({:.1} s); {} B per halo particle, \
             {} exchanges per step, {} µs per message; compute at {:.3e} particle-steps/s per rank",
            a.depth,
            t0.elapsed().as_secs_f64(),
            scaling::HALO_BYTES_F64,
            scaling::EXCHANGES,
            scaling::LATENCY_S * 1e6,
            a.rate
        );
        println!(
            "| ranks | particles/rank | imbalance | halo max | halo/owned | peers max | MB/step | comm ms | compute ms | comm/compute | break-even particle-steps/s |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|");
        for r in rows {
            let compute = r.per_rank * r.imbalance / a.rate;
            println!(
                "| {} | {:.3e} | {:.3} | {:.3e} | {:.3} | {} | {:.2} | {:.3} | {:.1} | {:.4} | {} |",
                r.ranks,
                r.per_rank,
                r.imbalance,
                r.halo_max as f64,
                r.halo_max as f64 / r.per_rank,
                r.peers_max,
                r.halo_max as f64 * scaling::HALO_BYTES_F64 / 1e6,
                r.comm_s * 1e3,
                compute * 1e3,
                r.comm_s / compute,
                if r.comm_s > 0.0 {
                    format!("{:.2e}", r.per_rank * r.imbalance / r.comm_s)
                } else {
                    "–".into()
                }
            );
        }
    }
    ExitCode::SUCCESS
}

#[cfg(not(feature = "mpi"))]
fn mpi_check(_: MpiCheckArgs) -> ExitCode {
    eprintln!(
        "error: this dustsph was built without MPI (cargo feature `mpi`; scripts/features turns \
         it on where OpenMPI is installed)"
    );
    ExitCode::from(2)
}

#[cfg(feature = "mpi")]
fn mpi_check(a: MpiCheckArgs) -> ExitCode {
    use dustsph::commands::mpi_check;
    if a.depth.is_some_and(|d| !(d.is_finite() && d >= 1.0)) {
        eprintln!("error: --depth must be a number ≥ 1 (kernel supports)");
        return ExitCode::from(2);
    }
    let loaded = match dustsph::scene::load(&a.scene, &a.set) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let world = match dustsph::dist::comm::World::init() {
        Ok(w) => w,
        Err(e) => {
            eprintln!("error: MPI: {e}");
            return ExitCode::from(2);
        }
    };
    let check_depth = a.depth.unwrap_or(1.0);
    match mpi_check::run(&world, &loaded.scene, check_depth, a.fail_rank) {
        Err(e) => {
            eprintln!("error: rank {}: {e}", world.rank());
            ExitCode::from(1)
        }
        Ok((reports, ok)) => {
            if world.rank() == 0 {
                println!(
                    "{}: {} ranks, halo depth {} kernel support(s)",
                    loaded.scene.scene.name,
                    reports.len(),
                    check_depth
                );
                println!("| rank | owned | halo | halo/owned | peers | MB sent | migrate ms | halo ms | gather ms | check |");
                println!("|---|---|---|---|---|---|---|---|---|---|");
                for r in &reports {
                    println!(
                        "| {} | {} | {} | {:.3} | {} | {:.3} | {:.2} | {:.2} | {:.2} | {} |",
                        r.rank,
                        r.owned,
                        r.halo,
                        r.halo as f64 / r.owned.max(1) as f64,
                        r.peers,
                        r.bytes_sent as f64 / 1e6,
                        r.migrate_s * 1e3,
                        r.halo_s * 1e3,
                        r.gather_s * 1e3,
                        if r.failure.is_empty() { "ok" } else { "FAILED" }
                    );
                }
                for r in reports.iter().filter(|r| !r.failure.is_empty()) {
                    eprintln!("error: rank {}: {}", r.rank, r.failure);
                }
            }
            if !ok {
                return ExitCode::from(1);
            }
            if a.steps == 0 {
                return ExitCode::SUCCESS;
            }
            let size = world.size();
            match mpi_check::step_over_ranks(world, &loaded.scene, a.depth, a.steps) {
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::from(1)
                }
                Ok(None) => ExitCode::SUCCESS,
                Ok(Some(r)) => {
                    println!(
                        "{} steps over {} ranks against one process, {} particles matched by id \
                         (max |difference| / field scale):",
                        r.steps, size, r.particles
                    );
                    let mut pass = true;
                    for (name, d) in &r.fields {
                        let ok = *d <= 1e-12;
                        pass &= ok;
                        println!(
                            "  {name:>4}: {d:.3e} {}",
                            if ok { "ok" } else { "ABOVE 1e-12" }
                        );
                    }
                    if pass {
                        ExitCode::SUCCESS
                    } else {
                        ExitCode::from(1)
                    }
                }
            }
        }
    }
}

/// MPI for a run started as one of several ranks (`None` otherwise). A rank that panics must
/// not finalise MPI while the others wait in a collective (that hangs the job): it prints and
/// leaves at once, and mpirun stops the others.
#[cfg(feature = "mpi")]
fn ranks_world() -> Option<Result<dustsph::dist::comm::World, RunError>> {
    if dustsph::dist::launched().is_none_or(|(_, n)| n <= 1) {
        return None;
    }
    let world =
        dustsph::dist::comm::World::init().map_err(|e| RunError::Input(format!("MPI: {e}")));
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        hook(info);
        std::process::exit(70);
    }));
    Some(world)
}
