//! The synthesis pipeline, one pure function per stage (the GPU path mirrors each):
//!
//! 1. [`classify::classify`]: G-buffer + camera + database -> [`types::SplatRecord`]s, sorted
//!    by layer, with [`types::FrameParams`] and per-layer info;
//! 2. [`splat::splat`]: records + database -> [`splat::LayerStack`], per layer four Laplacian
//!    and four direct planes (R, G, B, A), padded;
//! 3. [`integrate::integrate`]: Laplacian planes -> primal planes (pyramid or exact), direct
//!    planes added;
//! 4. [`composite::composite`]: layers back to front -> RGBA image.
//!
//! A frame with no Laplacian plane ([`direct::all_direct`]) runs 2 to 4 at once, band by band
//! ([`direct::splat_composite`]), without holding its layers as planes.

pub mod classify;
pub mod composite;
pub mod direct;
pub mod integrate;
pub mod packed;
mod sparse_runs;
pub mod splat;
pub mod types;
pub mod wide;

pub use classify::{classify, ClassifyOptions, DataWindow, Effects, FrameEdges};
pub use composite::{composite, CompositeOptions};
pub use integrate::{integrate, integrate_owned, IntegratedLayers, Integrator};
pub use splat::{splat, LayerStack, RotationSampling, SplatOptions};
pub use types::{Classified, FrameParams, LayerInfo, PathCounts, SplatPath, SplatRecord};
