//! spreadlet's file formats, each defined once and shared by the renderer (`spreadlet`), the
//! ground-truth renderer (`scene`), the metrics and the tools:
//!
//! - [`Camera`]: `camera.json` (lens, shutter, scene units), its one validation and the one
//!   thin-lens circle-of-confusion formula.
//! - [`RgbaImage`]: linear premultiplied RGBA, row-major from the top-left pixel, y down; EXR
//!   in and out, an sRGB PNG preview.
//! - [`GBuffer`]: the pinhole G-buffer (colour, planar depth, forward motion) from EXR, plain
//!   or Blender multilayer, with its data window beyond the frame (overscan).
//! - [`StochasticFrames`]: labelled samples (lens position, time, motion) in one EXR
//!   (`docs/STOCHASTIC.md`).
//! - [`DeepImage`]: deep scanline OpenEXR (samples per pixel, each with colour, alpha and
//!   depth), read and written by a reader of our own.
//! - [`exr_io`]: named f32 channels in and out, with the header's size checked against the
//!   file's before any pixel is decoded.
//! - [`srgb_encode`]: the one sRGB transfer function (IEC 61966-2-1).
//! - [`limits`]: every reader's size limits, in one place.
//! - [`write_atomically`]: every output appears complete or not at all, with the permissions
//!   any new file gets (0666 less the umask).

pub mod aperture_mask;
pub mod atomic;
pub mod camera;
pub mod deep;
pub mod error;
pub mod exr_blocks;
pub mod exr_io;
pub mod gbuffer;
pub mod image;
pub mod limits;
pub mod srgb;
pub mod stochastic;

pub use aperture_mask::{ApertureMask, MaskError, MaskSampler};
pub use atomic::write_atomically;
pub use camera::{Camera, CameraError, ThinLens};
pub use deep::{DeepCompression, DeepError, DeepImage, DeepSample};
pub use error::{Error, Result};
pub use gbuffer::{ChannelOptions, GBuffer, GBufferError, ViewLayer};
pub use image::RgbaImage;
pub use srgb::srgb_encode;
pub use stochastic::{GuidesError, Sample, SampleGuides, StochasticFrames};
