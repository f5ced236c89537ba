//! The camera: the thin-lens model of `camera.json`, a pose that may move linearly over the
//! shutter, ray generation and pinhole projection; or, when `camera.json` names a `lens`, that
//! lens traced from the sensor through every surface ([`PhysicalCamera`]).
//!
//! Conventions (see `docs/STOCHASTIC.md`):
//! - camera space: x right, y down (image rows), z forward along the viewing axis;
//! - pixel coordinates are continuous, (0,0) the top-left corner of the top-left pixel, so
//!   pixel (i, j) has its centre at (i + 0.5, j + 0.5);
//! - the sensor width maps to the image width (horizontal fit), square pixels;
//! - the thin lens follows Blender Cycles, whose `camera.json` fields these are: the field of
//!   view is fixed by the focal length (the image scale is `f / depth` whatever the focus, no
//!   focus breathing), and a lens ray through the aperture point passes through the pinhole
//!   ray's point on the focus plane. The circle of confusion then has diameter
//!   `A f |d - s| / (d s)` on the sensor, `A = f / N` (the textbook thin lens, with its sensor
//!   at `f s / (s - f)`, would magnify by `s / (s - f)` on focusing: 7.7 % on `comets`).

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::error::{invalid, Result};
use crate::sampling::sample_aperture;

/// The lens and shutter of `camera.json`: the one camera type of the project
/// ([`formats::Camera`], with its validation and CoC formula). This renderer works in metres
/// (`scene_unit_mm` 1000).
pub use formats::Camera as CameraSpec;

/// Parses a `camera.json` document; `source_name` names it in error messages.
pub fn camera_from_json(text: &str, source_name: &str) -> Result<CameraSpec> {
    let spec: CameraSpec =
        serde_json::from_str(text).map_err(|source| crate::error::Error::Json {
            source_name: source_name.to_string(),
            source,
        })?;
    validate_spec(&spec, source_name)?;
    Ok(spec)
}

/// The camera's own validation, with `context` naming where it came from; this renderer also
/// needs the scene in metres.
pub fn validate_spec(spec: &CameraSpec, context: &str) -> Result<()> {
    let ctx = format!("{context}: camera");
    spec.validate()
        .map_err(|e| invalid(ctx.clone(), e.to_string()))?;
    if spec.scene_unit_mm != 1000.0 {
        return Err(invalid(
            ctx,
            "the scene renderer works in metres: scene_unit_mm must be 1000",
        ));
    }
    Ok(())
}

/// Aperture radius in metres, `f / (2 N)`; 0 for a pinhole.
fn aperture_radius_m(spec: &CameraSpec) -> f64 {
    match (spec.f_stop, spec.focus_distance) {
        (Some(n), Some(_)) => spec.focal_length_mm * 1e-3 / (2.0 * n),
        _ => 0.0,
    }
}

/// Where the camera is and how it moves: it looks from `position` towards `look_at` and
/// translates by `velocity` metres per frame (no rotation).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraPose {
    /// Lens centre at the frame time (t = 0), metres.
    pub position: DVec3,
    /// A point on the viewing axis, metres.
    pub look_at: DVec3,
    /// World up direction (default +y).
    #[serde(default = "default_up")]
    pub up: DVec3,
    /// Linear velocity of the camera in metres per frame.
    #[serde(default)]
    pub velocity: DVec3,
}

fn default_up() -> DVec3 {
    DVec3::Y
}

/// A ray in world space; `direction` is unit length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point, metres.
    pub origin: DVec3,
    /// Unit direction.
    pub direction: DVec3,
    /// Time in frames relative to the frame time.
    pub time: f64,
}

/// A ready-to-use camera: lens, shutter and an orthonormal frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// The lens and shutter.
    pub spec: CameraSpec,
    /// The pose as given.
    pub pose: CameraPose,
    right: DVec3,
    down: DVec3,
    forward: DVec3,
    /// The user-drawn aperture of `spec.aperture_image`, read once.
    mask: Option<std::sync::Arc<formats::MaskSampler>>,
    /// The lens `spec.lens` names, focused; `None`: the thin lens.
    physical: Option<std::sync::Arc<PhysicalCamera>>,
}

