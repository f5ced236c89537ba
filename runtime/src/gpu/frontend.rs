//! The GPU twin of [`crate::synth::synthesize`], for `--backend gpu|auto`: classification on
//! the CPU (the same records both paths consume), then splat, integrate and composite on the
//! GPU, with the same [`SynthStats`].

use crate::synth::ms_since;
use std::time::Instant;

use super::{GpuContext, GpuError, GpuStageTimes, GpuSynthOptions, GpuSynthesizer};
use crate::camera::Camera;
use crate::dbset::DbSet;
use crate::gbuffer::GBuffer;
use crate::synth::{classify_for_synthesis, Prepared, SynthOptions, SynthStats};
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

/// Synthesises like [`crate::synth::synthesize`], with the stages after classification on the
/// GPU. `gpu` must have been made for `dbs.combined` (see [`GpuSynthesizer::for_database`];
/// a different database is an error); reuse it across frames. `stats.times` holds classification (CPU) and the GPU stages; the
/// GPU's own breakdown (upload, readback, whether timestamps were used) comes back too.
pub fn synthesize_gpu(
    gpu: &mut GpuSynthesizer,
    gbuffer: &GBuffer,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats, GpuStageTimes), GpuError> {
    synthesize_input_gpu(
        gpu,
        |o| classify_for_synthesis(gbuffer, camera, dbs, o),
        dbs,
        options,
    )
}

/// [`synthesize_gpu`] for a layered input (`synth::classify_layers_for_synthesis`).
pub fn synthesize_layers_gpu(
    gpu: &mut GpuSynthesizer,
    layers: &[crate::gbuffer::ViewLayer],
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats, GpuStageTimes), GpuError> {
    synthesize_input_gpu(
        gpu,
        |o| crate::synth::classify_layers_for_synthesis(layers, camera, dbs, o),
        dbs,
        options,
    )
}

/// [`crate::synth::synthesize_deep`] with the splat, integrate and composite stages on the
/// GPU (classification on the CPU).
pub fn synthesize_deep_gpu(
    gpu: &mut GpuSynthesizer,
    deep: &formats::DeepImage,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats, GpuStageTimes), GpuError> {
    synthesize_input_gpu(
        gpu,
        |o| crate::synth::classify_deep_for_synthesis(deep, camera, dbs, o),
        dbs,
        options,
    )
}

/// The GPU stages after `classify` has run on the CPU.
fn synthesize_input_gpu(
    gpu: &mut GpuSynthesizer,
    classify: impl FnOnce(
        &SynthOptions,
    ) -> Result<
        (crate::synth::Prepared, SynthStats),
        crate::pipeline::classify::ClassifyError,
    >,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats, GpuStageTimes), GpuError> {
    gpu.check_database(dbs.combined.as_ref())?;
    gpu.apply_call_options(options);
    let total = Instant::now();
    let (prepared, mut stats) = classify(options).map_err(|e| GpuError::Input(e.to_string()))?;
    let classified = match prepared {
        Prepared::PassThrough(image) => {
            stats.times.total_ms = ms_since(total);
            return Ok((image, stats, GpuStageTimes::default()));
        }
        Prepared::Classified(classified) => classified,
    };
    let (image, gpu_times) = gpu.run(&classified.frame, &classified.records, options.integrator)?;
    stats.times.splat_ms = gpu_times.splat_ms;
    stats.times.integrate_ms = gpu_times.integrate_ms;
    stats.times.composite_ms = gpu_times.composite_ms;
    stats.times.total_ms = ms_since(total);
    Ok((image, stats, gpu_times))
}

/// Reconstructs like [`crate::reconstruct::reconstruct`] from stochastic frames, with the
/// stages after classification on the GPU (the same records as the CPU path), then the same
/// density normalisation on the CPU.
pub fn reconstruct_gpu(
    gpu: &mut GpuSynthesizer,
    frames: &formats::StochasticFrames,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats, GpuStageTimes), GpuError> {
    gpu.check_database(dbs.combined.as_ref())?;
    let options = &crate::reconstruct::for_samples(options);
    gpu.apply_call_options(options);
    let total = Instant::now();
    let (classified, mut stats) = crate::reconstruct::classify_samples(
        frames,
        camera,
        dbs,
        options,
        crate::reconstruct::SamplePlacement::for_spp(frames.spp),
    )
    .map_err(|e| GpuError::Input(e.to_string()))?;
    gpu.layer_sharpness =
        crate::pipeline::composite::layer_sharpness(&classified, dbs.combined.as_ref());
    let result = gpu.run(&classified.frame, &classified.records, options.integrator);
    gpu.layer_sharpness.clear();
    let (mut image, gpu_times) = result?;
    crate::reconstruct::normalize_density(&mut image);
    stats.times.splat_ms = gpu_times.splat_ms;
    stats.times.integrate_ms = gpu_times.integrate_ms;
    stats.times.composite_ms = gpu_times.composite_ms;
    stats.times.total_ms = ms_since(total);
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
