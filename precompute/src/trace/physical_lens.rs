//! The physical-lens PSF: light from a point at `depth` (scene units, from the stop) whose
//! pinhole image lies `eccentricity` mm from the sensor centre along +x, traced through the
//! singlet at wavelengths over 400-700 nm and accumulated into linear RGB.
//!
//! Orientation: the image is the sensor turned by 180 degrees, and the lens is rotationally
//! symmetric, so the PSF of an image point at +e (radially outwards = +x) is the sensor PSF of
//! the sensor point at +e, mirrored in y (image y points down). The equivalent pinhole camera sits
//! at the stop centre with image distance `D` ([`Singlet::pinhole_distance`]), so the point is
//! placed at lateral `X = e * depth / D` and the PSF origin is its pinhole image `e`: chromatic
//! shifts, distortion and cat-eye vignetting all show in the PSF.

use glam::DVec3;

use super::{pilot_bounds, Bounds, Hit, LightTracer};
use crate::aperture::concentric_disk;
use crate::optics::singlet::Singlet;
use crate::optics::spectrum::Spectrum;
use crate::prefilter::ParamBox;

/// Light tracer of the `physical-lens` model; `s = [depth (scene units), eccentricity (mm)]`.
#[derive(Clone, Debug)]
pub struct PhysicalLensTracer {
    /// The focused singlet.
    pub lens: Singlet,
    /// Channel sensitivities.
    pub spectrum: Spectrum,
    /// Millimetres per scene unit.
    pub scene_unit_mm: f64,
    /// Pixel pitch on the sensor, mm.
    pub pixel_mm: f64,
    /// Image distance of the equivalent pinhole camera, mm.
    pub pinhole_distance_mm: f64,
}

impl PhysicalLensTracer {
    /// A tracer for a focused `lens`.
    pub fn new(lens: Singlet, scene_unit_mm: f64, pixel_mm: f64) -> Self {
        let d = lens.pinhole_distance(crate::optics::spectrum::LAMBDA_DESIGN_NM * 1e-3);
        PhysicalLensTracer {
            lens,
            spectrum: Spectrum::new(),
            scene_unit_mm,
            pixel_mm,
            pinhole_distance_mm: d,
        }
    }
}

impl LightTracer for PhysicalLensTracer {
    fn channels(&self) -> usize {
        3
    }
    fn ray_dims(&self) -> usize {
        3
    }
    fn bounds(&self, params: &ParamBox) -> Bounds {
        pilot_bounds(self, params, 16_384, 0.08, 4.0)
    }
    #[inline]
    fn trace(&self, s: [f64; 2], u: &[f64]) -> Option<Hit> {
        let depth_mm = s[0] * self.scene_unit_mm;
        let ecc_mm = s[1];
        let lambda_nm = Spectrum::wavelength_nm(u[2]);
        let n = self.lens.index(lambda_nm * 1e-3);
        // The object point: at -X, its chief ray crosses the axis at the stop and lands at +e.
        let lateral = ecc_mm * depth_mm / self.pinhole_distance_mm;
        let origin = DVec3::new(-lateral, 0.0, -depth_mm);
        let a = concentric_disk(u[0], u[1]);
        let target = DVec3::new(
            a[0] * self.lens.stop_radius_mm,
            a[1] * self.lens.stop_radius_mm,
            0.0,
        );
        let dir = (target - origin).normalize();
        let p = self.lens.trace_to_sensor(origin, dir, n)?;
        Some(Hit {
            offset: [(p[0] - ecc_mm) / self.pixel_mm, -p[1] / self.pixel_mm],
            weight: self.spectrum.rgb(lambda_nm),
        })
    }
}
