//! Scene files (JSON, serde) and the prepared scene: closest-hit queries at a time, shadows,
//! view-independent shading and the pinhole image motion of surface points.

use std::path::Path;

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::camera::{Camera, CameraPose, CameraSpec, Ray};
use crate::error::{invalid, Error, Result};
use crate::material::{Light, Material};
use crate::sampling::{cosine_hemisphere, ShadingRng};
use crate::shapes::{Motion, PreparedShape, Shape, Spin};

/// Depth written where a ray hits nothing (Blender's convention).
pub const MISS_DEPTH: f32 = 1e10;

/// Most objects a scene may hold (the tracer is brute force).
pub const MAX_OBJECTS: usize = 10_000;

/// The scene file's top level.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneDescription {
    /// Scene name (written into `camera.json` as `scene`).
    pub name: String,
    /// What the scene stresses, for people.
    #[serde(default)]
    pub description: String,
    /// The lens and shutter, exactly in `camera.json`'s format.
    pub camera: CameraSpec,
    /// Where the camera is and how it moves.
    pub camera_pose: CameraPose,
    /// Linear RGB radiance of rays that hit nothing (alpha stays 0 there).
    #[serde(default)]
    pub background: [f32; 3],
    /// Ambient term added to every surface's irradiance (linear RGB).
    #[serde(default)]
    pub ambient: [f32; 3],
    /// Lights.
    #[serde(default)]
    pub lights: Vec<Light>,
    /// One diffuse bounce: every shaded point also gathers, along one random direction drawn
    /// with density `cos / pi`, the light of what that direction sees (its emission and its
    /// direct lighting, or the background), as indirect light. Off by default.
    #[serde(default)]
    pub diffuse_bounce: bool,
    /// Objects.
    pub objects: Vec<ObjectDescription>,
}

/// One object of the scene file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectDescription {
    /// Optional name used in error messages.
    #[serde(default)]
    pub name: String,
    /// Geometry at the frame time.
    pub shape: Shape,
    /// Surface.
    #[serde(default)]
    pub material: Material,
    /// Linear velocity in metres per frame.
    #[serde(default)]
    pub velocity: DVec3,
    /// Optional spin (rotation over the shutter).
    #[serde(default)]
    pub spin: Option<Spin>,
    /// Whether the object blocks lights (default true; emitters usually should not).
    #[serde(default = "yes")]
    pub casts_shadow: bool,
}

fn yes() -> bool {
    true
}

/// A prepared object.
#[derive(Clone, Debug)]
pub struct Object {
    /// Name (or `object N`).
    pub name: String,
    /// Geometry.
    pub shape: PreparedShape,
    /// Surface.
    pub material: Material,
    /// Motion over the shutter.
    pub motion: Motion,
    /// Whether it blocks lights.
    pub casts_shadow: bool,
}

/// A surface hit in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Index into [`Scene::objects`].
    pub object: usize,
    /// Ray distance, metres.
    pub distance: f64,
    /// World point, metres.
    pub point: DVec3,
    /// The same point in the object's rest frame (t = 0), metres.
    pub rest_point: DVec3,
    /// World unit normal (facing the ray for two-sided shapes).
    pub normal: DVec3,
    /// Texture coordinates.
    pub uv: DVec2,
}

/// What one camera ray sees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trace {
    /// Premultiplied linear RGBA: alpha 1 on a hit, 0 on a miss (RGB = background then).
    pub color: [f32; 4],
    /// Planar depth of the hit from the camera at the ray's time, metres; [`MISS_DEPTH`] on a miss.
    pub depth: f64,
    /// The hit, if any.
    pub hit: Option<Hit>,
}

/// A validated scene ready to render.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Scene name.
    pub name: String,
    /// The camera.
    pub camera: Camera,
    /// Background radiance.
    pub background: [f32; 3],
    /// Ambient term.
    pub ambient: [f32; 3],
    /// Lights.
    pub lights: Vec<Light>,
    /// One diffuse bounce of indirect light ([`SceneDescription::diffuse_bounce`]).
    pub diffuse_bounce: bool,
    /// Objects.
    pub objects: Vec<Object>,
    description: SceneDescription,
}

/// The two view layers of a foreground/background split ([`Scene::trace_layer`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewLayerPass {
    /// Everything but the foreground objects, which still cast their shadows.
    Background,
    /// The foreground objects alone, the rest held out.
    Foreground,
}

