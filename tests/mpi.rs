//! Issue 14 under a real MPI launcher (`mpirun --oversubscribe`, OpenMPI): the decomposition,
//! migration and halo exchange of `dustsph mpi-check` on 1–4 ranks, and the clean stop of every
//! rank when one fails. Built only with the `mpi` feature (scripts/features turns it on where
//! OpenMPI is installed).
#![cfg(feature = "mpi")]
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// `mpirun -n ranks dustsph mpi-check args…`: exit code and output; fails the test if it hangs.
fn mpi_check(ranks: u32, args: &[&str]) -> (Option<i32>, String) {
    let mut child = Command::new("mpirun")
        .args(["--allow-run-as-root", "--oversubscribe", "-n"])
        .arg(ranks.to_string())
        .arg(env!("CARGO_BIN_EXE_dustsph"))
        .arg("mpi-check")
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("mpirun (openmpi-bin; scripts/ensure-deps installs it)");
    let start = Instant::now();
    loop {
        if let Some(_status) = child.try_wait().unwrap() {
            break;
        }
        if start.elapsed() > Duration::from_secs(180) {
            child.kill().ok();
            panic!("mpirun -n {ranks} mpi-check {args:?} hung");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let o = child.wait_with_output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    (o.status.code(), text)
}

/// Every particle owned by exactly the rank owning its cell, counts as the partition says, and
/// every particle within the halo depth of an owned one present (brute force, minimum image):
/// on a periodic 3D slab, the open 3D ball (halo 1 and 2 supports deep), a 1D periodic wave and
/// the 1D shock tube with its walls, on 1 to 4 ranks.
#[test]
fn decomposition_and_halo_exchange_are_complete_on_1_to_4_ranks() {
    let cases: [&[&str]; 5] = [
        &["configs/dustywave_phantom.toml"],
        &["configs/dusty_ball.toml", "--set", "sph.n=12"],
        &[
            "configs/dusty_ball.toml",
            "--set",
            "sph.n=12",
            "--depth",
            "2",
        ],
        &["configs/dustywave.toml"],
        &["configs/dustyshock.toml"],
    ];
    for ranks in 1..=4 {
        for args in cases {
            let (code, text) = mpi_check(ranks, args);
            assert_eq!(code, Some(0), "-n {ranks} {args:?}:\n{text}");
            let rows = text.lines().filter(|l| l.ends_with("| ok |")).count();
            assert_eq!(rows, ranks as usize, "-n {ranks} {args:?}:\n{text}");
        }
    }
}

/// One rank failing stops every rank with that rank's message and a non-zero exit; none
/// waits forever.
#[test]
fn one_failing_rank_stops_every_rank_with_its_message() {
    let (code, text) = mpi_check(3, &["configs/dustywave_phantom.toml", "--fail-rank", "1"]);
    assert_ne!(code, Some(0), "{text}");
    assert!(
        text.contains("rank 1: failure requested by --fail-rank"),
        "{text}"
    );
}

/// The decomposition with physics: stepping over 1–4 ranks (each rank its owned particles with
/// a halo four supports deep, the step's chain of neighbour passes recomputed on it, and a
/// fixed shell one support beyond at its owners' values; the step size from the maxima over
/// all ranks) matches one process to 1e-12 of each field's scale (velocities: at least the
/// sound speed) for every particle matched by id — on the 3D box, the 1D wave, the Phantom slab
/// (leapfrog, variable h, IAD, CFL), the shock tube (walls, adiabatic, heating) and the open 3D
/// ball. Too thin a halo is caught: three supports for the leapfrog's longer chain, one for the
/// first-order wave.
#[test]
fn stepping_over_ranks_with_a_deep_halo_matches_one_process() {
    let cases: [&[&str]; 5] = [
        &["configs/dustybox.toml"],
        &["configs/dustywave.toml"],
        &["configs/dustywave_phantom.toml", "--set", "sph.n=32"],
        &["configs/dustyshock.toml"],
        &["configs/dusty_ball.toml", "--set", "sph.n=12"],
    ];
    for ranks in 1..=4 {
        for args in cases {
            let mut a = args.to_vec();
            a.extend(["--depth", "4", "--steps", "20"]);
            let (code, text) = mpi_check(ranks, &a);
            assert_eq!(code, Some(0), "-n {ranks} {a:?}:\n{text}");
            assert!(text.contains("against one process"), "{text}");
        }
    }
    for (depth, args) in [
        (
            "3",
            &["configs/dustywave_phantom.toml", "--set", "sph.n=32"][..],
        ),
        ("1", &["configs/dustywave.toml"][..]),
    ] {
        let mut a = args.to_vec();
        a.extend(["--depth", depth, "--steps", "20"]);
        let (code, text) = mpi_check(3, &a);
        assert_eq!(code, Some(1), "{a:?}: a halo too thin passed:\n{text}");
        assert!(text.contains("ABOVE 1e-12"), "{text}");
    }
}
