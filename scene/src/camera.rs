//! The camera: the thin-lens model of `camera.json`, a pose that may move linearly over the
//! shutter, ray generation and pinhole projection.
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

/// Largest accepted image edge in pixels (guards against unbounded allocations).
pub const MAX_IMAGE_EDGE: u32 = 16384;

/// The lens and shutter exactly as `camera.json` gives them (unknown fields are ignored).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraSpec {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length f in millimetres.
    pub focal_length_mm: f64,
    /// Sensor width in millimetres; it maps to the image width.
    pub sensor_width_mm: f64,
    /// Aperture as an f-number N (aperture diameter f / N); `None` for a pinhole.
    #[serde(default)]
    pub f_stop: Option<f64>,
    /// Focus distance s in scene units (metres), planar like depth; `None` for a pinhole.
    #[serde(default)]
    pub focus_distance: Option<f64>,
    /// Number of aperture blades; 0 (or fewer than 3) for a circular aperture.
    #[serde(default)]
    pub aperture_blades: u32,
    /// Exposure as a fraction of the frame interval, centred on the frame time; 0 = no blur.
    #[serde(default)]
    pub shutter_frames: f64,
}

impl CameraSpec {
    /// Parses a `camera.json` document; `source_name` names it in error messages.
    pub fn from_json(text: &str, source_name: &str) -> Result<Self> {
        let spec: CameraSpec =
            serde_json::from_str(text).map_err(|source| crate::error::Error::Json {
                source_name: source_name.to_string(),
                source,
            })?;
        spec.validate(source_name)?;
        Ok(spec)
    }

    /// Checks that every field is usable; `context` prefixes the error message.
    pub fn validate(&self, context: &str) -> Result<()> {
        let ctx = format!("{context}: camera");
        if self.width == 0 || self.height == 0 {
            return Err(invalid(ctx, "width and height must be at least 1 pixel"));
        }
        if self.width > MAX_IMAGE_EDGE || self.height > MAX_IMAGE_EDGE {
            return Err(invalid(
                ctx,
                format!("width and height must be at most {MAX_IMAGE_EDGE} pixels"),
            ));
        }
        if !(self.focal_length_mm.is_finite() && self.focal_length_mm > 0.0) {
            return Err(invalid(ctx, "focal_length_mm must be a positive number"));
        }
        if !(self.sensor_width_mm.is_finite() && self.sensor_width_mm > 0.0) {
            return Err(invalid(ctx, "sensor_width_mm must be a positive number"));
        }
        if let Some(n) = self.f_stop {
            if !(n.is_finite() && n > 0.0) {
                return Err(invalid(ctx, "f_stop must be a positive number or null"));
            }
        }
        if let Some(s) = self.focus_distance {
            if !(s.is_finite() && s > self.focal_length_mm * 1e-3) {
                return Err(invalid(
                    ctx,
                    "focus_distance must be longer than the focal length (metres) or null",
                ));
            }
        }
        if !(self.shutter_frames.is_finite() && (0.0..=16.0).contains(&self.shutter_frames)) {
            return Err(invalid(ctx, "shutter_frames must lie in [0, 16]"));
        }
        if self.aperture_blades > 64 {
            return Err(invalid(ctx, "aperture_blades must be at most 64"));
        }
        Ok(())
    }

    /// True when the camera has no lens (no `f_stop` or no `focus_distance`).
    pub fn is_pinhole(&self) -> bool {
        self.f_stop.is_none() || self.focus_distance.is_none()
    }

    /// Pixels per millimetre on the sensor (`width / sensor_width_mm`).
    pub fn pixels_per_mm(&self) -> f64 {
        f64::from(self.width) / self.sensor_width_mm
    }

    /// Projection distance in millimetres: the focal length, focused or not (Blender's
    /// convention: the field of view does not change with focus).
    pub fn image_distance_mm(&self) -> f64 {
        self.focal_length_mm
    }

    /// Aperture radius in metres, `f / (2 N)`; 0 for a pinhole.
    pub fn aperture_radius_m(&self) -> f64 {
        match (self.f_stop, self.focus_distance) {
            (Some(n), Some(_)) => self.focal_length_mm * 1e-3 / (2.0 * n),
            _ => 0.0,
        }
    }

    /// Signed circle-of-confusion radius in pixels at planar depth `depth` (metres).
    ///
    /// A ray through the lens point `(u, v)` (unit disk, u right, v down) from a point at
    /// `depth` lands at its pinhole position plus `signed_coc_radius_px(depth) * (u, v)`:
    /// positive behind the focus plane, negative in front of it, 0 for a pinhole.
    pub fn signed_coc_radius_px(&self, depth: f64) -> f64 {
        match self.focus_distance {
            Some(s) if !self.is_pinhole() => {
                self.image_distance_mm()
                    * self.aperture_radius_m()
                    * (1.0 / s - 1.0 / depth)
                    * self.pixels_per_mm()
            }
            _ => 0.0,
        }
    }

    /// Circle-of-confusion radius in pixels at planar depth `depth` (metres):
    /// half of `A f |d - s| / (d s)` converted with `width / sensor_width_mm`.
    pub fn coc_radius_px(&self, depth: f64) -> f64 {
        self.signed_coc_radius_px(depth).abs()
    }

    /// Half the shutter interval in frames.
    pub fn half_shutter(&self) -> f64 {
        0.5 * self.shutter_frames
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
}

impl Camera {
    /// Builds the camera frame; fails if the pose is degenerate.
    pub fn new(spec: CameraSpec, pose: CameraPose, context: &str) -> Result<Self> {
        spec.validate(context)?;
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
        Ok(Self {
            spec,
            pose,
            right,
            down,
            forward,
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

    /// Image scale in pixels per unit of `x / z` in camera space.
    fn scale_px(&self) -> f64 {
        self.spec.image_distance_mm() * self.spec.pixels_per_mm()
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
            Some(s) if !self.spec.is_pinhole() => {
                let focus_point = pinhole * s;
                let lens_point = DVec3::new(lens.x, lens.y, 0.0) * self.spec.aperture_radius_m();
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
        let lens = if self.spec.is_pinhole() {
            DVec2::ZERO
        } else {
            sample_aperture(self.spec.aperture_blades, xi)
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
            shutter_frames: 0.5,
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
        let spec = CameraSpec::from_json(text, "camera.json").expect("valid camera");
        assert_eq!(spec.width, 512);
        assert_eq!(spec.f_stop, Some(1.6));
        assert!(!spec.is_pinhole());
        let pinhole = r#"{"width":8,"height":8,"focal_length_mm":50,"sensor_width_mm":36,
            "f_stop":null,"focus_distance":null,"aperture_blades":0,"shutter_frames":0}"#;
        assert!(CameraSpec::from_json(pinhole, "p")
            .expect("pinhole")
            .is_pinhole());
        let bad = r#"{"width":0,"height":8,"focal_length_mm":50,"sensor_width_mm":36}"#;
        let err = CameraSpec::from_json(bad, "bad.json").expect_err("zero width");
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
            assert!((s.coc_radius_px(d) - expected).abs() < 1e-9 * expected.max(1.0));
        }
    }

    #[test]
    fn lens_ray_lands_at_pinhole_plus_signed_coc() {
        let cam = Camera::new(spec(), pose(), "test").expect("camera");
        // A point at depth 3 m slightly off axis.
        let p = DVec3::new(0.1, 0.05, -3.0);
        let pin = cam.project(p, 0.0).expect("in front");
        let r = cam.spec.signed_coc_radius_px(3.0);
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
