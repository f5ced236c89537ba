//! The device check (`spreadlet bench --device-check DIR`, run by `scripts/gpu-check.sh`): the
//! micro-benchmarks of the device's limits, then synthesis of every scene (thin lens, lens and
//! motion, motion only) at every size with both splat stages on the GPU, configurations
//! interleaved (A B C A B C ...) after a warm-up, medians and spreads, each stage's time also
//! as a fraction of what the device allows for its atomics or bytes. One JSON and one
//! Markdown table.
//!
//! The report names the adapter and its device type; a software device (lavapipe) is marked
//! as such in both files, so that its figures are never read as a GPU's.

use std::path::{Path, PathBuf};
use std::time::Instant;

use metrics::median;
use poisson::pyramid::level_sizes;
use psf_db::PsfDatabase;

use crate::bench::{scene_frame, Scene};
use crate::microbench::{run_microbenchmarks, MicroConfig, MicroReport};
use spreadlet::gpu::{
    GpuContext, GpuError, GpuStageTimes, GpuSynthOptions, GpuSynthesizer, SplatMode,
};
use spreadlet::pipeline::types::SplatPath;
use spreadlet::pipeline::{Classified, Integrator, RotationSampling};

/// What the device check measures.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DeviceCheckConfig {
    /// Frame sizes (width, height), px.
    pub sizes: Vec<(u32, u32)>,
    /// Timed runs per configuration (after `warmup` untimed ones).
    pub runs: usize,
    /// Untimed runs per configuration first.
    pub warmup: usize,
    /// Depth layers.
    pub layers: u32,
    /// Rotated placement.
    pub rotation: RotationSampling,
    /// Splat stages compared.
    pub splats: Vec<SplatMode>,
    /// Micro-benchmark sizes.
    pub micro: MicroConfig,
    /// Profile of the databases (for the report).
    pub profile: String,
}

impl DeviceCheckConfig {
    /// The full check: 1024x1024, 1920x1080, 3840x2160, median of 10 after 2 warm-up runs.
    pub fn full() -> Self {
        DeviceCheckConfig {
            sizes: vec![(1024, 1024), (1920, 1080), (3840, 2160)],
            runs: 10,
            warmup: 2,
            layers: 8,
            rotation: RotationSampling::default(),
            splats: vec![SplatMode::Tiled, SplatMode::GlobalAtomic],
            micro: MicroConfig::full(),
            profile: "quick".into(),
        }
    }

    /// A smoke test of the check itself (a software device): small sizes, 3 runs.
    pub fn quick() -> Self {
        DeviceCheckConfig {
            sizes: vec![(64, 64), (96, 54)],
            runs: 3,
            warmup: 1,
            micro: MicroConfig::quick(),
            ..Self::full()
        }
    }
}

/// The work in one frame, counted on the CPU from the records and the database.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FrameWork {
    /// Records.
    pub records: usize,
    /// Spreadlets of the sparse records.
    pub spreadlets: u64,
    /// Non-zero dense pixels of the dense records.
    pub dense_pixels: u64,
    /// Copied records.
    pub copies: u64,
    /// Atomic adds of the global-atomic splat (samples times pixels of their placement times
    /// 4 channels; zero channels are skipped on the GPU, so this is an upper bound).
    pub adds: u64,
    /// Bytes the pyramid passes read and write at least once (every level's planes).
    pub integrate_bytes: u64,
    /// Bytes compositing reads and writes at least once.
    pub composite_bytes: u64,
}

/// One configuration's medians and spreads.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct DeviceCheckRow {
    /// `thin-lens`, `lens-motion` or `motion-only`.
    pub scene: String,
    /// Splat stage that ran (`tiled`, `global-atomic`).
    pub splat: String,
    /// Frame width, px.
    pub width: u32,
    /// Frame height, px.
    pub height: u32,
    /// Layers.
    pub layers: u32,
    /// The frame's work.
    pub work: FrameWork,
    /// Median of each stage over the runs, ms (`GpuStageTimes` fields).
    pub median: GpuStageTimes,
    /// Fastest run's total (wall), ms.
    pub total_min_ms: f64,
    /// Slowest run's total (wall), ms.
    pub total_max_ms: f64,
    /// Splat + integrate + composite (GPU time when timed by timestamps), median, ms.
    pub gpu_ms: f64,
    /// Fastest and slowest run of `gpu_ms`, ms.
    pub gpu_min_ms: f64,
    /// Slowest run of `gpu_ms`, ms.
    pub gpu_max_ms: f64,
    /// Samples (spreadlets, dense pixels, copies) drawn per second of the splat stage.
    pub samples_per_s: f64,
    /// Splat time over the time the frame's global adds take at the measured rate of random
    /// f32 atomic adds (1 = at that limit).
    pub splat_over_atomic_limit: f64,
    /// Integration time over the time its bytes take at the measured copy bandwidth.
    pub integrate_over_bandwidth: f64,
    /// Compositing time over the time its bytes take at the measured copy bandwidth.
    pub composite_over_bandwidth: f64,
    /// `timestamps` or `wall`.
    pub timing: String,
    /// Runs timed.
    pub runs: usize,
}

