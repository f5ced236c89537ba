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
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use precompute::{BuildConfig, Profile};
use psf_db::PsfModel;
use serde::Serialize;

use crate::cached_dbs_with;
use formats::image::RgbaImage;
use spreadlet::baseline::{filter, DenseKernels, FilterOptions};
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};
use spreadlet::pipeline::{ClassifyOptions, Effects, Integrator};
use spreadlet::synth::{synthesize, SynthOptions};

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

/// Database settings a configuration needs (each distinct one is a database of its own).
#[derive(Clone, Debug, PartialEq)]
struct DbVariant {
    budget: f32,
    /// PSF count relative to the profile's (the runtime's thin-lens count for thin-lens).
    psf_scale: f32,
    prefilter: bool,
    dense_ratio: f32,
    /// No fast track at all: every PSF stored sparse and kept sparse by conditioning.
    sparse_only: bool,
}

impl Default for DbVariant {
    fn default() -> Self {
        let base = BuildConfig::new(PsfModel::ThinLens, Profile::Test);
        Self {
            budget: base.spreadlet_budget,
            psf_scale: 1.0,
            prefilter: base.prefilter,
            dense_ratio: base.dense_ratio,
            sparse_only: false,
        }
    }
}

impl DbVariant {
    fn key(&self) -> String {
        format!(
            "b{} s{} p{} d{} o{}",
            self.budget, self.psf_scale, self.prefilter, self.dense_ratio, self.sparse_only
        )
    }

    fn apply(&self, mut cfg: BuildConfig) -> BuildConfig {
        cfg.spreadlet_budget = self.budget;
        cfg.prefilter = self.prefilter;
        cfg.dense_ratio = self.dense_ratio;
        if self.sparse_only {
            cfg = spreadlet::baseline::sparse_build_config(&cfg);
        }
        if self.psf_scale != 1.0 {
            let base = cfg
                .psf_count
                .unwrap_or_else(|| cfg.profile.spec(cfg.model).psf_count);
            cfg.psf_count = Some(((base as f32 * self.psf_scale).round() as u32).max(2));
        }
        cfg
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Method {
    Spreadlet,
    Dense,
    Filter,
}

impl Method {
    fn name(self) -> &'static str {
        match self {
            Method::Spreadlet => "spreadlet",
            Method::Dense => "dense",
            Method::Filter => "filter",
        }
    }
}

/// One configuration to run.
#[derive(Clone, Debug)]
struct Config {
    method: Method,
    knob: String,
    value: String,
    db: DbVariant,
    layers: u32,
    soft_layers: Option<f32>,
    integrator: Integrator,
    gpu: bool,
}

impl Config {
    fn base() -> Self {
        Config {
            method: Method::Spreadlet,
            knob: "base".into(),
            value: "-".into(),
            db: DbVariant::default(),
            layers: 8,
            soft_layers: Some(1.0),
            integrator: Integrator::Exact,
            gpu: false,
        }
    }

    /// What decides the result (the knob's name does not).
    fn key(&self) -> String {
        format!(
            "{:?} {} l{} s{:?} {:?} g{}",
            self.method,
            self.db.key(),
            self.layers,
            self.soft_layers,
            self.integrator,
            self.gpu
        )
    }

    fn with(&self, knob: &str, value: impl ToString, f: impl FnOnce(&mut Config)) -> Config {
        let mut c = self.clone();
        c.knob = knob.into();
        c.value = value.to_string();
        f(&mut c);
        c
    }

    fn synth_options(&self) -> SynthOptions {
        SynthOptions {
            classify: ClassifyOptions {
                layers: self.layers,
                soft_layers: self.soft_layers,
                ..ClassifyOptions::default()
            },
            integrator: self.integrator,
            ..SynthOptions::default()
        }
    }
}

fn integrator_name(i: Integrator) -> &'static str {
    match i {
        Integrator::Pyramid => "pyramid",
        Integrator::Exact => "exact",
    }
}

