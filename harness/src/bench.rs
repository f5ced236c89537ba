//! `spreadlet bench`: per-stage and total times of synthesis on both backends at several frame
//! sizes, on a synthetic frame, as a Markdown table (medians of several runs, one process).
//!
//! The frame is one record per pixel over a smooth field of PSF coordinates that spans the
//! database's whole parameter space (so every PSF size occurs), with a band in focus (copied
//! pixels), motion directions turning across the frame (lens-motion), and `layers` depth layers.
//! Classification is not timed (it is CPU work shared by both backends).

use spreadlet::synth::ms_since;
use std::fmt::Write as _;
use std::time::Instant;

use psf_db::PsfDatabase;

use spreadlet::pipeline::types::{FrameParams, SplatPath, SplatRecord};
use spreadlet::pipeline::{
    composite, integrate, splat, Classified, CompositeOptions, Integrator, LayerInfo, PathCounts,
    RotationSampling, SplatOptions,
};

/// What to measure.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchConfig {
    /// Square frame sizes, px.
    pub sizes: Vec<u32>,
    /// Runs per backend and size (the median is reported); at least 1.
    pub runs: usize,
    /// Depth layers.
    pub layers: u32,
    /// Integration method.
    pub integrator: Integrator,
    /// Measure the CPU path.
    pub cpu: bool,
    /// Measure the GPU path (skipped, with a note, when there is no adapter).
    pub gpu: bool,
    /// Placement of rotated spreadlets.
    pub rotation: RotationSampling,
    /// The GPU path splats with global atomics instead of the tiled stage.
    pub global_atomic_splat: bool,
}

impl Default for BenchConfig {
    fn default() -> Self {
        BenchConfig {
            sizes: vec![512, 1024],
            runs: 5,
            layers: 8,
            integrator: Integrator::Pyramid,
            cpu: true,
            rotation: RotationSampling::default(),
            gpu: true,
            global_atomic_splat: false,
        }
    }
}

/// Median times of one backend at one size, milliseconds.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct BenchRow {
    /// `cpu` or `gpu`.
    pub backend: String,
    /// Device: CPU thread count, or the GPU adapter's name.
    pub device: String,
    /// Frame edge, px.
    pub size: u32,
    /// Records in the frame.
    pub records: usize,
    /// Splatting, ms (median).
    pub splat_ms: f64,
    /// Integration, ms (median).
    pub integrate_ms: f64,
    /// Compositing, ms (median).
    pub composite_ms: f64,
    /// Whole frame after classification, ms (median; GPU: with record upload and image
    /// readback).
    pub total_ms: f64,
    /// How the GPU stages were timed (`timestamps` or `wall`); `wall` for the CPU.
    pub timing: String,
    /// Runs.
    pub runs: usize,
}

/// All rows of a benchmark run, and notes (e.g. why the GPU was skipped).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct BenchReport {
    /// The database measured with (model and PSF count).
    pub database: String,
    /// Rows, in the order measured.
    pub rows: Vec<BenchRow>,
    /// Remarks.
    pub notes: Vec<String>,
}

/// Errors of a benchmark run.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// Nothing to measure.
    #[error("benchmark configuration: {0}")]
    Config(String),
    /// The GPU path failed.
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] spreadlet::gpu::GpuError),
}

/// A synthetic `size x size` frame for `db` (see the module doc), as `pipeline::classify`
/// would give it: records sorted by layer, then row, then column.
pub fn synthetic_frame(db: &PsfDatabase, size: u32, layers: u32) -> Classified {
    scene_frame(db, Scene::Defocus, size, size, layers)
}

/// What a synthetic frame blurs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Scene {
    /// Defocus over the database's whole first dimension (CoC), and its second (motion) where
    /// it has one: a thin-lens database gives thin lens, a lens-motion one lens and motion.
    Defocus,
    /// Motion only: every pixel in focus (the smallest CoC), motion over the database's
    /// whole second dimension (a lens-motion database).
    MotionOnly,
}

