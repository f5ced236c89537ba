//! `spreadlet demo`: the whole job on built-in data, on a fresh machine, without arguments.
//!
//! Renders a built-in scene with the ground-truth renderer (a pinhole G-buffer, stochastic
//! frames at 16 spp, a converged reference), builds or reuses the quick databases, runs
//! synthesis from the G-buffer and reconstruction from 1 spp, and scores every result and the
//! plain per-pixel averages of 1 and 16 spp against the reference (SSIM as the project defines
//! it). Writes the images (EXR), a side-by-side PNG, `summary.json` and prints a table.

use spreadlet::synth::ms_since;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use serde::Serialize;

use formats::image::RgbaImage;
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::pipeline::Effects;
use spreadlet::reconstruct::reconstruct;
use spreadlet::synth::{synthesize, SynthOptions};

/// Knobs of the demo.
#[derive(Clone, Debug, PartialEq)]
pub struct DemoOptions {
    /// Output folder.
    pub out: PathBuf,
    /// Built-in scene name (`scene::BUILTIN_NAMES`).
    pub scene: String,
    /// Image size override, pixels (square); `None` keeps the scene's.
    pub size: Option<u32>,
    /// Samples per pixel of the reference.
    pub reference_spp: usize,
    /// Samples per pixel of the stochastic frames (the 1-spp input is their first sample).
    pub stochastic_spp: usize,
    /// Database profile.
    pub profile: precompute::Profile,
    /// Random seed of the renders.
    pub seed: u64,
    /// Show progress.
    pub progress: bool,
}

impl Default for DemoOptions {
    fn default() -> Self {
        Self {
            out: PathBuf::from("out/demo"),
            scene: "crossing".into(),
            size: None,
            reference_spp: 1024,
            stochastic_spp: 16,
            profile: precompute::Profile::Quick,
            seed: 1,
            progress: true,
        }
    }
}

/// One step of the demo: its scores against the reference and its time.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DemoStep {
    /// SSIM against the reference (sRGB, sigma 1.5, mean over R, G, B).
    pub ssim: f64,
    /// PSNR against the reference, dB.
    pub psnr: f64,
    /// Mean FLIP error against the reference (LDR, 67 px per degree; lower is better).
    pub flip_mean: f64,
    /// 99th percentile of the FLIP error.
    pub flip_p99: f64,
    /// Median luminance ratio to the reference over the outer 4 px of each frame edge (left,
    /// top, right, bottom).
    pub edge_luminance_ratio: metrics::EdgeRatios,
    /// Wall-clock time of the step, milliseconds (renders of the inputs excluded).
    pub ms: f64,
    /// What the step is.
    pub what: String,
}

/// The databases the effects call for, from the cache (built with `profile` when missing):
/// thin-lens for defocus and still pixels, lens-motion in addition when there is motion.
pub fn cached_dbs(
    effects: Effects,
    profile: precompute::Profile,
    aperture: psf_db::Aperture,
    progress: bool,
) -> Result<DbSet> {
    Ok(crate::cached_dbs_with(
        effects,
        profile,
        aperture,
        progress,
        false,
        &|c| c,
    )?)
}

fn score(result: &RgbaImage, reference: &RgbaImage, ms: f64, what: &str) -> Result<DemoStep> {
    let scores = crate::score_images(result, reference).context("scoring the demo images")?;
    Ok(DemoStep {
        ssim: scores.ssim,
        psnr: scores.psnr_db.unwrap_or(f64::INFINITY),
        flip_mean: scores.flip_mean,
        flip_p99: scores.flip_p99,
        edge_luminance_ratio: scores.edge_luminance_ratio,
        ms,
        what: what.into(),
    })
}

/// Side-by-side PNG (sRGB) of `images`, left to right, with a 4-pixel gap.
fn write_strip(path: &Path, images: &[&RgbaImage]) -> Result<()> {
    let gap = 4;
    let h = images.iter().map(|i| i.height).max().unwrap_or(0);
    let w: usize = images
        .iter()
        .map(|i| i.width + gap)
        .sum::<usize>()
        .saturating_sub(gap);
    let mut strip = RgbaImage::new(w, h);
    let mut x0 = 0;
    for image in images {
        for y in 0..image.height {
            for x in 0..image.width {
                let p = image.at(x, y);
                // Composite over black, opaque, for viewing.
                strip.pixels[y * w + x0 + x] = [p[0], p[1], p[2], 1.0];
            }
        }
        x0 += image.width + gap;
    }
    strip.write_png(path)?;
    Ok(())
}

