//! The camera: lens and shutter as a user types them into a 3D package (`camera.json`, or the
//! same names as command-line flags), validated, and the thin-lens circle of confusion.
//!
//! Units: `focal_length_mm` and `sensor_width_mm` in millimetres, `focus_distance` and depths in
//! scene units (planar, along the viewing axis), `scene_unit_mm` millimetres per scene unit
//! (1000 for metres, the default), CoC radii in output pixels, `shutter_frames` a fraction of
//! the frame interval centred on the frame's time.

use serde::{Deserialize, Serialize};
use std::path::Path;

pub use crate::limits::MAX_IMAGE_EDGE;

/// Errors of camera parsing and validation.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The file could not be read.
    #[error("cannot read camera file {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The JSON is malformed or a field has the wrong type or is missing.
    #[error("camera file {path} is not valid camera JSON: {source}")]
    Json {
        /// The file.
        path: String,
        /// The cause.
        source: serde_json::Error,
    },
    /// A field's value cannot describe a real camera.
    #[error("camera: {0}")]
    Invalid(String),
    /// Camera JSON text (not from a file) is malformed or lacks a field.
    #[error("not valid camera JSON: {source}")]
    Text {
        /// The cause.
        source: serde_json::Error,
    },
    /// A field has a value of the wrong type (a string for a number, a negative size...).
    #[error("camera field `{field}`: {message}")]
    Field {
        /// The field.
        field: &'static str,
        /// What is wrong, in serde's words.
        message: String,
    },
}

/// Largest accepted CoC radius at infinite depth, pixels: beyond it the parameters (a tiny
/// f-number, a tiny sensor) describe no camera, and the CoC arithmetic would overflow.
pub const MAX_COC_SCALE_PX: f64 = 1e9;

/// Checks one field of camera JSON by deserialising it alone as `T`.
fn check_field<T: serde::de::DeserializeOwned>(
    obj: &serde_json::Map<String, serde_json::Value>,
    field: &'static str,
) -> Result<(), CameraError> {
    match obj.get(field) {
        Some(v) => serde_json::from_value::<T>(v.clone())
            .map(|_| ())
            .map_err(|e| CameraError::Field {
                field,
                message: e.to_string(),
            }),
        None => Ok(()),
    }
}

/// A camera as in `camera.json` (see `shared/examples/README.md`). Unknown fields are ignored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Output width, pixels.
    pub width: u32,
    /// Output height, pixels.
    pub height: u32,
    /// Focal length, millimetres.
    pub focal_length_mm: f64,
    /// Sensor width, millimetres; maps onto the image width (horizontal sensor fit).
    pub sensor_width_mm: f64,
    /// Aperture as an f-number (diameter = focal length / f-stop); `None` for a pinhole.
    #[serde(default)]
    pub f_stop: Option<f64>,
    /// Focus distance in scene units, planar; `None` for a pinhole.
    #[serde(default)]
    pub focus_distance: Option<f64>,
    /// Number of aperture blades; 0 for a circular aperture.
    #[serde(default)]
    pub aperture_blades: u32,
    /// Rotation of the blade polygon, degrees, counter-clockwise as seen on the image; at 0 a
    /// vertex points right (+x). Ignored for a circular aperture.
    #[serde(default)]
    pub aperture_rotation_deg: f64,
    /// Anamorphic squeeze, as Blender's camera `aperture_ratio`: the aperture's width is
    /// divided by it after the blade rotation, so 2 gives bokeh twice as tall as wide; 1 (the
    /// default) is round. At least 1 (wider than round bokeh is not supported yet).
    #[serde(default = "default_aperture_ratio")]
    pub aperture_ratio: f64,
    /// A user-drawn aperture: a greyscale PNG whose brightness is the lens' transmission
    /// ([`crate::ApertureMask`]; the blades are then ignored, the ratio still squeezes it).
    /// A relative path is relative to the `camera.json` it is written in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aperture_image: Option<std::path::PathBuf>,
    /// A real lens: a built-in prescription's name (`singlet-51mm`, `double-gauss-50mm`,
    /// `wide-angle-22mm`) or a prescription file ([`optics::Prescription`]: JSON or pbrt's
    /// table), relative to the `camera.json` it is written in. Defocus is then traced through
    /// its glass (chromatic aberration, cat-eye vignetting) with the `physical-lens` model;
    /// `f_stop` stops it down, `focus_distance` focuses it (from its entrance pupil, where the
    /// pinhole G-buffer's camera sits), and `focal_length_mm` stays the thin-lens
    /// approximation's. `None`: the thin lens.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lens: Option<String>,
    /// Exposure as a fraction of the frame interval, centred on the frame; 0 = no motion blur.
    #[serde(default)]
    pub shutter_frames: f64,
    /// Millimetres per scene unit (1000 when the scene is in metres, the default).
    #[serde(default = "default_scene_unit_mm")]
    pub scene_unit_mm: f64,
}

