//! McGuire, Hennessy, Bukowski, Osman 2012, "A reconstruction filter for plausible motion
//! blur" (the single-velocity baseline of Guertin 2014, thesis Sec. 2.3 and 3.3).
//!
//! Choices where the text leaves a detail open (each one a parameter, see `docs/PEERS.md`):
//! - the per-pixel jitter is a Halton number (base `halton_base`, index = linear pixel
//!   index plus 1) in `[-jitter, +jitter]`, as Guertin did for his comparisons, instead of a noise
//!   texture; `jitter = 0.5` is McGuire's range;
//! - the tap is the nearest pixel `Y = round(X + t v_N)` and the cone and cylinder weights
//!   use the paper's `||X - Y||` between the two pixels (so a still pixel, whose velocity
//!   counts as 0.5 px, takes no colour from any other pixel);
//! - taps falling outside the image are skipped;
//! - depths are positive planar distances, so "Y in front of X" is
//!   `soft(Z[Y], Z[X]) = clamp(1 - (Z[Y] - Z[X]) / extent, 0, 1)` (the paper's argument order
//!   assumes negative camera-space z);
//! - velocity lengths below 0.5 px (including zero vectors) count as 0.5 px in the weights.

use crate::inputs::{GBufferView, Image};
use crate::tiles::{cone, cylinder, half_velocities, len2, neighbor_max, tile_max};
use crate::PeerError;
use rayon::prelude::*;

/// How two depths are compared softly.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum DepthCompare {
    /// McGuire 2012: a fixed transition width in scene units.
    Absolute {
        /// Width of the front/back transition, scene units (> 0).
        extent: f32,
    },
    /// Guertin 2014, Sec. 3.5: the transition width is the nearer of the two depths.
    Relative,
}

impl DepthCompare {
    /// Softly 1 when `z_sample` is in front of (or level with) `z_pixel`, 0 when well behind.
    pub fn in_front(&self, z_sample: f32, z_pixel: f32) -> f32 {
        let width = match *self {
            DepthCompare::Absolute { extent } => extent,
            DepthCompare::Relative => z_sample.min(z_pixel),
        };
        (1.0 - (z_sample - z_pixel) / width.max(1e-30)).clamp(0.0, 1.0)
    }

    pub(crate) fn validate(&self) -> Result<(), PeerError> {
        if let DepthCompare::Absolute { extent } = *self {
            if !(extent.is_finite() && extent > 0.0) {
                return Err(PeerError::BadParam {
                    name: "depth_compare.extent",
                    why: "must be finite and > 0",
                });
            }
        }
        Ok(())
    }
}

/// Parameters of [`mcguire`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct McGuireParams {
    /// Taps per pixel S (odd; the middle tap is skipped as in the paper). Default 35, as
    /// Guertin's comparisons.
    pub samples: usize,
    /// Tile size and largest blur radius r, pixels. Default 40.
    pub tile_size: usize,
    /// Soft depth comparison. Default absolute with a 0.01 scene-unit extent (1 cm for the
    /// metre-scaled examples; McGuire's value is scene dependent).
    pub depth_compare: DepthCompare,
    /// Half-range of the per-pixel jitter, in tap spacings. Default 0.5.
    pub jitter: f32,
    /// Base of the Halton sequence that jitters the taps. Default 2.
    pub halton_base: u64,
}

impl Default for McGuireParams {
    fn default() -> Self {
        McGuireParams {
            samples: 35,
            tile_size: 40,
            depth_compare: DepthCompare::Absolute { extent: 0.01 },
            jitter: 0.5,
            halton_base: 2,
        }
    }
}

/// McGuire 2012 motion blur of a pinhole G-buffer. Returns premultiplied RGBA, width x height.
pub fn mcguire(g: &GBufferView, p: &McGuireParams) -> Result<Image, PeerError> {
    g.validate()?;
    p.depth_compare.validate()?;
    if p.samples == 0 || p.samples > 1024 {
        return Err(PeerError::BadParam {
            name: "samples",
            why: "must be in 1..=1024",
        });
    }
    if p.tile_size == 0 || p.tile_size > 1024 {
        return Err(PeerError::BadParam {
            name: "tile_size",
            why: "must be in 1..=1024",
        });
    }
    if !(p.jitter.is_finite() && p.jitter >= 0.0) {
        return Err(PeerError::BadParam {
            name: "jitter",
            why: "must be finite and >= 0",
        });
    }
    let (w, h) = (g.width, g.height);
    let r = p.tile_size;
    let vel = half_velocities(g.motion, r as f32);
    let nm = neighbor_max(&tile_max(w, h, &vel, r), None);
    let s_count = p.samples;
    let mut out = vec![[0.0f32; 4]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = y * w + x;
            let vn = nm.v[(y / r) * nm.tw + x / r];
            let vn_len = len2(vn);
            let c = g.color[i];
            if vn_len <= 0.5 + 1e-5 {
                *o = c;
                continue;
            }
            let vx_len = len2(vel[i]).max(0.5);
            let zx = g.depth[i];
            let mut weight = 1.0 / vx_len;
            let mut sum = c.map(|v| v * weight);
            let j = crate::halton::halton(i as u64 + 1, p.halton_base, -p.jitter, p.jitter);
            for k in 0..s_count {
                if s_count % 2 == 1 && k == (s_count - 1) / 2 {
                    continue;
                }
                let t = -1.0 + 2.0 * (k as f32 + j + 1.0) / (s_count as f32 + 1.0);
                let sx = (x as f32 + t * vn[0]).round();
                let sy = (y as f32 + t * vn[1]).round();
                if sx < 0.0 || sy < 0.0 || sx >= w as f32 || sy >= h as f32 {
                    continue;
                }
                let si = sy as usize * w + sx as usize;
                let dist = ((sx - x as f32).powi(2) + (sy - y as f32).powi(2)).sqrt();
                let zy = g.depth[si];
                let vy_len = len2(vel[si]).max(0.5);
                let f = p.depth_compare.in_front(zy, zx);
                let b = p.depth_compare.in_front(zx, zy);
                let alpha = f * cone(dist, vy_len)
                    + b * cone(dist, vx_len)
                    + cylinder(dist, vy_len) * cylinder(dist, vx_len) * 2.0;
                weight += alpha;
                let cy = g.color[si];
                for ch in 0..4 {
                    sum[ch] += alpha * cy[ch];
                }
            }
            *o = sum.map(|v| v / weight);
        }
    });
    Ok(out)
}
