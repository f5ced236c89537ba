//! Buffer records shared by the CPU path and the GPU path.
//!
//! Every struct here is `#[repr(C)]` and `bytemuck::Pod`; its WGSL twin lives in
//! `shaders/common.wgsl` with the same field order. Change both or neither.

use bytemuck::{Pod, Zeroable};

/// One pixel (or one stochastic sample) after classification: where its PSF is centred, which
/// database PSF it uses, which layer it goes to and with what colour.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct SplatRecord {
    /// PSF centre in padded-layer pixel coordinates (x right), integer pixel.
    pub center_x: i32,
    /// PSF centre in padded-layer pixel coordinates (y down), integer pixel.
    pub center_y: i32,
    /// Index of the nearest database PSF (nested-grid cell).
    pub psf_index: u32,
    /// Destination layer, 0 = farthest.
    pub layer: u32,
    /// Cosine of the rotation from the database's reference direction (+x) to the motion.
    pub rot_cos: f32,
    /// Sine of that rotation (y down, so positive turns +x towards +y).
    pub rot_sin: f32,
    /// Weight of this record (soft layering splits a pixel into two records; stochastic
    /// samples of one pixel share its weight). Already folded into `color`; kept for stats.
    pub weight: f32,
    /// Which path draws it: see [`SplatPath`].
    pub path: u32,
    /// Premultiplied linear RGBA times `weight`.
    pub color: [f32; 4],
}

/// How a record is drawn.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SplatPath {
    /// Sparse spreadlets into the layer's Laplacian image.
    Sparse = 0,
    /// Dense fast-track PSF into the layer's direct image.
    Dense = 1,
    /// PSF under a pixel: the colour is copied into the layer's direct image.
    Copy = 2,
}

/// Per-frame constants.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct FrameParams {
    /// Output image width in pixels.
    pub width: u32,
    /// Output image height in pixels.
    pub height: u32,
    /// Padding added on every side of each layer, pixels (the largest PSF extent).
    pub pad: u32,
    /// Number of depth layers.
    pub layers: u32,
    /// `width + 2 * pad`.
    pub padded_width: u32,
    /// `height + 2 * pad`.
    pub padded_height: u32,
    /// Number of [`SplatRecord`]s.
    pub record_count: u32,
    /// Colour channels per spreadlet value in the database (1 or 3).
    pub db_channels: u32,
}
