//! Errors at the boundary of `ctadsa-core`: every variant names the file (or the item) and the
//! problem, so a user can fix the input.

use std::path::{Path, PathBuf};

/// An error of the core library.
#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// Reading or writing a file failed at the OS level. The message carries the OS's reason
    /// (`error` is not also the error's `source()`, so that a chain of causes says it once).
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: std::io::Error },
    /// A file was read but its content is not what it should be.
    #[error("{path}: {problem}")]
    Format { path: PathBuf, problem: String },
    /// An argument, setting or piece of data is out of range or inconsistent.
    #[error("{0}")]
    Invalid(String),
    /// The renderer rejected its input.
    #[error(transparent)]
    Render(#[from] ctadsa_render::RenderError),
    /// An op (`ctadsa_ops`) rejected its input or state.
    #[error(transparent)]
    Ops(#[from] ctadsa_ops::error::OpsError),
}

impl CoreError {
    /// An I/O error on `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), error: source }
    }

    /// A content error in `path`.
    pub fn format(path: &Path, problem: impl Into<String>) -> Self {
        Self::Format { path: path.to_path_buf(), problem: problem.into() }
    }

    /// An invalid argument or state.
    pub fn invalid(problem: impl Into<String>) -> Self {
        Self::Invalid(problem.into())
    }
}

/// Result with [`CoreError`].
pub type Result<T, E = CoreError> = std::result::Result<T, E>;

/// The largest input file read whole (bytes): far above any case's inputs (a 1024² DSA run of
/// 300 frames in 16 bits is 630 MB), far below what would exhaust a workstation.
pub const MAX_INPUT_BYTES: u64 = 2 << 30;

/// Reads a whole file, naming it on failure. Only a regular file (or a link to one) of at most
/// [`MAX_INPUT_BYTES`] is read: a device (`/dev/zero`), a FIFO or a folder is refused before it
/// is opened, so that a reference to one can neither hang the run nor exhaust memory.
pub fn read_file(path: &Path) -> Result<Vec<u8>> {
    use std::io::Read as _;
    let len = check_input_file(path)?;
    let file = std::fs::File::open(path).map_err(|e| CoreError::io(path, e))?;
    let mut bytes = Vec::with_capacity(len as usize);
    // `take`: a file that grows while it is read stops at the limit too.
    file.take(MAX_INPUT_BYTES + 1).read_to_end(&mut bytes).map_err(|e| CoreError::io(path, e))?;
    if bytes.len() as u64 > MAX_INPUT_BYTES {
        return Err(CoreError::format(path, format!("grew past the {MAX_INPUT_BYTES} bytes an input may have")));
    }
    Ok(bytes)
}

/// The size of the input file `path` (bytes) after checking that it is a regular file (or a link
/// to one) of at most [`MAX_INPUT_BYTES`]; for readers that open files themselves.
pub fn check_input_file(path: &Path) -> Result<u64> {
    let meta = std::fs::metadata(path).map_err(|e| CoreError::io(path, e))?;
    if !meta.is_file() {
        return Err(CoreError::format(
            path,
            "not a regular file (a folder, device, FIFO or socket); refusing to read it",
        ));
    }
    if meta.len() > MAX_INPUT_BYTES {
        return Err(CoreError::format(
            path,
            format!("{} bytes, more than the {} bytes an input may have", meta.len(), MAX_INPUT_BYTES),
        ));
    }
    Ok(meta.len())
}

/// Writes a whole file atomically (creating parent folders), naming it on failure: the bytes go
/// to a temporary file beside it, which is then renamed over `path`, so a reader (or a run killed
/// meanwhile) sees the old file or the new one, never half of one.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let name = path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
    write_through_temporary(path, &name, |tmp| std::fs::write(tmp, bytes).map_err(|e| CoreError::io(path, e)))
}

