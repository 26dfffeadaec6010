//! `dustsph mpi-check SCENE`, under `mpirun -n R` (a build with the mpi feature): the
//! decomposition and halo exchange of a scene's particles over the ranks, checked on every rank
//! ([`exchange`]); with `--steps N`, N steps over the ranks against one process.
pub mod exchange;

use crate::dist::Comm;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct MpiCheckArgs {
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

pub fn execute(a: MpiCheckArgs) -> u8 {
    // The command line: a build without MPI has no ranks to check.
    if !cfg!(feature = "mpi") {
        eprintln!(
            "error: this dustsph was built without MPI (cargo feature `mpi`; scripts/features \
             turns it on where OpenMPI is installed)"
        );
        return 2;
    }
    use self::exchange as mpi_check;
    if a.depth.is_some_and(|d| !(d.is_finite() && d >= 1.0)) {
        eprintln!("error: --depth must be a number ≥ 1 (kernel supports)");
        return 2;
    }
    let loaded = match crate::scene::load(&a.scene, &a.set) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("error: {e}");
            return 2;
        }
    };
    let world = match crate::dist::comm::World::init() {
        Ok(w) => w,
        Err(e) => {
            eprintln!("error: MPI: {e}");
            return 2;
        }
    };
    let check_depth = a.depth.unwrap_or(1.0);
    match mpi_check::run(&world, &loaded.scene, check_depth, a.fail_rank) {
        Err(e) => {
            eprintln!("error: rank {}: {e}", world.rank());
            1
        }
        Ok((reports, ok)) => {
            if world.rank() == 0 {
                println!(
                    "{}: {} ranks, halo depth {} kernel support(s)",
                    loaded.scene.name,
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
                return 1;
            }
            if a.steps == 0 {
                return 0;
            }
            let size = world.size();
            match mpi_check::step_over_ranks(world, &loaded.scene, a.depth, a.steps) {
                Err(e) => {
                    eprintln!("error: {e}");
                    1
                }
                Ok(None) => 0,
                Ok(Some(r)) => {
                    println!(
                        "{} steps over {} ranks against one process, {} particles matched by id \
                         (max |difference| / field scale):",
                        r.steps, size, r.particles
                    );
                    println!("  stepped: {}", r.stepping);
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
                        0
                    } else {
                        1
                    }
                }
            }
        }
    }
}
