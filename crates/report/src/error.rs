//! The one error type of the report crate.

use thiserror::Error;

/// What drawing a chart or writing a file can fail at.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ReportError {
    /// Reading or writing a file failed.
    #[error("I/O error on {path}: {source}")]
    Io {
        /// The file or folder.
        path: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A chart could not be drawn (empty or degenerate data, or a drawing error).
    #[error("chart: {0}")]
    Chart(String),
    /// Serialising to JSON failed.
    #[error("JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// An argument (a name, a shape, …) is out of range.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}

impl ReportError {
    /// A [`ReportError::Io`] on `path`.
    pub fn io(path: impl AsRef<std::path::Path>, source: std::io::Error) -> Self {
        ReportError::Io {
            path: path.as_ref().display().to_string(),
            source,
        }
    }
}

/// `Result` with [`ReportError`].
pub type Result<T> = std::result::Result<T, ReportError>;
