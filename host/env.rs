//! Every `DUSTSPH_*` environment variable the binary reads, in one table, each with why it is
//! not a scene key: none changes a value a run computes or writes (those are scene keys, in
//! the effective scene of every output). The debug checks and test hooks are compiled only
//! with the cargo feature `checks` (scripts/test turns it on).

/// What a variable is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// How fast, or in what pieces, the same values are computed or written.
    Tuning,
    /// Where a cache lives.
    Location,
    /// A debug check or trace (feature `checks`).
    Check,
    /// A failure a test asks for (feature `checks`).
    TestHook,
}

/// One environment variable the binary reads.
#[derive(Debug, Clone, Copy)]
pub struct Var {
    pub name: &'static str,
    pub role: Role,
    /// What it sets, and why that is not a scene key.
    pub why: &'static str,
}

/// The table: every `DUSTSPH_*` read at run time, and only those (a test checks the sources).
pub const VARS: &[Var] = &[
    Var {
        name: "DUSTSPH_PTX_MAXNREG",
        role: Role::Tuning,
        why: "the GPU kernels' register cap (16-255, or off): occupancy against spills, the \
              same arithmetic (host/launch/cuda.rs register_cap); a machine's choice, not a \
              scene's",
    },
    Var {
        name: "DUSTSPH_CHUNK_ROWS",
        role: Tuning,
        why: "rows per compressed chunk of a snapshot: the file's storage layout, the same \
              values (tests/mpi.rs writes small runs in many chunks so that every rank \
              deflates some)",
    },
    Var {
        name: "DUSTSPH_STREAM_RECORDS",
        role: Tuning,
        why: "records per message of a rank's stream to rank 0 at an output: message sizes, \
              the same values (tests/mpi.rs streams small runs in many messages)",
    },
    Var {
        name: "DUSTSPH_ROW_BLOCK",
        role: Tuning,
        why: "rows per block of a shared read of an initial-conditions file: which rank reads \
              which rows (tests/mpi.rs shares small files between every rank)",
    },
    Var {
        name: "DUSTSPH_CACHE",
        role: Role::Location,
        why: "where relaxed glasses are cached (else $XDG_CACHE_HOME/dustsph, else \
              ~/.cache/dustsph); a cached glass is the glass the run would relax",
    },
    Var {
        name: "DUSTSPH_HALO_CHECK",
        role: Role::Check,
        why: "after every halo refresh a full one, stopping the step where a ghost value \
              changes (a field written and not refreshed; tests/mpi.rs); doubles the traffic",
    },
    Var {
        name: "DUSTSPH_HALO_TRACE",
        role: Role::Check,
        why: "rank 0 prints each halo built, each retake and each balance judgement",
    },
    Var {
        name: "DUSTSPH_FAIL_IN_STEP",
        role: Role::TestHook,
        why: "rank:step fails that rank's ghost refresh in that step (tests/mpi.rs: a failure \
              inside a step stops every rank with its message, and does not hang)",
    },
];

use Role::Tuning;

/// The value of table variable `name` (`None` where unset). Panics on a name not in
/// [`VARS`]: every read goes through the table.
pub fn var(name: &str) -> Option<String> {
    let v = VARS.iter().find(|v| v.name == name);
    let v = v.unwrap_or_else(|| panic!("{name} is not in the table of host/env.rs"));
    debug_assert!(
        cfg!(feature = "checks") || !matches!(v.role, Role::Check | Role::TestHook),
        "{name} is read only with the feature `checks`"
    );
    std::env::var(name).ok()
}

/// A positive count from table variable `name`, otherwise `default`.
pub fn count(name: &str, default: usize) -> usize {
    (var(name))
        .and_then(|v| v.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(default)
}

/// Whether debug check `name` is on: set, in a build with the feature `checks` (always off
/// without it).
pub fn check(name: &str) -> bool {
    cfg!(feature = "checks") && var(name).is_some()
}

#[cfg(test)]
mod tests {
    use super::VARS;

    /// Every `DUSTSPH_*` the host's sources read at run time goes through the table, and
    /// every variable of the table is read somewhere: scans host/ (test modules aside) for
    /// `std::env::var` / `var_os` of a `"DUSTSPH_` literal, and for each table name.
    #[test]
    fn every_environment_variable_read_is_in_the_table() {
        fn walk(dir: &std::path::Path, out: &mut Vec<(String, String)>) {
            for e in std::fs::read_dir(dir).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    walk(&p, out);
                } else if p.extension().is_some_and(|x| x == "rs") {
                    out.push((
                        p.display().to_string(),
                        std::fs::read_to_string(&p).unwrap(),
                    ));
                }
            }
        }
        let mut files = Vec::new();
        walk(std::path::Path::new("host"), &mut files);
        for (path, text) in &files {
            // Test modules are not in the release binary.
            if path.ends_with("env.rs") || path.ends_with("tests.rs") {
                continue;
            }
            for pat in ["std::env::var(\"DUSTSPH_", "std::env::var_os(\"DUSTSPH_"] {
                assert!(
                    !text.contains(pat),
                    "{path} reads a DUSTSPH_ variable outside host/env.rs's table"
                );
            }
        }
        for v in VARS {
            let quoted = format!("\"{}\"", v.name);
            assert!(
                files
                    .iter()
                    .any(|(p, t)| !p.ends_with("env.rs") && t.contains(&quoted)),
                "{} is in the table but read nowhere",
                v.name
            );
        }
    }
}
