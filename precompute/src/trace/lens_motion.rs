//! The lens-motion PSF: the thin-lens CoC of radius `r` px swept along +x by a linear motion of
//! `m` px over a box shutter centred on the frame time: at shutter time `t` in `[0, 1)` the
//! point sits at `(t - 1/2) m`, so it moves from `-m/2` to `+m/2`.
//!
//! The shutter time is either sampled per ray like the lens (the paper's light tracing) or,
//! with [`LensMotionTracer::analytic_shutter`], integrated exactly: each lens sample then
//! deposits its whole sweep, a uniform segment of length `m` along +x ([`LightTracer::sweep_px`]),
//! which removes the time dimension's Monte Carlo noise (the same PSF in expectation).

use super::{Bounds, Hit, LightTracer};
use crate::aperture::LensAperture;
use crate::prefilter::ParamBox;

/// Light tracer of the `lens-motion` model; `s = [CoC radius px, motion length px]`.
#[derive(Clone, Debug)]
pub struct LensMotionTracer {
    /// Aperture shape.
    pub aperture: LensAperture,
    /// Integrate the box shutter exactly (each ray a segment) instead of sampling its time.
    pub analytic_shutter: bool,
}

impl LightTracer for LensMotionTracer {
    fn channels(&self) -> usize {
        1
    }
    fn ray_dims(&self) -> usize {
        if self.analytic_shutter {
            2
        } else {
            3
        }
    }
    fn bounds(&self, params: &ParamBox) -> Bounds {
        let range = params.range();
        let r = range[0][1].max(0.0);
        let m = range[1][1].max(0.0);
        [-r - 0.5 * m, r + 0.5 * m, -r, r]
    }
    #[inline]
    fn trace(&self, s: [f64; 2], u: &[f64]) -> Option<Hit> {
        let a = self.aperture.sample(u[0], u[1]);
        let r = s[0].max(0.0);
        let t = if self.analytic_shutter { 0.5 } else { u[2] };
        let m = s[1].max(0.0);
        Some(Hit {
            offset: [r * a[0] + (t - 0.5) * m, r * a[1]],
            weight: [1.0, 0.0, 0.0],
        })
    }
    fn sweep_px(&self, s: [f64; 2]) -> f64 {
        if self.analytic_shutter {
            s[1].max(0.0)
        } else {
            0.0
        }
    }
}