/// Sensor-radius bins of a physical camera's exit pupil bounds.
const EXIT_PUPIL_BINS: usize = 64;
/// Lattice edge of the exit pupil bounds' search, rays.
const EXIT_PUPIL_GRID: usize = 48;

/// A camera through a real lens, traced as pbrt's realistic camera: a ray starts at a point
/// of the sensor, aims at a point of the box that holds every ray passing the lens from that
/// sensor radius (the exit pupil bounds, found once), and is refracted through every surface
/// at its wavelength, blocked by every clear aperture. The equivalent pinhole (for G-buffers
/// and projection) sits at the entrance pupil's centre with the lens's pinhole distance, so
/// depths are measured from the entrance pupil, as the `physical-lens` PSFs are.
#[derive(Debug, PartialEq)]
pub struct PhysicalCamera {
    /// The focused lens, lens coordinates in mm (light towards +z).
    pub system: optics::LensSystem,
    /// Image distance of the equivalent pinhole at the focus distance, mm.
    pub pinhole_distance_mm: f64,
    /// Axial position of the entrance pupil's centre, mm (lens coordinates).
    pub pupil_z_mm: f64,
    /// Exit pupil bounds on the last surface's vertex plane, per sensor radius.
    pub exit_pupil: optics::PupilBounds,
    /// Wavelength to RGB.
    pub spectrum: optics::Spectrum,
}

impl PhysicalCamera {
    /// The lens of `spec` (which names one), stopped down and focused as `spec` says.
    pub fn new(spec: &CameraSpec, context: &str) -> Result<Option<Self>> {
        let ctx = || format!("{context}: camera lens");
        let Some(prescription) = spec
            .prescription()
            .map_err(|e| invalid(ctx(), e.to_string()))?
        else {
            return Ok(None);
        };
        let mm = spec.scene_unit_mm;
        let focus_mm = spec.focus_distance.unwrap_or(1.0) * mm;
        let system = optics::LensSystem::focused(prescription, spec.f_stop, focus_mm)
            .map_err(|e| invalid(ctx(), e.to_string()))?;
        let design = optics::system::LAMBDA_DESIGN_UM;
        let pinhole_distance_mm = system.pinhole_distance(focus_mm, design);
        let (pupil_z_mm, _) = system
            .entrance_pupil(design)
            .map_err(|e| invalid(ctx(), e.to_string()))?;
        if !(pinhole_distance_mm.is_finite() && pinhole_distance_mm > 0.0) {
            return Err(invalid(ctx(), "the chief ray does not reach the sensor"));
        }
        let mm_per_px = spec.sensor_width_mm / f64::from(spec.width);
        let half_diagonal_mm =
            0.5 * f64::from(spec.width).hypot(f64::from(spec.height)) * mm_per_px;
        let sensor_z = system.sensor_z_mm;
        let exit_pupil = optics::PupilBounds::build(
            &system,
            EXIT_PUPIL_BINS,
            half_diagonal_mm * 1.01,
            system.rear_vertex_z(),
            1.5 * system.rear_aperture_radius(),
            EXIT_PUPIL_GRID,
            &|r| vec![DVec3::new(r, 0.0, sensor_z)],
        );
        Ok(Some(PhysicalCamera {
            system,
            pinhole_distance_mm,
            pupil_z_mm,
            exit_pupil,
            spectrum: optics::Spectrum::new(),
        }))
    }

