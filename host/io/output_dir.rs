//! The output directory policy and atomic JSON output.

use std::fs;
use std::path::{Path, PathBuf};

use super::{write_bytes_atomic, IoError, WithPath, TMP_SUFFIX};

/// Name of the run summary written next to the snapshots.
pub const SUMMARY_NAME: &str = "summary.json";

/// snapshot_NNNN.h5 name (4 digits, more if needed).
pub fn snapshot_name(index: usize) -> String {
    format!("snapshot_{index:04}.h5")
}

/// True for exactly the names [`snapshot_name`] produces, so "snapshot_7.h5" or
/// "snapshot_00012.h5" (never ours) are left alone.
pub fn is_snapshot_name(name: &str) -> bool {
    name.strip_prefix("snapshot_")
        .and_then(|s| s.strip_suffix(".h5"))
        .filter(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
        .and_then(|d| d.parse::<usize>().ok())
        .is_some_and(|i| snapshot_name(i) == name)
}

/// True for a file this program writes: a snapshot, the summary, or the temporary of either.
fn is_ours(name: &str) -> bool {
    let final_name = name
        .strip_prefix('.')
        .and_then(|s| s.strip_suffix(TMP_SUFFIX))
        .unwrap_or(name);
    if final_name == SUMMARY_NAME
        || final_name == super::xdmf::SERIES_NAME
        || final_name == crate::sim::evolution::EVOLUTION_NAME
        || final_name == super::checkpoint::CHECKPOINT_NAME
        || is_snapshot_name(final_name)
    {
        return true;
    }
    // Sidecars and post-processing of a snapshot: snapshot_NNNN.xmf, snapshot_NNNN_<what>.
    let derived = [
        ".xmf",
        "_profile.csv",
        "_profiles.png",
        "_speed_tstop.png",
        "_xy.png",
    ];
    derived.iter().any(|suffix| {
        final_name
            .strip_suffix(suffix)
            .is_some_and(|stem| is_snapshot_name(&format!("{stem}.h5")))
    })
}

/// Prepare an output directory: create it if missing; if it exists and is non-empty, refuse with
/// an error naming the directory unless `force` is true. With force, do NOT delete unrelated user
/// files: only remove files that this program writes (snapshot_*.h5, summary.json, *.tmp left by
/// us) and keep everything else. Returns the canonical path.
pub fn prepare_output_dir(dir: &Path, force: bool) -> Result<PathBuf, IoError> {
    // A file that only carries a snapshot's name (not a snapshot dustsph wrote) is the user's:
    // refuse rather than remove it.
    if force {
        if let Ok(entries) = fs::read_dir(dir) {
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                let path = e.path();
                if is_snapshot_name(&name)
                    && path.is_file()
                    && super::snapshot::read_header(&path).is_err()
                {
                    return Err(IoError::invalid(
                        &path,
                        "has a snapshot's name but is not a dustsph snapshot: not removed by \
                         --force (move it away, or choose another --out)",
                    ));
                }
            }
        }
    }
    prepare_dir(dir, force, is_ours)
}

/// True for `name` or the temporary [`write_bytes_atomic`](super::write_bytes_atomic) writes
/// it under (`.name.tmp`), when `owned(name)`.
pub fn owned_or_temporary(name: &str, owned: impl Fn(&str) -> bool) -> bool {
    let final_name = name
        .strip_prefix('.')
        .and_then(|s| s.strip_suffix(TMP_SUFFIX))
        .unwrap_or(name);
    owned(final_name)
}

/// [`prepare_output_dir`] with another notion of which files are ours (`is_ours(file name)`):
/// `dustsph study` uses it for its own outputs.
pub fn prepare_dir(
    dir: &Path,
    force: bool,
    is_ours: impl Fn(&str) -> bool,
) -> Result<PathBuf, IoError> {
    match fs::metadata(dir) {
        Ok(meta) if !meta.is_dir() => {
            return Err(IoError::invalid(
                dir,
                "output path exists but is not a directory",
            ));
        }
        Ok(_) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            fs::create_dir_all(dir).with_path(dir)?;
        }
        Err(e) => return Err(IoError::io(dir, e)),
    }
    let canonical = fs::canonicalize(dir).with_path(dir)?;

    let mut entries = Vec::new();
    for entry in fs::read_dir(&canonical).with_path(&canonical)? {
        entries.push(entry.with_path(&canonical)?);
    }
    if entries.is_empty() {
        return Ok(canonical);
    }
    if !force {
        let mut names: Vec<String> = entries
            .iter()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        return Err(IoError::DirNotEmpty {
            path: canonical,
            example: names.swap_remove(0),
        });
    }
    for entry in entries {
        let name = entry.file_name();
        // Only regular files: a directory or link that merely carries one of our names is the
        // user's, not ours.
        let is_file = entry.file_type().with_path(&entry.path())?.is_file();
        if is_file && name.to_str().is_some_and(&is_ours) {
            fs::remove_file(entry.path()).with_path(&entry.path())?;
        }
    }
    Ok(canonical)
}

