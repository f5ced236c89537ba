//! The three renders: the pinhole G-buffer, stochastic frames and the converged reference.
//! Rows render in parallel with rayon; every pixel draws from its own generator seeded by
//! (seed, render kind, pixel index), so output bits do not depend on the thread count.

use glam::DVec2;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use crate::error::{invalid, Result};
use crate::gbuffer::GBuffer;
use formats::srgb_encode;

use crate::image::RgbaImage;
use crate::sampling::{latin_hypercube, pixel_rng, uniform, Stream};
use crate::scene::{Scene, MISS_DEPTH};
use crate::stochastic::{Sample, StochasticFrames};

/// Largest samples per pixel accepted by any render.
pub const MAX_SPP: usize = 1 << 20;
/// Largest number of stored samples in stochastic frames (48 bytes each: 3 GiB).
pub const MAX_STOCHASTIC_SAMPLES: usize = 1 << 26;

/// Settings shared by the renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderOptions {
    /// Seed of every random number (same seed, same bits).
    pub seed: u64,
    /// Show an indicatif progress bar on stderr.
    pub progress: bool,
    /// Stochastic frames only: jitter each sample's sensor position uniformly over its pixel
    /// (true) or shoot through the pixel centre (false).
    pub jitter: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            seed: 0,
            progress: false,
            jitter: true,
        }
    }
}