    /// A ray from sensor point `sensor_mm` (lens coordinates) through the lens at
    /// `lambda_nm`, aimed by two uniform numbers `xi` at the exit pupil bounds: the ray leaving
    /// the front towards the scene and the area of the box sampled (mm^2, the ray's weight), or
    /// `None` when the lens blocks it.
    pub fn trace(
        &self,
        sensor_mm: DVec2,
        xi: DVec2,
        lambda_nm: f64,
    ) -> Option<(optics::LensRay, f64)> {
        let r = sensor_mm.length();
        let b = self.exit_pupil.at(r)?;
        let (c, s) = if r > 0.0 {
            (sensor_mm.x / r, sensor_mm.y / r)
        } else {
            (1.0, 0.0)
        };
        let u = b[0] + xi.x * (b[1] - b[0]);
        let v = b[2] + xi.y * (b[3] - b[2]);
        let target = DVec3::new(c * u - s * v, s * u + c * v, self.exit_pupil.plane_z);
        let origin = DVec3::new(sensor_mm.x, sensor_mm.y, self.system.sensor_z_mm);
        let ray =
            self.system
                .trace_backward(origin, (target - origin).normalize(), lambda_nm * 1e-3)?;
        Some((ray, (b[1] - b[0]) * (b[3] - b[2])))
    }
}

impl Camera {
    /// Builds the camera frame; fails if the pose is degenerate.
    pub fn new(spec: CameraSpec, pose: CameraPose, context: &str) -> Result<Self> {
        validate_spec(&spec, context)?;
        let ctx = format!("{context}: camera pose");
        let finite = pose.position.is_finite()
            && pose.look_at.is_finite()
            && pose.up.is_finite()
            && pose.velocity.is_finite();
        if !finite {
            return Err(invalid(
                ctx,
                "position, look_at, up and velocity must be finite",
            ));
        }
        let forward = (pose.look_at - pose.position).normalize_or_zero();
        if forward == DVec3::ZERO {
            return Err(invalid(ctx, "look_at must differ from position"));
        }
        let right = forward.cross(pose.up).normalize_or_zero();
        if right == DVec3::ZERO {
            return Err(invalid(
                ctx,
                "up must not be parallel to the viewing direction",
            ));
        }
        let down = forward.cross(right);
        let mask = spec
            .aperture_mask()
            .map_err(|e| invalid(format!("{context}: camera"), e.to_string()))?
            .map(|m| std::sync::Arc::new(formats::MaskSampler::new(m)));
        let physical = PhysicalCamera::new(&spec, context)?.map(std::sync::Arc::new);
        Ok(Self {
            spec,
            pose,
            right,
            down,
            forward,
            mask,
            physical,
        })
    }

    /// Unit vector along the viewing axis (world space).
    pub fn forward(&self) -> DVec3 {
        self.forward
    }

    /// Unit vector pointing right in the image (world space).
    pub fn right(&self) -> DVec3 {
        self.right
    }

    /// Unit vector pointing down in the image (world space).
    pub fn down(&self) -> DVec3 {
        self.down
    }

    /// Lens centre at time `time` (frames), metres.
    pub fn position_at(&self, time: f64) -> DVec3 {
        self.pose.position + self.pose.velocity * time
    }

    /// The real lens `camera.json` names, focused; `None` for the thin lens.
    pub fn physical(&self) -> Option<&PhysicalCamera> {
        self.physical.as_deref()
    }

    /// Image scale in pixels per unit of `x / z` in camera space.
    fn scale_px(&self) -> f64 {
        match &self.physical {
            // A real lens: its equivalent pinhole at the entrance pupil (focus breathes).
            Some(p) => p.pinhole_distance_mm * self.spec.pixels_per_mm(),
            // Blender's convention: the projection distance is the focal length, focused or not.
            None => self.spec.focal_length_mm * self.spec.pixels_per_mm(),
        }
    }

