//! Reconstruction from 1 spp with each sample placement, against the plain averages of 1 and
//! 16 spp, on a built-in scene: `cargo run --release -p runtime --example recon_lab [SCENE]
//! [SIZE]` (quick databases from the cache, built when missing).

use anyhow::Context;
use runtime::camera::Camera;
use runtime::reconstruct::{effects_of, min_footprint_px, reconstruct_with, SamplePlacement};
use runtime::rgba::RgbaImage;
use runtime::synth::SynthOptions;

fn ssim(a: &RgbaImage, b: &RgbaImage) -> anyhow::Result<f64> {
    let flat = |i: &RgbaImage| -> Vec<f32> { i.pixels.iter().flatten().copied().collect() };
    Ok(metrics::ssim_rgb(&flat(a), &flat(b), a.width, a.height)?)
}

fn to_runtime(i: scene::RgbaImage) -> RgbaImage {
    RgbaImage {
        width: i.width,
        height: i.height,
        pixels: i.pixels,
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let name = args.get(1).map_or("crossing", String::as_str);
    let size: u32 = match args.get(2) {
        Some(s) => s.parse().context("SIZE must be a number of pixels")?,
        None => 256,
    };
    let scene = scene::builtin(name)?.with_size(size, size)?;
    let render = scene::RenderOptions {
        seed: 1,
        progress: false,
        ..Default::default()
    };
    let camera = Camera::from_json_str(&scene.camera_json())?;
    let frames = scene::render_stochastic(&scene, 16, &render)?;
    let reference = to_runtime(scene::render_reference(&scene, 1024, &render)?);
    let one = scene::StochasticFrames {
        width: frames.width,
        height: frames.height,
        spp: 1,
        samples: frames.samples.iter().step_by(16).copied().collect(),
    };
    let effects = effects_of(&camera, &frames);
    let dbs = runtime::demo::cached_dbs(
        effects,
        precompute::Profile::Quick,
        camera.aperture_blades,
        false,
    )?;
    println!(
        "{name} {size}px: average_1spp {:.4}, average_16spp {:.4}",
        ssim(&to_runtime(one.average()), &reference)?,
        ssim(&to_runtime(frames.average()), &reference)?
    );
    let mut options = SynthOptions::default();
    options.classify.min_coc_px = min_footprint_px(1);
    for placement in [SamplePlacement::Nearest, SamplePlacement::Bilinear] {
        let (image, _) = reconstruct_with(&one, &camera, &dbs, &options, placement)?;
        println!(
            "reconstruct_1spp, {placement:?} placement: {:.4}",
            ssim(&image, &reference)?
        );
    }
    Ok(())
}