/// The whole device check.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DeviceCheckReport {
    /// Adapter name and backend.
    pub adapter: String,
    /// Device type as wgpu reports it.
    pub device_type: String,
    /// True for a software device (wgpu device type `Cpu`, or lavapipe/llvmpipe by name):
    /// its figures say nothing about a GPU.
    pub software_device: bool,
    /// Driver and its version, as wgpu reports them.
    pub driver: String,
    /// What was measured.
    pub config: DeviceCheckConfig,
    /// The databases (model, PSFs, spreadlets, extent).
    pub databases: Vec<String>,
    /// Micro-benchmarks of the device's limits.
    pub micro: MicroReport,
    /// One row per scene, size and splat stage.
    pub rows: Vec<DeviceCheckRow>,
    /// Goals and how the measurement compares.
    pub goals: Vec<String>,
    /// Remarks.
    pub notes: Vec<String>,
    /// Seconds the whole check took.
    pub seconds: f64,
}

/// Errors of the device check.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    /// No adapter.
    #[error("the device check needs a GPU adapter, and none was found")]
    NoAdapter,
    /// The GPU path failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// A database could not be built or loaded.
    #[error("database: {0}")]
    Database(#[from] spreadlet::dbcache::CacheError),
    /// Writing the report failed.
    #[error("writing {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The configuration makes no sense.
    #[error("device check configuration: {0}")]
    Config(String),
}

fn scene_name(db: &PsfDatabase, scene: Scene) -> &'static str {
    match (scene, db.model()) {
        (Scene::MotionOnly, _) => "motion-only",
        (_, psf_db::PsfModel::ThinLens) => "thin-lens",
        (_, psf_db::PsfModel::LensMotion) => "lens-motion",
        (_, psf_db::PsfModel::PhysicalLens) => "physical-lens",
    }
}

/// Counts the work of `frame` with `db`.
pub fn frame_work(db: &PsfDatabase, frame: &Classified, rotation: RotationSampling) -> FrameWork {
    let mut w = FrameWork {
        records: frame.records.len(),
        ..FrameWork::default()
    };
    let dense_nonzero: Vec<u64> = (0..db.psf_count())
        .map(|i| {
            db.dense(i).map_or(0, |d| {
                d.data
                    .chunks(d.channels.max(1))
                    .filter(|v| v.iter().any(|&x| x != 0.0))
                    .count() as u64
            })
        })
        .collect();
    for r in &frame.records {
        let rotated = !(r.rot_cos == 1.0 && r.rot_sin == 0.0);
        let i = r.psf_index as usize;
        if r.path == SplatPath::Copy as u32 {
            w.copies += 1;
            w.adds += 4;
        } else if r.path == SplatPath::Sparse as u32 && i < db.psf_count() {
            let n = db.spreadlets(i).0.len() as u64;
            let taps = match (rotated, rotation) {
                (false, _) | (true, RotationSampling::Nearest) => 1,
                (true, RotationSampling::Bilinear) => 4,
                (true, RotationSampling::Bspline) => 9,
            };
            w.spreadlets += n;
            w.adds += 4 * taps * n;
        } else if r.path == SplatPath::Dense as u32 && i < db.psf_count() {
            let n = dense_nonzero[i];
            let taps = match (rotated, rotation) {
                (false, _) | (true, RotationSampling::Nearest) => 1,
                _ => 4,
            };
            w.dense_pixels += n;
            w.adds += 4 * taps * n;
        }
    }
    let f = &frame.frame;
    let (pw, ph) = (f.padded_width as usize, f.padded_height as usize);
    let planes = 4 * f.layers as u64;
    let sizes = level_sizes(pw, ph);
    let px: Vec<u64> = sizes.iter().map(|&(w, h)| (w * h) as u64).collect();
    let layer_px = (pw * ph) as u64;
    // Analysis i: read level i - 1, write level i; top: read and write the last; synthesis
    // i: read f_{i+1} and a_i, write f_i; output: read f_0 and the direct planes, write the
    // layer images.
    let mut bytes = 0u64;
    for i in 1..px.len() {
        bytes += px[i - 1] + px[i];
    }
    bytes += 2 * px[px.len() - 1];
    for i in 0..px.len() - 1 {
        bytes += px[i + 1] + 2 * px[i];
    }
    bytes += px[0] + 2 * layer_px;
    w.integrate_bytes = 4 * planes * bytes;
    w.composite_bytes = 4 * planes * layer_px + 16 * (f.width as u64 * f.height as u64);
    w
}

