//! `spreadlet`: depth of field and motion blur by splatting sparse Laplacian PSFs.
//!
//! Subcommands: `synth` (from a pinhole G-buffer), `reconstruct` (from stochastic frames),
//! `demo` (everything on built-in data) and `compare` (SSIM and PSNR of two EXRs).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};

use runtime::camera::Camera;
use runtime::dbcache;
use runtime::dbset::DbSet;
use runtime::gbuffer::{ChannelOptions, GBuffer, Layout};
use runtime::pipeline::{
    ClassifyOptions, CompositeOptions, Effects, FrameEdges, Integrator, RotationSampling,
    SplatOptions,
};
use runtime::rgba::RgbaImage;
use runtime::synth::{synthesize, SynthOptions};

#[derive(Parser, Debug)]
#[command(
    name = "spreadlet",
    version,
    about = "Depth of field and motion blur by splatting sparse Laplacian PSFs (Leimkühler et al. 2018)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Synthesise depth of field and motion blur from a pinhole G-buffer (OpenEXR).
    Synth(SynthArgs),
    /// SSIM and PSNR (sRGB, as DEVELOPERS.md defines them) of two OpenEXR images.
    Compare(CompareArgs),
    /// Reconstruct depth of field and motion blur from noisy stochastic frames (each sample
    /// labelled with its lens position and time; layout in docs/STOCHASTIC.md).
    Reconstruct(ReconstructArgs),
    /// The whole job on built-in data: render a scene, synthesise, reconstruct, score.
    Demo(DemoArgs),
    /// Per-stage and total times of both backends at several sizes (median of runs), as a
    /// Markdown table.
    #[cfg(feature = "gpu")]
    Bench(BenchArgs),
    /// What accuracy costs in time: sweeps of every knob and the dense and filter baselines on
    /// a scene, scored against a reference (CSV, Markdown, PNG; docs/STUDY.md).
    Study(StudyArgs),
}

#[derive(Args, Debug)]
struct StudyArgs {
    /// Output folder (study.csv, study.md, study.png, study.json).
    #[arg(long, default_value = "out/study")]
    out: PathBuf,
    /// Built-in scene to render (bokeh, crossing, occluder, rotating, physical).
    #[arg(long, default_value = "occluder")]
    scene: String,
    /// Square image size of the built-in scene, pixels (default: the scene's).
    #[arg(long)]
    size: Option<u32>,
    /// Pinhole G-buffer (OpenEXR) to study instead of a built-in scene (with --camera and
    /// --reference).
    #[arg(long, requires_all = ["camera", "reference"])]
    input: Option<PathBuf>,
    /// Camera description of --input.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Reference image (OpenEXR) of --input.
    #[arg(long)]
    reference: Option<PathBuf>,
    /// Larger sweeps (takes longer).
    #[arg(long)]
    full: bool,
    /// Timed runs per configuration (the median is reported).
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Samples per pixel of the built-in scene's reference.
    #[arg(long, default_value_t = 256)]
    reference_spp: usize,
    /// Profile of databases built on demand.
    #[arg(long, default_value = "quick")]
    db_profile: String,
    /// Skip the GPU rows.
    #[arg(long)]
    no_gpu: bool,
    /// Run the peer comparison (issue #8) instead.
    #[arg(long)]
    peers: bool,
    /// Print no progress.
    #[arg(long, short)]
    quiet: bool,
}

#[cfg(feature = "gpu")]
#[derive(Args, Debug)]
struct BenchArgs {
    /// Square frame sizes, pixels, comma-separated.
    #[arg(long, default_value = "512,1024", value_delimiter = ',')]
    sizes: Vec<u32>,
    /// Runs per backend and size (the median is reported).
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Profile of the lens-motion database (built on demand into the cache).
    #[arg(long, default_value = "quick")]
    db_profile: String,
    /// Skip the CPU backend.
    #[arg(long)]
    no_cpu: bool,
    /// Skip the GPU backend.
    #[arg(long)]
    no_gpu: bool,
    /// Instead: CPU time of spreadlet and dense splatting against image size (--sizes,
    /// default 256,512,1024,2048) and against PSF size (--coc-radii), thin-lens database.
    #[arg(long)]
    scaling: bool,
    /// CoC radii of the --scaling PSF-size sweep, px.
    #[arg(long, default_value = "2,4,8,16,32,64", value_delimiter = ',')]
    coc_radii: Vec<f32>,
    /// Largest size the dense splat is timed at in the --scaling size sweep, px.
    #[arg(long, default_value_t = 1024)]
    dense_max_size: u32,
    /// Placement of rotated (motion-aligned) spreadlets.
    #[arg(long, value_enum, default_value_t = RotationSampling::Bspline)]
    rotation: RotationSampling,
    /// Splat stage of the GPU path.
    #[arg(long, value_enum, default_value_t = runtime::gpu::SplatMode::Tiled)]
    splat: runtime::gpu::SplatMode,
    /// Instead: the device check (micro-benchmarks of the GPU's limits, then thin lens, lens
    /// and motion, and motion only at 1024x1024, 1920x1080 and 3840x2160 with both splat
    /// stages), written to device-check.json and device-check.md in this folder.
    #[arg(long)]
    device_check: Option<PathBuf>,
    /// With --device-check: small sizes and few runs (to test the check on a software device).
    #[arg(long)]
    quick: bool,
}

