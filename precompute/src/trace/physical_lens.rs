//! The physical-lens PSF: light from a point at inverse depth `s[0]` (1 / scene units, depth
//! from the entrance pupil: the blur grows linearly in it)
//! whose pinhole image lies `eccentricity` mm from the sensor centre along +x, traced through
//! the lens prescription at wavelengths over 400-700 nm and accumulated into linear RGB.
//!
//! Orientation: the image is the sensor turned by 180 degrees, and the lens is rotationally
//! symmetric, so the PSF of an image point at +e (radially outwards = +x) is the sensor PSF of
//! the sensor point at +e, mirrored in y (image y points down). The equivalent pinhole camera
//! sits at the entrance pupil's centre with image distance `D`
//! ([`optics::LensSystem::pinhole_distance`]), so the point is placed at lateral
//! `X = e * depth / D` and the PSF origin is its pinhole image `e`: chromatic shifts,
//! distortion and cat-eye vignetting all show in the PSF.
//!
//! Rays start at the object point and aim at the entrance pupil's plane: uniformly over the
//! stop when the stop is the first surface (it is then the entrance pupil, exactly); else
//! uniformly over the box, per eccentricity, that holds every ray passing the lens
//! ([`optics::PupilBounds`], found once when the tracer is made), each ray weighted by its
//! box's area so that the light a point sends stays proportional to the pupil it sees.

use glam::DVec3;
use optics::{LensSystem, PupilBounds, Spectrum};

use super::{pilot_bounds, Bounds, Hit, LightTracer};
use crate::aperture::concentric_disk;
use crate::prefilter::ParamBox;

/// Eccentricity bins of the pupil bounds.
const PUPIL_BINS: usize = 48;
/// Lattice edge of the pupil bounds' search, rays.
const PUPIL_GRID: usize = 40;

/// Light tracer of the `physical-lens` model; `s = [inverse depth (1 / scene units),
/// eccentricity (mm)]`.
#[derive(Clone, Debug)]
pub struct PhysicalLensTracer {
    /// The focused lens.
    pub lens: LensSystem,
    /// Channel sensitivities.
    pub spectrum: Spectrum,
    /// Millimetres per scene unit.
    pub scene_unit_mm: f64,
    /// Pixel pitch on the sensor, mm.
    pub pixel_mm: f64,
    /// Image distance of the equivalent pinhole camera, mm.
    pub pinhole_distance_mm: f64,
    /// Axial position of the entrance pupil's centre, mm (lens coordinates).
    pub pupil_z_mm: f64,
    /// Radius of the entrance pupil, mm (paraxial).
    pub pupil_radius_mm: f64,
    /// Where passing rays cross the pupil plane, per eccentricity; `None` when the stop is
    /// the first surface (its disk is sampled).
    pub pupil: Option<PupilBounds>,
}

impl PhysicalLensTracer {
    /// A tracer for a focused `lens`, for objects `depth_range_mm` (mm from the entrance
    /// pupil) and eccentricities up to `max_eccentricity_mm`, the pinhole distance taken at
    /// `focus_distance_mm`.
    pub fn new(
        lens: LensSystem,
        scene_unit_mm: f64,
        pixel_mm: f64,
        focus_distance_mm: f64,
        depth_range_mm: [f64; 2],
        max_eccentricity_mm: f64,
    ) -> Result<Self, optics::PrescriptionError> {
        let design = optics::system::LAMBDA_DESIGN_UM;
        let d = lens.pinhole_distance(focus_distance_mm, design);
        let (pupil_z_mm, pupil_radius_mm) = lens.entrance_pupil(design)?;
        let pupil = (lens.prescription.stop_index() != 0).then(|| {
            let [near, far] = depth_range_mm;
            let depths = [near, (near * far).sqrt(), focus_distance_mm, far];
            let front = 0.5 * lens.prescription.surfaces[0].aperture_diameter_mm;
            let half = (3.0 * pupil_radius_mm).max(front);
            PupilBounds::build(
                &lens,
                PUPIL_BINS,
                max_eccentricity_mm,
                pupil_z_mm,
                half,
                PUPIL_GRID,
                &|e| {
                    depths
                        .iter()
                        .map(|&z| DVec3::new(-e * z / d, 0.0, pupil_z_mm - z))
                        .collect()
                },
            )
        });
        Ok(PhysicalLensTracer {
            lens,
            spectrum: Spectrum::new(),
            scene_unit_mm,
            pixel_mm,
            pinhole_distance_mm: d,
            pupil_z_mm,
            pupil_radius_mm,
            pupil,
        })
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
        let depth_mm = self.scene_unit_mm / s[0];
        let ecc_mm = s[1];
        let lambda_nm = Spectrum::wavelength_nm(u[2]);
        // The object point: at -X, its chief ray crosses the axis at the pupil and lands at +e.
        let lateral = ecc_mm * depth_mm / self.pinhole_distance_mm;
        let origin = DVec3::new(-lateral, 0.0, self.pupil_z_mm - depth_mm);
        let (target, area) = match &self.pupil {
            None => {
                let a = concentric_disk(u[0], u[1]);
                let r = self.pupil_radius_mm;
                (DVec3::new(a[0] * r, a[1] * r, self.pupil_z_mm), 1.0)
            }
            Some(bounds) => {
                let b = bounds.at(ecc_mm)?;
                let x = b[0] + u[0] * (b[1] - b[0]);
                let y = b[2] + u[1] * (b[3] - b[2]);
                let r = self.pupil_radius_mm;
                let area = (b[1] - b[0]) * (b[3] - b[2]) / (std::f64::consts::PI * r * r);
                (DVec3::new(x, y, self.pupil_z_mm), area)
            }
        };
        let dir = (target - origin).normalize();
        let p = self.lens.trace_to_sensor(origin, dir, lambda_nm * 1e-3)?;
        let w = self.spectrum.rgb(lambda_nm);
        Some(Hit {
            offset: [(p[0] - ecc_mm) / self.pixel_mm, -p[1] / self.pixel_mm],
            weight: [w[0] * area, w[1] * area, w[2] * area],
        })
    }
}