/// A synthetic `width x height` frame for `db` (see the module doc), as `pipeline::classify`
/// would give it: records sorted by layer, then row, then column.
pub fn scene_frame(
    db: &PsfDatabase,
    scene: Scene,
    width: u32,
    height: u32,
    layers: u32,
) -> Classified {
    let layers = layers.max(1);
    let dims = db.space().dims();
    let range = |i: usize| {
        dims.get(i)
            .map_or((0.0, 0.0), |d| (d.min as f32, d.max as f32))
    };
    let (s0_min, s0_max) = range(0);
    let (s1_min, s1_max) = range(1);
    let pad = db.max_extent_px() + 2;
    let (nx, ny) = (width as usize, height as usize);
    let mut per_layer: Vec<Vec<SplatRecord>> = vec![Vec::new(); layers as usize];
    for y in 0..ny {
        for x in 0..nx {
            let (u, v) = (x as f32 / nx as f32, y as f32 / ny as f32);
            // Depth ramp top to bottom; the focus band is in the middle third.
            let depth = v;
            let defocus = match scene {
                Scene::Defocus => ((depth - 0.5).abs() * 2.0 - 0.15).max(0.0) / 0.85,
                Scene::MotionOnly => 0.0,
            };
            let wobble = 0.5 + 0.5 * (9.0 * u).sin() * (7.0 * v).cos();
            let s0 = s0_min + (s0_max - s0_min) * defocus * (0.6 + 0.4 * wobble);
            let s1 = s1_min + (s1_max - s1_min) * wobble * u;
            let (psf, _) = db.lookup([s0, s1]);
            let still = s1_max <= s1_min || wobble * u < 0.02;
            let in_focus = defocus == 0.0 && still;
            let path = if in_focus {
                SplatPath::Copy
            } else if db.dense(psf as usize).is_some() {
                SplatPath::Dense
            } else {
                SplatPath::Sparse
            };
            let angle = 6.0 * (u - 0.5) * (v - 0.5) + (3.0 * u).sin();
            let layer = ((depth * layers as f32) as u32).min(layers - 1);
            let checker = if (x / 16 + y / 16) % 2 == 0 {
                1.0
            } else {
                0.25
            };
            per_layer[layer as usize].push(SplatRecord {
                center_x: (x as u32 + pad) as i32,
                center_y: (y as u32 + pad) as i32,
                psf_index: psf,
                layer,
                rot_cos: angle.cos(),
                rot_sin: angle.sin(),
                weight: 1.0,
                path: path as u32,
                color: [checker * u, checker * 0.6, checker * (1.0 - u), 1.0],
            });
        }
    }
    let mut records = Vec::with_capacity(nx * ny);
    let mut infos = Vec::with_capacity(layers as usize);
    let mut counts = PathCounts::default();
    for recs in per_layer {
        let mut info = LayerInfo {
            first_record: records.len(),
            record_count: recs.len(),
            ..LayerInfo::default()
        };
        info.count_paths(&recs);
        counts.add_layer(&info);
        infos.push(info);
        records.extend(recs);
    }
    Classified {
        frame: FrameParams {
            record_count: records.len() as u32,
            db_channels: db.channels() as u32,
            ..FrameParams::padded(width, height, pad, layers)
        },
        records,
        layers: infos,
        counts,
        database: None,
        packed: None,
        coarse: Vec::new(),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    metrics::median(&mut v)
}

/// Times of the CPU path on `frame`, one entry per run: (splat, integrate, composite, total).
fn time_cpu(db: &PsfDatabase, frame: &Classified, config: &BenchConfig) -> Vec<[f64; 4]> {
    (0..config.runs)
        .map(|_| {
            let t0 = Instant::now();
            let t = Instant::now();
            let stack = splat(
                frame,
                Some(db),
                &SplatOptions {
                    rotation: config.rotation,
                },
            );
            let s = ms_since(t);
            let t = Instant::now();
            let layers = integrate(&stack, config.integrator);
            let i = ms_since(t);
            drop(stack);
            let t = Instant::now();
            let image = composite(&layers, &CompositeOptions::default());
            let c = ms_since(t);
            std::hint::black_box(image);
            [s, i, c, ms_since(t0)]
        })
        .collect()
}

fn row(
    backend: &str,
    device: String,
    size: u32,
    records: usize,
    runs: &[[f64; 4]],
    timing: &str,
) -> BenchRow {
    let col = |k: usize| median(runs.iter().map(|r| r[k]).collect());
    BenchRow {
        backend: backend.into(),
        device,
        size,
        records,
        splat_ms: col(0),
        integrate_ms: col(1),
        composite_ms: col(2),
        total_ms: col(3),
        timing: timing.into(),
        runs: runs.len(),
    }
}

/// Runs the benchmark with `db` (the lens-motion `quick` database is the paper's comparison
/// point). The GPU's first frame of each size (pipeline warm-up, buffer allocation) is not
/// counted.
pub fn run_bench(db: &PsfDatabase, config: &BenchConfig) -> Result<BenchReport, BenchError> {
    if config.sizes.is_empty() || config.runs == 0 || !(config.cpu || config.gpu) {
        return Err(BenchError::Config(
            "need at least one size, one run and one backend".into(),
        ));
    }
    if config.sizes.iter().any(|&s| s == 0 || s > 16384) {
        return Err(BenchError::Config("sizes must be in 1..=16384 px".into()));
    }
    let mut report = BenchReport {
        database: format!(
            "{} ({} PSFs, {} spreadlets, max extent {} px)",
            db.model().name(),
            db.psf_count(),
            db.spreadlet_count(),
            db.max_extent_px()
        ),
        ..BenchReport::default()
    };
    #[cfg(feature = "gpu")]
    let mut gpu = if config.gpu {
        match spreadlet::gpu::GpuContext::new()? {
            Some(ctx) => Some(spreadlet::gpu::GpuSynthesizer::new(
                &ctx,
                db,
                spreadlet::gpu::GpuSynthOptions {
                    rotation: config.rotation,
                    splat: if config.global_atomic_splat {
                        spreadlet::gpu::SplatMode::GlobalAtomic
                    } else {
                        spreadlet::gpu::SplatMode::Tiled
                    },
                    ..Default::default()
                },
            )?),
            None => {
                report.notes.push("no GPU adapter: GPU rows skipped".into());
                None
            }
        }
    } else {
        None
    };
    #[cfg(not(feature = "gpu"))]
    if config.gpu {
        report
            .notes
            .push("built without the `gpu` feature: GPU rows skipped".into());
    }
    for &size in &config.sizes {
        let frame = synthetic_frame(db, size, config.layers);
        let records = frame.records.len();
        if config.cpu {
            let runs = time_cpu(db, &frame, config);
            let device = format!("CPU, {} threads", rayon::current_num_threads());
            report
                .rows
                .push(row("cpu", device, size, records, &runs, "wall"));
        }
        #[cfg(feature = "gpu")]
        if let Some(gpu) = gpu.as_mut() {
            // Warm-up: pipelines compiled by the driver, buffers allocated.
            gpu.run(&frame.frame, &frame.records, config.integrator)?;
            let mut runs = Vec::with_capacity(config.runs);
            let mut timestamps = true;
            for _ in 0..config.runs {
                let (_, t) = gpu.run(&frame.frame, &frame.records, config.integrator)?;
                timestamps &= t.gpu_timestamps;
                runs.push([t.splat_ms, t.integrate_ms, t.composite_ms, t.total_ms]);
            }
            let timing = if timestamps { "timestamps" } else { "wall" };
            report
                .rows
                .push(row("gpu", gpu.adapter_name(), size, records, &runs, timing));
        }
    }
    Ok(report)
}

impl BenchReport {
    /// The rows as a Markdown table, with the database and notes above it.
    pub fn to_markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "Database: {}\n", self.database);
        let _ = writeln!(
            s,
            "| backend | device | size | records | splat ms | integrate ms | composite ms | total ms | timing | runs |"
        );
        let _ = writeln!(
            s,
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
        );
        for r in &self.rows {
            let _ = writeln!(
                s,
                "| {} | {} | {}x{} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {} |",
                r.backend,
                r.device,
                r.size,
                r.size,
                r.records,
                r.splat_ms,
                r.integrate_ms,
                r.composite_ms,
                r.total_ms,
                r.timing,
                r.runs
            );
        }
        for n in &self.notes {
            let _ = writeln!(s, "\nNote: {n}");
        }
        s
    }
}

