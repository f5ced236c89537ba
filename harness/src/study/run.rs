//! Running one configuration: the input prepared once, each configuration timed as the median
//! of several runs in this process and scored against the reference.

use super::*;
use anyhow::{bail, Context, Result};
use formats::image::RgbaImage;
use spreadlet::baseline::{filter, DenseKernels, FilterOptions};
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};
use spreadlet::synth::synthesize;

/// The study's input: G-buffer, camera, reference and a label.
pub(super) struct Prepared {
    pub(super) gbuffer: GBuffer,
    pub(super) camera: Camera,
    pub(super) reference: RgbaImage,
    pub(super) label: String,
}

pub(super) fn say(quiet: bool, s: &str) {
    if !quiet {
        eprintln!("{s}");
    }
}

pub(super) fn prepare_input(options: &StudyOptions) -> Result<Prepared> {
    if let Some(input) = &options.input {
        let camera = Camera::from_json_file(&input.camera)
            .with_context(|| format!("camera {}", input.camera.display()))?;
        let gbuffer = GBuffer::read_exr(&input.gbuffer, &ChannelOptions::default())
            .with_context(|| format!("G-buffer {}", input.gbuffer.display()))?;
        let r = GBuffer::read_exr(&input.reference, &ChannelOptions::default())
            .with_context(|| format!("reference {}", input.reference.display()))?;
        if (r.width, r.height) != (gbuffer.width, gbuffer.height) {
            bail!(
                "the reference is {}x{} but the G-buffer is {}x{}",
                r.width,
                r.height,
                gbuffer.width,
                gbuffer.height
            );
        }
        return Ok(Prepared {
            label: input.gbuffer.display().to_string(),
            reference: RgbaImage {
                width: r.width,
                height: r.height,
                pixels: r.color,
            },
            gbuffer,
            camera,
        });
    }
    let mut scene = scene::builtin(&options.scene)?;
    if let Some(size) = options.size {
        scene = scene.with_size(size, size)?;
    }
    let camera = Camera::from_json_str(&scene.camera_json())?;
    let render = scene::RenderOptions {
        seed: 1,
        progress: !options.quiet,
        ..Default::default()
    };
    say(
        options.quiet,
        &format!(
            "rendering '{}' ({}x{}): G-buffer and a {} spp reference",
            options.scene, camera.width, camera.height, options.reference_spp
        ),
    );
    let g = scene::render_gbuffer(&scene, 16, &render)?;
    let reference = scene::render_reference(&scene, options.reference_spp.max(1), &render)?;
    let (w, h) = (g.width, g.height);
    let gbuffer = crate::gbuffer_of(&g)?;
    Ok(Prepared {
        gbuffer,
        camera,
        reference: RgbaImage {
            width: reference.width,
            height: reference.height,
            pixels: reference.pixels,
        },
        label: format!("built-in scene '{}' ({w}x{h})", options.scene),
    })
}

pub(super) fn median(mut v: Vec<f64>) -> f64 {
    metrics::median(&mut v)
}

pub(super) fn score(image: &RgbaImage, reference: &RgbaImage) -> Result<metrics::Scores> {
    Ok(crate::score_images(image, reference)?)
}

/// Per-run times: total, classify, splat, integrate, composite (ms).
pub(super) type Times = [f64; 5];

pub(super) fn time_row(
    cfg: &Config,
    times: &[Times],
    image: &RgbaImage,
    reference: &RgbaImage,
    counts: spreadlet::pipeline::PathCounts,
    db_spreadlets: usize,
) -> Result<StudyRow> {
    let scores = score(image, reference)?;
    let col = |k: usize| median(times.iter().map(|t| t[k]).collect());
    let method = match (cfg.method, cfg.db.sparse_only) {
        (Method::Spreadlet, true) => "spreadlet-sparse",
        (m, _) => m.name(),
    };
    Ok(StudyRow {
        method: method.into(),
        knob: cfg.knob.clone(),
        value: cfg.value.clone(),
        backend: if cfg.gpu { "gpu" } else { "cpu" }.into(),
        ssim: scores.ssim,
        psnr: scores.psnr_db.unwrap_or(f64::INFINITY),
        flip_mean: scores.flip_mean,
        flip_p99: scores.flip_p99,
        ms: col(0),
        classify_ms: col(1),
        splat_ms: col(2),
        integrate_ms: col(3),
        composite_ms: col(4),
        sparse: counts.sparse,
        dense: counts.dense,
        copied: counts.copied,
        db_spreadlets,
        pareto: false,
    })
}

/// GPU state of a study: the context, and a synthesizer per database.
#[cfg(feature = "gpu")]
pub(super) struct GpuState {
    pub(super) ctx: spreadlet::gpu::GpuContext,
    pub(super) synths: std::collections::HashMap<String, spreadlet::gpu::GpuSynthesizer>,
}

/// Without the `gpu` feature there is never a GPU state.
#[cfg(not(feature = "gpu"))]
pub(super) struct GpuState;