/// Makes `path` atomically (creating parent folders): `write` fills a temporary file beside it,
/// which is then renamed over `path` (on failure the temporary is removed). Each call has a
/// temporary of its own, created exclusively, named from the process, a per-process count and
/// the clock, then `.` and `suffix` (for writers that choose a format by the name's ending), so
/// writers of one path in two threads, or in two processes of the same id on two nodes of a
/// shared file system, never write into each other's; the last rename wins.
pub(crate) fn write_through_temporary(
    path: &Path,
    suffix: &str,
    write: impl FnOnce(&Path) -> Result<()>,
) -> Result<()> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static WRITES: AtomicU64 = AtomicU64::new(0);
    if let Some(parent) = path.parent()
        && !parent.as_os_str().is_empty()
    {
        std::fs::create_dir_all(parent).map_err(|e| CoreError::io(parent, e))?;
    }
    let tmp = loop {
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
        let count = WRITES.fetch_add(1, Ordering::Relaxed);
        let tmp = path.with_file_name(format!(".tmp-{}-{count}-{nanos}.{suffix}", std::process::id()));
        match std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(_) => break tmp,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(CoreError::io(path, e)),
        }
    };
    let written = write(&tmp).and_then(|()| std::fs::rename(&tmp, path).map_err(|e| CoreError::io(path, e)));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

/// Removes a file or a whole folder if it is there, naming it on failure.
pub fn remove_path(path: &Path) -> Result<()> {
    let removed = if path.is_dir() {
        std::fs::remove_dir_all(path)
    } else if path.exists() {
        std::fs::remove_file(path)
    } else {
        Ok(())
    };
    removed.map_err(|e| CoreError::io(path, e))
}

/// `value` as pretty JSON, or an error naming `path` (never an empty file).
pub fn to_json(value: &impl serde::Serialize, path: &Path) -> Result<String> {
    serde_json::to_string_pretty(value).map_err(|e| CoreError::format(path, format!("cannot encode JSON: {e}")))
}

/// Checks that `name` (the `what` of something, e.g. "view name") can be used as one file or
/// folder name inside an output folder: not empty, no path separator, not `.` or `..`, no
/// control character, at most 128 bytes.
pub fn check_file_name(name: &str, what: &str) -> std::result::Result<(), String> {
    let bad = name.is_empty()
        || name.len() > 128
        || name == "."
        || name == ".."
        || name.chars().any(|c| c == '/' || c == '\\' || c.is_control());
    if bad {
        return Err(format!(
            "{what} `{}` cannot be used as a file name (no `/`, `\\`, `..`, control characters; 1–128 bytes)",
            name.escape_default()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_that_would_escape_are_refused() {
        for bad in ["", ".", "..", "../x", "a/b", "a\\b", "x\u{0}y", &"n".repeat(129)] {
            assert!(check_file_name(bad, "name").is_err(), "{bad:?} accepted");
        }
        for good in ["ap", "lat", "oblique-45", "BG0002.CNG", "view ..1"] {
            assert!(check_file_name(good, "name").is_ok(), "{good:?} refused");
        }
    }

    #[test]
    fn write_file_replaces_atomically_and_leaves_no_temporary() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let path = dir.join("sub/out.json");
        write_file(&path, b"first").unwrap();
        write_file(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        let names: Vec<_> = std::fs::read_dir(dir.join("sub")).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 1, "only the file itself: {names:?}");
    }

    #[test]
    fn writers_of_one_path_at_once_never_mix_their_bytes() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let path = dir.join("results.csv");
        let contents: Vec<Vec<u8>> = (0..4u8).map(|t| vec![b'a' + t; 200_000]).collect();
        std::thread::scope(|scope| {
            for bytes in &contents {
                let path = &path;
                scope.spawn(move || {
                    for _ in 0..25 {
                        write_file(path, bytes).expect("every write succeeds");
                    }
                });
            }
        });
        let last = std::fs::read(&path).unwrap();
        assert!(contents.contains(&last), "the file is one writer's bytes, whole");
        let names: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 1, "no temporary left behind: {names:?}");
    }
}