#[derive(Args, Debug)]
struct ReconstructArgs {
    /// Stochastic frames (OpenEXR, docs/STOCHASTIC.md); a run of # stands for the frame number
    /// with --frames.
    #[arg(long)]
    input: PathBuf,
    /// Method: spreadlet, or a peer reconstruction method for comparison, on the same
    /// samples and camera (shirley, shirley4, shirley-layered, vaidyanathan, munkberg,
    /// munkberg44; docs/PEERS.md).
    #[arg(long, default_value = "spreadlet")]
    method: String,
    /// Run a peer method even when it does not reproduce an effect of the input
    /// (vaidyanathan and shirley-layered on moving samples ignore the motion blur); without
    /// it that is an error.
    #[arg(long)]
    allow_unhandled_effects: bool,
    /// Frame range A-B of a sequence (# in the paths is replaced by the frame number).
    #[arg(long)]
    frames: Option<String>,
    /// Only part K of N of the frame range (auto/N: K from SLURM_ARRAY_TASK_ID or
    /// JOB_COMPLETION_INDEX).
    #[arg(long)]
    shard: Option<String>,
    /// Camera description (`camera.json`); flags with the same names override its fields.
    #[arg(long)]
    camera: Option<PathBuf>,
    #[command(flatten)]
    camera_flags: CameraFlags,
    /// Output OpenEXR (linear RGBA, f32), written atomically.
    #[arg(long)]
    out: PathBuf,
    /// Profile of databases built on demand.
    #[arg(long, default_value = "quick")]
    db_profile: String,
    /// Number of global depth layers (binned in constant parallax).
    #[arg(long, default_value_t = 8)]
    layers: u32,
    /// Poisson integrator (exact by default: the pyramid's small relative error becomes
    /// visible around HDR highlights).
    #[arg(long, value_enum, default_value_t = Integrator::Exact)]
    integrate: Integrator,
    /// Device for splatting, integration and compositing (`auto`: a hardware GPU when there is
    /// one, else the CPU).
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    backend: Backend,
    /// Write an sRGB PNG preview.
    #[arg(long)]
    preview: Option<PathBuf>,
    /// Write statistics (effects, counts per path, stage times) as JSON.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// Print no progress.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Args, Debug)]
struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "out/demo")]
    out: PathBuf,
    /// Built-in scene (bokeh, crossing, occluder, rotating, physical).
    #[arg(long, default_value = "crossing")]
    scene: String,
    /// Square image size override, pixels.
    #[arg(long)]
    size: Option<u32>,
    /// Samples per pixel of the reference.
    #[arg(long, default_value_t = 1024)]
    reference_spp: usize,
    /// Profile of databases built on demand.
    #[arg(long, default_value = "quick")]
    db_profile: String,
    /// Print no progress.
    #[arg(long, short)]
    quiet: bool,
}

/// Which device runs the pipeline.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ValueEnum)]
enum Backend {
    /// The GPU when an adapter exists, else the CPU.
    #[default]
    Auto,
    /// The GPU (an error when there is none).
    Gpu,
    /// The CPU (rayon).
    Cpu,
}

/// Camera fields given as flags (same names as in `camera.json`); they override the file.
#[derive(Args, Debug, Default)]
struct CameraFlags {
    /// Output width, pixels.
    #[arg(long)]
    width: Option<u32>,
    /// Output height, pixels.
    #[arg(long)]
    height: Option<u32>,
    /// Focal length, mm.
    #[arg(long)]
    focal_length_mm: Option<f64>,
    /// Sensor width, mm (maps to the image width).
    #[arg(long)]
    sensor_width_mm: Option<f64>,
    /// Aperture f-number (omit both this and --focus-distance for a pinhole).
    #[arg(long)]
    f_stop: Option<f64>,
    /// Focus distance, scene units (planar).
    #[arg(long)]
    focus_distance: Option<f64>,
    /// Aperture blades (0 = circular).
    #[arg(long)]
    aperture_blades: Option<u32>,
    /// Shutter as a fraction of the frame (0 = no motion blur).
    #[arg(long)]
    shutter_frames: Option<f64>,
    /// Millimetres per scene unit (default 1000: metres).
    #[arg(long)]
    scene_unit_mm: Option<f64>,
}

