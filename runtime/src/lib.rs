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
//! # The public API
//!
//! Everything exported at the crate's root, and nothing else, is the API this crate keeps:
//!
//! - the renderer: [`Renderer`] (`synthesize`, `synthesize_layers`, `synthesize_deep`,
//!   `reconstruct`, `render`, `filter`), [`RendererOptions`], [`Backend`], [`DbSource`],
//!   [`Profile`], [`Method`], [`Event`], what a call returns ([`Frame`], [`FilterFrame`],
//!   [`SynthStats`]) and the one [`Error`];
//! - the inputs and outputs: [`Camera`], [`GBuffer`], [`ViewLayer`], [`DeepImage`],
//!   [`StochasticFrames`], [`RgbaImage`], and the [`formats`] crate they come from;
//! - the options of a call: [`SynthOptions`] and its parts;
//! - the one seam under the renderer, for callers that hold their own databases: a [`Plan`]
//!   of an [`Input`], prepared with a [`DbSet`] into a [`PreparedFrame`], drawn by
//!   [`render_cpu`] (or `gpu::render_gpu` with the feature `harness`).
//!
//! The stages themselves (classification, splatting, integration, compositing and their GPU
//! hosts), the database loader and the baselines are internal. The feature `harness` opens
//! them, without any promise of stability, to the workspace's harness (study, benchmarks,
//! device check) and to the tests that check one stage against another.
//!
//! The stages of the paper's pipeline, each a module, each GPU stage beside its CPU twin:
//! `pipeline::classify` (each pixel's PSF, in O(1), and its depth layer) -> `pipeline::splat`
//! (spreadlets into layered Laplacian buffers) -> `pipeline::integrate` (convolution pyramid
//! or the exact lattice Green's function) -> `pipeline::composite` (back to front); see
//! `docs/DESIGN.md`.

// Without `harness` the internal modules are crate-private, and what only the harness and the
// tests call is unused here.
#![cfg_attr(not(feature = "harness"), allow(dead_code, unused_imports))]

/// Declares internal modules: public with the feature `harness`, crate-private without.
macro_rules! internal_modules {
    ($($(#[$attr:meta])* $name:ident),* $(,)?) => {
        $(
            $(#[$attr])*
            #[cfg(feature = "harness")]
            pub mod $name;
            $(#[$attr])*
            #[cfg(not(feature = "harness"))]
            pub(crate) mod $name;
        )*
    };
}

internal_modules!(
    baseline,
    behind_blur,
    condition,
    databases,
    dbcache,
    dbset,
    denoise,
    depth_motion,
    edge_field,
    error,
    #[cfg(feature = "gpu")]
    gpu,
    grid,
    motion_smear,
    pipeline,
    prepare,
    reconstruct,
    renderer,
    sample_density,
    sample_mean,
    sample_merge,
    smear_symmetry,
    subpixel_psf,
    synth,
);

pub use camera::Camera;
pub use error::Error;
/// `camera.json`: the camera type, its validation and the thin-lens CoC (from `formats`).
pub use formats::camera;
/// The pinhole G-buffer and its EXR reader (from `formats`).
pub use formats::gbuffer;
pub use formats::{DeepCompression, DeepImage, DeepSample, RgbaImage, Sample, StochasticFrames};
pub use gbuffer::{ChannelOptions, GBuffer, Layout, ViewLayer};

pub use baseline::{FilterOptions, FilterStats};
pub use databases::{Conditioned, DbUsed};
pub use dbcache::{cache_dir, CacheError, CacheEvent, CACHE_ENV};
pub use dbset::DbSet;
pub use pipeline::classify::ClassifyError;
pub use pipeline::{
    ClassifyOptions, CompositeOptions, Effects, FrameEdges, Integrator, PathCounts,
    RotationSampling, SplatOptions,
};
/// The profile of databases built on demand (quick or paper; from `precompute`).
pub use precompute::Profile;
pub use prepare::{Input, Plan, PreparedFrame};
pub use reconstruct::{reconstruct, SamplePlacement};
pub use renderer::{
    Backend, DbSource, Event, EventSink, FilterFrame, Frame, Method, Renderer, RendererOptions,
};
pub use synth::{render_cpu, synthesize, StageTimes, SynthOptions, SynthStats};

/// The file formats (images, stochastic frames, atomic writing), re-exported for embedders.
pub use formats;