fn default_aperture_ratio() -> f64 {
    1.0
}

/// Largest anamorphic squeeze a camera may ask for.
pub const MAX_APERTURE_RATIO: f64 = 16.0;

fn default_scene_unit_mm() -> f64 {
    1000.0
}

impl Camera {
    /// Reads and validates a `camera.json`.
    pub fn from_json_file(path: &Path) -> Result<Self, CameraError> {
        let text = std::fs::read_to_string(path).map_err(|source| CameraError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let mut camera = Self::from_json_str(&text).map_err(|e| match e {
            CameraError::Json { source, .. } | CameraError::Text { source } => CameraError::Json {
                path: path.display().to_string(),
                source,
            },
            other => other,
        })?;
        if let (Some(image), Some(dir)) = (&camera.aperture_image, path.parent()) {
            if image.is_relative() {
                camera.aperture_image = Some(dir.join(image));
            }
        }
        if let Some(dir) = path.parent() {
            camera.resolve_lens_from(dir);
        }
        Ok(camera)
    }

    /// The camera's aperture image, read ([`crate::ApertureMask::read_png`]); `None` without
    /// one.
    pub fn aperture_mask(&self) -> Result<Option<crate::ApertureMask>, crate::MaskError> {
        self.aperture_image
            .as_deref()
            .map(crate::ApertureMask::read_png)
            .transpose()
    }

    /// Takes a `lens` that names a prescription file by a relative path as relative to `dir`
    /// (the folder of the file that names it); built-in lens names and absolute paths stay.
    pub fn resolve_lens_from(&mut self, dir: &Path) {
        if let Some(lens) = &self.lens {
            let file = Path::new(lens);
            if optics::Prescription::builtin(lens).is_none() && file.is_relative() {
                self.lens = Some(dir.join(file).display().to_string());
            }
        }
    }

    /// The camera's lens prescription, read ([`optics::Prescription::resolve`]); `None` for
    /// the thin lens.
    pub fn prescription(&self) -> Result<Option<optics::Prescription>, optics::PrescriptionError> {
        self.lens
            .as_deref()
            .map(|l| optics::Prescription::resolve(l, None))
            .transpose()
    }

    /// Parses and validates camera JSON text. A field of the wrong type is named
    /// ([`CameraError::Field`]).
    pub fn from_json_str(text: &str) -> Result<Self, CameraError> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|source| CameraError::Text { source })?;
        let Some(obj) = value.as_object() else {
            return Err(CameraError::Invalid(format!(
                "the camera must be a JSON object with named fields, got {}",
                match &value {
                    serde_json::Value::Array(_) => "an array",
                    serde_json::Value::String(_) => "a string",
                    serde_json::Value::Number(_) => "a number",
                    serde_json::Value::Bool(_) => "a boolean",
                    _ => "null",
                }
            )));
        };
        let camera: Camera = match serde_json::from_value(value.clone()) {
            Ok(c) => c,
            Err(source) => {
                // serde's message does not say which field has the wrong type: find it.
                check_field::<u32>(obj, "width")?;
                check_field::<u32>(obj, "height")?;
                check_field::<f64>(obj, "focal_length_mm")?;
                check_field::<f64>(obj, "sensor_width_mm")?;
                check_field::<Option<f64>>(obj, "f_stop")?;
                check_field::<Option<f64>>(obj, "focus_distance")?;
                check_field::<u32>(obj, "aperture_blades")?;
                check_field::<f64>(obj, "aperture_rotation_deg")?;
                check_field::<f64>(obj, "aperture_ratio")?;
                check_field::<f64>(obj, "shutter_frames")?;
                check_field::<f64>(obj, "scene_unit_mm")?;
                check_field::<Option<String>>(obj, "lens")?;
                return Err(CameraError::Text { source });
            }
        };
        camera.validate()?;
        Ok(camera)
    }

    /// Checks that the camera can exist; the message names the field.
    pub fn validate(&self) -> Result<(), CameraError> {
        let bad = |m: String| Err(CameraError::Invalid(m));
        if self.width == 0 || self.height == 0 {
            return bad(format!(
                "image size {}x{} is empty: width and height must be at least 1",
                self.width, self.height
            ));
        }
        if self.width > MAX_IMAGE_EDGE || self.height > MAX_IMAGE_EDGE {
            return bad(format!(
                "image size {}x{} exceeds the limit of {MAX_IMAGE_EDGE} pixels per edge",
                self.width, self.height
            ));
        }
        if !(self.focal_length_mm.is_finite() && self.focal_length_mm > 0.0) {
            return bad(format!(
                "focal_length_mm must be a positive number, got {}",
                self.focal_length_mm
            ));
        }
        if !(self.sensor_width_mm.is_finite() && self.sensor_width_mm > 0.0) {
            return bad(format!(
                "sensor_width_mm must be a positive number, got {}",
                self.sensor_width_mm
            ));
        }
        if !(self.scene_unit_mm.is_finite() && self.scene_unit_mm > 0.0) {
            return bad(format!(
                "scene_unit_mm must be a positive number, got {}",
                self.scene_unit_mm
            ));
        }
        if let Some(n) = self.f_stop {
            if !(n.is_finite() && n > 0.0) {
                return bad(format!(
                    "f_stop must be a positive f-number (or null for a pinhole), got {n}"
                ));
            }
        }
        if let Some(s) = self.focus_distance {
            if !s.is_finite() || s <= 0.0 {
                return bad(format!(
                    "focus_distance must be a positive distance in scene units (or null), got {s}"
                ));
            }
            let f = self.focal_length_scene();
            if s <= f {
                return bad(format!(
                    "focus_distance {s} lies inside the focal length ({f} scene units = {} mm): a \
                     lens cannot focus there",
                    self.focal_length_mm
                ));
            }
        }
        if !(self.shutter_frames.is_finite() && self.shutter_frames >= 0.0) {
            return bad(format!(
                "shutter_frames must be zero or positive, got {}",
                self.shutter_frames
            ));
        }
        if let Some(lens) = self.thin_lens() {
            let k = lens.coc_scale_px;
            if !(k.is_finite() && k <= MAX_COC_SCALE_PX) {
                return bad(format!(
                    "f_stop {:?} with focal_length_mm {:?}, sensor_width_mm {:?} and focus_distance {:?} \
                     gives a blur of {k:e} px at infinity (limit {MAX_COC_SCALE_PX:e}): no real \
                     camera",
                    self.f_stop.unwrap_or(0.0),
                    self.focal_length_mm,
                    self.sensor_width_mm,
                    lens.focus_distance
                ));
            }
        }
        if !self.aperture_rotation_deg.is_finite() {
            return bad(format!(
                "aperture_rotation_deg must be a number of degrees, got {}",
                self.aperture_rotation_deg
            ));
        }
        if !(self.aperture_ratio.is_finite()
            && (1.0..=MAX_APERTURE_RATIO).contains(&self.aperture_ratio))
        {
            return bad(format!(
                "aperture_ratio must lie in [1, {MAX_APERTURE_RATIO}] (1 = round bokeh, 2 = twice as \
                 tall as wide), got {}; a ratio below 1 (bokeh wider than round) is not supported",
                self.aperture_ratio
            ));
        }
        if self.aperture_blades == 1 || self.aperture_blades == 2 {
            return bad(format!(
                "aperture_blades must be 0 (circular) or at least 3, got {}",
                self.aperture_blades
            ));
        }
        if let Some(lens) = &self.lens {
            let shaped = self.aperture_blades != 0
                || self.aperture_ratio != 1.0
                || self.aperture_image.is_some();
            if shaped {
                return bad(format!(
                    "lens {lens:?}: a lens prescription's aperture is its stop; aperture_blades, \
                     aperture_ratio and aperture_image apply to the thin lens only"
                ));
            }
            if self.f_stop.is_none() || self.focus_distance.is_none() {
                return bad(format!(
                    "lens {lens:?} needs f_stop and focus_distance (a pinhole has no lens)"
                ));
            }
        }
        Ok(())
    }

    /// The blade polygon's rotation in radians, counter-clockwise on the image, reduced to
    /// one blade's turn `[0, 2 pi / blades)` (rotations a blade apart give the same aperture);
    /// 0 for a circular aperture.
    pub fn aperture_rotation_rad(&self) -> f64 {
        if self.aperture_blades < 3 {
            return 0.0;
        }
        let turn = std::f64::consts::TAU / f64::from(self.aperture_blades);
        self.aperture_rotation_deg.to_radians().rem_euclid(turn)
    }

    /// Focal length in scene units.
    pub fn focal_length_scene(&self) -> f64 {
        self.focal_length_mm / self.scene_unit_mm
    }

    /// True when the camera has a finite aperture and a focus distance (depth of field).
    pub fn has_lens(&self) -> bool {
        matches!((self.f_stop, self.focus_distance), (Some(_), Some(_)))
    }

    /// True when the shutter is open for a non-zero fraction of the frame.
    pub fn has_shutter(&self) -> bool {
        self.shutter_frames > 0.0
    }

    /// Pixels per millimetre on the sensor.
    pub fn pixels_per_mm(&self) -> f64 {
        f64::from(self.width) / self.sensor_width_mm
    }

    /// The thin-lens model of this camera, `None` for a pinhole.
    pub fn thin_lens(&self) -> Option<ThinLens> {
        let (n, s) = (self.f_stop?, self.focus_distance?);
        let f = self.focal_length_scene();
        let aperture_mm = self.focal_length_mm / n;
        // Blender's thin lens keeps the pinhole's field of view (image scale f / depth, no focus
        // breathing), so the CoC diameter on the sensor (mm) is A f |d - s| / (d s), not the
        // textbook A f |d - s| / (d (s - f)), which over-blurs Cycles renders by s / (s - f).
        // Radius in pixels, signed: r(d) = k (1 - s/d), k = A f / s / 2 * px/mm. Linear in 1/d:
        // constant parallax.
        let k = 0.5 * aperture_mm * f / s * self.pixels_per_mm();
        Some(ThinLens {
            focus_distance: s,
            coc_scale_px: k,
        })
    }
}