#[derive(Args, Debug)]
struct SynthArgs {
    /// Pinhole G-buffer: OpenEXR with colour, depth and (for motion blur) motion vectors. For a
    /// sequence, a run of # stands for the frame number (frames/####.exr with --frames).
    #[arg(long)]
    input: PathBuf,
    /// Method: spreadlet; the baselines dense (every pre-filtered PSF drawn whole, no
    /// Laplacian) and filter (gathering with the same PSFs; docs/STUDY.md); or a peer
    /// method for comparison (mcguire, guertin: motion blur from the G-buffer, no defocus;
    /// docs/PEERS.md).
    #[arg(long, default_value = "spreadlet")]
    method: String,
    /// Frame range A-B of a sequence: # in --input, --out, --camera, --preview and --stats is
    /// replaced by the frame number; databases and GPU pipelines are reused across frames.
    #[arg(long)]
    frames: Option<String>,
    /// Synthesise only part K of N of the frame range (0-based; auto/N takes K from
    /// SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX).
    #[arg(long)]
    shard: Option<String>,
    /// Camera description (`camera.json`); flags with the same names override its fields.
    #[arg(long)]
    camera: Option<PathBuf>,
    #[command(flatten)]
    camera_flags: CameraFlags,
    /// Output OpenEXR (linear RGBA, f32), written atomically.
    #[arg(long)]
    out: PathBuf,
    /// PSF database to use instead of the cached one (built on demand).
    #[arg(long)]
    db: Option<PathBuf>,
    /// Profile of databases built on demand.
    #[arg(long, default_value = "quick")]
    db_profile: String,
    /// Number of global depth layers (binned in constant parallax).
    #[arg(long, default_value_t = 8)]
    layers: u32,
    /// Soft layering: blend width between neighbouring layers in layer units (0 = hard
    /// layers; the flag alone = 1).
    #[arg(long, num_args = 0..=1, default_missing_value = "1.0", default_value = "1.0")]
    soft_layers: f32,
    /// Do not split anti-aliased edge pixels into foreground and background parts.
    #[arg(long)]
    no_edge_split: bool,
    /// Do not scale the composite up to the layers' joint coverage.
    #[arg(long)]
    no_coverage_renormalization: bool,
    /// What lies beyond the input's pixels (its overscan, if the file has any): extend (the
    /// outermost pixels continue outwards, so a blurred frame keeps its brightness to the
    /// edge) or black (the frame's border loses light; for comparison).
    #[arg(long, value_enum, default_value_t = FrameEdges::Extend)]
    frame_edges: FrameEdges,
    /// Do not continue a blurred background behind the silhouettes of sharper occluders (the
    /// background then darkens along them).
    #[arg(long)]
    no_hidden_fill: bool,
    /// Poisson integrator (exact by default: the pyramid's small relative error becomes
    /// visible around HDR highlights).
    #[arg(long, value_enum, default_value_t = Integrator::Exact)]
    integrate: Integrator,
    /// Placement of rotated (motion-aligned) spreadlets.
    #[arg(long, value_enum, default_value_t = RotationSampling::Bspline)]
    rotation: RotationSampling,
    /// Write statistics (effects, databases, counts per path, stage times) as JSON.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// Write an sRGB PNG preview.
    #[arg(long)]
    preview: Option<PathBuf>,
    /// Device.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    backend: Backend,
    /// Input layout.
    #[arg(long, value_enum, default_value_t = Layout::Auto)]
    layout: Layout,
    /// Blender view layer to read (when the file has several).
    #[arg(long)]
    layer: Option<String>,
    /// Plain layout: depth channel name.
    #[arg(long)]
    depth_channel: Option<String>,
    /// Plain layout: forward motion channels, "X,Y" (pixels per frame, x right, y down).
    #[arg(long)]
    motion_channels: Option<String>,
    /// Plain layout: the motion's y axis points up.
    #[arg(long)]
    motion_y_up: bool,
    /// Use the database's spreadlets as stored (no monopole removal, no energy
    /// normalisation).
    #[arg(long)]
    no_condition: bool,
    /// Print no progress.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Args, Debug)]
struct CompareArgs {
    /// First image (OpenEXR; Blender multilayer or plain RGBA).
    a: PathBuf,
    /// Second image.
    b: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Write FLIP's per-pixel error map (magma colour map, as NVIDIA's tool shows it) as PNG.
    #[arg(long)]
    flip_map: Option<PathBuf>,
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Synth(args) => run_synth(args),
        Command::Compare(args) => run_compare(args),
        Command::Reconstruct(args) => run_reconstruct(args),
        Command::Demo(args) => run_demo(args),
        #[cfg(feature = "gpu")]
        Command::Bench(args) => run_bench(args),
        Command::Study(args) => run_study(args),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn load_camera(path: Option<&Path>, f: &CameraFlags) -> Result<Camera> {
    let mut value = match path {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("cannot read camera file {}", p.display()))?;
            serde_json::from_str::<serde_json::Value>(&text)
                .with_context(|| format!("camera file {} is not JSON", p.display()))?
        }
        None => serde_json::json!({}),
    };
    let Some(obj) = value.as_object_mut() else {
        bail!("the camera file must hold a JSON object");
    };
    let mut set = |k: &str, v: Option<serde_json::Value>| {
        if let Some(v) = v {
            obj.insert(k.to_string(), v);
        }
    };
    set("width", f.width.map(Into::into));
    set("height", f.height.map(Into::into));
    set("focal_length_mm", f.focal_length_mm.map(Into::into));
    set("sensor_width_mm", f.sensor_width_mm.map(Into::into));
    set("f_stop", f.f_stop.map(Into::into));
    set("focus_distance", f.focus_distance.map(Into::into));
    set("aperture_blades", f.aperture_blades.map(Into::into));
    set("shutter_frames", f.shutter_frames.map(Into::into));
    set("scene_unit_mm", f.scene_unit_mm.map(Into::into));
    let camera = Camera::from_json_str(&value.to_string()).map_err(|e| match path {
        Some(p) => anyhow::anyhow!("{}: {e}", p.display()),
        None => anyhow::anyhow!("{e} (give --camera or the camera flags)"),
    })?;
    Ok(camera)
}

/// One frame of a `synth` run: its files.
struct FrameJob {
    input: PathBuf,
    out: PathBuf,
    camera: Option<PathBuf>,
    preview: Option<PathBuf>,
    stats: Option<PathBuf>,
}

/// What a sequence keeps from frame to frame: the databases (loaded and conditioned once) and
/// the GPU synthesizer (pipelines compiled and the database uploaded once).
#[derive(Default)]
struct SequenceState {
    /// The model and aperture blades the loaded set was chosen for, and the set.
    dbs: Option<(Option<psf_db::PsfModel>, u32, std::sync::Arc<DbSet>)>,
    #[cfg(feature = "gpu")]
    gpu: Option<(runtime::gpu::GpuContext, runtime::gpu::GpuSynthesizer)>,
    /// The device chosen by the first frame ("cpu" or the GPU's name).
    device: Option<String>,
}

fn run_synth(args: SynthArgs) -> Result<()> {
    let jobs = frame_jobs(&FramePaths {
        input: &args.input,
        out: &args.out,
        camera: &args.camera,
        preview: &args.preview,
        stats: &args.stats,
        frames: &args.frames,
        shard: &args.shard,
    })?;
    let mut state = SequenceState::default();
    let started = Instant::now();
    let mut frame_ms = Vec::with_capacity(jobs.len());
    for job in &jobs {
        let t = Instant::now();
        synth_frame(&args, job, &mut state)
            .with_context(|| format!("frame {}", job.input.display()))?;
        frame_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    if jobs.len() > 1 && !args.quiet {
        let first = frame_ms.first().copied().unwrap_or(0.0);
        let mut rest = frame_ms[1..].to_vec();
        eprintln!(
            "{} frames in {:.1} s: first {:.0} ms, median of the others {:.0} ms",
            jobs.len(),
            started.elapsed().as_secs_f64(),
            first,
            metrics::median(&mut rest)
        );
    }
    Ok(())
}

/// Replaces the run of `#` in `path` by `frame`, zero-padded to the run's length.
fn frame_path(path: &Path, frame: u32) -> Result<PathBuf> {
    let text = path.to_string_lossy();
    let Some(start) = text.find('#') else {
        return Ok(path.to_path_buf());
    };
    let len = text[start..].chars().take_while(|c| *c == '#').count();
    if text[start + len..].contains('#') {
        bail!("{}: only one run of # is allowed", path.display());
    }
    Ok(PathBuf::from(format!(
        "{}{frame:0len$}{}",
        &text[..start],
        &text[start + len..]
    )))
}

/// The path arguments of a run that may cover a frame range.
struct FramePaths<'a> {
    input: &'a Path,
    out: &'a Path,
    camera: &'a Option<PathBuf>,
    preview: &'a Option<PathBuf>,
    stats: &'a Option<PathBuf>,
    frames: &'a Option<String>,
    shard: &'a Option<String>,
}