/// What `spreadlet bench --scaling` measures: CPU time against image size and against PSF
/// size, for the spreadlet path and the dense splat (the same PSFs, every one drawn whole).
#[derive(Clone, Debug, PartialEq)]
pub struct ScalingConfig {
    /// Square sizes of the size sweep, px (the frame spans the database's whole CoC range).
    pub sizes: Vec<u32>,
    /// Largest size the dense splat is timed at in the size sweep (it grows with the PSF area).
    pub dense_max_size: u32,
    /// CoC radii of the PSF-size sweep, px (every pixel of the frame gets this PSF).
    pub coc_radii: Vec<f32>,
    /// Square size of the PSF-size sweep's frame, px.
    pub psf_sweep_size: u32,
    /// Runs per point (the median is reported); at least 1.
    pub runs: usize,
    /// Depth layers.
    pub layers: u32,
    /// Integration method of the spreadlet path.
    pub integrator: Integrator,
    /// Placement of rotated spreadlets (the synthetic frames rotate their PSFs like motion).
    pub rotation: RotationSampling,
}

impl Default for ScalingConfig {
    fn default() -> Self {
        ScalingConfig {
            sizes: vec![256, 512, 1024, 2048],
            dense_max_size: 1024,
            coc_radii: vec![2.0, 4.0, 8.0, 16.0, 32.0, 64.0],
            psf_sweep_size: 512,
            runs: 3,
            layers: 8,
            integrator: Integrator::Pyramid,
            rotation: RotationSampling::default(),
        }
    }
}

