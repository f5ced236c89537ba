//! The GPU path: each stage a WGSL compute shader from the `shaders` crate, mirroring the CPU
//! path.
//!
//! - [`GpuContext`]: adapter and device acquisition, feature detection.
//! - [`GpuSynthesizer`]: pipelines and the uploaded PSF database, reused across frames;
//!   [`GpuSynthesizer::run`] takes the CPU path's classified records.
//! - [`render_gpu`]: the GPU device, drawing a [`crate::prepare::PreparedFrame`] as
//!   `synth::render_cpu` does on the CPU.
//! - [`GpuPyramid`]: the convolution pyramid alone (stage-level entry point).
//! - [`GpuFilter`], [`filter_gpu`]: the filter baseline (gathering), twin of
//!   `baseline::filter`.
//! - [`tiles`]: the tiled splat's binning and fixed-point scales on the CPU (mirror of
//!   `shaders/bin.wgsl`).
//! - [`util`]: building blocks of compute stages (buffers, bind groups, pipelines, readback).

mod composite;
mod context;
mod database;
mod error;
mod filter;
mod frame;
mod frontend;
mod integrate;
pub mod layout;
mod pyramid;
mod splat;
mod splat_tiled;
pub(crate) use ::shaders;
mod synth;
pub mod tiles;
pub mod util;

pub use ::shaders::shader_sources_for_validation;
pub use context::{adapter_label, GpuContext, Opened, SoftwareAdapter, REQUIRE_GPU_ENV};
pub use error::GpuError;
pub use filter::{filter_gpu, GpuFilter};
pub use frontend::render_gpu;
pub use pyramid::{GpuPyramid, PyramidLevels};
pub use synth::{
    AtomicMode, GpuStageTimes, GpuSynthOptions, GpuSynthesizer, SplatMode, SplatPlanes,
    SynthCounters,
};