/// The frames of a run: one, or the range `--frames A-B` (its `--shard K/N` share) with `#` in
/// the paths replaced by the frame number.
fn frame_jobs(args: &FramePaths) -> Result<Vec<FrameJob>> {
    let has_hash = |p: &Path| p.to_string_lossy().contains('#');
    let Some(range) = &args.frames else {
        if has_hash(args.input) || has_hash(args.out) {
            bail!("the paths hold # but no --frames A-B was given");
        }
        if args.shard.is_some() {
            bail!("--shard splits a frame range: give --frames A-B too");
        }
        return Ok(vec![FrameJob {
            input: args.input.to_path_buf(),
            out: args.out.to_path_buf(),
            camera: args.camera.clone(),
            preview: args.preview.clone(),
            stats: args.stats.clone(),
        }]);
    };
    let bad = || anyhow::anyhow!("--frames takes A-B (first and last frame), got '{range}'");
    let (a, b) = range.split_once('-').ok_or_else(bad)?;
    let (a, b): (u32, u32) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if b < a {
        return Err(bad());
    }
    if !has_hash(args.input) || !has_hash(args.out) {
        bail!("with --frames, --input and --out need a run of # for the frame number (frames/####.exr)");
    }
    let all: Vec<u32> = (a..=b).collect();
    let frames = match &args.shard {
        Some(spec) => {
            let (k, n) = parse_shard(spec)?;
            let r = psf_db::ShardRange::of(k, n, all.len() as u32)?;
            all[r.first_psf as usize..(r.first_psf + r.len) as usize].to_vec()
        }
        None => all,
    };
    let opt = |p: &Option<PathBuf>, f| p.as_deref().map(|p| frame_path(p, f)).transpose();
    frames
        .into_iter()
        .map(|f| {
            Ok(FrameJob {
                input: frame_path(args.input, f)?,
                out: frame_path(args.out, f)?,
                camera: opt(args.camera, f)?,
                preview: opt(args.preview, f)?,
                stats: opt(args.stats, f)?,
            })
        })
        .collect()
}

/// `K/N`, or `auto/N` with K from the batch engine (SLURM_ARRAY_TASK_ID, JOB_COMPLETION_INDEX).
fn parse_shard(spec: &str) -> Result<(u32, u32)> {
    let spec = match spec.strip_prefix("auto/") {
        Some(count) => {
            let k = ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"]
                .iter()
                .find_map(|v| std::env::var(v).ok())
                .ok_or_else(|| {
                    anyhow::anyhow!(
                        "--shard auto/{count}: neither SLURM_ARRAY_TASK_ID nor JOB_COMPLETION_INDEX is set"
                    )
                })?;
            format!("{k}/{count}")
        }
        None => spec.to_string(),
    };
    Ok(psf_db::ShardRange::parse_spec(&spec)?)
}