fn progress_bar(options: &RenderOptions, rows: usize, what: &str) -> ProgressBar {
    if !options.progress {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(rows as u64);
    if let Ok(style) = ProgressStyle::with_template(
        "{msg:>22} [{elapsed_precise}] {wide_bar} {pos}/{len} rows (eta {eta})",
    ) {
        bar.set_style(style);
    }
    bar.set_message(what.to_string());
    bar
}

fn check_spp(spp: usize, what: &str) -> Result<()> {
    if spp == 0 || spp > MAX_SPP {
        return Err(invalid(
            what,
            format!("samples per pixel must be in 1..={MAX_SPP}, got {spp}"),
        ));
    }
    Ok(())
}

/// Renders `row`-closures in parallel and concatenates them in row order.
fn render_rows<T: Send>(
    height: usize,
    bar: &ProgressBar,
    row: impl Fn(usize) -> Vec<T> + Sync + Send,
) -> Vec<T> {
    let rows: Vec<Vec<T>> = (0..height)
        .into_par_iter()
        .map(|y| {
            let out = row(y);
            bar.inc(1);
            out
        })
        .collect();
    bar.finish_and_clear();
    rows.into_iter().flatten().collect()
}

/// The pinhole G-buffer at the frame time: colour averaged over `aa_samples` stratified
/// positions in each pixel's area, depth and Blender Vector pass of the nearest hit at the
/// pixel centre (motion from the frame before and after, through the lens centre).
pub fn render_gbuffer(
    scene: &Scene,
    aa_samples: usize,
    options: &RenderOptions,
) -> Result<GBuffer> {
    render_gbuffer_with(scene, aa_samples, options, "pinhole G-buffer", &|ray| {
        scene.trace(ray)
    })
}

/// The view layers of a render split into the objects named in `foreground` and the rest,
/// as one render with two Blender view layers writes them (`Background`, `Foreground`;
/// [`Scene::trace_layer`]): each a pinhole G-buffer like [`render_gbuffer`]'s, with the same
/// seed, so compositing Foreground over Background gives that G-buffer's colour wherever the
/// layers' anti-aliased edges do not meet.
pub fn render_view_layers(
    scene: &Scene,
    aa_samples: usize,
    options: &RenderOptions,
    foreground: &[String],
) -> Result<Vec<(String, GBuffer)>> {
    let names: Vec<&str> = scene.objects.iter().map(|o| o.name.as_str()).collect();
    for f in foreground {
        if !names.contains(&f.as_str()) {
            return Err(crate::error::Error::Invalid {
                context: format!("scene {}", scene.name),
                message: format!(
                    "no object {f:?} for the foreground layer; the scene has {}",
                    names.join(", ")
                ),
            });
        }
    }
    let in_foreground: Vec<bool> = names
        .iter()
        .map(|n| foreground.iter().any(|f| f == n))
        .collect();
    let mut layers = Vec::new();
    for (name, pass) in [
        ("Background", crate::scene::ViewLayerPass::Background),
        ("Foreground", crate::scene::ViewLayerPass::Foreground),
    ] {
        let g = render_gbuffer_with(scene, aa_samples, options, name, &|ray| {
            scene.trace_layer(ray, pass, &in_foreground)
        })?;
        layers.push((name.to_string(), g));
    }
    Ok(layers)
}

/// The pinhole frame as a deep image: the same stratified sub-pixel positions (and seed) as
/// [`render_gbuffer`], each sub-sample's surface kept apart. A pixel's sub-samples that hit
/// the same object become one deep sample (its depth and forward motion the mean of theirs),
/// and those that miss one at the miss depth with alpha 0; samples are sorted front to back
/// and stored so that compositing them "over" one another gives [`render_gbuffer`]'s colour:
/// a sample covering a share `c` of the pixel behind samples covering `C` before it is stored
/// with alpha `c / (1 - C)` and colour scaled alike.
pub fn render_deep(
    scene: &Scene,
    aa_samples: usize,
    options: &RenderOptions,
) -> Result<formats::DeepImage> {
    use formats::DeepSample;
    check_spp(aa_samples, "deep image anti-aliasing")?;
    let camera = &scene.camera;
    let (width, height) = (camera.spec.width as usize, camera.spec.height as usize);
    let bar = progress_bar(options, height, "deep image");
    let pixels: Vec<Vec<DeepSample>> = render_rows(height, &bar, |y| {
        (0..width)
            .map(|x| {
                let index = (y * width + x) as u64;
                let mut rng = pixel_rng(options.seed, Stream::GBuffer, index);
                let set = latin_hypercube(&mut rng, aa_samples, 2);
                let mut groups: Vec<Surface> = Vec::new();
                for i in 0..aa_samples {
                    let pixel = DVec2::new(x as f64 + set[i], y as f64 + set[aa_samples + i]);
                    let trace = scene.trace(&camera.ray(pixel, DVec2::ZERO, 0.0));
                    let object = trace.hit.map(|h| h.object);
                    let motion = trace.hit.map_or(DVec2::ZERO, |hit| {
                        let now = scene.image_position(&hit, 0.0).unwrap_or(pixel);
                        scene.image_position(&hit, 1.0).unwrap_or(now) - now
                    });
                    let k = match groups.iter().position(|g| g.object == object) {
                        Some(k) => k,
                        None => {
                            groups.push(Surface {
                                object,
                                count: 0,
                                color: [0.0; 4],
                                depth: 0.0,
                                motion: DVec2::ZERO,
                            });
                            groups.len() - 1
                        }
                    };
                    let g = &mut groups[k];
                    g.count += 1;
                    for (s, c) in g.color.iter_mut().zip(trace.color) {
                        *s += f64::from(c);
                    }
                    g.depth += trace.depth;
                    g.motion += motion;
                }
                let n = aa_samples as f64;
                let mut samples: Vec<DeepSample> = groups
                    .iter()
                    .map(|g| {
                        let m = g.motion / g.count as f64;
                        let depth = (g.depth / g.count as f64) as f32;
                        DeepSample {
                            color: g.color.map(|c| (c / n) as f32),
                            depth,
                            depth_back: depth,
                            motion: [m.x as f32, m.y as f32],
                        }
                    })
                    .collect();
                samples.sort_by(|a, b| a.depth.total_cmp(&b.depth));
                // Shares of the pixel to "over" semantics, front to back.
                let mut covered = 0.0f32;
                for s in &mut samples {
                    let share = s.color[3];
                    let through = (1.0 - covered).max(f32::MIN_POSITIVE);
                    s.color = s.color.map(|c| c / through);
                    s.color[3] = s.color[3].min(1.0);
                    covered += share;
                }
                samples
            })
            .collect()
    });
    let mut offsets = Vec::with_capacity(width * height + 1);
    offsets.push(0);
    let mut samples = Vec::new();
    for pixel in pixels {
        samples.extend(pixel);
        offsets.push(samples.len());
    }
    formats::DeepImage::from_samples(width, height, offsets, samples, true)
        .map_err(|e| invalid("deep image", e.to_string()))
}

/// The sub-samples of one pixel that hit one surface (an object, or nothing), summed.
struct Surface {
    /// Index into [`Scene::objects`]; `None` for the sub-samples that miss.
    object: Option<usize>,
    count: usize,
    /// Premultiplied RGBA, summed.
    color: [f64; 4],
    /// Planar depth, metres, summed.
    depth: f64,
    /// Forward motion per frame, pixels, summed.
    motion: DVec2,
}

fn render_gbuffer_with(
    scene: &Scene,
    aa_samples: usize,
    options: &RenderOptions,
    label: &str,
    trace: &(dyn Fn(&crate::camera::Ray) -> crate::scene::Trace + Sync),
) -> Result<GBuffer> {
    check_spp(aa_samples, "G-buffer anti-aliasing")?;
    let camera = &scene.camera;
    let (width, height) = (camera.spec.width as usize, camera.spec.height as usize);
    let bar = progress_bar(options, height, label);
    let pixels = render_rows(height, &bar, |y| {
        (0..width)
            .map(|x| {
                let index = (y * width + x) as u64;
                let mut rng = pixel_rng(options.seed, Stream::GBuffer, index);
                let set = latin_hypercube(&mut rng, aa_samples, 2);
                let mut sum = [0.0f64; 4];
                for i in 0..aa_samples {
                    let pixel = DVec2::new(x as f64 + set[i], y as f64 + set[aa_samples + i]);
                    let trace = trace(&camera.ray(pixel, DVec2::ZERO, 0.0));
                    for (s, c) in sum.iter_mut().zip(trace.color) {
                        *s += f64::from(c);
                    }
                }
                let color = sum.map(|s| (s / aa_samples as f64) as f32);
                let centre = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                let trace = trace(&camera.ray(centre, DVec2::ZERO, 0.0));
                let (depth, vector) = match &trace.hit {
                    Some(hit) => {
                        let now = scene.image_position(hit, 0.0).unwrap_or(centre);
                        let previous = scene.image_position(hit, -1.0).unwrap_or(now);
                        let next = scene.image_position(hit, 1.0).unwrap_or(now);
                        (
                            trace.depth as f32,
                            GBuffer::blender_vector(previous, now, next),
                        )
                    }
                    None => (MISS_DEPTH, [0.0; 4]),
                };
                (color, depth, vector)
            })
            .collect()
    });
    let mut gbuffer = GBuffer {
        width,
        height,
        color: Vec::with_capacity(pixels.len()),
        depth: Vec::with_capacity(pixels.len()),
        vector: Vec::with_capacity(pixels.len()),
    };
    for (color, depth, vector) in pixels {
        gbuffer.color.push(color);
        gbuffer.depth.push(depth);
        gbuffer.vector.push(vector);
    }
    Ok(gbuffer)
}

/// Stochastic frames: `spp` independent samples per pixel, each one ray at a uniformly random
/// lens position, time in the shutter and (with `options.jitter`) position in the pixel, with
/// the denoiser's guides of what each ray hit ([`Scene::guides`]).
pub fn render_stochastic(
    scene: &Scene,
    spp: usize,
    options: &RenderOptions,
) -> Result<StochasticFrames> {
    check_spp(spp, "stochastic frames")?;
    let camera = &scene.camera;
    if camera.physical().is_some() {
        // A sample's label is its point on the thin lens's unit aperture, which a real lens's
        // rays have no counterpart of.
        return Err(invalid(
            "stochastic frames",
            "a camera with a real lens (camera.json `lens`) has no thin-lens sample labels: \
             render its reference and G-buffer, or use the thin lens",
        ));
    }
    let (width, height) = (camera.spec.width as usize, camera.spec.height as usize);
    let total = width * height * spp;
    if total > MAX_STOCHASTIC_SAMPLES {
        return Err(invalid(
            "stochastic frames",
            format!("{width}x{height} pixels at {spp} spp exceed {MAX_STOCHASTIC_SAMPLES} samples"),
        ));
    }
    let shutter = camera.spec.shutter_frames;
    let bar = progress_bar(options, height, "stochastic frames");
    let samples = render_rows(height, &bar, |y| {
        let mut row = Vec::with_capacity(width * spp);
        for x in 0..width {
            let index = (y * width + x) as u64;
            let mut rng = pixel_rng(options.seed, Stream::Stochastic, index);
            for _ in 0..spp {
                let jitter = if options.jitter {
                    DVec2::new(uniform(&mut rng) - 0.5, uniform(&mut rng) - 0.5)
                } else {
                    DVec2::ZERO
                };
                let xi = DVec2::new(uniform(&mut rng), uniform(&mut rng));
                let time = (uniform(&mut rng) - 0.5) * shutter;
                let pixel = DVec2::new(x as f64 + 0.5, y as f64 + 0.5) + jitter;
                let (ray, lens) = camera.ray_with_lens_sample(pixel, xi, time);
                let trace = scene.trace(&ray);
                let motion = trace
                    .hit
                    .map(|hit| scene.image_velocity(&hit, time))
                    .unwrap_or(DVec2::ZERO);
                let sample = Sample {
                    color: trace.color,
                    depth: trace.depth as f32,
                    lens: [lens.x as f32, lens.y as f32],
                    time: time as f32,
                    motion: [motion.x as f32, motion.y as f32],
                    jitter: [jitter.x as f32, jitter.y as f32],
                };
                row.push((sample, scene.guides(trace.hit.as_ref())));
            }
        }
        row
    });
    let (samples, guides) = samples.into_iter().unzip();
    StochasticFrames::new(width, height, spp, samples)
        .with_guides(guides)
        .map_err(|e| invalid("stochastic frames", e.to_string()))
}

/// The converged reference: per pixel the mean of `spp` rays whose pixel position, lens
/// position and time form a Latin hypercube (stratified in every dimension).
pub fn render_reference(scene: &Scene, spp: usize, options: &RenderOptions) -> Result<RgbaImage> {
    check_spp(spp, "reference")?;
    let camera = &scene.camera;
    let (width, height) = (camera.spec.width as usize, camera.spec.height as usize);
    let shutter = camera.spec.shutter_frames;
    let bar = progress_bar(options, height, "reference");
    let pixels = render_rows(height, &bar, |y| {
        (0..width)
            .map(|x| {
                let index = (y * width + x) as u64;
                let mut rng = pixel_rng(options.seed, Stream::Reference, index);
                if let Some(lens) = camera.physical() {
                    return physical_pixel(scene, lens, x, y, spp, shutter, &mut rng);
                }
                let set = latin_hypercube(&mut rng, spp, 5);
                let dim = |d: usize, i: usize| set[d * spp + i];
                let mut sum = [0.0f64; 4];
                for i in 0..spp {
                    let pixel = DVec2::new(x as f64 + dim(0, i), y as f64 + dim(1, i));
                    let xi = DVec2::new(dim(2, i), dim(3, i));
                    let time = (dim(4, i) - 0.5) * shutter;
                    let (ray, _) = camera.ray_with_lens_sample(pixel, xi, time);
                    let trace = scene.trace(&ray);
                    for (s, c) in sum.iter_mut().zip(trace.color) {
                        *s += f64::from(c);
                    }
                }
                sum.map(|s| (s / spp as f64) as f32)
            })
            .collect()
    });
    Ok(RgbaImage {
        width,
        height,
        pixels,
    })
}

/// One reference pixel through a real lens: `spp` rays whose pixel position, exit pupil
/// point, time and wavelength form a Latin hypercube, each channel the mean of the radiance the
/// passing rays bring weighted by that channel's response at their wavelength (and by the
/// exit pupil box each was drawn from). Normalising by the passing rays' weight, not by all
/// rays, keeps a uniform scene uniform to the frame's corners, as the `physical-lens` PSFs
/// (each of which keeps its point's light) do; alpha follows green.
fn physical_pixel(
    scene: &Scene,
    lens: &crate::camera::PhysicalCamera,
    x: usize,
    y: usize,
    spp: usize,
    shutter: f64,
    rng: &mut rand_chacha::ChaCha8Rng,
) -> [f32; 4] {
    let set = latin_hypercube(rng, spp, 6);
    let dim = |d: usize, i: usize| set[d * spp + i];
    let (mut sum, mut weight) = ([0.0f64; 4], [0.0f64; 4]);
    for i in 0..spp {
        let pixel = DVec2::new(x as f64 + dim(0, i), y as f64 + dim(1, i));
        let xi = DVec2::new(dim(2, i), dim(3, i));
        let time = (dim(4, i) - 0.5) * shutter;
        let lambda = optics::Spectrum::wavelength_nm(dim(5, i));
        let Some((ray, area)) = scene.camera.physical_ray(pixel, xi, lambda, time) else {
            continue;
        };
        let rgb = lens.spectrum.rgb(lambda);
        let w = [rgb[0] * area, rgb[1] * area, rgb[2] * area, rgb[1] * area];
        let trace = scene.trace(&ray);
        for c in 0..4 {
            sum[c] += f64::from(trace.color[c]) * w[c];
            weight[c] += w[c];
        }
    }
    std::array::from_fn(|c| {
        if weight[c] > 0.0 {
            (sum[c] / weight[c]) as f32
        } else {
            0.0
        }
    })
}

/// How noisy a reference of `spp` samples is, from two independent half renders.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseEstimate {
    /// Samples per pixel of the full reference (each half has spp / 2).
    pub spp: usize,
    /// RMS over pixels and RGB of the full reference's noise in linear units:
    /// RMS(half_a - half_b) / 2 (the mean of two halves has half their difference's spread).
    pub rms_linear: f64,
    /// The same on sRGB-encoded values clamped to [0, 1] (the scale SSIM sees).
    pub rms_srgb: f64,
    /// Largest |half_a - half_b| / 2 over pixels and RGB, sRGB-encoded.
    pub max_srgb: f64,
    /// SSIM (the project's definition, `metrics::ssim_rgb`) between the two half renders: a
    /// lower bound on the full reference's SSIM against the converged image.
    pub ssim_halves: f64,
}