/// One point of a scaling sweep (CPU, medians).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct ScalingRow {
    /// `size` or `psf`.
    pub sweep: String,
    /// `spreadlet` or `dense`.
    pub method: String,
    /// Frame edge, px.
    pub size: u32,
    /// CoC radius of every pixel (psf sweep), px; `None` for the size sweep (all radii).
    pub coc_px: Option<f32>,
    /// Mean support of the PSFs drawn (pixels with a non-zero value in the dense PSF).
    pub mean_psf_px: f64,
    /// Mean spreadlets per sparse record drawn (0 for dense).
    pub mean_spreadlets: f64,
    /// Records.
    pub records: usize,
    /// Splatting, ms.
    pub splat_ms: f64,
    /// Integration, ms.
    pub integrate_ms: f64,
    /// Compositing, ms.
    pub composite_ms: f64,
    /// Total after classification, ms.
    pub total_ms: f64,
    /// Runs.
    pub runs: usize,
}

/// A `size x size` frame in which every pixel uses the PSF of CoC radius `coc` (one layer per
/// band of rows, as [`synthetic_frame`] layers them), a checker of colours.
pub fn uniform_frame(db: &PsfDatabase, size: u32, coc: f32, layers: u32) -> Classified {
    let mut frame = synthetic_frame(db, size, layers);
    let (psf, _) = db.lookup([coc, 0.0]);
    let path = if db.dense(psf as usize).is_some() {
        SplatPath::Dense
    } else {
        SplatPath::Sparse
    };
    for r in &mut frame.records {
        r.psf_index = psf;
        r.path = path as u32;
        r.rot_cos = 1.0;
        r.rot_sin = 0.0;
    }
    let mut counts = PathCounts::default();
    for info in &mut frame.layers {
        let recs = &frame.records[info.first_record..info.first_record + info.record_count];
        *info = LayerInfo {
            first_record: info.first_record,
            record_count: info.record_count,
            ..LayerInfo::default()
        };
        info.count_paths(recs);
        counts.add_layer(info);
    }
    frame.counts = counts;
    frame
}