fn synth_frame(args: &SynthArgs, job: &FrameJob, state: &mut SequenceState) -> Result<()> {
    let started = Instant::now();
    let camera = load_camera(job.camera.as_deref(), &args.camera_flags)?;
    let motion = match &args.motion_channels {
        Some(s) => match s.split_once(',') {
            Some((x, y)) => Some((x.trim().to_string(), y.trim().to_string())),
            None => bail!("--motion-channels takes two names separated by a comma, got '{s}'"),
        },
        None => None,
    };
    let channel_options = ChannelOptions {
        layout: args.layout,
        layer: args.layer.clone(),
        depth: args.depth_channel.clone(),
        motion,
        motion_y_up: args.motion_y_up,
    };
    let t = Instant::now();
    let gbuffer = GBuffer::read_exr(&job.input, &channel_options)?;
    let read_ms = t.elapsed().as_secs_f64() * 1e3;
    if !(args.soft_layers.is_finite() && args.soft_layers >= 0.0) {
        bail!(
            "--soft-layers must be zero or positive, got {}",
            args.soft_layers
        );
    }
    if args.layers == 0 || args.layers > 64 {
        bail!("--layers must be between 1 and 64, got {}", args.layers);
    }

    if !runtime::baseline::METHODS.contains(&args.method.as_str()) {
        let t = Instant::now();
        // The peer methods know no overscan: they see the frame alone.
        let image = runtime::peer::synthesize_peer(&args.method, &gbuffer.frame_only(), &camera)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        image.write_exr(&job.out)?;
        if let Some(p) = &job.preview {
            image.write_preview_png(p)?;
        }
        if !args.quiet {
            eprintln!("{}: {} in {ms:.0} ms", job.out.display(), args.method);
        }
        if let Some(p) = &job.stats {
            let json = serde_json::json!({
                "input": job.input, "output": job.out, "method": args.method, "ms": ms,
            });
            write_json(p, &json)?;
        }
        return Ok(());
    }
    let effects = Effects::of(&camera, &gbuffer);
    let t = Instant::now();
    let mut db_sources = Vec::new();
    let mut condition_reports = Vec::new();
    let mut prepare = |db: psf_db::PsfDatabase| -> Result<psf_db::PsfDatabase> {
        if args.no_condition {
            return Ok(db);
        }
        let (db, report) = runtime::condition::condition(&db)?;
        condition_reports.push(serde_json::json!({ "model": db.model().name(), "report": report }));
        Ok(db)
    };
    let needed_model = effects.cheapest_model();
    let reuse = match &state.dbs {
        // A set chosen for lens-motion also serves defocus alone; otherwise the same model.
        Some((m, blades, set))
            if *blades == camera.aperture_blades
                && (*m == needed_model
                    || (*m == Some(psf_db::PsfModel::LensMotion)
                        && needed_model == Some(psf_db::PsfModel::ThinLens))) =>
        {
            Some(set.clone())
        }
        _ => None,
    };
    let dbs = if let Some(set) = reuse {
        set
    } else {
        let set = match (needed_model, &args.db) {
            (None, _) => DbSet::none(),
            (Some(needed), Some(path)) => {
                let mut db = dbcache::explicit_database(path, needed)?;
                db_sources.push(serde_json::json!({
                    "model": db.model().name(), "path": path, "built_now": false,
                }));
                if args.method == "dense" && runtime::baseline::sparse_psf_count(&db) > 0 {
                    // Issue #6 baseline: a given database that stores PSFs sparse has no
                    // pre-filtered images of them; integrate their spreadlets instead.
                    let (dense, n) = runtime::baseline::densify(&db)?;
                    if !args.quiet {
                        eprintln!(
                            "--method dense: {n} PSFs of {} are stored sparse; drawing their \
                             integrated spreadlets (not the pre-filtered PSFs)",
                            path.display()
                        );
                    }
                    db = dense;
                }
                DbSet::single(prepare(db)?)?
            }
            (Some(needed), None) => {
                let profile: precompute::Profile = args.db_profile.parse()?;
                // Still pixels always use the thin-lens database; moving ones the lens-motion one.
                let mut models = vec![psf_db::PsfModel::ThinLens];
                if needed == psf_db::PsfModel::LensMotion {
                    models.push(psf_db::PsfModel::LensMotion);
                }
                let mut loaded = Vec::new();
                for model in models {
                    let mut cfg = dbcache::build_config(model, profile, camera.aperture_blades);
                    if args.method == "dense" || args.method == "filter" {
                        // Issue #6 baselines: the same PSFs, every one stored dense (the
                        // pre-filtered images the filter gathers with too).
                        cfg = runtime::baseline::dense_build_config(&cfg);
                    }
                    let (db, source) =
                        dbcache::cached_database(&cfg, &dbcache::cache_dir(), !args.quiet)?;
                    db_sources.push(serde_json::json!({
                        "model": model.name(), "path": source.path, "built_now": source.built,
                    }));
                    loaded.push(prepare(db)?);
                }
                let main = (loaded.len() > 1).then(|| loaded.remove(1));
                DbSet::new(loaded.pop(), main)?
            }
        };
        let set = std::sync::Arc::new(set);
        state.dbs = Some((needed_model, camera.aperture_blades, set.clone()));
        #[cfg(feature = "gpu")]
        {
            state.gpu = None; // a new database: upload it again
        }
        set
    };
    let db_ms = t.elapsed().as_secs_f64() * 1e3;

    let options = SynthOptions {
        classify: ClassifyOptions {
            layers: args.layers,
            soft_layers: (args.soft_layers > 0.0).then_some(args.soft_layers),
            edge_split: !args.no_edge_split,
            frame_edges: args.frame_edges,
            fill_hidden: !args.no_hidden_fill,
            ..ClassifyOptions::default()
        },
        splat: SplatOptions {
            rotation: args.rotation,
        },
        integrator: args.integrate,
        composite: CompositeOptions {
            renormalize_coverage: !args.no_coverage_renormalization,
        },
    };
    if args.method == "filter" {
        // Issue #6 baseline: gathering with the same PSFs (CPU or GPU).
        let kernels = match &dbs.combined {
            Some(db) => runtime::baseline::DenseKernels::from_db(db),
            None => runtime::baseline::DenseKernels::default(),
        };
        let filter_options = runtime::baseline::FilterOptions {
            rotation: args.rotation,
            ..Default::default()
        };
        let (backend, image, fstats) = run_filter(
            args.backend,
            &gbuffer.frame_only(),
            &camera,
            &dbs,
            &kernels,
            &filter_options,
            args.quiet,
        )?;
        image.write_exr(&job.out)?;
        if let Some(p) = &job.preview {
            image.write_preview_png(p)?;
        }
        if !args.quiet {
            eprintln!(
                "{}: filter baseline, {} pixels filtered ({} kernels integrated from \
                 spreadlets), {} copied, in {:.0} ms on the {backend}",
                job.out.display(),
                fstats.filtered,
                kernels.integrated,
                fstats.copied,
                fstats.total_ms
            );
        }
        if let Some(p) = &job.stats {
            let json = serde_json::json!({
                "input": job.input, "output": job.out, "method": "filter", "backend": backend,
                "databases": db_sources, "filter": fstats,
                "kernels_integrated_from_spreadlets": kernels.integrated,
            });
            write_json(p, &json)?;
        }
        return Ok(());
    }
    let (backend, image, stats, gpu_stages) = run_backend(
        args.backend,
        Work::Synthesis(&gbuffer),
        &camera,
        &dbs,
        &options,
        args.quiet,
        state,
    )?;
    let t = Instant::now();
    image.write_exr(&job.out)?;
    // Everything after the image: on failure the image is removed too, so a failed run leaves
    // no output behind.
    let finish = || -> Result<()> {
        if let Some(p) = &job.preview {
            image.write_preview_png(p)?;
        }
        let write_ms = t.elapsed().as_secs_f64() * 1e3;
        if !args.quiet {
            eprintln!(
                "{}x{} ({}{}): {} sparse, {} dense, {} copied, {} dropped; {} of {} layers; \
             synthesis {:.0} ms (classify {:.0}, splat {:.0}, integrate {:.0}, composite {:.0}) \
             on the {backend}",
                stats.width,
                stats.height,
                if effects.defocus {
                    "defocus"
                } else {
                    "no defocus"
                },
                if effects.motion { " + motion" } else { "" },
                stats.counts.sparse,
                stats.counts.dense,
                stats.counts.copied,
                stats.counts.dropped,
                stats.layers_used,
                stats.layers,
                stats.times.total_ms,
                stats.times.classify_ms,
                stats.times.splat_ms,
                stats.times.integrate_ms,
                stats.times.composite_ms,
            );
        }
        if let Some(p) = &job.stats {
            let json = serde_json::json!({
                "input": job.input,
                "output": job.out,
                "backend": backend,
                "effects": { "defocus": stats.defocus, "motion": stats.motion },
                "databases": db_sources,
                "conditioning": condition_reports,
                "synthesis": stats,
                "gpu_stages_ms": gpu_stages,
                "times_ms": {
                    "read_input": read_ms,
                    "database": db_ms,
                    "write_output": write_ms,
                    "wall": started.elapsed().as_secs_f64() * 1e3,
                },
            });
            write_json(p, &json)?;
        }
        Ok(())
    };
    if let Err(e) = finish() {
        let _ = std::fs::remove_file(&job.out);
        if let Some(p) = &job.preview {
            let _ = std::fs::remove_file(p);
        }
        return Err(e);
    }
    if stats.counts.clamped > 0 {
        eprintln!(
            "warning: {} pixel(s) asked for a PSF beyond the database's range and were drawn with its largest (see --stats: counts.clamped)",
            stats.counts.clamped
        );
    }
    Ok(())
}