/// Estimates the noise of a `spp` reference by rendering two `spp / 2` halves with seeds
/// `seed` and `seed + 1` and comparing them.
pub fn estimate_reference_noise(
    scene: &Scene,
    spp: usize,
    options: &RenderOptions,
) -> Result<NoiseEstimate> {
    let half = (spp / 2).max(1);
    let a = render_reference(scene, half, options)?;
    let b = render_reference(
        scene,
        half,
        &RenderOptions {
            seed: options.seed.wrapping_add(1),
            ..*options
        },
    )?;
    let (mut lin, mut srgb, mut max) = (0.0f64, 0.0f64, 0.0f64);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        for c in 0..3 {
            let d = f64::from(p[c] - q[c]);
            lin += d * d;
            let e = f64::from(srgb_encode(p[c]) - srgb_encode(q[c]));
            srgb += e * e;
            max = max.max(e.abs());
        }
    }
    let n = (a.pixels.len() * 3).max(1) as f64;
    let flat = |image: &RgbaImage| image.pixels.iter().flatten().copied().collect::<Vec<f32>>();
    let ssim_halves = metrics::ssim_rgb(&flat(&a), &flat(&b), a.width, a.height)
        .map_err(|e| invalid("reference noise", format!("SSIM: {e}")))?;
    Ok(NoiseEstimate {
        spp: 2 * half,
        rms_linear: (lin / n).sqrt() / 2.0,
        rms_srgb: (srgb / n).sqrt() / 2.0,
        max_srgb: max / 2.0,
        ssim_halves,
    })
}

