//! Errors of the database crate: invalid parameter spaces and unreadable databases.

use std::path::PathBuf;

/// A parameter space or grid that cannot be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SpaceError {
    /// Only 1 and 2 dimensional spaces exist (or the ranges do not match the model).
    #[error("a parameter space has 1 or 2 dimensions matching its model, got {0}")]
    Dims(usize),
    /// The grid resolution is 0 or above [`crate::grid::MAX_GRID_RESOLUTION`].
    #[error("grid resolution {0} is outside 1..=65536")]
    Resolution(u32),
    /// A regular grid with no cell along a dimension, or more than the largest resolution.
    #[error(
        "a regular grid needs at least 1 cell per dimension and at most 65536 in all, got {0:?}"
    )]
    RegularCells([u32; 2]),
    /// A dimension whose range is empty or not finite, or whose beta is not positive.
    #[error("dimension {index}: need finite min < max and beta > 0, got min {min}, max {max}, beta {beta}")]
    BadDimension {
        /// Which dimension (0 or 1).
        index: usize,
        /// Its minimum.
        min: f64,
        /// Its maximum.
        max: f64,
        /// Its power-remapping exponent.
        beta: f64,
    },
}

/// Why a PSF database could not be read, written or built.
#[derive(Debug, thiserror::Error)]
pub enum DbError {
    /// The file could not be opened, read, written or renamed.
    #[error("database file {path}: {source}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The bytes end before the structure they declare does.
    #[error("database truncated: {needed} bytes needed, {found} present")]
    Truncated {
        /// Bytes the declared structure needs.
        needed: u64,
        /// Bytes present.
        found: u64,
    },
    /// The bytes present exceed what the declared structure needs (trailing garbage).
    #[error(
        "database length mismatch: the declared arrays need {expected} bytes, {found} present"
    )]
    LengthMismatch {
        /// Bytes the declared structure needs.
        expected: u64,
        /// Bytes present.
        found: u64,
    },
    /// The file does not start with the spreadlet magic: not a PSF database.
    #[error("not a spreadlet PSF database (bad magic bytes)")]
    BadMagic,
    /// A database written by another format version.
    #[error("unsupported database format version {found} (this build reads version {expected})")]
    UnsupportedVersion {
        /// Version in the file.
        found: u32,
        /// Version this build reads.
        expected: u32,
    },
    /// The stored CRC32 does not match the content: the file is corrupt.
    #[error("database checksum mismatch (stored {stored:#010x}, computed {computed:#010x}): the file is corrupt")]
    Checksum {
        /// CRC32 stored at the end of the file.
        stored: u32,
        /// CRC32 of the bytes before it.
        computed: u32,
    },
    /// The bincode header cannot be decoded or encoded.
    #[error("database header: {0}")]
    Header(String),
    /// An index, count, offset or position that points outside its array or the PSF.
    #[error("database is inconsistent: {what}")]
    OutOfBounds {
        /// What is out of bounds, in words.
        what: String,
    },
    /// Content that is well-formed but not acceptable (builder misuse, non-finite values, ...).
    #[error("invalid database content: {0}")]
    Invalid(String),
    /// The database was built for another PSF model than the caller needs.
    #[error("database holds {found} PSFs, {expected} needed")]
    WrongModel {
        /// Model in the file.
        found: crate::PsfModel,
        /// Model the caller asked for.
        expected: crate::PsfModel,
    },
    /// A partial file of a sharded build where a whole database is needed.
    #[error("this is part {index} of {count} of a sharded build, not a database: join the parts with `precompute merge`")]
    Partial {
        /// The part's index (0-based).
        index: u32,
        /// Number of parts.
        count: u32,
    },
    /// Parts of a sharded build that do not belong together or do not cover every PSF.
    #[error("cannot merge the parts: {0}")]
    Merge(String),
    /// The parameter space in the header is invalid.
    #[error("invalid parameter space: {0}")]
    Space(#[from] SpaceError),
}