/// Runs one configuration `runs` times; the row holds the medians.
pub(super) fn run_config(
    cfg: &Config,
    input: &Prepared,
    dbs: &DbSet,
    runs: usize,
    gpu: &mut Option<GpuState>,
) -> Result<StudyRow> {
    let db_spreadlets = dbs.combined.as_ref().map_or(0, |d| d.spreadlet_count());
    let mut times = Vec::with_capacity(runs);
    match cfg.method {
        Method::Filter => {
            let kernels = dbs
                .combined
                .as_ref()
                .map(DenseKernels::from_db)
                .unwrap_or_default();
            let mut last = None;
            if cfg.gpu {
                #[cfg(feature = "gpu")]
                {
                    let Some(state) = gpu.as_ref() else {
                        bail!("no GPU adapter");
                    };
                    let gpu_filter = spreadlet::gpu::GpuFilter::new(&state.ctx, &kernels)?;
                    let opts = FilterOptions::default();
                    // Warm-up: pipeline compiled, kernels resident.
                    spreadlet::gpu::filter_gpu(
                        &gpu_filter,
                        &input.gbuffer,
                        &input.camera,
                        dbs,
                        &opts,
                    )?;
                    for _ in 0..runs {
                        let (image, st) = spreadlet::gpu::filter_gpu(
                            &gpu_filter,
                            &input.gbuffer,
                            &input.camera,
                            dbs,
                            &opts,
                        )?;
                        times.push([st.total_ms, st.classify_ms, st.filter_ms, 0.0, 0.0]);
                        last = Some((image, st));
                    }
                }
                #[cfg(not(feature = "gpu"))]
                {
                    bail!("built without the `gpu` feature");
                }
            } else {
                for _ in 0..runs {
                    let (image, st) = filter(
                        &input.gbuffer,
                        &input.camera,
                        dbs,
                        &kernels,
                        &FilterOptions::default(),
                    )?;
                    times.push([st.total_ms, st.classify_ms, st.filter_ms, 0.0, 0.0]);
                    last = Some((image, st));
                }
            }
            let Some((image, st)) = last else {
                bail!("no run");
            };
            let counts = spreadlet::pipeline::PathCounts {
                dense: st.filtered,
                copied: st.copied,
                ..Default::default()
            };
            time_row(cfg, &times, &image, &input.reference, counts, db_spreadlets)
        }
        Method::Spreadlet | Method::Dense => {
            let options = cfg.synth_options();
            let mut last = None;
            if cfg.gpu {
                #[cfg(feature = "gpu")]
                {
                    let Some(state) = gpu.as_mut() else {
                        bail!("no GPU adapter");
                    };
                    // Every sparse record kept sparse, as `Renderer` classifies for the GPU.
                    let mut options = options.clone();
                    options.classify.few_sparse_images = false;
                    let key = cfg.db.key();
                    if !state.synths.contains_key(&key) {
                        let s = spreadlet::gpu::GpuSynthesizer::for_database(
                            &state.ctx,
                            dbs.combined.as_ref(),
                            spreadlet::gpu::GpuSynthOptions::from_synth(&options),
                        )?;
                        state.synths.insert(key.clone(), s);
                    }
                    let ctx = &state.ctx;
                    let Some(synth) = state.synths.get_mut(&key) else {
                        bail!("GPU synthesizer missing");
                    };
                    // A frame with PSF images of its own (PSFs smeared along the motion)
                    // uploads its database for that frame alone, as `Renderer` does.
                    let mut draw = |frame: spreadlet::PreparedFrame| -> Result<_> {
                        if frame.database_or(None).is_some() {
                            let mut own = spreadlet::gpu::GpuSynthesizer::for_database(
                                ctx,
                                frame.database_or(None),
                                spreadlet::gpu::GpuSynthOptions::from_synth(&options),
                            )?;
                            return Ok(spreadlet::gpu::render_gpu(&mut own, frame, dbs)?);
                        }
                        Ok(spreadlet::gpu::render_gpu(synth, frame, dbs)?)
                    };
                    let prepared = || {
                        spreadlet::Plan::new(
                            spreadlet::Input::Flat(&input.gbuffer),
                            &input.camera,
                            &options,
                        )?
                        .prepare(dbs)
                    };
                    // Warm-up: pipelines compiled, buffers allocated.
                    draw(prepared()?)?;
                    for _ in 0..runs {
                        let (image, st, _) = draw(prepared()?)?;
                        let t = st.times;
                        times.push([
                            t.total_ms,
                            t.classify_ms,
                            t.splat_ms,
                            t.integrate_ms,
                            t.composite_ms,
                        ]);
                        last = Some((image, st));
                    }
                }
                #[cfg(not(feature = "gpu"))]
                {
                    let _ = gpu;
                    bail!("built without the `gpu` feature");
                }
            } else {
                for _ in 0..runs {
                    let (image, st) = synthesize(&input.gbuffer, &input.camera, dbs, &options)?;
                    let t = st.times;
                    times.push([
                        t.total_ms,
                        t.classify_ms,
                        t.splat_ms,
                        t.integrate_ms,
                        t.composite_ms,
                    ]);
                    last = Some((image, st));
                }
            }
            let Some((image, st)) = last else {
                bail!("no run");
            };
            time_row(
                cfg,
                &times,
                &image,
                &input.reference,
                st.counts,
                db_spreadlets,
            )
        }
    }
}
