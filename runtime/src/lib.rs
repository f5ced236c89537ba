//! spreadlet: depth of field and motion blur added to rendered images by splatting sparse
//! Laplacian point-spread functions ("spreadlets"; Leimkühler, Seidel and Ritschel 2018), on the
//! CPU and (feature `gpu`) with wgpu.
//!
//! Most users need one type, [`Renderer`]: it chooses the device, loads (or builds) the PSF
//! databases an input needs and keeps them, and the GPU pipelines, across calls.
//!
//! ```no_run
//! use spreadlet::{Backend, Camera, GBuffer, Renderer, RendererOptions, SynthOptions};
//! # fn main() -> Result<(), spreadlet::Error> {
//! let gbuffer = GBuffer::read_exr("input.exr".as_ref(), &Default::default())?;
//! let camera = Camera::from_json_file("camera.json".as_ref())?;
//! let mut renderer = Renderer::new(RendererOptions { backend: Backend::Auto, ..Default::default() })?;
//! let frame = renderer.synthesize(&gbuffer, &camera, &SynthOptions::default())?;
//! frame.image.write_exr("out.exr".as_ref())?;
//! # Ok(()) }
//! ```
//!
//! The stages of the paper's pipeline, each a module, each GPU stage beside its CPU twin:
//! [`pipeline::classify`] (each pixel's PSF, in O(1), and its depth layer) ->
//! [`pipeline::splat`] (spreadlets into layered Laplacian buffers) -> [`pipeline::integrate`]
//! (convolution pyramid or the exact lattice Green's function) -> [`pipeline::composite`]
//! (back to front). The databases come from [`databases`] (the one loader) and `precompute`.

pub mod baseline;
pub mod condition;
pub mod databases;
pub mod dbcache;
pub mod dbset;
pub mod denoise;
pub mod error;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod pipeline;
pub mod reconstruct;
pub mod renderer;
pub mod synth;

pub use camera::Camera;
pub use error::Error;
/// `camera.json`: the camera type, its validation and the thin-lens CoC (from `formats`).
pub use formats::camera;
/// The pinhole G-buffer and its EXR reader (from `formats`).
pub use formats::gbuffer;
pub use formats::{DeepImage, RgbaImage, Sample, StochasticFrames};
pub use gbuffer::{ChannelOptions, GBuffer, ViewLayer};
pub use renderer::{Backend, DbSource, Event, Frame, Method, Renderer, RendererOptions};
pub use synth::{SynthOptions, SynthStats};

/// The file formats (images, stochastic frames, atomic writing), re-exported for embedders.
pub use formats;
