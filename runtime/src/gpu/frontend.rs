//! The GPU device: a [`PreparedFrame`] (classified on the CPU, the same records the CPU device
//! draws) drawn by the splat, integrate and composite stages on the GPU, with the same
//! [`SynthStats`].

use std::time::Instant;

use crate::synth::ms_since;

use super::{GpuContext, GpuError, GpuStageTimes, GpuSynthOptions, GpuSynthesizer};
use crate::dbset::DbSet;
use crate::prepare::{Content, PreparedFrame};
use crate::synth::{SynthOptions, SynthStats};
use formats::RgbaImage;

impl GpuSynthOptions {
    /// The GPU knobs matching the CPU path's `options` (rotation sampling, compositing).
    pub fn from_synth(options: &SynthOptions) -> Self {
        GpuSynthOptions {
            rotation: options.splat.rotation,
            composite: options.composite,
            ..GpuSynthOptions::default()
        }
    }
}

/// Draws a prepared frame on the GPU, as [`crate::synth::render_cpu`] does on the CPU. `gpu`
/// must have been made for the database the frame's records index
/// ([`PreparedFrame::database_or`] of `dbs.combined`: see [`GpuSynthesizer::for_database`]; a
/// different database is an error); reuse it across frames. `stats.times` holds classification (CPU)
/// and the GPU stages; the GPU's own breakdown (upload, readback, whether timestamps were
/// used) comes back too.
pub fn render_gpu(
    gpu: &mut GpuSynthesizer,
    frame: PreparedFrame,
    dbs: &DbSet,
) -> Result<(RgbaImage, SynthStats, GpuStageTimes), GpuError> {
    let PreparedFrame {
        content,
        mut stats,
        options,
        normalize_density,
        sample_means,
        started,
    } = frame;
    let classified = match content {
        Content::PassThrough(image) => {
            stats.times.total_ms = ms_since(started);
            return Ok((image, stats, GpuStageTimes::default()));
        }
        Content::Records(classified) => classified,
    };
    if classified.packed.is_some() {
        return Err(GpuError::Input(
            "the frame was classified with its PSF images packed, which only the CPU splat \
             draws: classify it with `pack_images` off"
                .into(),
        ));
    }
    let db = classified.database_or(dbs.combined.as_ref());
    gpu.check_database(db)?;
    gpu.apply_call_options(&options);
    if options.composite.restore_occluded {
        gpu.layer_sharpness = crate::pipeline::composite::layer_sharpness(&classified, db);
    }
    let result = if classified.coarse.is_empty() {
        gpu.run(&classified.frame, &classified.records, options.integrator)
    } else {
        with_coarse_levels(gpu, &classified, &options)
    };
    gpu.layer_sharpness.clear();
    let (mut image, gpu_times) = result?;
    if normalize_density {
        crate::reconstruct::normalize_density(&mut image);
    }
    if let Some(means) = &sample_means {
        means.lean(&mut image);
    }
    stats.times.splat_ms = gpu_times.splat_ms;
    stats.times.integrate_ms = gpu_times.integrate_ms;
    stats.times.composite_ms = gpu_times.composite_ms;
    stats.times.total_ms = ms_since(started);
    Ok((image, stats, gpu_times))
}

impl GpuSynthesizer {
    /// A synthesizer for `db` (`None`: copies only), the usual entry point of the binary
    /// (pass `DbSet::combined`).
    pub fn for_database(
        ctx: &GpuContext,
        db: Option<&psf_db::PsfDatabase>,
        options: GpuSynthOptions,
    ) -> Result<Self, GpuError> {
        match db {
            Some(db) => Self::new(ctx, db, options),
            None => Self::without_database(ctx, options),
        }
    }
}

/// A frame with coarse levels ([`crate::pipeline::types::CoarseLevel`]): every level splatted
/// and integrated on the device and read back, the coarse ones upsampled into the frame's
/// layers and composited on the CPU, as the CPU path does.
fn with_coarse_levels(
    gpu: &mut GpuSynthesizer,
    classified: &crate::pipeline::Classified,
    options: &crate::synth::SynthOptions,
) -> Result<(RgbaImage, GpuStageTimes), GpuError> {
    use crate::pipeline::IntegratedLayers;
    let mut times = GpuStageTimes::default();
    let t = Instant::now();
    let mut layers_of =
        |frame: &crate::pipeline::Classified| -> Result<IntegratedLayers, GpuError> {
            let planes = gpu.layer_images(&frame.frame, &frame.records, options.integrator)?;
            Ok(IntegratedLayers {
                frame: frame.frame,
                planes,
                rows: Vec::new(),
                coarse: Vec::new(),
            })
        };
    let mut layers = layers_of(classified)?;
    for level in &classified.coarse {
        let coarse = layers_of(&level.classified)?;
        crate::pipeline::integrate::add_upsampled(&mut layers, coarse, level.scale);
    }
    times.integrate_ms = ms_since(t);
    let t = Instant::now();
    let image = crate::pipeline::composite::composite_with_sharpness(
        &layers,
        &options.composite,
        &gpu.layer_sharpness,
    );
    times.composite_ms = ms_since(t);
    times.total_ms = times.integrate_ms + times.composite_ms;
    Ok((image, times))
}
