//! The errors of the precompute library.

/// What went wrong while building a PSF database.
#[derive(Debug, thiserror::Error)]
pub enum PrecomputeError {
    /// A build setting is out of its valid range (the message names it and the range).
    #[error("invalid build setting: {0}")]
    InvalidConfig(String),
    /// The lens prescription cannot be traced (e.g. it does not form a real image).
    #[error("invalid lens: {0}")]
    InvalidLens(String),
    /// The parameter space could not be built.
    #[error("parameter space: {0}")]
    Space(#[from] psf_db::SpaceError),
    /// The database could not be assembled or written.
    #[error("database: {0}")]
    Database(#[from] psf_db::DbError),
    /// Writing a file (report, database) failed.
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
    /// A PSF came out empty (no ray reached the sensor), so it cannot be normalised.
    #[error(
        "PSF {index} is empty: no traced light reached the sensor (through a real lens: the point \
         lies outside the image circle, or every ray is vignetted; a smaller sensor or \
         eccentricity range keeps to the circle)"
    )]
    EmptyPsf {
        /// Index of the PSF in the database.
        index: u32,
    },
}
