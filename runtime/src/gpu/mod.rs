//! The GPU path: each stage a WGSL compute shader in `shaders/`, mirroring the CPU path.
//!
//! - [`GpuContext`]: adapter and device acquisition, feature detection.
//! - [`GpuSynthesizer`]: pipelines and the uploaded PSF database, reused across frames;
//!   [`GpuSynthesizer::run`] takes the CPU path's classified records.
//! - [`synthesize_gpu`]: the GPU twin of `synth::synthesize` (classification on the CPU).
//! - [`GpuPyramid`]: the convolution pyramid alone (stage-level entry point).
//! - [`GpuFilter`], [`filter_gpu`]: the filter baseline (gathering), twin of
//!   `baseline::filter`.
//! - [`tiles`]: the tiled splat's binning and fixed-point scales on the CPU (mirror of
//!   `shaders/bin.wgsl`).
//! - [`check`]: the device check (micro-benchmarks, then every scene and size), JSON and
//!   Markdown.
//! - [`microbench`]: what the device allows (copy bandwidth, atomic adds), to state each
//!   stage's time as a fraction of its limit.

pub mod check;
mod context;
mod error;
mod filter;
mod frontend;
pub mod layout;
pub mod microbench;
mod pyramid;
mod shaders;
mod synth;
pub mod tiles;
mod util;

pub use context::{GpuContext, REQUIRE_GPU_ENV};
pub use error::GpuError;
pub use filter::{filter_gpu, GpuFilter};
pub use frontend::{reconstruct_gpu, synthesize_gpu};
pub use pyramid::{GpuPyramid, PyramidLevels};
pub use shaders::shader_sources_for_validation;
pub use synth::{
    AtomicMode, GpuSynthOptions, GpuSynthesizer, SplatMode, SplatPlanes, StageTimes, SynthCounters,
};