/// The thin-lens circle of confusion as a function of depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThinLens {
    /// Focus distance, scene units.
    pub focus_distance: f64,
    /// The signed CoC radius (pixels) that a point at infinite depth gets.
    pub coc_scale_px: f64,
}

impl ThinLens {
    /// Signed CoC radius in pixels at planar depth `depth` (scene units): positive behind the
    /// focus plane, negative in front; proportional to the parallax `1/s - 1/d`.
    /// `depth` must be positive; `+inf` gives [`ThinLens::coc_scale_px`].
    pub fn signed_coc_px(&self, depth: f64) -> f64 {
        self.coc_scale_px * (1.0 - self.focus_distance / depth)
    }

    /// Unsigned CoC radius in pixels.
    pub fn coc_px(&self, depth: f64) -> f64 {
        self.signed_coc_px(depth).abs()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn comets() -> Camera {
        Camera::from_json_str(
            r#"{"scene":"comets","width":512,"height":512,"focal_length_mm":50.0,
            "sensor_width_mm":36.0,"f_stop":1.6,"focus_distance":0.7,"aperture_blades":0,
            "shutter_frames":1.0,"reference_spp":2048,"reference_seconds":null}"#,
        )
        .expect("valid camera")
    }

    #[test]
    fn coc_matches_the_thin_lens_formula_by_hand() {
        let cam = comets();
        let lens = cam.thin_lens().expect("lens");
        // d = 1.4 m: A = 50/1.6 = 31.25 mm, f = 0.05 m, s = 0.7 m.
        // diameter = 31.25 * 0.05 * 0.7 / (1.4 * 0.7) mm = 1.1161 mm; radius px = /2 * 512/36.
        let d = 1.4;
        let diameter_mm: f64 = 31.25 * 0.05 * (d - 0.7) / (d * 0.7);
        let expected = diameter_mm / 2.0 * 512.0 / 36.0;
        assert!((lens.coc_px(d) - expected).abs() < 1e-9);
        assert!(lens.signed_coc_px(d) > 0.0);
        assert!(lens.signed_coc_px(0.5) < 0.0);
        assert!(lens.coc_px(0.7).abs() < 1e-12);
    }