/// The configurations of a study, in the order they run.
fn configurations(options: &StudyOptions, gpu: bool) -> Vec<Config> {
    let base = Config::base();
    let mut v = vec![base.clone()];
    // Values of budget, PSF-count scale, layers, soft layering, fast-track ratio.
    type Sweeps = (Vec<f32>, Vec<f32>, Vec<u32>, Vec<f32>, Vec<f32>);
    let (budgets, scales, layers, softs, ratios): Sweeps = if options.tiny {
        (vec![0.5], vec![], vec![1], vec![], vec![])
    } else if options.full {
        (
            vec![0.25, 0.5, 1.0, 2.0, 4.0],
            vec![0.5, 1.0, 2.0, 4.0],
            vec![1, 2, 4, 8, 16],
            vec![0.0, 0.25, 0.5, 1.0],
            vec![0.1, 0.25, 0.5, 1.0, 2.0],
        )
    } else {
        (
            vec![0.5, 1.0, 2.0],
            vec![0.5, 1.0, 2.0],
            vec![1, 2, 4, 8],
            vec![0.0, 0.5, 1.0],
            vec![0.25, 0.5, 1.0],
        )
    };
    // The database knobs act on the spreadlets: swept with the fast track off (every PSF
    // sparse), where they decide every record.
    let sparse = base.with("fast_track", "off", |c| c.db.sparse_only = true);
    for b in &budgets {
        v.push(sparse.with("budget", b, |c| c.db.budget = *b));
    }
    for s in &scales {
        v.push(sparse.with("psf_samples", format!("x{s}"), |c| c.db.psf_scale = *s));
    }
    if !options.tiny {
        for p in [true, false] {
            v.push(sparse.with("prefilter", if p { "on" } else { "off" }, |c| {
                c.db.prefilter = p
            }));
        }
    }
    for r in &ratios {
        v.push(base.with("fast_track", r, |c| c.db.dense_ratio = *r));
    }
    // The speed end as shipped (fast track on): fewer spreadlets and the pyramid.
    if !options.tiny {
        for b in [0.5f32, 1.0] {
            v.push(base.with("budget_pyramid", b, |c| {
                c.db.budget = b;
                c.integrator = Integrator::Pyramid;
            }));
        }
    }
    v.push(sparse.clone());
    for l in &layers {
        v.push(base.with("layers", l, |c| c.layers = *l));
    }
    for s in &softs {
        v.push(base.with("soft_layers", s, |c| {
            c.soft_layers = (*s > 0.0).then_some(*s)
        }));
    }
    if !options.tiny {
        for i in [Integrator::Pyramid, Integrator::Exact] {
            v.push(base.with("integration", integrator_name(i), |c| c.integrator = i));
        }
    }
    v.push(base.with("backend", "cpu", |_| {}));
    if gpu {
        v.push(base.with("backend", "gpu", |c| c.gpu = true));
    }
    // Baselines: the same layering and compositing, with every PSF dense.
    let dense = base.with("baseline", "dense", |c| {
        c.method = Method::Dense;
        c.db.dense_ratio = 0.0;
    });
    v.push(dense.clone());
    if gpu {
        v.push(dense.with("baseline", "dense-gpu", |c| c.gpu = true));
        v.push(dense.with("baseline", "filter-gpu", |c| {
            c.method = Method::Filter;
            c.gpu = true;
        }));
    }
    v.push(dense.with("baseline", "filter", |c| c.method = Method::Filter));
    if options.full {
        for l in [1, 2, 4] {
            v.push(dense.with("baseline", format!("dense-layers-{l}"), |c| c.layers = l));
        }
    }
    // Jointly.
    if !options.tiny {
        let (jb, jl, ji, js): (Vec<f32>, Vec<u32>, Vec<Integrator>, Vec<f32>) = if options.full {
            (
                vec![0.5, 1.0, 2.0],
                vec![1, 2, 4, 8],
                vec![Integrator::Pyramid, Integrator::Exact],
                vec![0.5, 1.0, 2.0],
            )
        } else {
            (
                vec![0.5, 1.0, 2.0],
                vec![2, 8],
                vec![Integrator::Pyramid, Integrator::Exact],
                vec![1.0],
            )
        };
        for b in &jb {
            for l in &jl {
                for i in &ji {
                    for s in &js {
                        let value = format!(
                            "budget={b};layers={l};integration={};psf_samples=x{s}",
                            integrator_name(*i)
                        );
                        v.push(sparse.with("joint", value, |c| {
                            c.db.budget = *b;
                            c.layers = *l;
                            c.integrator = *i;
                            c.db.psf_scale = *s;
                        }));
                    }
                }
            }
        }
    }
    v
}

/// The study's input: G-buffer, camera, reference and a label.
struct Prepared {
    gbuffer: GBuffer,
    camera: Camera,
    reference: RgbaImage,
    label: String,
}

