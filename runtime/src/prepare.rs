//! The one seam between what a frame is and the device that draws it.
//!
//! Every frame, of any input kind, goes the same two steps:
//!
//! 1. [`Plan::new`] checks the options and the camera against the input and finds the effects
//!    the frame calls for, once ([`Plan::effects`] says which database model it needs);
//!    [`Plan::prepare`] then classifies the input into splat records with those databases
//!    (or sees that nothing needs simulating) and starts the frame's statistics.
//! 2. A device draws the [`PreparedFrame`]: [`crate::synth::render_cpu`] on the CPU, or
//!    `gpu::render_gpu` on the GPU. Both start from the same records, so both report the
//!    same classification, and a bad input fails in step 1 with the same typed error on
//!    either device.
//!
//! ```
//! use spreadlet::{render_cpu, Camera, DbSet, GBuffer, Input, Plan, SynthOptions};
//! # fn main() -> Result<(), spreadlet::Error> {
//! let gbuffer = GBuffer::from_planes(3, 1, vec![[0.2, 0.4, 0.6, 1.0]; 3], Some(vec![1.5; 3]), None)?;
//! let camera = Camera::from_json_str(
//!     r#"{"width": 3, "height": 1, "focal_length_mm": 50, "sensor_width_mm": 36}"#,
//! )?;
//! let plan = Plan::new(Input::Flat(&gbuffer), &camera, &SynthOptions::default())?;
//! // The databases plan.model() asks for; a pinhole that does not move asks for none.
//! let dbs = DbSet::new(None, None)?;
//! let prepared = plan.prepare(&dbs)?;
//! assert!(prepared.classified().is_none()); // nothing to draw: the input passes through
//! let (image, stats) = render_cpu(prepared, &dbs);
//! assert_eq!(image.pixels, gbuffer.color);
//! assert_eq!(stats.counts.copied, 3);
//! # Ok(()) }
//! ```

use std::time::Instant;

use formats::{DeepImage, RgbaImage, StochasticFrames};
use psf_db::PsfModel;

use crate::camera::Camera;
use crate::dbset::DbSet;
use crate::gbuffer::{GBuffer, ViewLayer};
use crate::pipeline::classify::{self, ClassifyError};
use crate::pipeline::{Classified, Effects, PathCounts};
use crate::reconstruct::SamplePlacement;
use crate::synth::{ms_since, record_classified, SynthOptions, SynthStats};
use crate::Error;

