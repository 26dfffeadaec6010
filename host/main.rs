//! The `dustsph` command line: the arguments parsed here, each subcommand carried out by its
//! module of `dustsph::commands` (which returns the exit code; README, "Exit codes").
use clap::{Parser, Subcommand};
use dustsph::commands::{bench, gpu, mpi_check, parity, profile, run, scaling, stiffness, study};
use std::process::ExitCode;

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
    Run(run::RunArgs),
    /// The GPU path: how its kernels were built, whether a device is usable; optionally write
    /// the embedded PTX (for `ptxas`).
    Gpu(gpu::GpuArgs),
    /// Run each scene kind for a few steps on a one-thread CPU reference and on a device, and
    /// compare every array after every step (bit for bit expected).
    Parity(parity::ParityArgs),
    /// CPU speed: a uniform 3D box at ≈60 neighbours and the 3D ball, on 1 and 2 threads.
    Bench(bench::BenchArgs),
    /// Radial profiles (CSV) and figures (PNG) of a snapshot, written next to it; for the ball
    /// also the errors against the 1D reference and the spherical-symmetry check.
    Profile(profile::ProfileArgs),
    /// Run a study (configs/studies/*.toml): a scene over a grid of parameters, in this process;
    /// writes results.csv, results.md and error-against-run-time plots (PNG).
    Study(study::StudyArgs),
    /// The stiffness and extremes matrix (IDIC): every case must stay finite, conserve momentum
    /// to 1e-12, keep densities positive and match the exact wave/box solutions. Prints a line
    /// per case; exit code 1 if any fails.
    Stiffness(stiffness::StiffnessArgs),
    /// Continue an interrupted run from DIR/checkpoint.h5, bit for bit.
    Resume(run::ResumeArgs),
    /// The multi-rank model (docs/scaling.md): the Morton decomposition of a ball and a slab of
    /// N particles over R ranks, its halo and what exchanging it costs; no physics, no MPI.
    Scaling(scaling::ScalingArgs),
    /// Under `mpirun -n R` (a build with the mpi feature): the decomposition, migration and
    /// halo exchange of a scene's particles over the ranks, checked on every rank (no physics;
    /// exit 1 on every rank if any rank's check fails).
    MpiCheck(mpi_check::MpiCheckArgs),
}

fn main() -> ExitCode {
    // Rust ignores SIGPIPE, so a print to a closed pipe (`dustsph run … | head`) panics (exit
    // 101, which says "a bug"); with the default a reader that stops ends the process quietly,
    // as for any Unix tool. Progress, warnings and errors go to stderr; the outputs are files.
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to its default before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
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
    ExitCode::from(match cmd {
        Cmd::MpiCheck(a) => mpi_check::execute(a),
        Cmd::Run(a) => run::execute(a),
        Cmd::Bench(a) => bench::execute(a),
        Cmd::Profile(a) => profile::execute(a),
        Cmd::Study(a) => study::execute(a),
        Cmd::Stiffness(a) => stiffness::execute(a),
        Cmd::Resume(a) => run::execute_resume(a),
        Cmd::Scaling(a) => scaling::execute(a),
        Cmd::Parity(a) => parity::execute(a),
        Cmd::Gpu(a) => gpu::execute(a),
    })
}
