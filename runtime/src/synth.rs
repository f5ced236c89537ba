//! Synthesis on the CPU: the four pipeline stages in order, timed, with the statistics that
//! `--stats` writes. A pinhole, still input is returned unchanged without touching any stage.

use std::time::Instant;

use serde::Serialize;

use crate::camera::Camera;
use crate::dbset::DbSet;
use crate::gbuffer::{GBuffer, ViewLayer};
use crate::pipeline::{
    classify, integrate, splat, ClassifyOptions, CompositeOptions, Effects, Integrator, PathCounts,
    SplatOptions,
};
use formats::{DeepImage, RgbaImage};

/// All knobs of synthesis. The default is exactly what `spreadlet synth` does with no flags.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SynthOptions {
    /// Classification (layers, soft layering, edge fix, copy threshold).
    pub classify: ClassifyOptions,
    /// Splatting (rotation sampling).
    pub splat: SplatOptions,
    /// Integration method.
    pub integrator: Integrator,
    /// Compositing.
    pub composite: CompositeOptions,
}

impl SynthOptions {
    /// Refuses options out of range, naming the option as the command line does.
    pub fn validate(&self) -> Result<(), crate::Error> {
        let layers = self.classify.layers;
        if layers == 0 || layers > 64 {
            return Err(crate::Error::InvalidOption {
                option: "--layers",
                message: format!("must be between 1 and 64, got {layers}"),
            });
        }
        if let Some(soft) = self.classify.soft_layers {
            if !(soft.is_finite() && soft >= 0.0) {
                return Err(crate::Error::InvalidOption {
                    option: "--soft-layers",
                    message: format!("must be zero or positive, got {soft}"),
                });
            }
        }
        Ok(())
    }
}

/// Wall-clock time of each stage, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StageTimes {
    /// Classification.
    pub classify_ms: f64,
    /// Splatting (sparse and dense).
    pub splat_ms: f64,
    /// Integration.
    pub integrate_ms: f64,
    /// Compositing.
    pub composite_ms: f64,
    /// The four together.
    pub total_ms: f64,
}

/// What a synthesis did: effects, database, counts per path, layers, times.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SynthStats {
    /// Depth of field simulated.
    pub defocus: bool,
    /// Motion blur simulated.
    pub motion: bool,
    /// The models of the databases used (empty when nothing was simulated).
    pub models: Vec<&'static str>,
    /// Image width, pixels (the frame, without overscan).
    pub width: usize,
    /// Image height, pixels (the frame, without overscan).
    pub height: usize,
    /// Pixels of the input beyond the frame on each side, used as real data.
    pub overscan: crate::gbuffer::Overscan,
    /// What was assumed beyond the input's pixels.
    pub frame_edges: crate::pipeline::FrameEdges,
    /// Records per path (and dropped, clamped, split counts).
    pub counts: PathCounts,
    /// Layers requested.
    pub layers: u32,
    /// Layers holding at least one record.
    pub layers_used: u32,
    /// Padding of each layer, pixels.
    pub pad_px: u32,
    /// Integration method.
    pub integrator: Integrator,
    /// Stage times.
    pub times: StageTimes,
}

/// Milliseconds since `t`: the one timer of the stage statistics.
pub fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

impl SynthStats {
    /// The statistics a run starts with: its effects, the frame of `gbuffer` and the options.
    fn starting(effects: Effects, gbuffer: &GBuffer, options: &SynthOptions) -> Self {
        SynthStats {
            defocus: effects.defocus,
            motion: effects.motion,
            width: gbuffer.frame_width(),
            height: gbuffer.frame_height(),
            overscan: gbuffer.overscan,
            frame_edges: options.classify.frame_edges,
            layers: options.classify.layers,
            integrator: options.integrator,
            ..SynthStats::default()
        }
    }
}

/// The device-independent front of synthesis: what the input calls for, classified, or the
/// input itself when it calls for nothing.
#[derive(Clone, Debug)]
pub enum Prepared {
    /// Nothing to simulate (pinhole and still): the input, unchanged.
    PassThrough(RgbaImage),
    /// Records for the splat, integrate and composite stages (on either device).
    Classified(crate::pipeline::Classified),
}