fn say(quiet: bool, s: &str) {
    if !quiet {
        eprintln!("{s}");
    }
}

fn prepare_input(options: &StudyOptions) -> Result<Prepared> {
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

fn median(mut v: Vec<f64>) -> f64 {
    metrics::median(&mut v)
}

fn score(image: &RgbaImage, reference: &RgbaImage) -> Result<metrics::Scores> {
    Ok(crate::score_images(image, reference)?)
}

/// Per-run times: total, classify, splat, integrate, composite (ms).
type Times = [f64; 5];

fn time_row(
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
struct GpuState {
    ctx: spreadlet::gpu::GpuContext,
    synths: HashMap<String, spreadlet::gpu::GpuSynthesizer>,
}

/// Without the `gpu` feature there is never a GPU state.
#[cfg(not(feature = "gpu"))]
struct GpuState;

/// Runs one configuration `runs` times; the row holds the medians.
fn run_config(
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
                    let key = cfg.db.key();
                    if !state.synths.contains_key(&key) {
                        let s = spreadlet::gpu::GpuSynthesizer::for_database(
                            &state.ctx,
                            dbs.combined.as_ref(),
                            spreadlet::gpu::GpuSynthOptions::from_synth(&options),
                        )?;
                        state.synths.insert(key.clone(), s);
                    }
                    let Some(synth) = state.synths.get_mut(&key) else {
                        bail!("GPU synthesizer missing");
                    };
                    // Warm-up: pipelines compiled, buffers allocated.
                    spreadlet::gpu::synthesize_gpu(
                        synth,
                        &input.gbuffer,
                        &input.camera,
                        dbs,
                        &options,
                    )?;
                    for _ in 0..runs {
                        let (image, st, _) = spreadlet::gpu::synthesize_gpu(
                            synth,
                            &input.gbuffer,
                            &input.camera,
                            dbs,
                            &options,
                        )?;
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

/// Marks the rows no other row beats in both SSIM (higher) and time (lower).
pub fn mark_pareto(rows: &mut [StudyRow]) {
    let flags: Vec<bool> = rows
        .iter()
        .map(|r| {
            !rows
                .iter()
                .any(|o| (o.ssim >= r.ssim && o.ms < r.ms) || (o.ssim > r.ssim && o.ms <= r.ms))
        })
        .collect();
    for (r, f) in rows.iter_mut().zip(flags) {
        r.pareto = f;
    }
}

/// The headline figures of a study, computed from the rows (CPU only).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Findings {
    /// SSIM and ms of the dense splat (CPU, base settings).
    pub dense: Option<(f64, f64)>,
    /// SSIM and ms of the base spreadlet configuration (CPU).
    pub spreadlet_base: Option<(f64, f64)>,
    /// The fastest CPU spreadlet row that draws most of its records as spreadlets (not
    /// through the fast track), layers as the dense splat does (8 soft layers), and scores SSIM
    /// at least the dense splat's minus 0.005: its configuration, SSIM and ms.
    pub spreadlet_at_dense_ssim: Option<(String, f64, f64)>,
    /// The best-scoring CPU spreadlet row that draws most of its records as spreadlets: its
    /// configuration, SSIM and ms.
    pub best_mostly_sparse: Option<(String, f64, f64)>,
    /// Dense ms over that row's ms (the speed-up at equal SSIM).
    pub speedup_at_equal_ssim: Option<f64>,
    /// Dense ms over the base spreadlet's ms.
    pub speedup_base: Option<f64>,
    /// SSIM and ms of the filter (CPU).
    pub filter: Option<(f64, f64)>,
    /// SSIM of the pinhole input itself against the reference (doing nothing).
    pub pinhole_ssim: Option<f64>,
}

/// Computes the [`Findings`] of `rows`.
pub fn findings(rows: &[StudyRow]) -> Findings {
    let cpu = |m: &str, knob: &str, value: &str| {
        rows.iter()
            .find(|r| r.method == m && r.backend == "cpu" && r.knob == knob && r.value == value)
    };
    let dense = cpu("dense", "baseline", "dense");
    let base = cpu("spreadlet", "base", "-");
    let filter_row = cpu("filter", "baseline", "filter");
    let mut f = Findings {
        dense: dense.map(|r| (r.ssim, r.ms)),
        spreadlet_base: base.map(|r| (r.ssim, r.ms)),
        filter: filter_row.map(|r| (r.ssim, r.ms)),
        ..Findings::default()
    };
    // Only rows that really splat spreadlets count: a row whose records mostly go through the
    // fast track is a dense splat itself.
    let mostly_sparse = |r: &&StudyRow| {
        r.method.starts_with("spreadlet") && r.backend == "cpu" && r.sparse > r.dense
    };
    // The speed-up at equal SSIM compares like with like: the dense splat's layering (the
    // base's 8 soft layers), so that fewer layers are not counted as the spreadlets' gain.
    let same_layering = |r: &&StudyRow| {
        !(r.knob == "layers"
            || r.knob == "soft_layers"
            || (r.knob == "joint" && !r.value.contains("layers=8")))
    };
    f.best_mostly_sparse = rows
        .iter()
        .filter(mostly_sparse)
        .max_by(|a, b| a.ssim.total_cmp(&b.ssim))
        .map(|b| (format!("{} {}={}", b.method, b.knob, b.value), b.ssim, b.ms));
    if let Some(d) = dense {
        let best = rows
            .iter()
            .filter(mostly_sparse)
            .filter(same_layering)
            .filter(|r| r.ssim >= d.ssim - 0.005)
            .min_by(|a, b| a.ms.total_cmp(&b.ms));
        if let Some(b) = best {
            f.spreadlet_at_dense_ssim =
                Some((format!("{} {}={}", b.method, b.knob, b.value), b.ssim, b.ms));
            f.speedup_at_equal_ssim = Some(d.ms / b.ms);
        }
        if let Some(b) = base {
            f.speedup_base = Some(d.ms / b.ms);
        }
    }
    f
}

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

/// The CSV columns, in order.
pub const CSV_COLUMNS: [&str; 19] = [
    "method",
    "knob",
    "value",
    "backend",
    "ssim",
    "psnr",
    "flip_mean",
    "flip_p99",
    "ms",
    "classify_ms",
    "splat_ms",
    "integrate_ms",
    "composite_ms",
    "sparse",
    "dense",
    "copied",
    "db_spreadlets",
    "pareto",
    "note",
];

fn csv_text(rows: &[StudyRow]) -> String {
    let mut s = CSV_COLUMNS.join(",");
    s.push('\n');
    for r in rows {
        let note = match r.method.as_str() {
            "filter" => "gathering; splat_ms holds the gathering",
            "dense" => "every PSF dense (pre-filtered)",
            "spreadlet-sparse" => "fast track off: every PSF sparse",
            _ => "",
        };
        let _ = writeln!(
            s,
            "{},{},{},{},{:.5},{:.3},{:.5},{:.5},{:.2},{:.2},{:.2},{:.2},{:.2},{},{},{},{},{},{}",
            r.method,
            r.knob,
            r.value,
            r.backend,
            r.ssim,
            r.psnr,
            r.flip_mean,
            r.flip_p99,
            r.ms,
            r.classify_ms,
            r.splat_ms,
            r.integrate_ms,
            r.composite_ms,
            r.sparse,
            r.dense,
            r.copied,
            r.db_spreadlets,
            r.pareto,
            note
        );
    }
    s
}

fn markdown_text(
    rows: &[StudyRow],
    f: &Findings,
    label: &str,
    runs: usize,
    elapsed_s: f64,
    full: bool,
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# spreadlet study\n");
    let _ = writeln!(
        s,
        "Input: {label}. Times: median of {runs} runs in one process, {} CPU threads; database \
         loading excluded. SSIM/PSNR against the reference (sRGB, DEVELOPERS.md). Base: \
         spreadlet, budget 1, profile PSF count, pre-filtered, fast-track ratio 0.5, 8 layers, \
         soft layering 1, exact integration, CPU. Study took {elapsed_s:.0} s{}.\n",
        rayon::current_num_threads(),
        if full { " (--full)" } else { "" }
    );
    let _ = writeln!(s, "## Findings\n");
    if let Some(p) = f.pinhole_ssim {
        let _ = writeln!(
            s,
            "- The pinhole input itself scores SSIM {p:.4} (doing nothing)."
        );
    }
    match (
        f.dense,
        f.spreadlet_at_dense_ssim.as_ref(),
        f.speedup_at_equal_ssim,
    ) {
        (Some((ds, dm)), Some((cfg, ss, sm)), Some(x)) => {
            let _ = writeln!(
                s,
                "- Dense splat: SSIM {ds:.4} in {dm:.0} ms. Fastest configuration drawing mostly \
                 spreadlets within 0.005 SSIM of it: {cfg} (SSIM {ss:.4}, {sm:.0} ms): \
                 **{x:.1}x faster** on the CPU."
            );
        }
        (Some((ds, dm)), _, _) => {
            let _ = writeln!(
                s,
                "- Dense splat: SSIM {ds:.4} in {dm:.0} ms. **No configuration drawing mostly \
                 spreadlets comes within 0.005 SSIM of it.**"
            );
        }
        _ => {}
    }
    if let (Some((cfg, bs, bm)), Some((ds, dm))) = (&f.best_mostly_sparse, f.dense) {
        let _ = writeln!(
            s,
            "- Best configuration drawing mostly spreadlets: {cfg}: SSIM {bs:.4} ({:+.4} against \
             dense) in {bm:.0} ms ({:.1}x faster than dense).",
            bs - ds,
            dm / bm
        );
    }
    if let (Some(x), Some((bs, bm))) = (f.speedup_base, f.spreadlet_base) {
        let _ = writeln!(
            s,
            "- Base spreadlet (as shipped, fast track on): SSIM {bs:.4} in {bm:.0} ms ({x:.1}x \
             faster than dense; look at its sparse/dense record counts below)."
        );
    }
    if let (Some((fs, fm)), Some((ds, _))) = (f.filter, f.dense) {
        let verdict = if fs < ds { "lower" } else { "not lower" };
        let _ = writeln!(
            s,
            "- Filter (gathering with the same pre-filtered PSFs): SSIM {fs:.4} in {fm:.0} ms, \
             {verdict} than the dense splat's {ds:.4} (difference {:+.4}).",
            fs - ds
        );
    }
    if let Some((bs, _)) = f.spreadlet_base {
        if let Some((fs, _)) = f.filter {
            let verdict = if fs < bs { "lower" } else { "not lower" };
            let _ = writeln!(
                s,
                "- Filter vs splatting (base spreadlet): {fs:.4} vs {bs:.4}, {verdict} \
                 (difference {:+.4}).",
                fs - bs
            );
        }
    }
    let _ = writeln!(s, "\n## All configurations\n");
    let _ = writeln!(
        s,
        "| method | knob | value | backend | SSIM | PSNR dB | FLIP mean | FLIP p99 | ms | classify | splat | integrate | composite | sparse | dense | copied | Pareto |"
    );
    let _ = writeln!(
        s,
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.4} | {:.2} | {:.4} | {:.4} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {} | {} | {} | {} |",
            r.method,
            r.knob,
            r.value.replace(';', "; "),
            r.backend,
            r.ssim,
            r.psnr,
            r.flip_mean,
            r.flip_p99,
            r.ms,
            r.classify_ms,
            r.splat_ms,
            r.integrate_ms,
            r.composite_ms,
            r.sparse,
            r.dense,
            r.copied,
            if r.pareto { "yes" } else { "" }
        );
    }
    let _ = writeln!(
        s,
        "\nFilter rows: `splat` is the gathering time, `dense` the pixels filtered. Rows with the \
         same configuration under several knobs are measured once."
    );
    s
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    formats::atomic::write_bytes_atomically(path, text.as_bytes())?;
    Ok(())
}

fn write_outputs(
    rows: &[StudyRow],
    options: &StudyOptions,
    label: &str,
    runs: usize,
    elapsed_s: f64,
    pinhole_ssim: f64,
) -> Result<()> {
    let dir = &options.out_dir;
    let mut f = findings(rows);
    f.pinhole_ssim = Some(pinhole_ssim);
    write_text(&dir.join("study.csv"), &csv_text(rows))?;
    write_text(
        &dir.join("study.md"),
        &markdown_text(rows, &f, label, runs, elapsed_s, options.full),
    )?;
    let json = serde_json::json!({
        "input": label, "runs": runs, "threads": rayon::current_num_threads(),
        "seconds": elapsed_s, "findings": f, "rows": rows,
    });
    write_text(
        &dir.join("study.json"),
        &serde_json::to_string_pretty(&json)?,
    )?;
    plot(rows, &dir.join("study.png"), label)?;
    Ok(())
}

/// Registers a system sans-serif font for the plot's text, when one is found
/// (`$SPREADLET_FONT`, else DejaVu Sans or Liberation Sans in the usual places).
fn font_available() -> bool {
    static FONT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *FONT.get_or_init(|| {
        let mut candidates: Vec<PathBuf> = std::env::var_os("SPREADLET_FONT")
            .map(PathBuf::from)
            .into_iter()
            .collect();
        candidates.extend(
            [
                "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/TTF/DejaVuSans.ttf",
                "/usr/share/fonts/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
                "/Library/Fonts/Arial.ttf",
                "C:\\Windows\\Fonts\\arial.ttf",
            ]
            .iter()
            .map(PathBuf::from),
        );
        for p in candidates {
            if let Ok(bytes) = std::fs::read(&p) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font(
                    "sans-serif",
                    plotters::style::FontStyle::Normal,
                    bytes,
                )
                .is_ok()
                {
                    return true;
                }
            }
        }
        false
    })
}