/// One frame's input, of any kind.
#[derive(Clone, Copy, Debug)]
pub enum Input<'a> {
    /// A pinhole G-buffer (colour, depth, motion).
    Flat(&'a GBuffer),
    /// Several render layers of one frame (Blender view layers, or one file per layer): each
    /// layer's pixels blurred with their own depth and motion.
    Layers(&'a [ViewLayer]),
    /// A deep image: every deep sample blurred with its own depth and motion.
    Deep(&'a DeepImage),
    /// Stochastic frames (each sample labelled with its lens position and time), and how each
    /// sample, moved back to the lens and shutter centre, is put on the pixel grid.
    Samples(&'a StochasticFrames, SamplePlacement),
}

impl<'a> Input<'a> {
    /// Stochastic frames with the placement their sample count calls for
    /// ([`SamplePlacement::for_spp`]).
    pub fn samples(frames: &'a StochasticFrames) -> Self {
        Input::Samples(frames, SamplePlacement::for_spp(frames.spp))
    }

    /// The effects `camera` and this input call for.
    pub fn effects(&self, camera: &Camera) -> Effects {
        match *self {
            Input::Flat(g) => Effects::of(camera, g),
            Input::Layers(layers) => classify::layered_effects(layers, camera),
            Input::Deep(deep) => classify::deep_effects(deep, camera),
            Input::Samples(frames, _) => crate::reconstruct::effects_of(camera, frames),
        }
    }
}

/// A frame checked and its effects found, before any database is needed.
#[derive(Clone, Debug)]
pub struct Plan<'a> {
    input: Input<'a>,
    camera: &'a Camera,
    options: SynthOptions,
    effects: Effects,
}

impl<'a> Plan<'a> {
    /// Checks `options` and what `camera` can do with `input`, and finds the effects. Stochastic
    /// frames take `options` as reconstruction applies them (colour restored behind occluders, `reconstruct::for_samples`).
    pub fn new(
        input: Input<'a>,
        camera: &'a Camera,
        options: &SynthOptions,
    ) -> Result<Self, Error> {
        options.validate()?;
        let options = match input {
            Input::Samples(..) => {
                if let Some(lens) = &camera.lens {
                    // A sample's label is a point on the thin lens's unit aperture: it says where
                    // the sample's pinhole image is only through the thin lens.
                    return Err(Error::Unsupported(format!(
                        "reconstruction through a real lens (camera.json lens {lens:?}) is not \
                         supported: stochastic frames are labelled for the thin lens; remove \
                         `lens`"
                    )));
                }
                crate::reconstruct::for_samples(options)
            }
            _ => options.clone(),
        };
        Ok(Plan {
            input,
            camera,
            options,
            effects: input.effects(camera),
        })
    }

    /// The effects the frame calls for.
    pub fn effects(&self) -> Effects {
        self.effects
    }

    /// The cheapest database model that serves the frame (`None`: nothing to simulate).
    pub fn model(&self) -> Option<PsfModel> {
        self.effects.cheapest_model()
    }

    /// The camera.
    pub fn camera(&self) -> &'a Camera {
        self.camera
    }

    /// The options as the frame applies them.
    pub fn options(&self) -> &SynthOptions {
        &self.options
    }

    /// The plan with the frame's own PSF images kept packed
    /// ([`crate::pipeline::ClassifyOptions::pack_images`]), for the CPU splat.
    pub(crate) fn with_images_packed(mut self) -> Self {
        self.options.classify.pack_images = true;
        self
    }

    /// The plan with every sparse record kept sparse
    /// ([`crate::pipeline::ClassifyOptions::few_sparse_images`] off), for the GPU: it
    /// integrates a layer in a fraction of the CPU's time, and a frame with PSF images of its
    /// own would upload its database, pipelines and all, for that frame alone.
    pub(crate) fn with_sparse_records_kept(mut self) -> Self {
        self.options.classify.few_sparse_images = false;
        self
    }

    /// Classifies the input with `dbs` (which must serve [`Plan::model`]; not touched when
    /// nothing needs simulating) and starts the frame's statistics and its clock.
    pub fn prepare(self, dbs: &DbSet) -> Result<PreparedFrame, Error> {
        let started = Instant::now();
        let Plan {
            input,
            camera,
            options,
            effects,
        } = self;
        let sample_means = match input {
            Input::Samples(frames, _) if options.classify.lean_to_sample_means => {
                crate::sample_mean::PixelSampleMeans::of(frames, camera)
            }
            _ => None,
        };
        let (content, mut stats) = match input {
            Input::Flat(g) => prepare_flat(g, camera, effects, dbs, &options)?,
            Input::Layers(layers) => match layers {
                // One layer that is not declared still goes exactly the single-input way.
                [one] if !one.still => prepare_flat(&one.gbuffer, camera, effects, dbs, &options)?,
                _ => prepare_layers(layers, camera, effects, dbs, &options)?,
            },
            Input::Deep(deep) => prepare_deep(deep, camera, effects, dbs, &options)?,
            Input::Samples(frames, placement) => {
                let (classified, stats) = crate::reconstruct::classify_samples(
                    frames, camera, effects, dbs, &options, placement,
                )?;
                (Content::Records(classified), stats)
            }
        };
        if let Content::Records(classified) = &content {
            record_classified(classified, dbs, &mut stats);
        }
        stats.times.classify_ms = ms_since(started);
        Ok(PreparedFrame {
            content,
            stats,
            normalize_density: matches!(input, Input::Samples(..)),
            sample_means,
            options,
            started,
        })
    }
}

/// A frame ready for a device: its splat records (or the input itself when nothing needs
/// simulating), the options it applies and its statistics so far.
#[derive(Clone, Debug)]
pub struct PreparedFrame {
    pub(crate) content: Content,
    pub(crate) stats: SynthStats,
    pub(crate) options: SynthOptions,
    /// Divide by the accumulated coverage after compositing (stochastic samples land unevenly).
    pub(crate) normalize_density: bool,
    /// After the normalisation, lean the image towards these per-pixel sample means
    /// ([`crate::sample_mean`]).
    pub(crate) sample_means: Option<crate::sample_mean::PixelSampleMeans>,
    /// When preparation started: the frame's total time counts from here.
    pub(crate) started: Instant,
}

impl PreparedFrame {
    /// The splat records, or `None` when the frame needs nothing simulated.
    pub fn classified(&self) -> Option<&Classified> {
        match &self.content {
            Content::Records(c) => Some(c),
            Content::PassThrough(_) => None,
        }
    }

    /// The statistics so far: effects, size, counts per path, layers, classification time.
    pub fn stats(&self) -> &SynthStats {
        &self.stats
    }

    /// The options the frame applies.
    pub fn options(&self) -> &SynthOptions {
        &self.options
    }

    /// The database the frame's records index: its own when classification added PSFs to the
    /// set's (the physical-lens PSFs of its moving pixels smeared along their motion), else
    /// `combined` (the set's).
    pub fn database_or<'a>(
        &'a self,
        combined: Option<&'a psf_db::PsfDatabase>,
    ) -> Option<&'a psf_db::PsfDatabase> {
        match &self.content {
            Content::Records(c) => c.database_or(combined),
            Content::PassThrough(_) => combined,
        }
    }
}