/// Classifies `gbuffer` (or recognises that it needs nothing) and starts the statistics of the
/// run: effects, size, counts per path, layers used, classification time. Shared by the CPU
/// path ([`synthesize`]) and the GPU path (`gpu::synthesize_gpu`), so both report alike.
pub fn classify_for_synthesis(
    gbuffer: &GBuffer,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(Prepared, SynthStats), crate::pipeline::classify::ClassifyError> {
    let effects = Effects::of(camera, gbuffer);
    let mut stats = SynthStats::starting(effects, gbuffer, options);
    let t = Instant::now();
    if effects.cheapest_model().is_none() {
        // Nothing to simulate: every PSF is a single pixel; the input comes back as it is.
        classify::classify_sizes(gbuffer, camera)?;
        stats.counts = PathCounts {
            copied: gbuffer.color.iter().filter(|c| **c != [0.0; 4]).count(),
            dropped: gbuffer.dropped_pixels,
            ..PathCounts::default()
        };
        stats.layers_used = 1;
        let frame = gbuffer.frame_only();
        let image = RgbaImage {
            width: frame.width,
            height: frame.height,
            pixels: frame.color,
        };
        stats.times.classify_ms = ms_since(t);
        return Ok((Prepared::PassThrough(image), stats));
    }
    let classified = classify(gbuffer, camera, dbs, &options.classify)?;
    stats.times.classify_ms = ms_since(t);
    record_classified(&classified, dbs, &mut stats);
    Ok((Prepared::Classified(classified), stats))
}

/// [`classify_for_synthesis`] for a layered input (view layers, one file per render layer):
/// the layers' pixels classified together ([`crate::pipeline::classify::classify_layers`]).
/// A single layer that is not declared still goes exactly the single-input way.
pub fn classify_layers_for_synthesis(
    layers: &[ViewLayer],
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(Prepared, SynthStats), crate::pipeline::classify::ClassifyError> {
    use crate::pipeline::classify::{classify_layers, layered_effects, ClassifyError};
    let first = match layers {
        [one] if !one.still => return classify_for_synthesis(&one.gbuffer, camera, dbs, options),
        [first, ..] => &first.gbuffer,
        [] => return Err(ClassifyError::NoInputLayers),
    };
    let effects = layered_effects(layers, camera);
    let mut stats = SynthStats::starting(effects, first, options);
    let t = Instant::now();
    if effects.cheapest_model().is_none() {
        // Nothing to blur: the layers composited per pixel, nearest over farthest.
        crate::pipeline::classify::check_layers_line_up(layers, camera)?;
        let image = composite_layers_per_pixel(layers);
        stats.counts.copied = image.pixels.iter().filter(|c| **c != [0.0; 4]).count();
        stats.layers_used = 1;
        stats.times.classify_ms = ms_since(t);
        return Ok((Prepared::PassThrough(image), stats));
    }
    let classified = classify_layers(layers, camera, dbs, &options.classify)?;
    stats.times.classify_ms = ms_since(t);
    record_classified(&classified, dbs, &mut stats);
    Ok((Prepared::Classified(classified), stats))
}

/// The layers' frames composited per pixel, nearest over farthest (premultiplied "over"),
/// each pixel's order by its depth in each layer (no depth: farthest).
fn composite_layers_per_pixel(layers: &[ViewLayer]) -> RgbaImage {
    let frames: Vec<GBuffer> = layers.iter().map(|l| l.gbuffer.frame_only()).collect();
    let (w, h) = (frames[0].width, frames[0].height);
    let mut image = RgbaImage::new(w, h);
    let mut order: Vec<(f32, [f32; 4])> = Vec::with_capacity(frames.len());
    for (i, out) in image.pixels.iter_mut().enumerate() {
        order.clear();
        order.extend(frames.iter().map(|f| {
            let d = f.depth.as_ref().map_or(f32::INFINITY, |d| d[i]);
            (d, f.color[i])
        }));
        order.sort_by(|a, b| b.0.total_cmp(&a.0)); // farthest first
        let mut acc = [0.0f32; 4];
        for (_, c) in &order {
            let keep = 1.0 - c[3].clamp(0.0, 1.0);
            acc = std::array::from_fn(|k| c[k] + keep * acc[k]);
        }
        *out = acc;
    }
    image
}

/// [`classify_for_synthesis`] for a deep image: every deep sample a fragment
/// ([`crate::pipeline::classify::classify_deep`]); with nothing to blur, the image flattened.
pub fn classify_deep_for_synthesis(
    deep: &DeepImage,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(Prepared, SynthStats), crate::pipeline::classify::ClassifyError> {
    use crate::pipeline::classify::{check_deep_size, classify_deep, deep_effects};
    let effects = deep_effects(deep, camera);
    let mut stats = SynthStats {
        defocus: effects.defocus,
        motion: effects.motion,
        width: deep.frame_width(),
        height: deep.frame_height(),
        overscan: deep.overscan,
        frame_edges: options.classify.frame_edges,
        layers: options.classify.layers,
        integrator: options.integrator,
        ..SynthStats::default()
    };
    let t = Instant::now();
    if effects.cheapest_model().is_none() {
        check_deep_size(deep, camera)?;
        let flat = deep.flatten();
        let (fw, fh, o) = (deep.frame_width(), deep.frame_height(), deep.overscan);
        let pixels = (0..fw * fh)
            .map(|i| flat[(o.top + i / fw) * deep.width + o.left + i % fw])
            .collect();
        let image = RgbaImage {
            width: fw,
            height: fh,
            pixels,
        };
        stats.counts.copied = image.pixels.iter().filter(|c| **c != [0.0; 4]).count();
        stats.counts.dropped = deep.dropped_samples;
        stats.layers_used = 1;
        stats.times.classify_ms = ms_since(t);
        return Ok((Prepared::PassThrough(image), stats));
    }
    let classified = classify_deep(deep, camera, dbs, &options.classify)?;
    stats.times.classify_ms = ms_since(t);
    record_classified(&classified, dbs, &mut stats);
    Ok((Prepared::Classified(classified), stats))
}

/// [`synthesize`] for a deep image ([`classify_deep_for_synthesis`]).
pub fn synthesize_deep(
    deep: &DeepImage,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats), crate::pipeline::classify::ClassifyError> {
    let total = Instant::now();
    let prepared = classify_deep_for_synthesis(deep, camera, dbs, options)?;
    Ok(render_prepared(prepared, dbs, options, total))
}

/// [`synthesize`] for a layered input ([`classify_layers_for_synthesis`]).
pub fn synthesize_layers(
    layers: &[ViewLayer],
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats), crate::pipeline::classify::ClassifyError> {
    let total = Instant::now();
    let prepared = classify_layers_for_synthesis(layers, camera, dbs, options)?;
    Ok(render_prepared(prepared, dbs, options, total))
}

/// Synthesises depth of field and motion blur from a pinhole G-buffer. `dbs` must hold a
/// database of the model the camera and input call for ([`Effects::cheapest_model`]); it is
/// not touched when they call for nothing.
pub fn synthesize(
    gbuffer: &GBuffer,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats), crate::pipeline::classify::ClassifyError> {
    let total = Instant::now();
    let prepared = classify_for_synthesis(gbuffer, camera, dbs, options)?;
    Ok(render_prepared(prepared, dbs, options, total))
}

/// The CPU stages after classification: the image of `prepared`, its statistics completed
/// with the total time since `total`.
fn render_prepared(
    (prepared, mut stats): (Prepared, SynthStats),
    dbs: &DbSet,
    options: &SynthOptions,
    total: Instant,
) -> (RgbaImage, SynthStats) {
    let image = match prepared {
        Prepared::PassThrough(image) => image,
        Prepared::Classified(classified) => {
            render_classified(&classified, dbs, options, &mut stats)
        }
    };
    stats.times.total_ms = ms_since(total);
    (image, stats)
}

/// Records what classification produced in `stats`: models, counts per path, padding, layers
/// holding at least one record.
pub fn record_classified(
    classified: &crate::pipeline::Classified,
    dbs: &DbSet,
    stats: &mut SynthStats,
) {
    stats.models = dbs.models();
    stats.counts = classified.counts;
    stats.pad_px = classified.frame.pad;
    stats.layers_used = classified
        .layers
        .iter()
        .filter(|l| l.record_count > 0)
        .count() as u32;
}

/// The CPU stages after classification, shared by synthesis and reconstruction: splat,
/// integrate, composite, with their times (and what [`record_classified`] records) in `stats`.
pub fn render_classified(
    classified: &crate::pipeline::Classified,
    dbs: &DbSet,
    options: &SynthOptions,
    stats: &mut SynthStats,
) -> RgbaImage {
    record_classified(classified, dbs, stats);

    let t = Instant::now();
    let stack = splat(classified, dbs.combined.as_ref(), &options.splat);
    stats.times.splat_ms = ms_since(t);

    let t = Instant::now();
    let layers = integrate(&stack, options.integrator);
    stats.times.integrate_ms = ms_since(t);
    drop(stack);

    let t = Instant::now();
    let sharpness = if options.composite.restore_occluded {
        crate::pipeline::composite::layer_sharpness(classified, dbs.combined.as_ref())
    } else {
        Vec::new()
    };
    let image = crate::pipeline::composite::composite_with_sharpness(
        &layers,
        &options.composite,
        &sharpness,
    );
    stats.times.composite_ms = ms_since(t);
    image
}
