//! `dustsph` command line.
use clap::{Parser, Subcommand};
use dustsph::run::{run, RunError, RunOptions};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "dustsph",
    version,
    about = "Gas + polydisperse dust by SPH-IDIC"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run a scene: snapshots at the scene's output times and summary.json in the output directory.
    Run {
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
        /// No per-snapshot progress lines
        #[arg(long, short)]
        quiet: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Run {
            scene,
            set,
            out,
            force,
            quiet,
        } => {
            let loaded = match dustsph::scene::load(&scene, &set) {
                Ok(l) => l,
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::from(2);
                }
            };
            let out = out.unwrap_or_else(|| PathBuf::from("output").join(&loaded.scene.scene.name));
            let opts = RunOptions {
                out: out.clone(),
                force,
                verbose: !quiet,
            };
            if !quiet {
                eprintln!("dustsph: {} → {}", scene.display(), out.display());
            }
            match run(&loaded, &opts) {
                Ok((s, _)) => {
                    println!(
                        "{}: {} steps to t = {} in {:.2} s ({:.3e} particle-steps/s); summary: {}",
                        s.scene,
                        s.steps,
                        s.t_final,
                        s.wall_seconds,
                        s.particle_steps_per_second,
                        out.join("summary.json").display()
                    );
                    if let Some(last) = s.errors.iter().rev().find(|e| e.t == s.t_final) {
                        for f in &last.fields {
                            println!(
                                "  {:>8}: L1 {:.3e}  L2 {:.3e}  Linf {:.3e}",
                                f.field, f.norms.l1, f.norms.l2, f.norms.linf
                            );
                        }
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::from(match e {
                        RunError::Input(_) => 2,
                        _ => 1,
                    })
                }
            }
        }
    }
}
