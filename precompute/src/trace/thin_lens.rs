//! The thin-lens PSF: a point at CoC radius `r` pixels lands uniformly on the aperture shape
//! scaled by `r` (a disk of radius r, or the bladed polygon inscribed in it).

use super::{Bounds, Hit, LightTracer};
use crate::aperture::LensAperture;
use crate::prefilter::ParamBox;

/// Light tracer of the `thin-lens` model; `s = [CoC radius px, -]`.
#[derive(Clone, Debug)]
pub struct ThinLensTracer {
    /// Aperture shape.
    pub aperture: LensAperture,
}

impl LightTracer for ThinLensTracer {
    fn channels(&self) -> usize {
        1
    }
    fn ray_dims(&self) -> usize {
        2
    }
    fn bounds(&self, params: &ParamBox) -> Bounds {
        let r = params.range()[0][1].max(0.0);
        [-r, r, -r, r]
    }
    #[inline]
    fn trace(&self, s: [f64; 2], u: &[f64]) -> Option<Hit> {
        let a = self.aperture.sample(u[0], u[1]);
        let r = s[0].max(0.0);
        Some(Hit {
            offset: [r * a[0], r * a[1]],
            weight: [1.0, 0.0, 0.0],
        })
    }
}
