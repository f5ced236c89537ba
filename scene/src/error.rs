//! The one error type of the crate: every failure says what went wrong and where.

use std::path::PathBuf;

/// Errors from reading scenes, rendering and EXR input/output.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scene or camera JSON document did not parse (the message names line, column and field).
    #[error("{source_name}: invalid JSON: {source}")]
    Json {
        /// File name or builtin name the JSON came from.
        source_name: String,
        /// The parser's message.
        #[source]
        source: serde_json::Error,
    },
    /// A value parsed but makes no sense (negative radius, zero width, ...).
    #[error("{context}: {message}")]
    Invalid {
        /// Which scene, object or field.
        context: String,
        /// What is wrong with it.
        message: String,
    },
    /// No builtin scene of that name.
    #[error("no builtin scene named {name:?} (known: {known})")]
    UnknownBuiltin {
        /// The name asked for.
        name: String,
        /// Comma-separated list of the builtin names.
        known: String,
    },
    /// A file could not be read or written.
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
    /// An EXR file was readable but is not in the expected layout.
    #[error("{path}: {message}")]
    Layout {
        /// The file concerned.
        path: PathBuf,
        /// What is missing or inconsistent.
        message: String,
    },
}

impl From<formats::Error> for Error {
    fn from(e: formats::Error) -> Self {
        match e {
            formats::Error::Io { path, source } => Error::Io { path, source },
            formats::Error::Exr { path, source } => Error::Exr { path, source },
            formats::Error::Layout { path, message } => Error::Layout { path, message },
            formats::Error::Png { path, source } => Error::Io {
                path,
                source: std::io::Error::other(source),
            },
        }
    }
}

/// Shorthand for results of this crate.
pub type Result<T> = std::result::Result<T, Error>;

/// Builds an [`Error::Invalid`].
pub(crate) fn invalid(context: impl Into<String>, message: impl Into<String>) -> Error {
    Error::Invalid {
        context: context.into(),
        message: message.into(),
    }
}