/// Write any serde-serialisable value as pretty JSON atomically (tmp + rename).
pub fn write_json_atomic<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), IoError> {
    // Serialise first: a value that cannot be serialised never touches the disk.
    let mut text = serde_json::to_string_pretty(value).with_path(path)?;
    text.push('\n');
    write_bytes_atomic(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::{Deserialize, Serialize};
    use std::collections::BTreeMap;

    fn names_in(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn snapshot_names_have_at_least_four_digits() {
        assert_eq!(snapshot_name(0), "snapshot_0000.h5");
        assert_eq!(snapshot_name(3), "snapshot_0003.h5");
        assert_eq!(snapshot_name(9999), "snapshot_9999.h5");
        assert_eq!(snapshot_name(12345), "snapshot_12345.h5");
    }

    #[test]
    fn only_our_names_are_recognised() {
        for ours in [
            "snapshot_0000.h5",
            "snapshot_12345.h5",
            "summary.json",
            ".snapshot_0042.h5.tmp",
            ".summary.json.tmp",
        ] {
            assert!(is_ours(ours), "{ours}");
        }
        for theirs in [
            "snapshot_7.h5",
            "snapshot_00012.h5",
            "snapshot_abcd.h5",
            "snapshot_0001.h5.bak",
            "my_snapshot_0001.h5",
            "summary.json.bak",
            "notes.tmp",
            ".notes.tmp",
            "snapshot_0001.h5.tmp",
            ".snapshot_.h5.tmp",
            "snapshot_+001.h5",
        ] {
            assert!(!is_ours(theirs), "{theirs}");
        }
    }

    #[test]
    fn creates_a_missing_directory_and_returns_its_canonical_path() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("a").join("b");
        let got = prepare_output_dir(&dir, false).unwrap();
        assert!(dir.is_dir());
        assert_eq!(got, fs::canonicalize(&dir).unwrap());
        assert!(got.is_absolute());
        // An existing empty directory is fine without force, also through a "..".
        let indirect = dir.join("..").join("b");
        assert_eq!(prepare_output_dir(&indirect, false).unwrap(), got);
    }

    #[test]
    fn refuses_a_non_empty_directory_without_force_and_touches_nothing() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("out");
        fs::create_dir(&dir).unwrap();
        fs::write(dir.join("snapshot_0000.h5"), b"old").unwrap();
        fs::write(dir.join(".hidden"), b"x").unwrap();
        let err = prepare_output_dir(&dir, false).unwrap_err();
        let msg = err.to_string();
        let canon = fs::canonicalize(&dir).unwrap();
        assert!(msg.contains(&*canon.to_string_lossy()), "{msg}");
        assert!(matches!(err, IoError::DirNotEmpty { .. }));
        assert_eq!(names_in(&dir), vec![".hidden", "snapshot_0000.h5"]);
    }

    #[test]
    fn force_removes_only_our_files() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("out");
        fs::create_dir(&dir).unwrap();
        let ours = [
            "snapshot_0000.h5",
            "snapshot_0001.h5",
            "snapshot_12345.h5",
            "summary.json",
            ".snapshot_0002.h5.tmp",
            ".summary.json.tmp",
        ];
        let theirs = [
            "notes.txt",
            "scene.toml",
            "snapshot_7.h5",
            "snapshot_0001.h5.bak",
            "my_snapshot_0001.h5",
            ".notes.tmp",
        ];
        for n in ours.iter().chain(&theirs) {
            fs::write(dir.join(n), n.as_bytes()).unwrap();
        }
        // Directories are never removed, even under our names, nor is what is inside them.
        fs::create_dir(dir.join("snapshot_0003.h5")).unwrap();
        fs::create_dir(dir.join("sub")).unwrap();
        fs::write(dir.join("sub").join("snapshot_0004.h5"), b"keep").unwrap();

        // (By name: these stand-ins are not HDF5; `prepare_output_dir` would refuse them, below.)
        prepare_dir(&dir, true, is_ours).unwrap();
        let mut want: Vec<&str> = theirs.to_vec();
        want.extend(["snapshot_0003.h5", "sub"]);
        want.sort();
        assert_eq!(names_in(&dir), want);
        assert_eq!(fs::read(dir.join("notes.txt")).unwrap(), b"notes.txt");
        assert!(dir.join("sub").join("snapshot_0004.h5").is_file());
    }

    /// A file named like a snapshot that is not one (no dustsph snapshot header) is the
    /// user's: --force stops, naming it, and removes nothing.
    #[test]
    fn force_refuses_a_file_that_only_has_a_snapshots_name() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("out");
        fs::create_dir(&dir).unwrap();
        fs::write(dir.join("snapshot_9999.h5"), b"my notes").unwrap();
        fs::write(dir.join("summary.json"), b"{}").unwrap();
        let err = prepare_output_dir(&dir, true).unwrap_err().to_string();
        assert!(
            err.contains("snapshot_9999.h5") && err.contains("not a dustsph snapshot"),
            "{err}"
        );
        assert_eq!(fs::read(dir.join("snapshot_9999.h5")).unwrap(), b"my notes");
        assert!(
            dir.join("summary.json").exists(),
            "removed something before refusing"
        );
    }

    #[test]
    fn a_file_in_place_of_the_directory_is_an_error_naming_it() {
        let root = tempfile::tempdir().unwrap();
        let path = root.path().join("out");
        fs::write(&path, b"x").unwrap();
        for force in [false, true] {
            let err = prepare_output_dir(&path, force).unwrap_err();
            assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
        }
        assert_eq!(fs::read(&path).unwrap(), b"x");
    }

    #[derive(Serialize, Deserialize, Debug, PartialEq)]
    struct Summary {
        steps: u64,
        wall_s: f64,
        label: String,
    }

    #[test]
    fn json_is_written_atomically_and_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(SUMMARY_NAME);
        let a = Summary {
            steps: 10,
            wall_s: 0.1,
            label: "première".into(),
        };
        write_json_atomic(&path, &a).unwrap();
        let text = fs::read_to_string(&path).unwrap();
        assert!(text.contains("\n  \"steps\": 10"), "not pretty: {text}");
        assert!(text.ends_with('\n'));
        assert_eq!(serde_json::from_str::<Summary>(&text).unwrap(), a);

        // Overwrite, with a stale temporary in the way.
        fs::write(dir.path().join(".summary.json.tmp"), b"{").unwrap();
        let b = Summary { steps: 20, ..a };
        write_json_atomic(&path, &b).unwrap();
        let got: Summary = serde_json::from_str(&fs::read_to_string(&path).unwrap()).unwrap();
        assert_eq!(got, b);
        assert_eq!(names_in(dir.path()), vec![SUMMARY_NAME]);
    }

    #[test]
    fn json_into_a_missing_directory_fails_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("gone");
        let err = write_json_atomic(&missing.join("summary.json"), &1u8).unwrap_err();
        assert!(
            err.to_string().contains(&*missing.to_string_lossy()),
            "{err}"
        );
        assert!(names_in(dir.path()).is_empty());
    }

    #[test]
    fn unserialisable_value_fails_without_touching_the_disk() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("summary.json");
        fs::write(&path, b"{\"old\": true}\n").unwrap();
        // JSON object keys must be strings; a vector key cannot be serialised.
        let bad: BTreeMap<Vec<u8>, u8> = [(vec![1u8], 1u8)].into_iter().collect();
        let err = write_json_atomic(&path, &bad).unwrap_err();
        assert!(matches!(err, IoError::Json { .. }), "{err:?}");
        assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
        assert_eq!(fs::read(&path).unwrap(), b"{\"old\": true}\n");
        assert_eq!(names_in(dir.path()), vec!["summary.json"]);
    }
}