/// `frame` with every record pointed at `db` instead (same PSF indices: `db` must share the
/// parameter space), and its paths set from `db`.
fn repath(frame: &Classified, db: &PsfDatabase) -> Classified {
    let mut f = frame.clone();
    for r in &mut f.records {
        if r.path == SplatPath::Copy as u32 {
            continue;
        }
        r.path = if db.dense(r.psf_index as usize).is_some() {
            SplatPath::Dense
        } else {
            SplatPath::Sparse
        } as u32;
    }
    let mut counts = PathCounts::default();
    for info in &mut f.layers {
        let recs = &f.records[info.first_record..info.first_record + info.record_count];
        info.sparse = 0;
        info.dense = 0;
        info.copied = 0;
        info.count_paths(recs);
        counts.add_layer(info);
    }
    f.counts = counts;
    f.frame.pad = f.frame.pad.max(db.max_extent_px() + 2);
    f
}

/// Mean support (non-zero pixels of the dense PSF) and mean spreadlet count of the records of
/// `frame` that are not copies; supports come from `dense_db`.
fn psf_means(frame: &Classified, sparse_db: &PsfDatabase, dense_db: &PsfDatabase) -> (f64, f64) {
    let support: Vec<usize> = (0..dense_db.psf_count())
        .map(|i| {
            dense_db.dense(i).map_or(0, |d| {
                d.data
                    .chunks(d.channels)
                    .filter(|v| v.iter().any(|&x| x != 0.0))
                    .count()
            })
        })
        .collect();
    let (mut s, mut n_sp, mut n) = (0.0f64, 0.0f64, 0usize);
    for r in frame
        .records
        .iter()
        .filter(|r| r.path != SplatPath::Copy as u32)
    {
        let i = r.psf_index as usize;
        s += support.get(i).copied().unwrap_or(0) as f64;
        if sparse_db.dense(i).is_none() {
            n_sp += sparse_db.spreadlets(i).0.len() as f64;
        }
        n += 1;
    }
    if n == 0 {
        (0.0, 0.0)
    } else {
        (s / n as f64, n_sp / n as f64)
    }
}

fn scaling_row(
    sweep: &str,
    method: &str,
    size: u32,
    coc: Option<f32>,
    frame: &Classified,
    means: (f64, f64),
    runs: &[[f64; 4]],
) -> ScalingRow {
    let col = |k: usize| median(runs.iter().map(|r| r[k]).collect());
    ScalingRow {
        sweep: sweep.into(),
        method: method.into(),
        size,
        coc_px: coc,
        mean_psf_px: means.0,
        mean_spreadlets: if method == "dense" { 0.0 } else { means.1 },
        records: frame.records.len(),
        splat_ms: col(0),
        integrate_ms: col(1),
        composite_ms: col(2),
        total_ms: col(3),
        runs: runs.len(),
    }
}