/// Runs the demo; returns the steps in order.
pub fn run(options: &DemoOptions) -> Result<Vec<(String, DemoStep)>> {
    let out = &options.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut scene = scene::builtin(&options.scene)?;
    if let Some(size) = options.size {
        scene = scene.with_size(size, size)?;
    }
    let render = scene::RenderOptions {
        seed: options.seed,
        progress: options.progress,
        ..Default::default()
    };
    let camera = Camera::from_json_str(&scene.camera_json())?;
    let say = |s: &str| {
        if options.progress {
            eprintln!("{s}");
        }
    };

    say(&format!(
        "rendering '{}' ({}x{}): G-buffer, {} spp stochastic frames, {} spp reference",
        options.scene, camera.width, camera.height, options.stochastic_spp, options.reference_spp
    ));
    let g = scene::render_gbuffer(&scene, 16, &render)?;
    let frames = scene::render_stochastic(&scene, options.stochastic_spp.max(1), &render)?;
    let reference = scene::render_reference(&scene, options.reference_spp, &render)?;
    g.write_exr(&out.join("gbuffer.exr"))?;
    reference.write_exr(&out.join("reference.exr"))?;
    formats::atomic::write_bytes_atomically(
        &out.join("camera.json"),
        scene.camera_json().as_bytes(),
    )?;

    let (w, h) = (g.width, g.height);
    let gbuffer = crate::gbuffer_of(&g)?;

    // One-sample frames: the first sample of every pixel.
    let one_spp = frames.first_samples(1);

    let effects = Effects::of(&camera, &gbuffer);
    say("loading (or building) the databases");
    let dbs = cached_dbs(
        effects,
        options.profile,
        spreadlet::databases::aperture_of(&camera),
        options.progress,
    )?;
    // The command line's default integrator, so the demo scores what `spreadlet synth` makes.
    let synth_options = SynthOptions {
        integrator: spreadlet::pipeline::Integrator::Exact,
        ..SynthOptions::default()
    };

    let mut steps = Vec::new();
    let t = Instant::now();
    let (synthesis, _) = synthesize(&gbuffer, &camera, &dbs, &synth_options)?;
    let ms = ms_since(t);
    synthesis.write_exr(&out.join("synthesis.exr"))?;
    steps.push((
        "synthesis".to_string(),
        score(
            &synthesis,
            &reference,
            ms,
            "spreadlet synthesis from the pinhole G-buffer",
        )?,
    ));

    let t = Instant::now();
    let (recon, _) = reconstruct(&one_spp, &camera, &dbs, &synth_options)?;
    let ms = ms_since(t);
    recon.write_exr(&out.join("reconstruct_1spp.exr"))?;
    steps.push((
        "reconstruct_1spp".to_string(),
        score(
            &recon,
            &reference,
            ms,
            "spreadlet reconstruction from 1 spp",
        )?,
    ));

    let t = Instant::now();
    let avg1 = one_spp.average();
    let ms = ms_since(t);
    steps.push((
        "average_1spp".to_string(),
        score(&avg1, &reference, ms, "per-pixel average of 1 spp")?,
    ));
    let t = Instant::now();
    let avg_n = frames.average();
    let ms = ms_since(t);
    let name = format!("average_{}spp", frames.spp);
    steps.push((
        name.clone(),
        score(
            &avg_n,
            &reference,
            ms,
            &format!("per-pixel average of {} spp", frames.spp),
        )?,
    ));

    let pinhole = g.color_image();
    write_strip(
        &out.join("side_by_side.png"),
        &[&pinhole, &synthesis, &recon, &avg1, &avg_n, &reference],
    )?;
    let summary: serde_json::Map<String, serde_json::Value> = steps
        .iter()
        .map(|(k, v)| Ok((k.clone(), serde_json::to_value(v)?)))
        .collect::<Result<_>>()?;
    let summary = serde_json::json!({
        "scene": options.scene,
        "width": w,
        "height": h,
        "reference_spp": options.reference_spp,
        "side_by_side": "side_by_side.png: pinhole input | synthesis | reconstruct_1spp | average_1spp | average_Nspp | reference",
        "steps": summary,
    });
    let summary_path = out.join("summary.json");
    let text = serde_json::to_string_pretty(&summary)?;
    formats::atomic::write_bytes_atomically(&summary_path, text.as_bytes())?;
    Ok(steps)
}

/// The demo's table, Markdown.
pub fn table(steps: &[(String, DemoStep)]) -> String {
    let mut s = String::from(
        "| step | SSIM | PSNR (dB) | FLIP mean | FLIP p99 | darkest edge | ms |\n\
         | --- | --- | --- | --- | --- | --- | --- |\n",
    );
    for (name, step) in steps {
        s.push_str(&format!(
            "| {name} | {:.4} | {:.2} | {:.4} | {:.4} | {:.3} | {:.1} |\n",
            step.ssim,
            step.psnr,
            step.flip_mean,
            step.flip_p99,
            step.edge_luminance_ratio.worst(),
            step.ms
        ));
    }
    s
}
