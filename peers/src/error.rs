//! The one error type of the peer methods.

use thiserror::Error;

/// What went wrong when a peer method was given its input.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum PeerError {
    /// The image has no pixels, or more than the methods accept.
    #[error("image size {width}x{height} is not supported (each side 1..={max})")]
    BadSize {
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
        /// Largest side accepted.
        max: usize,
    },
    /// A buffer's length does not match the image size.
    #[error("buffer `{name}` has {got} entries, expected {expected}")]
    BadLength {
        /// Which buffer.
        name: &'static str,
        /// Entries found.
        got: usize,
        /// Entries expected.
        expected: usize,
    },
    /// A value is NaN, infinite where it must be finite, or out of its range.
    #[error("invalid value in `{name}` at index {index}: {why}")]
    BadValue {
        /// Which buffer or field.
        name: &'static str,
        /// Index of the first offending entry.
        index: usize,
        /// Why it was rejected.
        why: &'static str,
    },
    /// A parameter is out of its range.
    #[error("invalid parameter `{name}`: {why}")]
    BadParam {
        /// Parameter name.
        name: &'static str,
        /// Why it was rejected.
        why: &'static str,
    },
    /// The method does not handle this kind of input (e.g. motion given to a defocus-only path).
    #[error("unsupported input: {0}")]
    Unsupported(&'static str),
}
