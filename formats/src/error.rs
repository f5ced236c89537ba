//! The one error type of the formats: every failure names the file and says what went wrong.

use std::path::PathBuf;

/// Errors from reading and writing files.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be created, read, written or renamed into place.
    #[error("{path}: {source}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The EXR library failed to read or write a file.
    #[error("{path}: EXR error: {source}")]
    Exr {
        /// The file concerned.
        path: PathBuf,
        /// The EXR library's error.
        #[source]
        source: exr::error::Error,
    },
    /// The PNG encoder failed.
    #[error("{path}: cannot encode PNG: {source}")]
    Png {
        /// The file concerned.
        path: PathBuf,
        /// The encoder's error.
        #[source]
        source: ::image::ImageError,
    },
    /// A file was readable but is not in the expected layout.
    #[error("{path}: {message}")]
    Layout {
        /// The file concerned.
        path: PathBuf,
        /// What is missing or inconsistent.
        message: String,
    },
}

impl Error {
    /// An [`Error::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}

/// Shorthand for results of this crate.
pub type Result<T> = std::result::Result<T, Error>;