/// SSIM against milliseconds (log scale), one colour per method, the Pareto front joined.
pub fn plot(rows: &[StudyRow], path: &Path, title: &str) -> Result<()> {
    use plotters::prelude::*;
    if rows.is_empty() {
        bail!("nothing to plot");
    }
    let text = font_available();
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, (960, 640)).into_drawing_area();
        root.fill(&WHITE)?;
        let (mut lo_ms, mut hi_ms) = (f64::INFINITY, 0.0f64);
        let (mut lo_s, mut hi_s) = (f64::INFINITY, f64::NEG_INFINITY);
        for r in rows.iter().filter(|r| r.ms.is_finite() && r.ms > 0.0) {
            lo_ms = lo_ms.min(r.ms);
            hi_ms = hi_ms.max(r.ms);
            lo_s = lo_s.min(r.ssim);
            hi_s = hi_s.max(r.ssim);
        }
        if !(lo_ms.is_finite() && lo_s.is_finite()) {
            bail!("no finite times to plot");
        }
        let pad_s = ((hi_s - lo_s) * 0.08).max(0.002);
        let mut builder = ChartBuilder::on(&root);
        builder.margin(16);
        if text {
            builder
                .caption(format!("accuracy vs time: {title}"), ("sans-serif", 20))
                .x_label_area_size(44)
                .y_label_area_size(64);
        } else {
            builder.x_label_area_size(8).y_label_area_size(8);
        }
        let mut chart = builder.build_cartesian_2d(
            ((lo_ms * 0.8)..(hi_ms * 1.25)).log_scale(),
            (lo_s - pad_s)..(hi_s + pad_s),
        )?;
        let mut mesh = chart.configure_mesh();
        if text {
            mesh.x_desc("time per frame, ms (log)")
                .y_desc("SSIM against the reference")
                .label_style(("sans-serif", 14));
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw()?;
        let colour = |m: &str| match m {
            "dense" => RGBColor(200, 40, 40),
            "filter" => RGBColor(30, 150, 60),
            "spreadlet-sparse" => RGBColor(120, 170, 240),
            _ => RGBColor(40, 80, 200),
        };
        for method in ["spreadlet", "spreadlet-sparse", "dense", "filter"] {
            let c = colour(method);
            let pts: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.method == method && r.ms > 0.0)
                .map(|r| (r.ms, r.ssim))
                .collect();
            let series = chart.draw_series(pts.iter().map(|&p| Circle::new(p, 5, c.filled())))?;
            if text {
                series
                    .label(method)
                    .legend(move |(x, y)| Circle::new((x, y), 5, c.filled()));
            }
        }
        let mut front: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.pareto && r.ms > 0.0)
            .map(|r| (r.ms, r.ssim))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        let series = chart.draw_series(LineSeries::new(front.clone(), BLACK.stroke_width(2)))?;
        if text {
            series
                .label("Pareto front")
                .legend(|(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], BLACK));
        }
        chart.draw_series(
            front
                .iter()
                .map(|&p| Circle::new(p, 8, BLACK.stroke_width(2))),
        )?;
        if text {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .position(SeriesLabelPosition::LowerRight)
                .label_font(("sans-serif", 14))
                .draw()?;
        }
        root.present()?;
    }
    std::fs::rename(&tmp, path)
        .with_context(|| format!("moving the plot to {}", path.display()))?;
    Ok(())
}
