//! Output: GADGET/GIZMO-style HDF5 snapshots, atomic JSON files and the output directory policy.
//!
//! Every file is written under a temporary name in its final directory and renamed into place, so
//! a crash never leaves a half-written file under a name a reader would pick up. Every error names
//! the file or directory it concerns.

pub mod checkpoint;
pub mod chunks;
pub(crate) mod h5;
pub mod ics;
pub mod output_dir;
pub mod sha256;
pub(crate) mod shared;
pub mod snapshot;
pub mod xdmf;

use std::fmt;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

pub use output_dir::{
    owned_or_temporary, prepare_dir, prepare_output_dir, snapshot_name, write_json_atomic,
};
pub use snapshot::{
    read_snapshot, write_snapshot, write_snapshot_shared, PhaseData, PhaseView, SceneSource,
    SnapshotData, SnapshotView,
};
pub use xdmf::{write_xdmf, write_xdmf_series, write_xdmf_view, write_xdmf_view_rows};

/// An output error; the message always names the offending file or directory.
#[derive(Debug)]
pub enum IoError {
    /// An operating-system error.
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// An HDF5 library error; `object` is the object inside the file (empty for the file itself).
    Hdf5 {
        path: PathBuf,
        object: String,
        source: hdf5::Error,
    },
    /// A JSON serialisation error.
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    /// The output directory holds files and overwriting was not requested.
    DirNotEmpty { path: PathBuf, example: String },
    /// Inconsistent input data or an unexpected file layout.
    Invalid { path: PathBuf, reason: String },
}

impl IoError {
    /// The file or directory the error concerns.
    pub fn path(&self) -> &Path {
        match self {
            IoError::Io { path, .. }
            | IoError::Hdf5 { path, .. }
            | IoError::Json { path, .. }
            | IoError::DirNotEmpty { path, .. }
            | IoError::Invalid { path, .. } => path,
        }
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        IoError::Io {
            path: path.into(),
            source,
        }
    }

    pub fn hdf5(path: impl Into<PathBuf>, object: impl Into<String>, source: hdf5::Error) -> Self {
        IoError::Hdf5 {
            path: path.into(),
            object: object.into(),
            source,
        }
    }

    pub fn invalid(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        IoError::Invalid {
            path: path.into(),
            reason: reason.into(),
        }
    }
}

impl fmt::Display for IoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            IoError::Io { path, source } => write!(f, "{}: {source}", path.display()),
            IoError::Hdf5 {
                path,
                object,
                source,
            } => {
                if object.is_empty() {
                    write!(f, "{}: HDF5 error: {source}", path.display())
                } else {
                    write!(f, "{}: HDF5 error at {object}: {source}", path.display())
                }
            }
            IoError::Json { path, source } => {
                write!(f, "{}: JSON serialisation failed: {source}", path.display())
            }
            IoError::DirNotEmpty { path, example } => write!(
                f,
                "output directory {} is not empty (it holds '{example}'); \
                 refusing to overwrite without force",
                path.display()
            ),
            IoError::Invalid { path, reason } => write!(f, "{}: {reason}", path.display()),
        }
    }
}

impl std::error::Error for IoError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            IoError::Io { source, .. } => Some(source),
            IoError::Hdf5 { source, .. } => Some(source),
            IoError::Json { source, .. } => Some(source),
            IoError::DirNotEmpty { .. } | IoError::Invalid { .. } => None,
        }
    }
}

/// Attaches a path to a foreign error, turning it into an [`IoError`].
pub trait WithPath<T> {
    fn with_path(self, path: &Path) -> Result<T, IoError>;
}

impl<T> WithPath<T> for Result<T, std::io::Error> {
    fn with_path(self, path: &Path) -> Result<T, IoError> {
        self.map_err(|e| IoError::io(path, e))
    }
}

impl<T> WithPath<T> for Result<T, hdf5::Error> {
    fn with_path(self, path: &Path) -> Result<T, IoError> {
        self.map_err(|e| IoError::hdf5(path, "", e))
    }
}

impl<T> WithPath<T> for Result<T, serde_json::Error> {
    fn with_path(self, path: &Path) -> Result<T, IoError> {
        self.map_err(|source| IoError::Json {
            path: path.to_path_buf(),
            source,
        })
    }
}

/// Suffix of the temporary names used while a file is written.
pub(crate) const TMP_SUFFIX: &str = ".tmp";

/// The directory holding `path` ("." for a bare file name).
pub(crate) fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// The temporary name for `path`: hidden, same directory, so the final rename stays atomic.
pub(crate) fn tmp_path(path: &Path) -> Result<PathBuf, IoError> {
    let name = path
        .file_name()
        .ok_or_else(|| IoError::invalid(path, "not a file path (no file name)"))?;
    let mut tmp = std::ffi::OsString::from(".");
    tmp.push(name);
    tmp.push(TMP_SUFFIX);
    Ok(parent_dir(path).join(tmp))
}

/// Fails, naming the directory, unless the directory that will hold `path` exists.
pub(crate) fn require_parent_dir(path: &Path) -> Result<(), IoError> {
    let dir = parent_dir(path);
    let meta = fs::metadata(dir).with_path(dir)?;
    if meta.is_dir() {
        Ok(())
    } else {
        Err(IoError::invalid(dir, "not a directory"))
    }
}

/// Removes a leftover temporary file; a missing one is fine.
pub(crate) fn remove_stale(tmp: &Path) -> Result<(), IoError> {
    match fs::remove_file(tmp) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(IoError::io(tmp, e)),
        _ => Ok(()),
    }
}

/// Makes the finished temporary file durable, then renames it to `path`.
pub(crate) fn commit_tmp(tmp: &Path, path: &Path) -> Result<(), IoError> {
    // fsync before rename: otherwise a crash can leave the final name pointing at empty data.
    fs::File::open(tmp)
        .and_then(|f| f.sync_all())
        .with_path(tmp)?;
    fs::rename(tmp, path).with_path(path)?;
    // Persist the rename itself; not every filesystem supports syncing a directory.
    if let Ok(d) = fs::File::open(parent_dir(path)) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Writes `bytes` to `path` atomically: a temporary in the same directory, fsync, rename. On
/// failure the temporary is removed and nothing carries the final name.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    require_parent_dir(path)?;
    let tmp = tmp_path(path)?;
    remove_stale(&tmp)?;
    // create_new: never write through something that appeared under the temporary name.
    let result = fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)
        .and_then(|mut f| f.write_all(bytes))
        .with_path(&tmp)
        .and_then(|()| commit_tmp(&tmp, path));
    if result.is_err() {
        // Best effort: the original error matters more than a failed cleanup.
        let _ = fs::remove_file(&tmp);
    }
    result
}