/// What [`run_backend`] runs: synthesis from a G-buffer or reconstruction from stochastic frames.
#[derive(Clone, Copy)]
enum Work<'a> {
    Synthesis(&'a GBuffer),
    Reconstruction(&'a scene::StochasticFrames),
}

/// Runs synthesis or reconstruction on the chosen device. `auto` takes a hardware GPU when there is one and the
/// CPU otherwise (a software adapter such as lavapipe is slower than the CPU path, so `auto`
/// does not pick it; `--backend gpu` does).
fn run_backend(
    backend: Backend,
    work: Work,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
    quiet: bool,
    state: &mut SequenceState,
) -> Result<(
    String,
    RgbaImage,
    runtime::synth::SynthStats,
    Option<serde_json::Value>,
)> {
    #[cfg(feature = "gpu")]
    if backend != Backend::Cpu && state.device.as_deref() != Some("cpu") {
        use runtime::gpu::{synthesize_gpu, GpuSynthOptions, GpuSynthesizer};
        if state.gpu.is_none() {
            match pick_gpu(backend, quiet)? {
                Some(ctx) => {
                    let gpu = GpuSynthesizer::for_database(
                        &ctx,
                        dbs.combined.as_ref(),
                        GpuSynthOptions::from_synth(options),
                    )?;
                    state.device = Some(format!("gpu ({})", ctx.adapter_name()));
                    state.gpu = Some((ctx, gpu));
                }
                None => state.device = Some("cpu".into()),
            }
        }
        if let Some((_, gpu)) = state.gpu.as_mut() {
            let (image, stats, stages) = match work {
                Work::Synthesis(gbuffer) => synthesize_gpu(gpu, gbuffer, camera, dbs, options)?,
                Work::Reconstruction(frames) => {
                    runtime::gpu::reconstruct_gpu(gpu, frames, camera, dbs, options)?
                }
            };
            let name = state.device.clone().unwrap_or_default();
            return Ok((name, image, stats, Some(serde_json::to_value(stages)?)));
        }
    }
    #[cfg(not(feature = "gpu"))]
    let _ = (state, quiet);
    #[cfg(not(feature = "gpu"))]
    if backend == Backend::Gpu {
        bail!("--backend gpu: this build has no GPU support (feature `gpu`)");
    }
    let (image, stats) = match work {
        Work::Synthesis(gbuffer) => synthesize(gbuffer, camera, dbs, options)?,
        Work::Reconstruction(frames) => {
            runtime::reconstruct::reconstruct(frames, camera, dbs, options)?
        }
    };
    Ok(("cpu".to_string(), image, stats, None))
}

/// The GPU `backend` asks for: `gpu` requires one (an error without), `auto` takes a hardware
/// adapter and says why it falls back to the CPU otherwise (lavapipe is slower than the CPU
/// path). `None`: run on the CPU.
#[cfg(feature = "gpu")]
fn pick_gpu(backend: Backend, quiet: bool) -> Result<Option<runtime::gpu::GpuContext>> {
    if backend == Backend::Cpu {
        return Ok(None);
    }
    match runtime::gpu::GpuContext::with_requirement(backend == Backend::Gpu)? {
        Some(ctx)
            if backend == Backend::Gpu
                || ctx.adapter_info().device_type != wgpu::DeviceType::Cpu =>
        {
            Ok(Some(ctx))
        }
        Some(ctx) => {
            if !quiet {
                eprintln!(
                    "backend auto: {} is a software adapter; using the CPU",
                    ctx.adapter_name()
                );
            }
            Ok(None)
        }
        None => {
            if !quiet {
                eprintln!("backend auto: no GPU adapter; using the CPU");
            }
            Ok(None)
        }
    }
}

/// The filter baseline on `backend` (auto: a hardware GPU when there is one, as for synthesis).
/// Returns the device's name, the image and the stats.
fn run_filter(
    backend: Backend,
    gbuffer: &runtime::gbuffer::GBuffer,
    camera: &Camera,
    dbs: &DbSet,
    kernels: &runtime::baseline::DenseKernels,
    options: &runtime::baseline::FilterOptions,
    quiet: bool,
) -> Result<(String, RgbaImage, runtime::baseline::FilterStats)> {
    #[cfg(feature = "gpu")]
    if let Some(ctx) = pick_gpu(backend, quiet)? {
        let gpu = runtime::gpu::GpuFilter::new(&ctx, kernels)?;
        let (image, stats) = runtime::gpu::filter_gpu(&gpu, gbuffer, camera, dbs, options)?;
        return Ok((format!("gpu ({})", ctx.adapter_name()), image, stats));
    }
    #[cfg(not(feature = "gpu"))]
    {
        let _ = quiet;
        if backend == Backend::Gpu {
            bail!("--backend gpu: this build has no GPU support (feature `gpu`)");
        }
    }
    let (image, stats) = runtime::baseline::filter(gbuffer, camera, dbs, kernels, options)?;
    Ok(("cpu".to_string(), image, stats))
}

/// Writes `value` as pretty JSON to `path`, atomically.
fn write_json(path: &Path, value: &serde_json::Value) -> Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    runtime::rgba::write_atomically(path, |f| {
        use std::io::Write;
        f.write_all(text.as_bytes())
            .map_err(|source| runtime::rgba::WriteError::Io {
                path: path.display().to_string(),
                source,
            })
    })?;
    Ok(())
}

