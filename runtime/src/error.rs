//! The crate's one error type: every failure of the renderer, with its cause kept as the
//! error's source (not flattened into a string), so callers can match on it or print the chain.

/// Everything [`crate::Renderer`] and the library's entry points can fail with.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The camera description is unreadable or impossible.
    #[error(transparent)]
    Camera(#[from] crate::camera::CameraError),
    /// The G-buffer is unreadable or inconsistent (sizes, missing passes, NaN depth).
    #[error(transparent)]
    GBuffer(#[from] crate::gbuffer::GBufferError),
    /// Classification refused the input (sizes, passes, databases).
    #[error(transparent)]
    Classify(#[from] crate::pipeline::classify::ClassifyError),
    /// A database could not be found, built, read or conditioned.
    #[error(transparent)]
    Database(#[from] crate::dbcache::CacheError),
    /// A database could not be read or changed.
    #[error(transparent)]
    Db(#[from] psf_db::DbError),
    /// A baseline method failed.
    #[error(transparent)]
    Baseline(#[from] crate::baseline::BaselineError),
    /// Reading or writing a file failed.
    #[error(transparent)]
    Format(#[from] formats::Error),
    /// A deep OpenEXR is unreadable or breaks the deep reader's policy.
    #[error(transparent)]
    Deep(#[from] formats::DeepError),
    /// The camera's aperture image is unreadable or cannot be an aperture.
    #[error(transparent)]
    ApertureImage(#[from] formats::MaskError),
    /// The camera's lens prescription is unreadable or cannot be a lens.
    #[error(transparent)]
    Lens(#[from] precompute::optics::PrescriptionError),
    /// The camera asks for something its lens cannot do (stochastic samples, labelled for the thin
    /// lens, through a real lens).
    #[error("{0}")]
    Unsupported(String),
    /// The GPU path failed (no adapter when one was required, a device limit, a wgpu error).
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
    /// The GPU was asked for, and this build has no GPU support (feature `gpu`).
    #[error("a GPU was asked for, and this build has no GPU support (feature `gpu`)")]
    NoGpuSupport,
    /// An option is out of its range.
    #[error("{option} {message}")]
    InvalidOption {
        /// The option, as the command line names it (`--layers`).
        option: &'static str,
        /// What is wrong with its value.
        message: String,
    },
}
