//! `spreadlet study`: what accuracy costs in time.
//!
//! On one scene (a built-in scene rendered with the `scene` crate: pinhole G-buffer and a
//! converged reference; or a G-buffer, camera and reference given as files), every knob of the
//! method is swept one at a time around a base configuration, then a few jointly, and the
//! baselines run on the same input: dense splatting of the pre-filtered PSFs and filtering
//! (gathering) with them (see [`spreadlet::baseline`]). Each configuration is timed as the median
//! of several runs in this one process and scored against the reference (SSIM and PSNR as
//! `DEVELOPERS.md` defines them).
//!
//! Knobs: spreadlet budget and number of PSF samples (each a database of its own, built into
//! the cache), pre-filtering, fast-track threshold (`dense_ratio`), layers, soft layering,
//! integration, backend. Outputs (into `--out`): `study.csv`, `study.md`, `study.png` (SSIM
//! against milliseconds, log scale, the Pareto front marked) and `study.json`.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use precompute::Profile;
use serde::Serialize;

use crate::cached_dbs_with;
use formats::image::RgbaImage;
use spreadlet::dbset::DbSet;
use spreadlet::pipeline::Effects;

/// A G-buffer, its camera and a reference image, given as files.
#[derive(Clone, Debug, PartialEq)]
pub struct StudyInput {
    /// Pinhole G-buffer (OpenEXR).
    pub gbuffer: PathBuf,
    /// Camera description (`camera.json`).
    pub camera: PathBuf,
    /// Reference image (OpenEXR) the results are scored against.
    pub reference: PathBuf,
}

/// What to study.
#[derive(Clone, Debug, PartialEq)]
pub struct StudyOptions {
    /// Output folder.
    pub out_dir: PathBuf,
    /// Built-in scene (`scene::BUILTIN_NAMES`), used when `input` is `None`.
    pub scene: String,
    /// Square image size of the built-in scene, pixels; `None` keeps the scene's.
    pub size: Option<u32>,
    /// Files to study instead of a built-in scene.
    pub input: Option<StudyInput>,
    /// Larger sweeps (more values per knob, a larger joint grid).
    pub full: bool,
    /// Only the base configuration, one value per knob besides it, and the baselines (for
    /// tests: seconds).
    pub tiny: bool,
    /// Profile of the databases (built on demand into the cache).
    pub profile: Profile,
    /// Timed runs per configuration (the median is reported); at least 1.
    pub runs: usize,
    /// Samples per pixel of the built-in scene's reference.
    pub reference_spp: usize,
    /// Also time the GPU backend when an adapter exists.
    pub gpu: bool,
    /// Print no progress.
    pub quiet: bool,
}

impl Default for StudyOptions {
    fn default() -> Self {
        Self {
            out_dir: PathBuf::from("out/study"),
            scene: "occluder".into(),
            size: None,
            input: None,
            full: false,
            tiny: false,
            profile: Profile::Quick,
            runs: 3,
            reference_spp: 256,
            gpu: true,
            quiet: false,
        }
    }
}

/// One configuration's result: one line of `study.csv`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StudyRow {
    /// `spreadlet` (as shipped: fast track on), `spreadlet-sparse` (fast track off: every PSF
    /// drawn as spreadlets), `dense` (dense splat of the pre-filtered PSFs) or `filter`
    /// (gathering).
    pub method: String,
    /// The knob swept (`base`, `budget`, `psf_samples`, `prefilter`, `fast_track`, `layers`,
    /// `soft_layers`, `integration`, `backend`, `baseline`, `joint`).
    pub knob: String,
    /// Its value (for `joint`: every value, `;`-separated).
    pub value: String,
    /// `cpu` or `gpu`.
    pub backend: String,
    /// SSIM against the reference.
    pub ssim: f64,
    /// PSNR against the reference, dB.
    pub psnr: f64,
    /// Mean FLIP error against the reference (lower is better).
    pub flip_mean: f64,
    /// 99th percentile of the FLIP error.
    pub flip_p99: f64,
    /// Median total time of synthesis, ms (database loading excluded).
    pub ms: f64,
    /// Median classification time, ms (filter: the per-pixel PSF lookup).
    pub classify_ms: f64,
    /// Median splat time, ms (filter: the gathering).
    pub splat_ms: f64,
    /// Median integration time, ms.
    pub integrate_ms: f64,
    /// Median compositing time, ms.
    pub composite_ms: f64,
    /// Records drawn as spreadlets.
    pub sparse: usize,
    /// Records drawn dense (fast track).
    pub dense: usize,
    /// Records copied.
    pub copied: usize,
    /// Spreadlets in the database used.
    pub db_spreadlets: usize,
    /// On the Pareto front (no other row is both faster and better).
    pub pareto: bool,
}

