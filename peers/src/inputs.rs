//! The small input types the peer methods read. The runtime adapts its own buffers to these.
//!
//! Conventions (as in the rest of spreadlet): linear premultiplied RGBA, pixel (0,0) top-left,
//! x right, y down, row-major; depth planar in scene units; CoC a signed radius in pixels.

use crate::PeerError;

/// Largest image side the peers accept (pixels): bounds every allocation.
pub const MAX_SIDE: usize = 1 << 15;

/// Output of every method: premultiplied linear RGBA, `width * height`, row-major.
pub type Image = Vec<[f32; 4]>;

pub(crate) fn check_size(width: usize, height: usize) -> Result<(), PeerError> {
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(PeerError::BadSize {
            width,
            height,
            max: MAX_SIDE,
        });
    }
    Ok(())
}

pub(crate) fn check_len(name: &'static str, got: usize, expected: usize) -> Result<(), PeerError> {
    if got != expected {
        return Err(PeerError::BadLength {
            name,
            got,
            expected,
        });
    }
    Ok(())
}

/// A pinhole G-buffer for the post-process motion blur methods (McGuire 2012, Guertin 2014).
#[derive(Debug, Clone, Copy)]
pub struct GBufferView<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Premultiplied linear RGBA per pixel, row-major, y down.
    pub color: &'a [[f32; 4]],
    /// Planar depth per pixel in scene units (> 0; large finite values such as 1e10 for misses).
    pub depth: &'a [f32],
    /// Forward screen motion per pixel over the whole shutter, in pixels (the per-frame motion
    /// already multiplied by `shutter_frames`); x right, y down. The blur of a pixel spans
    /// half of it before and half after the pixel's position.
    pub motion: &'a [[f32; 2]],
}

impl GBufferView<'_> {
    /// Checks sizes, lengths and that every value is finite (depths also > 0).
    pub fn validate(&self) -> Result<(), PeerError> {
        check_size(self.width, self.height)?;
        let n = self.width * self.height;
        check_len("color", self.color.len(), n)?;
        check_len("depth", self.depth.len(), n)?;
        check_len("motion", self.motion.len(), n)?;
        if let Some(i) = self
            .color
            .iter()
            .position(|c| c.iter().any(|v| !v.is_finite()))
        {
            return Err(PeerError::BadValue {
                name: "color",
                index: i,
                why: "not finite",
            });
        }
        if let Some(i) = self.depth.iter().position(|d| !(d.is_finite() && *d > 0.0)) {
            return Err(PeerError::BadValue {
                name: "depth",
                index: i,
                why: "not finite and > 0",
            });
        }
        if let Some(i) = self
            .motion
            .iter()
            .position(|m| m.iter().any(|v| !v.is_finite()))
        {
            return Err(PeerError::BadValue {
                name: "motion",
                index: i,
                why: "not finite",
            });
        }
        Ok(())
    }
}

/// One stochastic sample of a distribution-effects render (one ray: a lens position and a time).
/// The fields follow `scene::stochastic::Sample`, plus the signed CoC that the camera gives
/// for the depth (`formats::ThinLens::signed_coc_px`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Sensor position of the ray relative to its pixel's centre, pixels, each component in
    /// [-0.5, 0.5].
    pub jitter: [f32; 2],
    /// Premultiplied linear RGBA that the ray returned.
    pub color: [f32; 4],
    /// Planar depth of the hit in scene units (> 0; large finite values for misses).
    pub depth: f32,
    /// Lens position on the unit disk (|lens| <= 1), u right, v down.
    pub lens: [f32; 2],
    /// Time of the ray in frames, relative to the frame's centre (|t| <= shutter_frames / 2).
    pub time: f32,
    /// Screen motion of the hit point in pixels per frame, x right, y down.
    pub motion: [f32; 2],
    /// Signed circle of confusion radius of the hit in pixels: negative in front of the focus
    /// plane, positive behind. Convention (the scene crate's): the ray lands at the hit
    /// point's pinhole image plus `coc * lens`, so that pinhole image at time 0 lies at
    /// `pixel centre + jitter - coc * lens - motion * time`.
    pub coc: f32,
}

/// All samples of one frame, pixel-major: sample `s` of pixel (x, y) is
/// `samples[(y * width + x) * spp + s]`.
#[derive(Debug, Clone, Copy)]
pub struct SampleView<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Samples per pixel (>= 1).
    pub spp: usize,
    /// Exposure as a fraction of a frame (>= 0); sample times lie in +-shutter_frames/2.
    pub shutter_frames: f32,
    /// The samples, `width * height * spp` of them.
    pub samples: &'a [Sample],
}

impl SampleView<'_> {
    /// Checks sizes, lengths and that every field is finite and in its range.
    pub fn validate(&self) -> Result<(), PeerError> {
        check_size(self.width, self.height)?;
        if self.spp == 0 || self.spp > 4096 {
            return Err(PeerError::BadParam {
                name: "spp",
                why: "must be in 1..=4096",
            });
        }
        if !(self.shutter_frames.is_finite() && self.shutter_frames >= 0.0) {
            return Err(PeerError::BadParam {
                name: "shutter_frames",
                why: "must be finite and >= 0",
            });
        }
        check_len(
            "samples",
            self.samples.len(),
            self.width * self.height * self.spp,
        )?;
        for (i, s) in self.samples.iter().enumerate() {
            let finite = s.color.iter().all(|v| v.is_finite())
                && s.jitter.iter().all(|v| v.is_finite())
                && s.lens.iter().all(|v| v.is_finite())
                && s.motion.iter().all(|v| v.is_finite())
                && s.time.is_finite()
                && s.coc.is_finite()
                && s.depth.is_finite();
            if !finite {
                return Err(PeerError::BadValue {
                    name: "samples",
                    index: i,
                    why: "not finite",
                });
            }
            if s.depth <= 0.0 {
                return Err(PeerError::BadValue {
                    name: "samples.depth",
                    index: i,
                    why: "must be > 0",
                });
            }
            if s.jitter.iter().any(|v| !(-0.5..=0.5).contains(v)) {
                return Err(PeerError::BadValue {
                    name: "samples.jitter",
                    index: i,
                    why: "must be in [-0.5, 0.5]",
                });
            }
            if s.lens[0] * s.lens[0] + s.lens[1] * s.lens[1] > 1.0 + 1e-4 {
                return Err(PeerError::BadValue {
                    name: "samples.lens",
                    index: i,
                    why: "outside the unit disk",
                });
            }
        }
        Ok(())
    }
}

/// Thin-lens circle of confusion in pixels as a function of depth:
/// `coc(z) = coc_scale * (1/focus_depth - 1/z)` (Vaidyanathan 2015, Eq. 1, scaled to pixels):
/// negative in front of the focus plane, positive behind, `coc_scale / focus_depth` at infinity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LensModel {
    /// Aperture radius times image distance, in pixels times scene units (> 0 for a lens,
    /// 0 for a pinhole). For a thin lens: `A * f / (F - f) * F / pixel_pitch` with aperture radius A.
    pub coc_scale: f32,
    /// Distance of the plane in focus, scene units (> 0).
    pub focus_depth: f32,
}

impl LensModel {
    /// Signed CoC radius in pixels at planar depth `depth` (scene units).
    pub fn coc(&self, depth: f32) -> f32 {
        self.coc_scale * (1.0 / self.focus_depth - 1.0 / depth)
    }
}