fn read_rgba(path: &Path) -> Result<RgbaImage> {
    let mut g = GBuffer::read_exr(path, &ChannelOptions::default())?;
    if !g.overscan.is_none() {
        g = g.frame_only();
    }
    Ok(RgbaImage {
        width: g.width,
        height: g.height,
        pixels: g.color,
    })
}

fn run_compare(args: CompareArgs) -> Result<()> {
    let a = read_rgba(&args.a)?;
    let b = read_rgba(&args.b)?;
    if (a.width, a.height) != (b.width, b.height) {
        bail!(
            "the images differ in size: {} is {}x{}, {} is {}x{}",
            args.a.display(),
            a.width,
            a.height,
            args.b.display(),
            b.width,
            b.height
        );
    }
    let fa: &[f32] = bytemuck::cast_slice(&a.pixels);
    let fb: &[f32] = bytemuck::cast_slice(&b.pixels);
    let (scores, flip) = metrics::score_rgb(fa, fb, a.width, a.height)?;
    if let Some(path) = &args.flip_map {
        write_rgb8_png(path, a.width, a.height, flip.magma_rgb8())?;
    }
    let e = scores.edge_luminance_ratio;
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "a": args.a,
                "b": args.b,
                "ssim": scores.ssim,
                "psnr_db": scores.psnr_db,
                "flip_mean": scores.flip_mean,
                "flip_p99": scores.flip_p99,
                "edge_luminance_ratio": e,
            })
        );
    } else {
        let psnr = scores
            .psnr_db
            .map_or("inf".to_string(), |p| format!("{p:.2}"));
        println!(
            "SSIM {:.4}  PSNR {psnr} dB  FLIP mean {:.4} p99 {:.4}  edge luminance ratio \
             (left, top, right, bottom) {:.3} {:.3} {:.3} {:.3}",
            scores.ssim, scores.flip_mean, scores.flip_p99, e.left, e.top, e.right, e.bottom
        );
    }
    Ok(())
}

/// Writes interleaved 8-bit RGB as a PNG, atomically.
fn write_rgb8_png(path: &Path, width: usize, height: usize, rgb: Vec<u8>) -> Result<()> {
    let buffer = image::RgbImage::from_raw(width as u32, height as u32, rgb)
        .context("an RGB buffer of the wrong size")?;
    runtime::rgba::write_atomically(path, |file| {
        buffer
            .write_to(&mut std::io::BufWriter::new(file), image::ImageFormat::Png)
            .map_err(|e| runtime::rgba::WriteError::Png {
                path: path.display().to_string(),
                message: e.to_string(),
            })
    })?;
    Ok(())
}

fn run_reconstruct(args: ReconstructArgs) -> Result<()> {
    if args.layers == 0 || args.layers > 64 {
        bail!("--layers must be between 1 and 64, got {}", args.layers);
    }
    let profile: precompute::Profile = args.db_profile.parse()?;
    runtime::peer::check_reconstruct_method(&args.method)?;
    let jobs = frame_jobs(&FramePaths {
        input: &args.input,
        out: &args.out,
        camera: &args.camera,
        preview: &args.preview,
        stats: &args.stats,
        frames: &args.frames,
        shard: &args.shard,
    })?;
    // The databases of the previous frame, kept while the effects stay the same.
    let mut loaded: Option<(runtime::pipeline::Effects, u32, DbSet)> = None;
    let mut state = SequenceState::default();
    for job in &jobs {
        let camera = load_camera(job.camera.as_deref(), &args.camera_flags)?;
        let frames = scene::StochasticFrames::read_exr(&job.input)
            .with_context(|| format!("reading stochastic frames {}", job.input.display()))?;
        if args.method != "spreadlet" {
            reconstruct_frame_peer(&args, job, &frames, &camera)?;
            continue;
        }
        let effects = runtime::reconstruct::effects_of(&camera, &frames);
        let key = (effects, camera.aperture_blades);
        let dbs = match loaded.take() {
            Some((e, b, dbs)) if (e, b) == key => dbs,
            _ => {
                #[cfg(feature = "gpu")]
                {
                    state.gpu = None; // a new database: upload it again
                }
                runtime::demo::cached_dbs(effects, profile, camera.aperture_blades, !args.quiet)?
            }
        };
        let options = SynthOptions {
            classify: ClassifyOptions {
                layers: args.layers,
                ..ClassifyOptions::default()
            },
            integrator: args.integrate,
            ..SynthOptions::default()
        };
        let (device, image, stats, gpu_stages) = run_backend(
            args.backend,
            Work::Reconstruction(&frames),
            &camera,
            &dbs,
            &options,
            args.quiet,
            &mut state,
        )?;
        image.write_exr(&job.out)?;
        if let Some(p) = &job.preview {
            image.write_preview_png(p)?;
        }
        if !args.quiet {
            eprintln!(
                "{}: {}x{} from {} spp: {} sparse, {} dense, {} copied, {} dropped; {:.0} ms on the {device}",
                job.out.display(),
                stats.width,
                stats.height,
                frames.spp,
                stats.counts.sparse,
                stats.counts.dense,
                stats.counts.copied,
                stats.counts.dropped,
                stats.times.total_ms
            );
        }
        if let Some(p) = &job.stats {
            let json = serde_json::json!({
                "input": job.input, "output": job.out, "spp": frames.spp, "backend": device,
                "reconstruction": stats, "gpu_stages_ms": gpu_stages,
            });
            write_json(p, &json)?;
        }
        loaded = Some((key.0, key.1, dbs));
    }
    Ok(())
}