    /// A ray through the real lens from continuous pixel position `pixel` at `time`, aimed by
    /// `xi` at the exit pupil, at wavelength `lambda_nm`: the world ray and its weight (the
    /// area of the exit pupil box sampled, mm^2), or `None` when the lens blocks it or the
    /// camera has no real lens.
    pub fn physical_ray(
        &self,
        pixel: DVec2,
        xi: DVec2,
        lambda_nm: f64,
        time: f64,
    ) -> Option<(Ray, f64)> {
        let p = self.physical.as_deref()?;
        let half = DVec2::new(
            0.5 * f64::from(self.spec.width),
            0.5 * f64::from(self.spec.height),
        );
        // The lens turns the image by half a turn: pixel offset +d is sensor point -d.
        let sensor_mm = -(pixel - half) / self.spec.pixels_per_mm();
        let (ray, weight) = p.trace(sensor_mm, xi, lambda_nm)?;
        // Lens coordinates (x, y, z towards the sensor) to camera space (x right, y down,
        // z forward from the entrance pupil).
        let origin_cam = DVec3::new(ray.origin.x, ray.origin.y, p.pupil_z_mm - ray.origin.z);
        let dir_cam = DVec3::new(ray.dir.x, ray.dir.y, -ray.dir.z);
        let to_world = |v: DVec3| self.right * v.x + self.down * v.y + self.forward * v.z;
        let mm = self.spec.scene_unit_mm;
        Some((
            Ray {
                origin: self.position_at(time) + to_world(origin_cam / mm),
                direction: to_world(dir_cam).normalize(),
                time,
            },
            weight,
        ))
    }

    /// The ray through continuous pixel position `pixel` (pixels), lens point `lens` (unit
    /// disk or blade polygon, u right, v down) at `time` (frames).
    pub fn ray(&self, pixel: DVec2, lens: DVec2, time: f64) -> Ray {
        let scale = self.scale_px();
        let half = DVec2::new(
            0.5 * f64::from(self.spec.width),
            0.5 * f64::from(self.spec.height),
        );
        let slope = (pixel - half) / scale;
        let centre = self.position_at(time);
        // Camera-space direction of the pinhole ray (z = 1).
        let pinhole = DVec3::new(slope.x, slope.y, 1.0);
        let (origin_cam, dir_cam) = match self.spec.focus_distance {
            Some(s) if self.spec.has_lens() => {
                let focus_point = pinhole * s;
                let lens_point = DVec3::new(lens.x, lens.y, 0.0) * aperture_radius_m(&self.spec);
                (lens_point, focus_point - lens_point)
            }
            _ => (DVec3::ZERO, pinhole),
        };
        let to_world = |v: DVec3| self.right * v.x + self.down * v.y + self.forward * v.z;
        Ray {
            origin: centre + to_world(origin_cam),
            direction: to_world(dir_cam).normalize(),
            time,
        }
    }

    /// A ray with a lens sample drawn from two uniform numbers in [0, 1) (see
    /// [`sample_aperture`]); returns the ray and the lens point used.
    pub fn ray_with_lens_sample(&self, pixel: DVec2, xi: DVec2, time: f64) -> (Ray, DVec2) {
        let lens = if !self.spec.has_lens() {
            DVec2::ZERO
        } else {
            // A drawn aperture replaces the blades; the anamorphic squeeze comes after the
            // rotation, as Cycles does.
            let p = match &self.mask {
                Some(mask) => {
                    let [x, y] = mask.sample(xi.x, xi.y);
                    DVec2::new(x, y)
                }
                None => sample_aperture(
                    self.spec.aperture_blades,
                    self.spec.aperture_rotation_rad(),
                    xi,
                ),
            };
            DVec2::new(p.x / self.spec.aperture_ratio, p.y)
        };
        (self.ray(pixel, lens, time), lens)
    }

    /// Planar depth of world point `p` seen by the camera at `time`: distance along the axis.
    pub fn planar_depth(&self, p: DVec3, time: f64) -> f64 {
        (p - self.position_at(time)).dot(self.forward)
    }