/// Names of the scenes embedded in the library.
pub const BUILTIN_NAMES: [&str; 7] = [
    "bokeh", "crossing", "occluder", "rotating", "physical", "rain", "studio",
];

/// The JSON text of a builtin scene.
pub fn builtin_json(name: &str) -> Option<&'static str> {
    Some(match name {
        "bokeh" => include_str!("../scenes/bokeh.json"),
        "crossing" => include_str!("../scenes/crossing.json"),
        "occluder" => include_str!("../scenes/occluder.json"),
        "rotating" => include_str!("../scenes/rotating.json"),
        "physical" => include_str!("../scenes/physical.json"),
        "rain" => include_str!("../scenes/rain.json"),
        "studio" => include_str!("../scenes/studio.json"),
        _ => return None,
    })
}

/// A builtin scene by name (see [`BUILTIN_NAMES`]).
pub fn builtin(name: &str) -> Result<Scene> {
    let text = builtin_json(name).ok_or_else(|| Error::UnknownBuiltin {
        name: name.to_string(),
        known: BUILTIN_NAMES.join(", "),
    })?;
    Scene::from_json(text, &format!("builtin scene {name}"))
}

impl Scene {
    /// Parses and validates a scene document; `source_name` names it in error messages.
    pub fn from_json(text: &str, source_name: &str) -> Result<Self> {
        let description: SceneDescription =
            serde_json::from_str(text).map_err(|source| Error::Json {
                source_name: source_name.to_string(),
                source,
            })?;
        Self::new(description, source_name)
    }