    #[test]
    fn pinhole_when_either_is_null() {
        let cam = Camera::from_json_str(
            r#"{"width":8,"height":8,"focal_length_mm":50,"sensor_width_mm":36,"f_stop":null,
            "focus_distance":2.0}"#,
        )
        .expect("valid");
        assert!(!cam.has_lens());
        assert!(cam.thin_lens().is_none());
        assert!(!cam.has_shutter());
    }

    #[test]
    fn impossible_cameras_are_rejected_with_the_field_named() {
        let cases = [
            (r#""f_stop":-2.0,"focus_distance":1.0"#, "f_stop"),
            (r#""f_stop":2.0,"focus_distance":0.01"#, "focal length"),
            (r#""f_stop":0.0,"focus_distance":1.0"#, "f_stop"),
            (
                r#""f_stop":2.0,"focus_distance":1.0,"shutter_frames":-1"#,
                "shutter_frames",
            ),
        ];
        for (fields, needle) in cases {
            let text = format!(
                r#"{{"width":8,"height":8,"focal_length_mm":50,"sensor_width_mm":36,{fields}}}"#
            );
            let err = Camera::from_json_str(&text).expect_err(fields).to_string();
            assert!(err.contains(needle), "{err} should mention {needle}");
        }
        let zero = r#"{"width":0,"height":8,"focal_length_mm":50,"sensor_width_mm":36}"#;
        assert!(Camera::from_json_str(zero).is_err());
        let missing = r#"{"width":8,"height":8,"sensor_width_mm":36}"#;
        let err = Camera::from_json_str(missing)
            .expect_err("missing")
            .to_string();
        assert!(err.contains("focal_length_mm"), "{err}");
        // A field of the wrong type is named; not an object is said so; an absurd lens too.
        let text = r#"{"width":"eight","height":8,"focal_length_mm":50,"sensor_width_mm":36}"#;
        let err = Camera::from_json_str(text).expect_err("type").to_string();
        assert!(err.contains("`width`"), "{err}");
        let err = Camera::from_json_str("[8, 8]")
            .expect_err("array")
            .to_string();
        assert!(err.contains("JSON object"), "{err}");
        let tiny = r#"{"width":8,"height":8,"focal_length_mm":50,"sensor_width_mm":36,
            "f_stop":1e-310,"focus_distance":1.0}"#;
        let err = Camera::from_json_str(tiny)
            .expect_err("tiny f-stop")
            .to_string();
        assert!(err.contains("f_stop"), "{err}");
    }
}