mod config;
mod plot;
mod report;
mod run;

use config::*;
pub use plot::plot;
use report::*;
pub use report::{findings, mark_pareto, Findings, CSV_COLUMNS};
use run::*;

/// Runs the study and writes its outputs; returns the rows.
pub fn run(options: &StudyOptions) -> Result<Vec<StudyRow>> {
    let started = Instant::now();
    std::fs::create_dir_all(&options.out_dir)
        .with_context(|| format!("creating {}", options.out_dir.display()))?;
    let input = prepare_input(options)?;
    let effects = Effects::of(&input.camera, &input.gbuffer);
    if effects.cheapest_model().is_none() {
        bail!("the input calls for neither defocus nor motion blur: nothing to study");
    }

    #[cfg(feature = "gpu")]
    let mut gpu_state = if options.gpu {
        match spreadlet::gpu::GpuContext::new() {
            Ok(Some(ctx)) if ctx.adapter_info().device_type == wgpu::DeviceType::Cpu => {
                say(
                    options.quiet,
                    &format!(
                        "{} is a software adapter: GPU rows skipped",
                        ctx.adapter_name()
                    ),
                );
                None
            }
            Ok(Some(ctx)) => Some(GpuState {
                ctx,
                synths: HashMap::new(),
            }),
            Ok(None) => {
                say(options.quiet, "no GPU adapter: GPU rows skipped");
                None
            }
            Err(e) => {
                say(
                    options.quiet,
                    &format!("GPU unavailable ({e}): GPU rows skipped"),
                );
                None
            }
        }
    } else {
        None
    };
    #[cfg(not(feature = "gpu"))]
    let mut gpu_state: Option<GpuState> = None;
    let has_gpu = gpu_state.is_some();

    let configs = configurations(options, has_gpu);
    let runs = options.runs.max(1);
    let aperture = spreadlet::databases::aperture_of(&input.camera);
    let mut db_sets: HashMap<String, DbSet> = HashMap::new();
    let mut done: HashMap<String, StudyRow> = HashMap::new();
    let mut rows = Vec::with_capacity(configs.len());
    let bar = if options.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(configs.len() as u64)
    };
    for cfg in &configs {
        bar.set_message(format!("{} {}={}", cfg.method.name(), cfg.knob, cfg.value));
        let key = cfg.key();
        let row = match done.get(&key) {
            Some(r) => StudyRow {
                knob: cfg.knob.clone(),
                value: cfg.value.clone(),
                ..r.clone()
            },
            None => {
                let dkey = cfg.db.key();
                if !db_sets.contains_key(&dkey) {
                    let variant = cfg.db.clone();
                    let set = bar.suspend(|| {
                        cached_dbs_with(
                            effects,
                            options.profile,
                            aperture,
                            !options.quiet,
                            variant.sparse_only,
                            &|c| variant.apply(c),
                        )
                    })?;
                    db_sets.insert(dkey.clone(), set);
                }
                let Some(dbs) = db_sets.get(&dkey) else {
                    bail!("database set missing");
                };
                let row = run_config(cfg, &input, dbs, runs, &mut gpu_state)
                    .with_context(|| format!("{} {}={}", cfg.method.name(), cfg.knob, cfg.value))?;
                done.insert(key, row.clone());
                row
            }
        };
        bar.inc(1);
        rows.push(row);
    }
    bar.finish_and_clear();
    mark_pareto(&mut rows);
    let elapsed = started.elapsed().as_secs_f64();
    let pinhole = RgbaImage {
        width: input.gbuffer.width,
        height: input.gbuffer.height,
        pixels: input.gbuffer.color.clone(),
    };
    let pinhole_ssim = score(&pinhole, &input.reference)?.ssim;
    write_outputs(&rows, options, &input.label, runs, elapsed, pinhole_ssim)?;
    Ok(rows)
}
