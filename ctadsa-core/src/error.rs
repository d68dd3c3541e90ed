//! Errors at the boundary of `ctadsa-core`: every variant names the file (or the item) and the
//! problem, so a user can fix the input.

use std::path::{Path, PathBuf};

/// An error of the core library.
#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// Reading or writing a file failed at the OS level.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file was read but its content is not what it should be.
    #[error("{path}: {problem}")]
    Format { path: PathBuf, problem: String },
    /// An argument, setting or piece of data is out of range or inconsistent.
    #[error("{0}")]
    Invalid(String),
    /// The renderer rejected its input.
    #[error(transparent)]
    Render(#[from] ctadsa_render::RenderError),
}

impl CoreError {
    /// An I/O error on `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
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

/// Reads a whole file, naming it on failure.
pub fn read_file(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| CoreError::io(path, e))
}

/// Writes a whole file (creating parent folders), naming it on failure.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(parent) = path.parent()
        && !parent.as_os_str().is_empty()
    {
        std::fs::create_dir_all(parent).map_err(|e| CoreError::io(parent, e))?;
    }
    std::fs::write(path, bytes).map_err(|e| CoreError::io(path, e))
}
