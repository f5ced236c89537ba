//! scene: a small distribution ray tracer for analytic scenes, the ground truth of spreadlet.
//!
//! It renders, with the same thin-lens camera as `camera.json` describes:
//! 1. a pinhole G-buffer in Blender's multilayer EXR layout ([`render_gbuffer`], [`GBuffer`]);
//! 2. stochastic frames, one labelled ray per sample ([`render_stochastic`],
//!    [`StochasticFrames`]; layout in `docs/STOCHASTIC.md`);
//! 3. a converged reference with depth of field and motion blur ([`render_reference`]).
//!
//! Scenes are JSON files ([`Scene::from_json`], [`Scene::load`]); five are built in
//! ([`builtin`], [`BUILTIN_NAMES`]). Units: metres, frames, pixels, millimetres on the sensor.
//!
//! ```
//! let scene = scene::builtin("bokeh")?.with_size(32, 32)?;
//! let options = scene::RenderOptions { seed: 1, ..Default::default() };
//! let reference = scene::render_reference(&scene, 16, &options)?;
//! assert_eq!(reference.pixels.len(), 32 * 32);
//! # Ok::<(), scene::Error>(())
//! ```

pub use formats::{exr_io, image, stochastic};

pub mod camera;
pub mod error;
pub mod gbuffer;
pub mod material;
pub mod render;
pub mod sampling;
pub mod scene;
pub mod shapes;
pub mod texture;

pub use camera::{Camera, CameraPose, CameraSpec, Ray};
pub use error::{Error, Result};
pub use gbuffer::GBuffer;
pub use image::RgbaImage;
pub use render::{
    estimate_reference_noise, render_deep, render_gbuffer, render_reference, render_stochastic,
    render_view_layers, NoiseEstimate, RenderOptions,
};
pub use scene::{
    builtin, builtin_json, Scene, SceneDescription, ViewLayerPass, BUILTIN_NAMES, MISS_DEPTH,
};
pub use stochastic::{Sample, StochasticFrames};
