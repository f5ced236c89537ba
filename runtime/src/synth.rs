//! Synthesis options and statistics, and the CPU device: a [`PreparedFrame`] drawn by the
//! splat, integrate and composite stages in order, timed, with the statistics that `--stats`
//! writes. A pinhole, still input is returned unchanged without touching any stage.

use std::time::Instant;

use serde::Serialize;

use crate::camera::Camera;
use crate::dbset::DbSet;
use crate::gbuffer::GBuffer;
use crate::pipeline::{
    integrate_owned, splat, ClassifyOptions, CompositeOptions, Integrator, PathCounts, SplatOptions,
};
use crate::prepare::{Content, Input, Plan, PreparedFrame};
use formats::RgbaImage;

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
        let coarse = self.classify.coarse_above_px;
        if coarse.is_nan() || coarse < 1.0 {
            return Err(crate::Error::InvalidOption {
                option: "--coarse-above",
                message: format!("must be a CoC radius of at least 1 px, got {coarse}"),
            });
        }
        Ok(())
    }
}

/// Wall-clock time of each stage, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct StageTimes {
    /// Classification.
    pub classify_ms: f64,
    /// Splatting (sparse and dense). A frame without a Laplacian plane is splatted and
    /// composited band by band, and both are counted here.
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

/// Synthesises depth of field and motion blur from a pinhole G-buffer on the CPU:
/// [`Plan`] with [`Input::Flat`], drawn by [`render_cpu`]. `dbs` must hold a database of the
/// model the camera and input call for ([`Plan::model`]); it is not touched when they call
/// for nothing, and the input comes back unchanged.
///
/// ```no_run
/// use spreadlet::{Camera, GBuffer, Renderer, SynthOptions};
/// # fn main() -> Result<(), spreadlet::Error> {
/// let gbuffer = GBuffer::read_exr("input.exr".as_ref(), &Default::default())?;
/// let camera = Camera::from_json_file("camera.json".as_ref())?;
/// let mut renderer = Renderer::new(Default::default())?;
/// renderer.synthesize(&gbuffer, &camera, &SynthOptions::default())?; // loads the databases
/// let dbs = renderer.databases().expect("loaded by the first frame");
/// let (image, stats) = spreadlet::synthesize(&gbuffer, &camera, dbs, &SynthOptions::default())?;
/// println!("{} sparse records, {:.0} ms", stats.counts.sparse, stats.times.total_ms);
/// # Ok(()) }
/// ```
pub fn synthesize(
    gbuffer: &GBuffer,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats), crate::Error> {
    let prepared = Plan::new(Input::Flat(gbuffer), camera, options)?.prepare(dbs)?;
    Ok(render_cpu(prepared, dbs))
}

/// Draws a prepared frame on the CPU (splat, integrate, composite; for stochastic samples the
/// density normalisation after), and completes its statistics with the stage times and the
/// total since preparation started.
pub fn render_cpu(frame: PreparedFrame, dbs: &DbSet) -> (RgbaImage, SynthStats) {
    let PreparedFrame {
        content,
        mut stats,
        options,
        normalize_density,
        sample_means,
        started,
    } = frame;
    let mut image = match content {
        Content::PassThrough(image) => image,
        Content::Records(classified) => render_classified(&classified, dbs, &options, &mut stats),
    };
    if normalize_density {
        crate::reconstruct::normalize_density(&mut image);
    }
    if let Some(means) = &sample_means {
        means.lean(&mut image);
    }
    stats.times.total_ms = ms_since(started);
    (image, stats)
}

impl SynthStats {
    /// The statistics a frame starts with: its effects, its size without overscan, the
    /// overscan, and what `options` fix.
    pub(crate) fn starting(
        effects: crate::pipeline::Effects,
        (width, height): (usize, usize),
        overscan: crate::gbuffer::Overscan,
        options: &SynthOptions,
    ) -> Self {
        SynthStats {
            defocus: effects.defocus,
            motion: effects.motion,
            width,
            height,
            overscan,
            frame_edges: options.classify.frame_edges,
            layers: options.classify.layers,
            integrator: options.integrator,
            ..SynthStats::default()
        }
    }
}

/// Records what classification produced in `stats`: models, counts per path, padding, layers
/// holding at least one record.
pub(crate) fn record_classified(
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

/// The CPU stages after classification: splat, integrate, composite, with their times in
/// `stats`.
fn render_classified(
    classified: &crate::pipeline::Classified,
    dbs: &DbSet,
    options: &SynthOptions,
    stats: &mut SynthStats,
) -> RgbaImage {
    let db = classified.database_or(dbs.combined.as_ref());
    let sharpness = |db| {
        if options.composite.restore_occluded {
            crate::pipeline::composite::layer_sharpness(classified, db)
        } else {
            Vec::new()
        }
    };
    if crate::pipeline::direct::all_direct(classified) {
        let t = Instant::now();
        let sharpness = sharpness(db);
        let image = crate::pipeline::direct::splat_composite(
            classified,
            db,
            &options.splat,
            &options.composite,
            &sharpness,
        );
        stats.times.splat_ms = ms_since(t);
        return image;
    }
    let draw = |frame: &crate::pipeline::Classified, times: &mut crate::synth::StageTimes| {
        let t = Instant::now();
        let stack = splat(frame, db, &options.splat);
        times.splat_ms += ms_since(t);
        let t = Instant::now();
        let layers = integrate_owned(stack, options.integrator);
        times.integrate_ms += ms_since(t);
        layers
    };
    let mut layers = draw(classified, &mut stats.times);
    for level in &classified.coarse {
        let coarse = draw(&level.classified, &mut stats.times);
        let t = Instant::now();
        crate::pipeline::integrate::add_upsampled(&mut layers, coarse, level.scale);
        stats.times.integrate_ms += ms_since(t);
    }

    let t = Instant::now();
    let sharpness = sharpness(db);
    let image = crate::pipeline::composite::composite_with_sharpness(
        &layers,
        &options.composite,
        &sharpness,
    );
    stats.times.composite_ms = ms_since(t);
    image
}