    /// Pinhole (lens-centre) image position of world point `p` at `time`, in continuous pixel
    /// coordinates; `None` if the point is not in front of the lens.
    pub fn project(&self, p: DVec3, time: f64) -> Option<DVec2> {
        let rel = p - self.position_at(time);
        let z = rel.dot(self.forward);
        if z <= 1e-9 {
            return None;
        }
        let scale = self.scale_px();
        Some(DVec2::new(
            0.5 * f64::from(self.spec.width) + scale * rel.dot(self.right) / z,
            0.5 * f64::from(self.spec.height) + scale * rel.dot(self.down) / z,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> CameraSpec {
        CameraSpec {
            width: 200,
            height: 100,
            focal_length_mm: 50.0,
            sensor_width_mm: 36.0,
            f_stop: Some(2.0),
            focus_distance: Some(1.0),
            aperture_blades: 0,
            aperture_rotation_deg: 0.0,
            aperture_ratio: 1.0,
            aperture_image: None,
            lens: None,
            shutter_frames: 0.5,
            scene_unit_mm: 1000.0,
        }
    }

    fn pose() -> CameraPose {
        CameraPose {
            position: DVec3::new(0.0, 0.0, 0.0),
            look_at: DVec3::new(0.0, 0.0, -1.0),
            up: DVec3::Y,
            velocity: DVec3::ZERO,
        }
    }

    #[test]
    fn parses_camera_json_ignoring_unknown_fields() {
        let text = r#"{"scene":"comets","width":512,"height":512,"focal_length_mm":50.0,
            "sensor_width_mm":36.0,"f_stop":1.6,"focus_distance":0.7,"aperture_blades":0,
            "shutter_frames":1.0,"reference_spp":2048,"renderer":"x"}"#;
        let spec = camera_from_json(text, "camera.json").expect("valid camera");
        assert_eq!(spec.width, 512);
        assert_eq!(spec.f_stop, Some(1.6));
        assert!(spec.has_lens());
        let pinhole = r#"{"width":8,"height":8,"focal_length_mm":50,"sensor_width_mm":36,
            "f_stop":null,"focus_distance":null,"aperture_blades":0,"shutter_frames":0}"#;
        assert!(!camera_from_json(pinhole, "p").expect("pinhole").has_lens());
        let bad = r#"{"width":0,"height":8,"focal_length_mm":50,"sensor_width_mm":36}"#;
        let err = camera_from_json(bad, "bad.json").expect_err("zero width");
        assert!(err.to_string().contains("width"), "{err}");
    }

    #[test]
    fn coc_matches_textbook_formula() {
        let s = spec();
        let (f, n, focus): (f64, f64, f64) = (0.05, 2.0, 1.0);
        let a = f / n;
        for d in [0.3, 0.8, 1.0, 2.5, 40.0] {
            let diameter_m = a * f * (d - focus).abs() / (d * focus);
            let expected = 0.5 * diameter_m * 1e3 * 200.0 / 36.0;
            let coc = s.thin_lens().expect("lens").coc_px(d);
            assert!((coc - expected).abs() < 1e-9 * expected.max(1.0));
        }
    }

    #[test]
    fn lens_ray_lands_at_pinhole_plus_signed_coc() {
        let cam = Camera::new(spec(), pose(), "test").expect("camera");
        // A point at depth 3 m slightly off axis.
        let p = DVec3::new(0.1, 0.05, -3.0);
        let pin = cam.project(p, 0.0).expect("in front");
        let r = cam.spec.thin_lens().expect("lens").signed_coc_px(3.0);
        let lens = DVec2::new(0.6, -0.3);
        // The ray through pixel pin + r * lens with that lens point must pass through p.
        let ray = cam.ray(pin + r * lens, lens, 0.0);
        let to_p = p - ray.origin;
        let miss = (to_p - ray.direction * to_p.dot(ray.direction)).length();
        assert!(miss < 1e-9, "ray misses the point by {miss} m");
    }

    #[test]
    fn projection_inverts_pinhole_rays() {
        let mut s = spec();
        s.f_stop = None;
        let cam = Camera::new(s, pose(), "test").expect("camera");
        let pixel = DVec2::new(37.25, 80.5);
        let ray = cam.ray(pixel, DVec2::ZERO, 0.0);
        let p = ray.origin + ray.direction * 2.0;
        let back = cam.project(p, 0.0).expect("in front");
        assert!((back - pixel).length() < 1e-9);
    }
}
