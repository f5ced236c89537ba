//! The camera flags shared by `synth` and `reconstruct`: the fields of `camera.json`, given on
//! the command line, overriding the file's.

use std::path::Path;

use anyhow::{bail, Context, Result};
use clap::Args;
use spreadlet::Camera;

#[derive(Args, Debug, Default)]
pub(crate) struct CameraFlags {
    /// Output width, pixels.
    #[arg(long)]
    pub(crate) width: Option<u32>,
    /// Output height, pixels.
    #[arg(long)]
    pub(crate) height: Option<u32>,
    /// Focal length, mm.
    #[arg(long)]
    pub(crate) focal_length_mm: Option<f64>,
    /// Sensor width, mm (maps to the image width).
    #[arg(long)]
    pub(crate) sensor_width_mm: Option<f64>,
    /// Aperture f-number (omit both this and --focus-distance for a pinhole).
    #[arg(long)]
    pub(crate) f_stop: Option<f64>,
    /// Focus distance, scene units (planar).
    #[arg(long)]
    pub(crate) focus_distance: Option<f64>,
    /// Aperture blades (0 = circular).
    #[arg(long)]
    pub(crate) aperture_blades: Option<u32>,
    /// Rotation of the blade polygon, degrees, counter-clockwise on the image (0: a vertex
    /// points right).
    #[arg(long)]
    pub(crate) aperture_rotation_deg: Option<f64>,
    /// Anamorphic squeeze, as Blender's aperture_ratio (the aperture's width divided by it;
    /// 2 = bokeh twice as tall as wide; at least 1).
    #[arg(long)]
    pub(crate) aperture_ratio: Option<f64>,
    /// A user-drawn aperture: a greyscale PNG whose brightness is the lens' transmission
    /// (upright in background bokeh; replaces the blades).
    #[arg(long)]
    pub(crate) aperture_image: Option<std::path::PathBuf>,
    /// A real lens, traced through its glass: a built-in prescription (singlet-51mm,
    /// double-gauss-50mm, wide-angle-22mm) or a prescription file (JSON, or pbrt's
    /// `radius thickness index aperture [abbe]` table).
    #[arg(long)]
    pub(crate) lens: Option<String>,
    /// Shutter as a fraction of the frame (0 = no motion blur).
    #[arg(long)]
    pub(crate) shutter_frames: Option<f64>,
    /// Millimetres per scene unit (default 1000: metres).
    #[arg(long)]
    pub(crate) scene_unit_mm: Option<f64>,
}

/// The camera of `path` (or none) with the flags `f` laid over its fields, validated once.
pub(crate) fn load_camera(path: Option<&Path>, f: &CameraFlags) -> Result<Camera> {
    let mut value = match path {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("cannot read camera file {}", p.display()))?;
            serde_json::from_str::<serde_json::Value>(&text)
                .with_context(|| format!("camera file {} is not JSON", p.display()))?
        }
        None => serde_json::json!({}),
    };
    let Some(obj) = value.as_object_mut() else {
        bail!("the camera file must hold a JSON object");
    };
    let mut set = |k: &str, v: Option<serde_json::Value>| {
        if let Some(v) = v {
            obj.insert(k.to_string(), v);
        }
    };
    set("width", f.width.map(Into::into));
    set("height", f.height.map(Into::into));
    set("focal_length_mm", f.focal_length_mm.map(Into::into));
    set("sensor_width_mm", f.sensor_width_mm.map(Into::into));
    set("f_stop", f.f_stop.map(Into::into));
    set("focus_distance", f.focus_distance.map(Into::into));
    set("aperture_blades", f.aperture_blades.map(Into::into));
    set(
        "aperture_rotation_deg",
        f.aperture_rotation_deg.map(Into::into),
    );
    set("aperture_ratio", f.aperture_ratio.map(Into::into));
    set("shutter_frames", f.shutter_frames.map(Into::into));
    set("scene_unit_mm", f.scene_unit_mm.map(Into::into));
    // The flag's path is the command line's (relative to here), the file's is the file's.
    let from_file = f.aperture_image.is_none();
    let lens_from_file = f.lens.is_none();
    set("lens", f.lens.clone().map(Into::into));
    set(
        "aperture_image",
        f.aperture_image
            .as_ref()
            .map(|p| p.display().to_string().into()),
    );
    let mut camera = Camera::from_json_str(&value.to_string()).map_err(|e| match path {
        Some(p) => anyhow::anyhow!("{}: {e}", p.display()),
        None => anyhow::anyhow!("{e} (give --camera or the camera flags)"),
    })?;
    if let (true, Some(dir), Some(image)) = (
        from_file,
        path.and_then(Path::parent),
        camera.aperture_image.as_ref(),
    ) {
        if image.is_relative() {
            camera.aperture_image = Some(dir.join(image));
        }
    }
    if let (true, Some(dir)) = (lens_from_file, path.and_then(Path::parent)) {
        camera.resolve_lens_from(dir);
    }
    Ok(camera)
}
