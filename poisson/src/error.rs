//! Errors of the poisson crate.

/// A plane whose data does not match its size.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PoissonError {
    /// `data.len()` differs from `width * height`.
    #[error("plane of {width}x{height} px needs {} values, got {len}", width * height)]
    SizeMismatch {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
        /// Values given.
        len: usize,
    },
}