/// Runs the scaling sweeps on the CPU with `sparse_db` (as the spreadlet path uses it) and
/// `dense_db` (the same PSFs stored dense, see `baseline::dense_build_config`); both
/// conditioned, thin-lens. `progress` prints each point to stderr as it is measured.
pub fn run_scaling(
    sparse_db: &PsfDatabase,
    dense_db: &PsfDatabase,
    config: &ScalingConfig,
    progress: bool,
) -> Result<Vec<ScalingRow>, BenchError> {
    if config.runs == 0 || (config.sizes.is_empty() && config.coc_radii.is_empty()) {
        return Err(BenchError::Config(
            "need at least one run and one point".into(),
        ));
    }
    if config
        .sizes
        .iter()
        .chain(std::iter::once(&config.psf_sweep_size))
        .any(|&s| s == 0 || s > 8192)
    {
        return Err(BenchError::Config("sizes must be in 1..=8192 px".into()));
    }
    if sparse_db.psf_count() != dense_db.psf_count() {
        return Err(BenchError::Config(
            "the sparse and dense databases must share their PSF space".into(),
        ));
    }
    let bench = BenchConfig {
        runs: config.runs,
        layers: config.layers,
        integrator: config.integrator,
        rotation: config.rotation,
        ..BenchConfig::default()
    };
    // As `DbSet` hands it to the pipeline: spreadlets in row order.
    let sorted;
    let sparse_db = if sparse_db.spreadlets_in_row_order() {
        sparse_db
    } else {
        sorted = sparse_db.with_spreadlets_in_row_order();
        &sorted
    };
    let mut rows = Vec::new();
    let measure = |sweep: &str, size: u32, coc: Option<f32>, frame: Classified, dense: bool| {
        let means = psf_means(&frame, sparse_db, dense_db);
        let mut out = vec![];
        let runs = time_cpu(sparse_db, &frame, &bench);
        out.push(scaling_row(
            sweep,
            "spreadlet",
            size,
            coc,
            &frame,
            means,
            &runs,
        ));
        if dense {
            let dframe = repath(&frame, dense_db);
            let runs = time_cpu(dense_db, &dframe, &bench);
            out.push(scaling_row(
                sweep, "dense", size, coc, &dframe, means, &runs,
            ));
        }
        for r in &out {
            if progress {
                eprintln!(
                    "{} sweep: {} {}x{} coc {:?}: {:.1} ms",
                    r.sweep, r.method, r.size, r.size, r.coc_px, r.total_ms
                );
            }
        }
        out
    };
    for &size in &config.sizes {
        let frame = synthetic_frame(sparse_db, size, config.layers);
        rows.extend(measure(
            "size",
            size,
            None,
            frame,
            size <= config.dense_max_size,
        ));
    }
    for &coc in &config.coc_radii {
        let frame = uniform_frame(sparse_db, config.psf_sweep_size, coc, config.layers);
        rows.extend(measure(
            "psf",
            config.psf_sweep_size,
            Some(coc),
            frame,
            true,
        ));
    }
    Ok(rows)
}

/// The scaling rows as two Markdown tables (size sweep, PSF sweep) with the dense/spreadlet
/// time ratio per point.
pub fn scaling_markdown(rows: &[ScalingRow], database: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Database: {database}; CPU, {} threads; medians.\n",
        rayon::current_num_threads()
    );
    for sweep in ["size", "psf"] {
        let _ = writeln!(
            s,
            "| sweep | size | CoC px | mean PSF support px | mean spreadlets | spreadlet ms (splat / integrate / composite) | dense ms | dense / spreadlet |"
        );
        let _ = writeln!(s, "| --- | --- | --- | --- | --- | --- | --- | --- |");
        for r in rows
            .iter()
            .filter(|r| r.sweep == sweep && r.method == "spreadlet")
        {
            let dense = rows.iter().find(|d| {
                d.sweep == sweep && d.method == "dense" && d.size == r.size && d.coc_px == r.coc_px
            });
            let _ = writeln!(
                s,
                "| {} | {}x{} | {} | {:.0} | {:.0} | {:.1} ({:.1} / {:.1} / {:.1}) | {} | {} |",
                sweep,
                r.size,
                r.size,
                r.coc_px.map_or("all".to_string(), |c| format!("{c}")),
                r.mean_psf_px,
                r.mean_spreadlets,
                r.total_ms,
                r.splat_ms,
                r.integrate_ms,
                r.composite_ms,
                dense.map_or("-".to_string(), |d| format!("{:.1}", d.total_ms)),
                dense.map_or("-".to_string(), |d| format!(
                    "{:.1}x",
                    d.total_ms / r.total_ms
                )),
            );
        }
        s.push('\n');
    }
    s
}