#[cfg(test)]
mod view_layer_tests {
    use super::*;

    #[test]
    fn foreground_over_background_is_the_flat_render_where_coverage_is_whole() {
        let scene = crate::builtin("occluder")
            .and_then(|s| s.with_size(48, 48))
            .expect("scene");
        let options = RenderOptions::default();
        let flat = render_gbuffer(&scene, 4, &options).expect("flat");
        let fg: Vec<String> = ["bar left", "bar middle", "bar right"]
            .map(String::from)
            .to_vec();
        let layers = render_view_layers(&scene, 4, &options, &fg).expect("layers");
        let (bg, fgl) = (&layers[0].1, &layers[1].1);
        let (mut whole, mut empty) = (0, 0);
        for i in 0..flat.color.len() {
            let a = fgl.color[i][3];
            if a == 1.0 {
                assert_eq!(fgl.color[i], flat.color[i], "pixel {i}");
                assert_eq!(fgl.depth[i], flat.depth[i]);
                whole += 1;
            } else if a == 0.0 {
                assert_eq!(bg.color[i], flat.color[i], "pixel {i}");
                assert_eq!(fgl.color[i], [0.0; 4]);
                assert_eq!(fgl.depth[i], crate::MISS_DEPTH);
                empty += 1;
            }
            // The background layer covers the whole frame behind the bars.
            assert!(
                bg.depth[i] > 1.0,
                "the bars are in the background layer at pixel {i}"
            );
        }
        assert!(whole > 50 && empty > 1000, "whole {whole}, empty {empty}");
        let none = render_view_layers(&scene, 4, &options, &["tree".to_string()]);
        assert!(none.is_err());
    }
}