/// One frame of `reconstruct --method PEER` (runtime::peer::reconstruct_peer).
fn reconstruct_frame_peer(
    args: &ReconstructArgs,
    job: &FrameJob,
    frames: &scene::StochasticFrames,
    camera: &Camera,
) -> Result<()> {
    let run = runtime::peer::reconstruct_peer(
        &args.method,
        frames,
        camera,
        args.allow_unhandled_effects,
    )?;
    run.image.write_exr(&job.out)?;
    if let Some(p) = &job.preview {
        run.image.write_preview_png(p)?;
    }
    if !args.quiet {
        let ignored = if run.ignored.is_empty() {
            String::new()
        } else {
            format!(" (warning: ignored {})", run.ignored.join(", "))
        };
        eprintln!(
            "{}: {} from {} spp in {:.0} ms{ignored}",
            job.out.display(),
            args.method,
            frames.spp,
            run.ms
        );
    }
    if let Some(p) = &job.stats {
        let json = serde_json::json!({
            "input": job.input, "output": job.out, "method": args.method, "spp": frames.spp,
            "ms": run.ms, "ignored_effects": run.ignored,
        });
        write_json(p, &json)?;
    }
    Ok(())
}

fn run_study(args: StudyArgs) -> Result<()> {
    if args.peers {
        return runtime::peer_study::run(&runtime::peer_study::PeerStudyOptions {
            out_dir: args.out,
            full: args.full,
            db_profile: args.db_profile,
            quiet: args.quiet,
        });
    }
    let input = match (args.input, args.camera, args.reference) {
        (Some(gbuffer), Some(camera), Some(reference)) => Some(runtime::study::StudyInput {
            gbuffer,
            camera,
            reference,
        }),
        (None, None, None) => None,
        _ => bail!("--input, --camera and --reference go together"),
    };
    if args.runs == 0 || args.runs > 100 {
        bail!("--runs must be between 1 and 100, got {}", args.runs);
    }
    let options = runtime::study::StudyOptions {
        out_dir: args.out.clone(),
        scene: args.scene,
        size: args.size,
        input,
        full: args.full,
        tiny: false,
        profile: args.db_profile.parse()?,
        runs: args.runs,
        reference_spp: args.reference_spp,
        gpu: !args.no_gpu,
        quiet: args.quiet,
    };
    let rows = runtime::study::run(&options)?;
    let md = std::fs::read_to_string(args.out.join("study.md")).unwrap_or_default();
    let findings = md.split("## All configurations").next().unwrap_or_default();
    println!("{}", findings.trim_end());
    println!(
        "wrote {} rows to {} (study.csv, study.md, study.png, study.json)",
        rows.len(),
        args.out.display()
    );
    Ok(())
}

fn run_demo(args: DemoArgs) -> Result<()> {
    let options = runtime::demo::DemoOptions {
        out: args.out.clone(),
        scene: args.scene,
        size: args.size,
        reference_spp: args.reference_spp,
        profile: args.db_profile.parse()?,
        progress: !args.quiet,
        ..Default::default()
    };
    let steps = runtime::demo::run(&options)?;
    println!("{}", runtime::demo::table(&steps));
    println!(
        "wrote {}: side_by_side.png (pinhole | synthesis | reconstruct_1spp | average_1spp | \
         average_16spp | reference), summary.json and the EXRs",
        args.out.display()
    );
    Ok(())
}

#[cfg(feature = "gpu")]
fn run_bench(args: BenchArgs) -> Result<()> {
    let profile: precompute::Profile = args.db_profile.parse()?;
    if let Some(dir) = &args.device_check {
        let (json, md) =
            runtime::gpu::check::run_to_folder(dir, args.quick, profile, args.rotation)?;
        println!("wrote {} and {}", json.display(), md.display());
        return Ok(());
    }
    if args.scaling {
        let cfg = dbcache::build_config(psf_db::PsfModel::ThinLens, profile, 0);
        let load = |cfg: &precompute::BuildConfig| -> Result<psf_db::PsfDatabase> {
            let (db, _) = dbcache::cached_database(cfg, &dbcache::cache_dir(), true)?;
            Ok(runtime::condition::condition(&db)?.0)
        };
        let sparse = load(&cfg)?;
        let dense = load(&runtime::baseline::dense_build_config(&cfg))?;
        let sizes = if args.sizes == [512, 1024] {
            vec![256, 512, 1024, 2048]
        } else {
            args.sizes.clone()
        };
        let config = runtime::bench::ScalingConfig {
            sizes,
            coc_radii: args.coc_radii.clone(),
            dense_max_size: args.dense_max_size,
            runs: args.runs.max(1),
            rotation: args.rotation,
            ..Default::default()
        };
        let rows = runtime::bench::run_scaling(&sparse, &dense, &config, true)?;
        let database = format!(
            "thin-lens {} ({} PSFs, {} spreadlets, max extent {} px)",
            profile,
            sparse.psf_count(),
            sparse.spreadlet_count(),
            sparse.max_extent_px()
        );
        println!("{}", runtime::bench::scaling_markdown(&rows, &database));
        return Ok(());
    }
    let cfg = dbcache::build_config(psf_db::PsfModel::LensMotion, profile, 0);
    let (db, _) = dbcache::cached_database(&cfg, &dbcache::cache_dir(), true)?;
    let config = runtime::bench::BenchConfig {
        sizes: args.sizes,
        runs: args.runs.max(1),
        cpu: !args.no_cpu,
        gpu: !args.no_gpu,
        rotation: args.rotation,
        global_atomic_splat: args.splat == runtime::gpu::SplatMode::GlobalAtomic,
        ..Default::default()
    };
    // As `DbSet` hands it to the pipeline: spreadlets in row order.
    let db = db.into_spreadlets_in_row_order();
    let report = runtime::bench::run_bench(&db, &config)?;
    println!("{}", report.to_markdown());
    Ok(())
}