/// What a device draws.
#[derive(Clone, Debug)]
pub(crate) enum Content {
    /// Nothing to simulate (pinhole and still): the input, unchanged.
    PassThrough(RgbaImage),
    /// Records for the splat, integrate and composite stages.
    Records(Classified),
}

fn prepare_flat(
    gbuffer: &GBuffer,
    camera: &Camera,
    effects: Effects,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(Content, SynthStats), ClassifyError> {
    let mut stats = SynthStats::starting(
        effects,
        (gbuffer.frame_width(), gbuffer.frame_height()),
        gbuffer.overscan,
        options,
    );
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
        return Ok((Content::PassThrough(image), stats));
    }
    let classified = classify::classify_with(gbuffer, camera, effects, dbs, &options.classify)?;
    Ok((Content::Records(classified), stats))
}

fn prepare_layers(
    layers: &[ViewLayer],
    camera: &Camera,
    effects: Effects,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(Content, SynthStats), ClassifyError> {
    let first = &layers.first().ok_or(ClassifyError::NoInputLayers)?.gbuffer;
    let mut stats = SynthStats::starting(
        effects,
        (first.frame_width(), first.frame_height()),
        first.overscan,
        options,
    );
    if effects.cheapest_model().is_none() {
        // Nothing to blur: the layers composited per pixel, nearest over farthest.
        classify::check_layers_line_up(layers, camera)?;
        let image = composite_layers_per_pixel(layers);
        stats.counts.copied = image.pixels.iter().filter(|c| **c != [0.0; 4]).count();
        stats.layers_used = 1;
        return Ok((Content::PassThrough(image), stats));
    }
    let classified =
        classify::classify_layers_with(layers, camera, effects, dbs, &options.classify)?;
    Ok((Content::Records(classified), stats))
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

fn prepare_deep(
    deep: &DeepImage,
    camera: &Camera,
    effects: Effects,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(Content, SynthStats), ClassifyError> {
    let mut stats = SynthStats::starting(
        effects,
        (deep.frame_width(), deep.frame_height()),
        deep.overscan,
        options,
    );
    if effects.cheapest_model().is_none() {
        classify::check_deep_size(deep, camera)?;
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
        return Ok((Content::PassThrough(image), stats));
    }
    let classified = classify::classify_deep_with(deep, camera, effects, dbs, &options.classify)?;
    Ok((Content::Records(classified), stats))
}