    /// Reads a scene file, or a builtin scene when `path` names one and no such file exists (a
    /// folder of that name does not count).
    pub fn load(path: &Path) -> Result<Self> {
        // A built-in name wins unless a file of that name exists: a folder called `rotating`
        // (where its renders went) is no scene file.
        if !path.is_file() {
            if let Some(name) = path.to_str().filter(|n| builtin_json(n).is_some()) {
                return builtin(name);
            }
        }
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let name = path.display().to_string();
        let mut description: SceneDescription =
            serde_json::from_str(&text).map_err(|source| Error::Json {
                source_name: name.clone(),
                source,
            })?;
        // An aperture image named relative to the scene file.
        if let (Some(image), Some(dir)) = (&description.camera.aperture_image, path.parent()) {
            if image.is_relative() {
                // Absolute, so the camera.json written beside the renders finds it anywhere.
                let joined = dir.join(image);
                let absolute = std::fs::canonicalize(&joined).unwrap_or(joined);
                description.camera.aperture_image = Some(absolute);
            }
        }
        // A lens prescription file named relative to the scene file (built-in names stay),
        // made absolute so the camera.json written beside the renders finds it anywhere.
        if let Some(dir) = path.parent() {
            let dir = if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                dir
            };
            let absolute = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf());
            description.camera.resolve_lens_from(&absolute);
        }
        Self::new(description, &name)
    }

    /// Validates a parsed description.
    pub fn new(description: SceneDescription, source_name: &str) -> Result<Self> {
        let camera = Camera::new(
            description.camera.clone(),
            description.camera_pose.clone(),
            source_name,
        )?;
        let colour_ok = |c: &[f32; 3]| c.iter().all(|v| v.is_finite() && *v >= 0.0);
        if !colour_ok(&description.background) || !colour_ok(&description.ambient) {
            return Err(invalid(
                source_name,
                "background and ambient must be finite and >= 0",
            ));
        }
        if description.objects.len() > MAX_OBJECTS {
            return Err(invalid(
                source_name,
                format!("at most {MAX_OBJECTS} objects are supported"),
            ));
        }
        for (i, light) in description.lights.iter().enumerate() {
            light.validate(&format!("{source_name}: light {i}"))?;
        }
        let mut objects = Vec::with_capacity(description.objects.len());
        for (i, object) in description.objects.iter().enumerate() {
            let name = if object.name.is_empty() {
                format!("object {i}")
            } else {
                object.name.clone()
            };
            let context = format!("{source_name}: {name}");
            let shape = PreparedShape::new(object.shape.clone(), &context)?;
            object.material.validate(&context)?;
            let motion = Motion::new(
                object.velocity,
                object.spin.as_ref(),
                shape.centre(),
                &context,
            )?;
            objects.push(Object {
                name,
                shape,
                material: object.material.clone(),
                motion,
                casts_shadow: object.casts_shadow,
            });
        }
        Ok(Self {
            name: description.name.clone(),
            camera,
            background: description.background,
            ambient: description.ambient,
            lights: description.lights.clone(),
            diffuse_bounce: description.diffuse_bounce,
            objects,
            description,
        })
    }

    /// The description this scene was built from.
    pub fn description(&self) -> &SceneDescription {
        &self.description
    }

    /// The camera's lens and shutter.
    pub fn camera_spec(&self) -> &CameraSpec {
        &self.camera.spec
    }

    /// The same scene with another camera spec (image size, lens or shutter); the field of view
    /// follows from the focal length and sensor width, so changing only the size keeps the view.
    pub fn with_camera_spec(&self, spec: CameraSpec) -> Result<Self> {
        let mut description = self.description.clone();
        description.camera = spec;
        Self::new(description, &self.name)
    }

    /// The same scene at another image size (pixels), keeping the field of view.
    pub fn with_size(&self, width: u32, height: u32) -> Result<Self> {
        let mut spec = self.camera.spec.clone();
        spec.width = width;
        spec.height = height;
        self.with_camera_spec(spec)
    }

    /// The same scene rendered `px` pixels further on every side (overscan): the pixel pitch
    /// and the lens are kept and the sensor grows with the image, so pixel `(x + px, y + px)`
    /// of the larger image is pixel `(x, y)` of this one.
    pub fn with_overscan(&self, px: u32) -> Result<Self> {
        let mut spec = self.camera.spec.clone();
        let grown = spec.width + 2 * px;
        spec.sensor_width_mm *= f64::from(grown) / f64::from(spec.width);
        spec.width = grown;
        spec.height += 2 * px;
        self.with_camera_spec(spec)
    }

    /// `camera.json` for this scene: the camera spec plus `"scene": name`.
    pub fn camera_json(&self) -> String {
        let mut value = serde_json::to_value(&self.camera.spec).unwrap_or(serde_json::Value::Null);
        if let serde_json::Value::Object(map) = &mut value {
            map.insert(
                "scene".to_string(),
                serde_json::Value::String(self.name.clone()),
            );
            map.insert(
                "renderer".to_string(),
                serde_json::Value::String("spreadlet-scene".to_string()),
            );
        }
        serde_json::to_string_pretty(&value).unwrap_or_default()
    }

    /// Closest hit of a world ray at time `ray.time` with distance in (1e-9, t_max).
    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<Hit> {
        self.intersect_visible(ray, t_max, &|_| true)
    }

    /// [`Scene::intersect`] among the objects for which `visible(index)` holds.
    pub fn intersect_visible(
        &self,
        ray: &Ray,
        t_max: f64,
        visible: &dyn Fn(usize) -> bool,
    ) -> Option<Hit> {
        let mut best: Option<(usize, crate::shapes::RestHit)> = None;
        let mut limit = t_max;
        for (i, object) in self.objects.iter().enumerate() {
            if !visible(i) {
                continue;
            }
            let rest_ray = object.motion.to_rest(ray);
            if let Some(hit) = object.shape.intersect(&rest_ray, 1e-9, limit) {
                limit = hit.distance;
                best = Some((i, hit));
            }
        }
        best.map(|(i, rest)| {
            let motion = &self.objects[i].motion;
            Hit {
                object: i,
                distance: rest.distance,
                point: ray.origin + ray.direction * rest.distance,
                rest_point: rest.point,
                normal: motion.rotate(rest.normal, ray.time),
                uv: rest.uv,
            }
        })
    }

    /// True if a shadow-casting object blocks the segment of `ray` up to `t_max`.
    fn occluded(&self, ray: &Ray, t_max: f64) -> bool {
        self.objects.iter().any(|object| {
            object.casts_shadow
                && object
                    .shape
                    .intersect(&object.motion.to_rest(ray), 1e-9, t_max)
                    .is_some()
        })
    }

    /// Outgoing radiance of a hit at `time`: emission + albedo * (ambient + shadowed lights +
    /// with [`Scene::diffuse_bounce`], one sample of indirect light). Area lights and the
    /// bounce draw their random numbers from `rng`; scenes without them draw none.
    pub fn shade(&self, hit: &Hit, time: f64, rng: &mut ShadingRng) -> [f32; 3] {
        let material = &self.objects[hit.object].material;
        let albedo = material.albedo_at(hit.uv);
        let mut irradiance = self.direct_irradiance(hit, time, rng);
        if self.diffuse_bounce {
            let indirect = self.indirect_radiance(hit, time, rng);
            for (e, l) in irradiance.iter_mut().zip(indirect) {
                *e += l;
            }
        }
        std::array::from_fn(|c| {
            (f64::from(material.emission[c]) + f64::from(albedo[c]) * irradiance[c]) as f32
        })
    }

    /// The light a hit gathers from the ambient term and the lights (shadowed), in the units
    /// of `albedo * irradiance = radiance` (the irradiance over pi).
    fn direct_irradiance(&self, hit: &Hit, time: f64, rng: &mut ShadingRng) -> [f64; 3] {
        let mut irradiance = [
            f64::from(self.ambient[0]),
            f64::from(self.ambient[1]),
            f64::from(self.ambient[2]),
        ];
        let origin = hit.point + hit.normal * 1e-7;
        for light in &self.lights {
            let (to_light, distance, scale, intensity) = match light {
                Light::Point {
                    position,
                    intensity,
                } => {
                    let d = *position - hit.point;
                    let dist = d.length();
                    if dist <= 0.0 {
                        continue;
                    }
                    (d / dist, dist, 1.0 / (dist * dist), intensity)
                }
                Light::Directional {
                    direction,
                    intensity,
                } => (-direction.normalize(), f64::INFINITY, 1.0, intensity),
                Light::Area {
                    corner,
                    edge_u,
                    edge_v,
                    radiance,
                } => {
                    let (a, b) = (rng.uniform(), rng.uniform());
                    let point = *corner + *edge_u * a + *edge_v * b;
                    let d = point - hit.point;
                    let dist = d.length();
                    let facing = edge_u.cross(*edge_v);
                    let area = facing.length();
                    let cos_light = -(facing / area).dot(d) / dist;
                    if dist <= 0.0 || cos_light <= 0.0 {
                        continue;
                    }
                    let scale = cos_light * area / (std::f64::consts::PI * dist * dist);
                    // The shadow ray stops just short of the light's surface.
                    (d / dist, dist * (1.0 - 1e-9), scale, radiance)
                }
            };
            let cosine = hit.normal.dot(to_light);
            if cosine <= 0.0 {
                continue;
            }
            let shadow = Ray {
                origin,
                direction: to_light,
                time,
            };
            if self.occluded(&shadow, distance) {
                continue;
            }
            for (e, i) in irradiance.iter_mut().zip(intensity) {
                *e += f64::from(*i) * cosine * scale;
            }
        }
        irradiance
    }

    /// One sample of the indirect light at a hit: the radiance along a direction drawn with
    /// density `cos / pi` (emission and direct light of what it meets, or the background), which
    /// is an unbiased estimate of the gathered irradiance over pi.
    fn indirect_radiance(&self, hit: &Hit, time: f64, rng: &mut ShadingRng) -> [f64; 3] {
        let direction = cosine_hemisphere(hit.normal, rng.uniform(), rng.uniform());
        let ray = Ray {
            origin: hit.point + hit.normal * 1e-7,
            direction,
            time,
        };
        match self.intersect(&ray, f64::INFINITY) {
            Some(next) => {
                let material = &self.objects[next.object].material;
                let albedo = material.albedo_at(next.uv);
                let direct = self.direct_irradiance(&next, time, rng);
                std::array::from_fn(|c| {
                    f64::from(material.emission[c]) + f64::from(albedo[c]) * direct[c]
                })
            }
            None => self.background.map(f64::from),
        }
    }

    /// The denoiser's guides of what a ray hit: its albedo (emission added, as Cycles does) and
    /// its normal in camera space (x right, y up, z along the view: a surface facing the camera
    /// reads (0, 0, -1)); zero on a miss.
    pub fn guides(&self, hit: Option<&Hit>) -> formats::SampleGuides {
        let Some(hit) = hit else {
            return formats::SampleGuides::default();
        };
        let material = &self.objects[hit.object].material;
        let albedo = material.albedo_at(hit.uv);
        let n = hit.normal;
        formats::SampleGuides {
            albedo: std::array::from_fn(|c| albedo[c] + material.emission[c]),
            normal: [
                n.dot(self.camera.right()) as f32,
                -n.dot(self.camera.down()) as f32,
                n.dot(self.camera.forward()) as f32,
            ],
        }
    }

    /// Traces one camera ray: colour, alpha and planar depth.
    pub fn trace(&self, ray: &Ray) -> Trace {
        self.shaded(ray, self.intersect(ray, f64::INFINITY), self.background)
    }

    /// What `ray` sees in one view layer of a render split into a foreground (the objects
    /// `in_foreground` marks) and a background, as a compositing artist renders them in
    /// Blender: the background layer does not see the foreground objects but keeps their
    /// shadows ("indirect only"); the foreground layer sees only them, everything else held
    /// out (colour and alpha 0, miss depth).
    pub fn trace_layer(&self, ray: &Ray, layer: ViewLayerPass, in_foreground: &[bool]) -> Trace {
        let fg = |i: usize| in_foreground.get(i).copied().unwrap_or(false);
        match layer {
            ViewLayerPass::Background => {
                let hit = self.intersect_visible(ray, f64::INFINITY, &|i| !fg(i));
                self.shaded(ray, hit, self.background)
            }
            ViewLayerPass::Foreground => {
                let hit = self.intersect(ray, f64::INFINITY).filter(|h| fg(h.object));
                self.shaded(ray, hit, [0.0; 3])
            }
        }
    }

    /// The trace of `ray` with its nearest `hit`, or `missed` radiance (alpha 0) without one.
    fn shaded(&self, ray: &Ray, hit: Option<Hit>, missed: [f32; 3]) -> Trace {
        match hit {
            Some(hit) => {
                let [r, g, b] = self.shade(&hit, ray.time, &mut ShadingRng::new(ray));
                Trace {
                    color: [r, g, b, 1.0],
                    depth: self.camera.planar_depth(hit.point, ray.time),
                    hit: Some(hit),
                }
            }
            None => {
                let [r, g, b] = missed;
                Trace {
                    color: [r, g, b, 0.0],
                    depth: f64::from(MISS_DEPTH),
                    hit: None,
                }
            }
        }
    }

    /// Pinhole image position (pixels) at `time` of the surface point of `hit`, following the
    /// object's motion and the camera's.
    pub fn image_position(&self, hit: &Hit, time: f64) -> Option<DVec2> {
        let world = self.objects[hit.object].motion.place(hit.rest_point, time);
        self.camera.project(world, time)
    }

    /// Instantaneous forward image motion (pixels per frame, x right, y down) of the hit's
    /// surface point at `time`, by a central difference of +-1e-4 frames; zero if the point
    /// leaves the front of the camera.
    pub fn image_velocity(&self, hit: &Hit, time: f64) -> DVec2 {
        const H: f64 = 1e-4;
        match (
            self.image_position(hit, time + H),
            self.image_position(hit, time - H),
        ) {
            (Some(a), Some(b)) => (a - b) / (2.0 * H),
            _ => DVec2::ZERO,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at the origin looking down -z at a grey floor plane facing it at `z = -1`,
    /// with `lights` and the bounce as given, and `extra` objects.
    fn studio(lights: &str, bounce: bool, extra: &str) -> Scene {
        let text = format!(
            r#"{{"name": "studio",
              "camera": {{"width": 8, "height": 8, "focal_length_mm": 50, "sensor_width_mm": 36}},
              "camera_pose": {{"position": [0, 0, 0], "look_at": [0, 0, -1]}},
              "lights": [{lights}], "diffuse_bounce": {bounce},
              "objects": [{{"name": "floor", "shape": {{"type": "plane", "point": [0, 0, -1],
                            "normal": [0, 0, 1]}}, "material": {{"albedo": [0.5, 0.5, 0.5]}}}}{extra}]}}"#
        );
        Scene::from_json(&text, "studio").expect("scene")
    }

    /// The mean of `n` shadings of the floor's point on the viewing axis (seen from just above
    /// it, below any ceiling).
    fn mean_shading(scene: &Scene, n: usize) -> f64 {
        let ray = Ray {
            origin: DVec3::new(0.0, 0.0, -0.9),
            direction: DVec3::new(0.0, 0.0, -1.0),
            time: 0.0,
        };
        let hit = scene.intersect(&ray, f64::INFINITY).expect("the floor");
        let mut rng = ShadingRng::from_rng(
            crate::sampling::pixel_rng(7, crate::sampling::Stream::Reference, 0),
            &ray,
        );
        let sum: f64 = (0..n)
            .map(|_| f64::from(scene.shade(&hit, 0.0, &mut rng)[0]))
            .sum();
        sum / n as f64
    }

    /// The form factor from a point to a parallel rectangle `a x b` at height `h` above one of
    /// its corners (the standard closed form), which is the irradiance over pi per unit
    /// radiance.
    fn corner_form_factor(a: f64, b: f64, h: f64) -> f64 {
        let (x, y) = (a / h, b / h);
        let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
        ((x / sx) * (y / sx).atan() + (y / sy) * (x / sy).atan()) / (2.0 * std::f64::consts::PI)
    }

    /// A square area light facing the floor point below its centre lights it as the closed
    /// form says (four corner rectangles), within the Monte Carlo error; seen from behind it
    /// gives nothing.
    #[test]
    fn an_area_light_gives_its_form_factor() {
        // Side 0.6 m, 0.5 m above the floor point (0, 0, -1), facing down.
        let light = r#"{"type": "area", "corner": [-0.3, -0.3, -0.5], "edge_u": [0.0, 0.6, 0.0],
                        "edge_v": [0.6, 0.0, 0.0], "radiance": [2.0, 2.0, 2.0]}"#;
        let scene = studio(light, false, "");
        let want = 0.5 * 2.0 * 4.0 * corner_form_factor(0.3, 0.3, 0.5);
        let got = mean_shading(&scene, 200_000);
        assert!((got / want - 1.0).abs() < 0.01, "{got} against {want}");
        let backwards = light
            .replace("[0.0, 0.6, 0.0]", "[0.0, -0.6, 0.0]")
            .replace("[-0.3, -0.3, -0.5]", "[-0.3, 0.3, -0.5]");
        assert_eq!(mean_shading(&studio(&backwards, false, ""), 1000), 0.0);
    }

    /// One diffuse bounce under a wide emissive ceiling: the floor gathers the ceiling's
    /// radiance times its form factor, times its own albedo; without the bounce it stays dark.
    #[test]
    fn one_bounce_gathers_an_emissive_ceiling() {
        let ceiling = r#", {"name": "ceiling", "shape": {"type": "quad", "corner": [-20, -20, -0.8],
                        "edge_u": [40, 0, 0], "edge_v": [0, 40, 0]},
                        "material": {"albedo": [0, 0, 0], "emission": [3, 3, 3]}}"#;
        let want = 0.5 * 3.0 * 4.0 * corner_form_factor(20.0, 20.0, 0.2);
        let got = mean_shading(&studio("", true, ceiling), 100_000);
        assert!((got / want - 1.0).abs() < 0.01, "{got} against {want}");
        assert_eq!(mean_shading(&studio("", false, ceiling), 100), 0.0);
    }

    /// The guides of the floor: its albedo, and its normal facing the camera, (0, 0, -1) in
    /// camera space; a miss has none.
    #[test]
    fn guides_hold_the_albedo_and_the_camera_space_normal() {
        let scene = studio("", false, "");
        let ray = Ray {
            origin: DVec3::ZERO,
            direction: DVec3::new(0.3, 0.2, -1.0).normalize(),
            time: 0.0,
        };
        let hit = scene.intersect(&ray, f64::INFINITY);
        let g = scene.guides(hit.as_ref());
        assert_eq!(g.albedo, [0.5; 3]);
        assert!(
            (g.normal[2] + 1.0).abs() < 1e-6 && g.normal[0].abs() < 1e-6,
            "{g:?}"
        );
        assert_eq!(scene.guides(None), formats::SampleGuides::default());
    }

    #[test]
    fn builtins_parse() {
        for name in BUILTIN_NAMES {
            let scene = builtin(name).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(scene.name, name);
            assert!(!scene.objects.is_empty());
        }
        let err = builtin("nope").expect_err("unknown");
        assert!(err.to_string().contains("bokeh"));
    }

    #[test]
    fn errors_name_the_problem() {
        let text = builtin_json("bokeh").expect("bokeh");
        let typo = text.replacen("\"objects\"", "\"objcts\"", 1);
        let err = Scene::from_json(&typo, "typo.json").expect_err("typo");
        assert!(err.to_string().contains("objcts"), "{err}");
        let bad = text.replacen("\"radius\": ", "\"radius\": -", 1);
        let err = Scene::from_json(&bad, "neg.json").expect_err("negative radius");
        assert!(err.to_string().contains("radius"), "{err}");
        let err = Scene::from_json("{", "trunc.json").expect_err("truncated");
        assert!(err.to_string().contains("trunc.json"), "{err}");
    }
}