fn median_times(runs: &[GpuStageTimes]) -> GpuStageTimes {
    let col = |f: fn(&GpuStageTimes) -> f64| median(&mut runs.iter().map(f).collect::<Vec<_>>());
    GpuStageTimes {
        upload_ms: col(|t| t.upload_ms),
        splat_ms: col(|t| t.splat_ms),
        bin_ms: col(|t| t.bin_ms),
        integrate_ms: col(|t| t.integrate_ms),
        composite_ms: col(|t| t.composite_ms),
        readback_ms: col(|t| t.readback_ms),
        total_ms: col(|t| t.total_ms),
        gpu_timestamps: runs.iter().all(|t| t.gpu_timestamps),
    }
}

/// Whether `ctx` is a software device.
pub fn is_software(ctx: &GpuContext) -> bool {
    let info = ctx.adapter_info();
    let name = info.name.to_lowercase();
    info.device_type == wgpu::DeviceType::Cpu
        || name.contains("llvmpipe")
        || name.contains("lavapipe")
        || name.contains("swiftshader")
}

/// Runs the device check on `ctx` with `dbs` (each with the scenes drawn with it), printing
/// progress to stderr when `progress`.
pub fn run_device_check(
    ctx: &GpuContext,
    dbs: &[(&PsfDatabase, Vec<Scene>)],
    config: &DeviceCheckConfig,
    progress: bool,
) -> Result<DeviceCheckReport, CheckError> {
    if config.sizes.is_empty() || config.runs == 0 || config.splats.is_empty() || dbs.is_empty() {
        return Err(CheckError::Config(
            "need a size, a run, a splat stage and a database".into(),
        ));
    }
    let t0 = Instant::now();
    let say = |m: String| {
        if progress {
            eprintln!("[{:6.1} s] {m}", t0.elapsed().as_secs_f64());
        }
    };
    let software = is_software(ctx);
    say(format!(
        "adapter {} ({:?}){}",
        ctx.adapter_name(),
        ctx.adapter_info().device_type,
        if software {
            ": a SOFTWARE device, figures are not a GPU's"
        } else {
            ""
        }
    ));
    say("micro-benchmarks".into());
    let micro = run_microbenchmarks(ctx, &config.micro)?;
    for r in &micro.results {
        say(format!(
            "  {}: {:.3} ms, {:.2} {} ({})",
            r.name,
            r.median_ms,
            r.rate_per_s / 1e9,
            r.unit,
            r.timing
        ));
    }
    let random_rate = micro.rate("atomic-global-random").unwrap_or(f64::NAN);
    let bandwidth = micro.rate("copy-shader").unwrap_or(f64::NAN);
    let mut synths = Vec::new();
    for (db, _) in dbs {
        say(format!(
            "compiling pipelines, uploading {}",
            db.model().name()
        ));
        synths.push(GpuSynthesizer::new(
            ctx,
            db,
            GpuSynthOptions {
                rotation: config.rotation,
                ..GpuSynthOptions::default()
            },
        )?);
    }
    let mut notes = Vec::new();
    if synths.iter().any(|s| {
        s.effective_splat_mode(SplatMode::Tiled) != SplatMode::Tiled
            && config.splats.contains(&SplatMode::Tiled)
    }) {
        notes.push(
            "the device cannot run the tiled splat (workgroup memory or storage bindings): its rows ran the global-atomic splat"
                .into(),
        );
    }
    let mut rows = Vec::new();
    for &(w, h) in &config.sizes {
        // Configurations: (database, scene, splat), each with its frame.
        struct Config {
            db: usize,
            scene: Scene,
            splat: SplatMode,
            frame: usize,
            runs: Vec<GpuStageTimes>,
        }
        let mut frames = Vec::new();
        let mut configs = Vec::new();
        for (d, (db, scenes)) in dbs.iter().enumerate() {
            for &scene in scenes {
                say(format!(
                    "{w}x{h}: building the {} frame",
                    scene_name(db, scene)
                ));
                let frame = scene_frame(db, scene, w, h, config.layers);
                let work = frame_work(db, &frame, config.rotation);
                frames.push((frame, work));
                for &splat in &config.splats {
                    configs.push(Config {
                        db: d,
                        scene,
                        splat,
                        frame: frames.len() - 1,
                        runs: Vec::new(),
                    });
                }
            }
        }
        for round in 0..config.warmup + config.runs {
            if round == config.warmup {
                say(format!(
                    "{w}x{h}: timing {} configurations x {} runs, interleaved",
                    configs.len(),
                    config.runs
                ));
            }
            for c in &mut configs {
                let synth = &mut synths[c.db];
                synth.set_splat_mode(c.splat);
                let frame = &frames[c.frame].0;
                let (_, t) = synth.run(&frame.frame, &frame.records, Integrator::Pyramid)?;
                if round >= config.warmup {
                    c.runs.push(t);
                }
            }
        }
        // Exact integration stays an FFT on the CPU: what it costs, once per check (the
        // first size, lens and motion, a few runs).
        let exact = if Some(&(w, h)) == config.sizes.first() {
            configs
                .iter()
                .find(|c| {
                    c.scene == Scene::Defocus && dbs[c.db].0.model() == psf_db::PsfModel::LensMotion
                })
                .map(|c| (c.db, c.frame, c.splat))
        } else {
            None
        };
        let mut exact_runs = Vec::new();
        if let Some((d, f, splat)) = exact {
            say(format!(
                "{w}x{h}: exact integration (CPU FFT, read-back and upload)"
            ));
            let synth = &mut synths[d];
            synth.set_splat_mode(splat);
            let frame = &frames[f].0;
            for _ in 0..config.runs.min(3) {
                let (_, t) = synth.run(&frame.frame, &frame.records, Integrator::Exact)?;
                exact_runs.push(t);
            }
            configs.push(Config {
                db: d,
                scene: Scene::Defocus,
                splat,
                frame: f,
                runs: exact_runs,
            });
        }
        let exact_index = exact.map(|_| configs.len() - 1);
        for (k, c) in configs.into_iter().enumerate() {
            let (db, _) = &dbs[c.db];
            let work = frames[c.frame].1;
            let m = median_times(&c.runs);
            let mut gpu: Vec<f64> = c
                .runs
                .iter()
                .map(|t| t.splat_ms + t.integrate_ms + t.composite_ms)
                .collect();
            let mut total: Vec<f64> = c.runs.iter().map(|t| t.total_ms).collect();
            let gpu_ms = median(&mut gpu);
            total.sort_by(f64::total_cmp);
            let samples = (work.spreadlets + work.dense_pixels + work.copies) as f64;
            let scene = if Some(k) == exact_index {
                format!("{} (exact: CPU FFT)", scene_name(db, c.scene))
            } else {
                scene_name(db, c.scene).into()
            };
            let row = DeviceCheckRow {
                scene,
                splat: synths[c.db].effective_splat_mode(c.splat).name().into(),
                width: w,
                height: h,
                layers: config.layers,
                work,
                median: m,
                total_min_ms: total.first().copied().unwrap_or(f64::NAN),
                total_max_ms: total.last().copied().unwrap_or(f64::NAN),
                gpu_ms,
                gpu_min_ms: gpu.first().copied().unwrap_or(f64::NAN),
                gpu_max_ms: gpu.last().copied().unwrap_or(f64::NAN),
                samples_per_s: samples / (m.splat_ms * 1e-3),
                splat_over_atomic_limit: m.splat_ms / (work.adds as f64 / random_rate * 1e3),
                integrate_over_bandwidth: m.integrate_ms
                    / (work.integrate_bytes as f64 / bandwidth * 1e3),
                composite_over_bandwidth: m.composite_ms
                    / (work.composite_bytes as f64 / bandwidth * 1e3),
                timing: if m.gpu_timestamps {
                    "timestamps"
                } else {
                    "wall"
                }
                .into(),
                runs: c.runs.len(),
            };
            say(format!(
                "  {} {} {}x{}: GPU {:.3} ms (splat {:.3}, integrate {:.3}, composite {:.3}), wall {:.3} ms",
                row.scene, row.splat, w, h, row.gpu_ms, m.splat_ms, m.integrate_ms, m.composite_ms, m.total_ms
            ));
            rows.push(row);
        }
    }
    let goals = goals(&rows, software);
    if !micro.timestamps {
        notes.push("no TIMESTAMP_QUERY on this adapter: stage times are wall times around separate submissions".into());
    }
    let info = ctx.adapter_info();
    Ok(DeviceCheckReport {
        adapter: ctx.adapter_name(),
        device_type: format!("{:?}", info.device_type),
        software_device: software,
        driver: format!("{} {}", info.driver, info.driver_info),
        config: config.clone(),
        databases: dbs
            .iter()
            .map(|(db, _)| {
                format!(
                    "{} ({} PSFs, {} spreadlets, max extent {} px)",
                    db.model().name(),
                    db.psf_count(),
                    db.spreadlet_count(),
                    db.max_extent_px()
                )
            })
            .collect(),
        micro,
        rows,
        goals,
        notes,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The goals of an H100/H200-class GPU, against the best splat stage of each row.
fn goals(rows: &[DeviceCheckRow], software: bool) -> Vec<String> {
    let best = |scene: &str, w: u32, h: u32| {
        rows.iter()
            .filter(|r| r.scene == scene && r.width == w && r.height == h)
            .min_by(|a, b| a.gpu_ms.total_cmp(&b.gpu_ms))
    };
    let mut out = Vec::new();
    if software {
        out.push(
            "software device: the goals are for an H100/H200-class GPU and are not judged here"
                .into(),
        );
        return out;
    }
    let verdict = |what: String, got: f64, goal: f64| {
        if got <= goal {
            format!("{what}: {got:.3} ms, goal {goal} ms: met")
        } else {
            format!(
                "{what}: {got:.3} ms, goal {goal} ms: missed by {:.1}x",
                got / goal
            )
        }
    };
    if let Some(r) = best("lens-motion", 1024, 1024) {
        out.push(verdict(
            format!("lens+motion 1024x1024 GPU time ({})", r.splat),
            r.gpu_ms,
            2.0,
        ));
        out.push(verdict(
            format!(
                "lens+motion 1024x1024 wall time, records uploaded and image read back ({})",
                r.splat
            ),
            r.median.total_ms,
            2.0,
        ));
        out.push(verdict(
            "integration per layer, 1024x1024".into(),
            r.median.integrate_ms / r.layers as f64,
            0.3,
        ));
        out.push(format!(
            "splat at {:.1}x the random-atomic limit of its adds ({}; goal within 3x)",
            r.splat_over_atomic_limit, r.splat
        ));
    }
    if let Some(r) = best("lens-motion", 3840, 2160) {
        out.push(verdict(
            format!("lens+motion 3840x2160 GPU time ({})", r.splat),
            r.gpu_ms,
            8.0,
        ));
    }
    out
}

impl DeviceCheckReport {
    /// The report as Markdown: device, micro-benchmarks, one row per configuration, goals.
    pub fn to_markdown(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "Device: {} ({}; driver {}){}\n",
            self.adapter,
            self.device_type,
            self.driver,
            if self.software_device {
                " -- a SOFTWARE device: these figures are not a GPU's"
            } else {
                ""
            }
        );
        let _ = writeln!(
            s,
            "Databases ({} profile): {}\n",
            self.config.profile,
            self.databases.join("; ")
        );
        let _ = writeln!(
            s,
            "| micro-benchmark | median ms | min-max ms | rate | timing |"
        );
        let _ = writeln!(s, "| --- | --- | --- | --- | --- |");
        for r in &self.micro.results {
            let _ = writeln!(
                s,
                "| {} | {:.3} | {:.3}-{:.3} | {:.2} {} | {} |",
                r.name,
                r.median_ms,
                r.min_ms,
                r.max_ms,
                r.rate_per_s / 1e9,
                r.unit,
                r.timing
            );
        }
        let _ = writeln!(
            s,
            "\nGlobal atomics: {}.\n",
            if self.micro.float_atomics {
                "native f32 atomicAdd"
            } else {
                "compare-exchange loop on u32 (no SHADER_FLOAT32_ATOMIC)"
            }
        );
        let _ = writeln!(
            s,
            "| scene | splat | size | records | samples | GPU ms (min-max) | splat (bin) | integrate | composite | upload | wait + readback | wall ms (min-max) | Msamples/s | splat / atomic limit | integrate / bandwidth | composite / bandwidth | timing |"
        );
        let _ = writeln!(
            s,
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
        );
        for r in &self.rows {
            let m = &r.median;
            let _ = writeln!(
                s,
                "| {} | {} | {}x{} | {} | {} | {:.3} ({:.3}-{:.3}) | {:.3} ({:.3}) | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} ({:.3}-{:.3}) | {:.0} | {:.1}x | {:.1}x | {:.1}x | {} |",
                r.scene,
                r.splat,
                r.width,
                r.height,
                r.work.records,
                r.work.spreadlets + r.work.dense_pixels + r.work.copies,
                r.gpu_ms,
                r.gpu_min_ms,
                r.gpu_max_ms,
                m.splat_ms,
                m.bin_ms,
                m.integrate_ms,
                m.composite_ms,
                m.upload_ms,
                m.readback_ms,
                m.total_ms,
                r.total_min_ms,
                r.total_max_ms,
                r.samples_per_s / 1e6,
                r.splat_over_atomic_limit,
                r.integrate_over_bandwidth,
                r.composite_over_bandwidth,
                r.timing
            );
        }
        let _ = writeln!(
            s,
            "\n{} layers; medians of {} runs after {} warm-up runs, configurations interleaved; GPU ms = splat + integrate + composite; wall = the whole `run` call (record upload and image readback included). Ratios: stage time over the time its adds (random f32 atomics) or bytes (shader copy bandwidth) take at the measured limits.\n",
            self.config.layers, self.config.runs, self.config.warmup
        );
        for g in &self.goals {
            let _ = writeln!(s, "- {g}");
        }
        for n in &self.notes {
            let _ = writeln!(s, "\nNote: {n}");
        }
        let _ = writeln!(s, "\nThe check took {:.0} s.", self.seconds);
        s
    }
}

/// Writes `contents` to `path` through a temporary file and a rename (never half a file).
fn write_atomically(path: &Path, contents: &[u8]) -> Result<(), CheckError> {
    formats::atomic::write_bytes_atomically(path, contents).map_err(|e| CheckError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::other(e),
    })
}

/// The device check as `spreadlet bench --device-check DIR` runs it: loads (or builds) the
/// thin-lens and lens-motion databases of `profile`, runs the check on the first adapter and
/// writes `device-check.json` and `device-check.md` into `dir`. Returns the two paths.
pub fn run_to_folder(
    dir: &Path,
    quick: bool,
    profile: precompute::Profile,
    rotation: RotationSampling,
) -> Result<(PathBuf, PathBuf), CheckError> {
    std::fs::create_dir_all(dir).map_err(|source| CheckError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let ctx = GpuContext::with_requirement(true)?.ok_or(CheckError::NoAdapter)?;
    let load = |model| -> Result<PsfDatabase, CheckError> {
        let cfg = spreadlet::dbcache::build_config(model, profile, 0);
        let (db, _) = spreadlet::dbcache::cached_database(
            &cfg,
            &spreadlet::dbcache::cache_dir(),
            true,
            &crate::print_cache_event,
        )?;
        // As `DbSet` hands it to the pipeline: spreadlets in row order.
        Ok(db.into_spreadlets_in_row_order())
    };
    eprintln!("loading (or building) the {profile} databases");
    let thin = load(psf_db::PsfModel::ThinLens)?;
    let motion = load(psf_db::PsfModel::LensMotion)?;
    let mut config = if quick {
        DeviceCheckConfig::quick()
    } else {
        DeviceCheckConfig::full()
    };
    config.rotation = rotation;
    config.profile = profile.to_string();
    let report = run_device_check(
        &ctx,
        &[
            (&thin, vec![Scene::Defocus]),
            (&motion, vec![Scene::Defocus, Scene::MotionOnly]),
        ],
        &config,
        true,
    )?;
    let json = dir.join("device-check.json");
    let md = dir.join("device-check.md");
    let text = serde_json::to_vec_pretty(&report)
        .map_err(|e| CheckError::Config(format!("serialising the report: {e}")))?;
    write_atomically(&json, &text)?;
    write_atomically(&md, report.to_markdown().as_bytes())?;
    Ok((json, md))
}
