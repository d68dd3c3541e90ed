//! Errors of the ops crate.

/// What an op can fail with.
#[derive(Debug, thiserror::Error)]
pub enum OpsError {
    /// A value or state the op cannot work with.
    #[error("{0}")]
    Invalid(String),
}

impl OpsError {
    /// An [`OpsError::Invalid`].
    pub fn invalid(problem: impl Into<String>) -> Self {
        Self::Invalid(problem.into())
    }
}

/// Result with [`OpsError`].
pub type Result<T, E = OpsError> = std::result::Result<T, E>;
