//! `spreadlet synth`: depth of field and motion blur from a pinhole G-buffer, one frame or a
//! sequence, through [`spreadlet::Renderer`].

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Args;

use spreadlet::{
    Backend, ChannelOptions, ClassifyOptions, CompositeOptions, DeepImage, FilterOptions,
    FrameEdges, GBuffer, Integrator, Layout, Method, Renderer, RotationSampling, SplatOptions,
    SynthOptions, ViewLayer,
};

use super::camera_flags::{load_camera, CameraFlags};
use super::frames::{frame_jobs, FrameJob, FramePaths};
use super::{ms_since, renderer_options, write_json};

#[derive(Args, Debug)]
pub(crate) struct SynthArgs {
    /// Pinhole G-buffer: OpenEXR with colour, depth and (for motion blur) motion vectors. For a
    /// sequence, a run of # stands for the frame number (frames/####.exr with --frames). A
    /// Blender file with several view layers is a layered input (every layer with Combined
    /// and Depth, or those of --view-layers); several --input files are the render layers of
    /// one frame: every layer's pixels are blurred with their own depth and motion, so what a
    /// blurred foreground hides is the background layer's real pixels. A deep OpenEXR (deep
    /// scanline: R, G, B, A, Z, optionally ZBack and motion.x/motion.y) is read as such: every
    /// deep sample is blurred with its own depth and motion.
    #[arg(long, required = true)]
    pub(crate) input: Vec<PathBuf>,
    /// The view layers to use from a multi-view-layer file, comma-separated (default: every
    /// layer with Combined and Depth passes).
    #[arg(long, value_delimiter = ',')]
    pub(crate) view_layers: Option<Vec<String>>,
    /// Layers without motion vectors that are still, comma-separated (else a layer without
    /// vectors in a frame with motion blur is an error).
    #[arg(long, value_delimiter = ',')]
    pub(crate) still_layers: Vec<String>,
    /// Method: spreadlet; the baselines dense (every pre-filtered PSF drawn whole, no
    /// Laplacian) and filter (gathering with the same PSFs; docs/STUDY.md); or a peer
    /// method for comparison (mcguire, guertin: motion blur from the G-buffer, no defocus;
    /// docs/PEERS.md).
    #[arg(long, default_value = "spreadlet")]
    pub(crate) method: String,
    /// Frame range A-B of a sequence: # in --input, --out, --camera, --preview and --stats is
    /// replaced by the frame number; databases and GPU pipelines are reused across frames.
    #[arg(long)]
    pub(crate) frames: Option<String>,
    /// Synthesise only part K of N of the frame range (0-based; auto/N takes K from
    /// SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX).
    #[arg(long)]
    pub(crate) shard: Option<String>,
    /// Camera description (`camera.json`); flags with the same names override its fields.
    #[arg(long)]
    pub(crate) camera: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) camera_flags: CameraFlags,
    /// Output OpenEXR (linear RGBA, f32), written atomically.
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// PSF database to use instead of the cached one (built on demand).
    #[arg(long)]
    pub(crate) db: Option<PathBuf>,
    /// Profile of databases built on demand.
    #[arg(long, default_value = "quick")]
    pub(crate) db_profile: String,
    /// Number of global depth layers (binned in constant parallax).
    #[arg(long, default_value_t = 8)]
    pub(crate) layers: u32,
    /// Soft layering: blend width between neighbouring layers in layer units (0 = hard
    /// layers; the flag alone = 1), for moving pixels: still ones are layered hard and
    /// continued across the layers, unless --no-layer-continuation.
    #[arg(long, num_args = 0..=1, default_missing_value = "1.0", default_value = "1.0")]
    pub(crate) soft_layers: f32,
    /// Do not split anti-aliased edge pixels into foreground and background parts.
    #[arg(long)]
    pub(crate) no_edge_split: bool,
    /// Do not scale the composite up to the layers' joint coverage.
    #[arg(long)]
    pub(crate) no_coverage_renormalization: bool,
    /// What lies beyond the input's pixels (its overscan, if the file has any): extend (the
    /// outermost pixels continue outwards, so a blurred frame keeps its brightness to the
    /// edge) or black (the frame's border loses light; for comparison).
    #[arg(long, value_enum, default_value_t = FrameEdges::default())]
    pub(crate) frame_edges: FrameEdges,
    /// Do not continue the background behind the silhouettes of sharper or blurrier
    /// occluders (a blurred background then darkens along a sharp occluder, and a moving or
    /// defocused occluder's smear ends in a hard edge at its silhouette).
    #[arg(long)]
    pub(crate) no_hidden_fill: bool,
    /// Look each pixel's PSF up in the one database cell holding its CoC and motion, with
    /// no dither or blend between neighbouring cells (a surface whose blur varies smoothly
    /// then shows a line at each cell boundary; for comparison).
    #[arg(long)]
    pub(crate) nearest_cell: bool,
    /// Through a real lens, mix the PSFs of two neighbouring depth cells as they are, not each
    /// scaled onto the pixel's own depth first (the bokeh then has two rims a cell's blur
    /// apart; for comparison).
    #[arg(long)]
    pub(crate) unscaled_blends: bool,
    /// Draw moving pixels with the lens-motion database's PSF of their cell (turned onto the
    /// motion, blended with the neighbouring cell) instead of the thin-lens PSF of their CoC
    /// smeared along their own motion (for comparison: streak ends are then soft over a
    /// cell's width, and a frame where everything moves is several times slower).
    #[arg(long)]
    pub(crate) motion_database: bool,
    /// Poisson integrator (exact by default: the pyramid's small relative error becomes
    /// visible around HDR highlights).
    #[arg(long, value_enum, default_value_t = Integrator::default())]
    pub(crate) integrate: Integrator,
    /// Placement of rotated (motion-aligned) spreadlets.
    #[arg(long, value_enum, default_value_t = RotationSampling::default())]
    pub(crate) rotation: RotationSampling,
    /// Write statistics (effects, databases, counts per path, stage times) as JSON.
    #[arg(long)]
    pub(crate) stats: Option<PathBuf>,
    /// Write an sRGB PNG preview.
    #[arg(long)]
    pub(crate) preview: Option<PathBuf>,
    /// Device.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub(crate) backend: Backend,
    /// Input layout.
    #[arg(long, value_enum, default_value_t = Layout::Auto)]
    pub(crate) layout: Layout,
    /// Blender view layer to read (when the file has several).
    #[arg(long)]
    pub(crate) layer: Option<String>,
    /// Plain layout: depth channel name.
    #[arg(long)]
    pub(crate) depth_channel: Option<String>,
    /// Plain layout: forward motion channels, "X,Y" (pixels per frame, x right, y down).
    #[arg(long)]
    pub(crate) motion_channels: Option<String>,
    /// Plain layout: the motion's y axis points up.
    #[arg(long)]
    pub(crate) motion_y_up: bool,
    /// Draw a pixel whose CoC radius (px) is above this at a half, a quarter or an eighth of
    /// the frame's resolution, where it is this or below, and upsample it: faster for large
    /// blur, rims about a pixel softer (default: only CoCs beyond the database's range, or
    /// motion beyond its length, are drawn that way).
    #[arg(long, value_name = "PX")]
    pub(crate) coarse_above: Option<f32>,
    /// Layer still pixels softly, as moving ones, instead of hard with each surface continued
    /// under the nearer part where it crosses into a nearer depth layer (for comparison: a
    /// surface split between two layers is then seen through by up to a quarter).
    #[arg(long)]
    pub(crate) no_layer_continuation: bool,
    /// Use the database's spreadlets as stored (no monopole removal, no energy
    /// normalisation).
    #[arg(long)]
    pub(crate) no_condition: bool,
    /// Print no progress.
    #[arg(long, short)]
    pub(crate) quiet: bool,
}

impl SynthArgs {
    /// The library's options these flags ask for; no flags give [`SynthOptions::default`].
    pub(crate) fn synth_options(&self) -> SynthOptions {
        SynthOptions {
            classify: ClassifyOptions {
                layers: self.layers,
                // Zero is hard layers; anything else, negative or NaN too, goes to the validation.
                soft_layers: (self.soft_layers != 0.0).then_some(self.soft_layers),
                edge_split: !self.no_edge_split,
                frame_edges: self.frame_edges,
                fill_hidden: !self.no_hidden_fill,
                continuous_lookup: !self.nearest_cell,
                scaled_blends: !self.unscaled_blends,
                smear_motion: !self.motion_database,
                coarse_above_px: self.coarse_above.unwrap_or(f32::INFINITY),
                continue_layers: !self.no_layer_continuation,
                ..ClassifyOptions::default()
            },
            splat: SplatOptions {
                rotation: self.rotation,
            },
            integrator: self.integrate,
            composite: CompositeOptions {
                renormalize_coverage: !self.no_coverage_renormalization,
                ..CompositeOptions::default()
            },
        }
    }

    fn channel_options(&self) -> Result<ChannelOptions> {
        let motion = match &self.motion_channels {
            Some(s) => match s.split_once(',') {
                Some((x, y)) => Some((x.trim().to_string(), y.trim().to_string())),
                None => bail!("--motion-channels takes two names separated by a comma, got '{s}'"),
            },
            None => None,
        };
        Ok(ChannelOptions {
            layout: self.layout,
            layer: self.layer.clone(),
            depth: self.depth_channel.clone(),
            motion,
            motion_y_up: self.motion_y_up,
        })
    }
}

/// The render layers of `job`'s frame: every --input file's view layers (a file with one
/// layer, or read with explicit channel flags, is one layer, read exactly as a single
/// G-buffer).
fn read_layers(args: &SynthArgs, job: &FrameJob) -> Result<Vec<ViewLayer>> {
    let plain_flags = args.layer.is_some()
        || args.layout != Layout::Auto
        || args.depth_channel.is_some()
        || args.motion_channels.is_some()
        || args.motion_y_up;
    let mut paths = vec![job.input.clone()];
    for extra in &args.input[1..] {
        paths.push(match job.frame {
            Some(f) => super::frames::frame_path(extra, f)?,
            None => extra.clone(),
        });
    }
    if paths.len() > 1 && args.view_layers.is_some() {
        bail!("--view-layers picks layers of one multi-view-layer file; with several --input files every file is a layer");
    }
    if plain_flags && paths.len() > 1 {
        bail!("--layer, --layout and the plain-layout channel flags read one --input file");
    }
    if plain_flags {
        let g = GBuffer::read_exr(&paths[0], &args.channel_options()?)?;
        return Ok(vec![ViewLayer::new(
            args.layer.clone().unwrap_or_default(),
            g,
        )]);
    }
    let mut layers = Vec::new();
    for path in &paths {
        let in_file = GBuffer::read_view_layers(path, args.view_layers.as_deref())?;
        let single = in_file.len() == 1;
        for mut layer in in_file {
            // Several files: a file's one layer is named after the file, else "file/layer".
            if paths.len() > 1 {
                let stem = path.file_stem().map(|s| s.to_string_lossy().to_string());
                let file = stem.unwrap_or_default();
                layer.name = if single {
                    file
                } else {
                    format!("{file}/{}", layer.name)
                };
            }
            layers.push(layer);
        }
    }
    for layer in &mut layers {
        layer.still = args.still_layers.contains(&layer.name);
    }
    for s in &args.still_layers {
        if !layers.iter().any(|l| l.name == *s) {
            let names: Vec<&str> = layers.iter().map(|l| l.name.as_str()).collect();
            bail!(
                "--still-layers names {s:?}, which is not a layer of the input ({})",
                names.join(", ")
            );
        }
    }
    Ok(layers)
}

/// The deep image of `job`'s frame; the flags that pick channels or layers of flat files are
/// errors with it.
fn read_deep(args: &SynthArgs, job: &FrameJob) -> Result<DeepImage> {
    if args.input.len() > 1 {
        bail!(
            "{} is a deep image, which holds every layer of its frame: give it as the only --input",
            job.input.display()
        );
    }
    if args.view_layers.is_some()
        || !args.still_layers.is_empty()
        || args.layer.is_some()
        || args.layout != Layout::Auto
        || args.depth_channel.is_some()
        || args.motion_channels.is_some()
        || args.motion_y_up
    {
        bail!(
            "{} is a deep image (channels R, G, B, A, Z, optionally ZBack and motion.x/motion.y):              --view-layers, --still-layers, --layer, --layout and the channel flags do not apply",
            job.input.display()
        );
    }
    if !matches!(args.method.as_str(), "spreadlet" | "dense") {
        bail!(
            "a deep input works with the spreadlet and dense methods, not {}",
            args.method
        );
    }
    Ok(DeepImage::read(&job.input)?)
}

/// One frame of a deep input through the renderer.
fn deep_frame(
    args: &SynthArgs,
    job: &FrameJob,
    deep: &DeepImage,
    camera: &spreadlet::Camera,
    renderer: &mut Renderer,
    read_ms: f64,
    started: Instant,
) -> Result<()> {
    let options = args.synth_options();
    let frame = renderer.synthesize_deep(deep, camera, &options)?;
    let (image, stats) = (&frame.image, &frame.stats);
    write_frame_outputs(job, image, |write_ms| {
        if !args.quiet {
            let source = format!(
                "a deep image ({} samples, up to {} per pixel)",
                deep.samples.len(),
                deep.max_samples_per_pixel()
            );
            report_frame(stats, &source);
        }
        if let Some(p) = &job.stats {
            let input = serde_json::json!({
                "input": args.input,
                "deep": {
                    "samples": deep.samples.len(),
                    "max_samples_per_pixel": deep.max_samples_per_pixel(),
                    "dropped_samples": deep.dropped_samples,
                    "channels": deep.channels_present,
                },
                "output": job.out,
            });
            let times = times_json(read_ms, frame.database_ms, write_ms, started);
            write_json(p, &frame_json(input, &frame, times))?;
        }
        Ok(())
    })
}

/// One frame of a layered input through the renderer.
fn layered_frame(
    args: &SynthArgs,
    job: &FrameJob,
    layers: &[ViewLayer],
    camera: &spreadlet::Camera,
    renderer: &mut Renderer,
    read_ms: f64,
    started: Instant,
) -> Result<()> {
    let options = args.synth_options();
    let frame = renderer.synthesize_layers(layers, camera, &options)?;
    let (image, stats) = (&frame.image, &frame.stats);
    let names: Vec<&str> = layers.iter().map(|l| l.name.as_str()).collect();
    write_frame_outputs(job, image, |write_ms| {
        if !args.quiet {
            report_frame(stats, &format!("view layers {}", names.join(", ")));
        }
        if let Some(p) = &job.stats {
            let input = serde_json::json!({
                "input": args.input,
                "view_layers": names,
                "still_layers": layers.iter().filter(|l| l.still).map(|l| l.name.as_str()).collect::<Vec<_>>(),
                "output": job.out,
            });
            let times = times_json(read_ms, frame.database_ms, write_ms, started);
            write_json(p, &frame_json(input, &frame, times))?;
        }
        Ok(())
    })
}

/// The one line a layered or deep frame prints: its size, `source`, the records per path,
/// the layers used and the synthesis time.
fn report_frame(stats: &spreadlet::SynthStats, source: &str) {
    eprintln!(
        "{}x{} from {source}: {} sparse, {} dense, {} copied; {} of {} layers; {:.1} ms",
        stats.width,
        stats.height,
        stats.counts.sparse,
        stats.counts.dense,
        stats.counts.copied,
        stats.layers_used,
        stats.layers,
        stats.times.total_ms,
    );
}

/// A layered or deep frame's statistics: `input` (an object saying what was read) with the
/// frame's device, effects, databases, synthesis statistics and `times`.
fn frame_json(
    mut input: serde_json::Value,
    frame: &spreadlet::Frame,
    times: serde_json::Value,
) -> serde_json::Value {
    let stats = &frame.stats;
    if let Some(obj) = input.as_object_mut() {
        obj.insert("backend".into(), frame.device.clone().into());
        obj.insert(
            "effects".into(),
            serde_json::json!({ "defocus": stats.defocus, "motion": stats.motion }),
        );
        obj.insert(
            "databases".into(),
            serde_json::to_value(&frame.databases).unwrap_or_default(),
        );
        obj.insert(
            "synthesis".into(),
            serde_json::to_value(stats).unwrap_or_default(),
        );
        obj.insert("times_ms".into(), times);
    }
    input
}

/// The `times_ms` of a frame's statistics.
fn times_json(
    read_ms: f64,
    database_ms: f64,
    write_ms: f64,
    started: Instant,
) -> serde_json::Value {
    serde_json::json!({
        "read_input": read_ms,
        "database": database_ms,
        "write_output": write_ms,
        "wall": ms_since(started),
    })
}

/// Writes `image` to the job's output and preview, then runs `rest` with the milliseconds the
/// writing took (statistics, messages); when anything after the image fails, the image and
/// the preview are removed too, so a failed run leaves no output behind.
fn write_frame_outputs(
    job: &FrameJob,
    image: &spreadlet::RgbaImage,
    rest: impl FnOnce(f64) -> Result<()>,
) -> Result<()> {
    let t = Instant::now();
    image.write_exr(&job.out)?;
    let finish = || -> Result<()> {
        if let Some(p) = &job.preview {
            image.write_png(p)?;
        }
        rest(ms_since(t))
    };
    if let Err(e) = finish() {
        let _ = std::fs::remove_file(&job.out);
        if let Some(p) = &job.preview {
            let _ = std::fs::remove_file(p);
        }
        return Err(e);
    }
    Ok(())
}

/// Runs `spreadlet synth`: every frame of the run through one renderer, so databases and GPU
/// pipelines are loaded once.
pub(crate) fn run(args: SynthArgs) -> Result<()> {
    let jobs = frame_jobs(&FramePaths {
        input: &args.input[0],
        out: &args.out,
        camera: &args.camera,
        preview: &args.preview,
        stats: &args.stats,
        frames: &args.frames,
        shard: &args.shard,
    })?;
    let method = match args.method.as_str() {
        "dense" => Method::Dense,
        "filter" => Method::Filter,
        _ => Method::Spreadlet,
    };
    let mut renderer = Renderer::new(renderer_options(
        args.backend,
        args.db.as_deref(),
        &args.db_profile,
        method,
        !args.no_condition,
        args.quiet,
    )?)?;
    let started = Instant::now();
    let mut frame_ms = Vec::with_capacity(jobs.len());
    for job in &jobs {
        let t = Instant::now();
        synth_frame(&args, job, &mut renderer)
            .with_context(|| format!("frame {}", job.input.display()))?;
        frame_ms.push(ms_since(t));
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

fn synth_frame(args: &SynthArgs, job: &FrameJob, renderer: &mut Renderer) -> Result<()> {
    let started = Instant::now();
    let camera = load_camera(job.camera.as_deref(), &args.camera_flags)?;
    super::keep_freed_memory_below(camera.width, camera.height);
    let t = Instant::now();
    if spreadlet::formats::deep::is_deep_exr_file(&job.input) {
        let deep = read_deep(args, job)?;
        return deep_frame(args, job, &deep, &camera, renderer, ms_since(t), started);
    }
    let mut layers = read_layers(args, job)?;
    let read_ms = ms_since(t);
    let options = args.synth_options();
    let layer_names: Vec<String> = layers.iter().map(|l| l.name.clone()).collect();
    // A single layer declared still goes the layered way too: it needs no vectors.
    if layers.len() > 1 || layers[0].still {
        if !matches!(args.method.as_str(), "spreadlet" | "dense") {
            bail!(
                "a layered input ({}) works with the spreadlet and dense methods, not {}",
                layer_names.join(", "),
                args.method
            );
        }
        return layered_frame(args, job, &layers, &camera, renderer, read_ms, started);
    }
    let gbuffer = layers.remove(0).gbuffer;
    if !Method::NAMES.contains(&args.method.as_str()) {
        return peer_frame(args, job, &gbuffer, &camera);
    }
    if args.method == "filter" {
        return filter_frame(args, job, &gbuffer, &camera, renderer);
    }
    let frame = renderer.synthesize(&gbuffer, &camera, &options)?;
    let (image, stats) = (&frame.image, &frame.stats);
    write_frame_outputs(job, image, |write_ms| {
        if !args.quiet {
            eprintln!(
                "{}x{} ({}{}): {} sparse, {} dense{}, {} copied, {} dropped{}; {} of {} layers; \
             synthesis {:.0} ms (classify {:.0}, splat {:.0}, integrate {:.0}, composite {:.0}) \
             on the {}",
                stats.width,
                stats.height,
                if stats.defocus {
                    "defocus"
                } else {
                    "no defocus"
                },
                if stats.motion { " + motion" } else { "" },
                stats.counts.sparse,
                stats.counts.dense,
                if stats.counts.smeared > 0 {
                    format!(
                        " ({} lens PSFs smeared along the motion)",
                        stats.counts.smeared
                    )
                } else {
                    String::new()
                },
                stats.counts.copied,
                stats.counts.dropped,
                super::reduced_note(stats.counts.reduced),
                stats.layers_used,
                stats.layers,
                stats.times.total_ms,
                stats.times.classify_ms,
                stats.times.splat_ms,
                stats.times.integrate_ms,
                stats.times.composite_ms,
                frame.device,
            );
            if stats.counts.reduced > 0 {
                eprintln!(
                    "{} pixel(s) drawn at a reduced resolution, their blur beyond the database's range or above --coarse-above (see --stats: counts.reduced)",
                    stats.counts.reduced
                );
            }
        }
        if let Some(p) = &job.stats {
            #[cfg(feature = "gpu")]
            let gpu_stages = frame.gpu_stages.map(serde_json::to_value).transpose()?;
            #[cfg(not(feature = "gpu"))]
            let gpu_stages: Option<serde_json::Value> = None;
            let json = serde_json::json!({
                "input": job.input,
                "output": job.out,
                "backend": frame.device,
                "effects": { "defocus": stats.defocus, "motion": stats.motion },
                "databases": frame.databases,
                "conditioning": frame.conditioning,
                "synthesis": stats,
                "gpu_stages_ms": gpu_stages,
                "times_ms": times_json(read_ms, frame.database_ms, write_ms, started),
            });
            write_json(p, &json)?;
        }
        Ok(())
    })?;
    if stats.counts.clamped > 0 {
        eprintln!(
            "warning: {} pixel(s) asked for a PSF beyond the database's range and were drawn with its largest (see --stats: counts.clamped)",
            stats.counts.clamped
        );
    }
    Ok(())
}

/// One frame of a peer method (`--method mcguire|guertin`): they know no overscan and see the
/// frame alone.
fn peer_frame(
    args: &SynthArgs,
    job: &FrameJob,
    gbuffer: &GBuffer,
    camera: &spreadlet::Camera,
) -> Result<()> {
    let t = Instant::now();
    let image =
        spreadlet_harness::peer::synthesize_peer(&args.method, &gbuffer.frame_only(), camera)?;
    let ms = ms_since(t);
    image.write_exr(&job.out)?;
    if let Some(p) = &job.preview {
        image.write_png(p)?;
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
    Ok(())
}

/// One frame of the filter baseline: gathering with the same PSFs (CPU or GPU).
fn filter_frame(
    args: &SynthArgs,
    job: &FrameJob,
    gbuffer: &GBuffer,
    camera: &spreadlet::Camera,
    renderer: &mut Renderer,
) -> Result<()> {
    let options = FilterOptions {
        rotation: args.rotation,
        ..Default::default()
    };
    let frame = renderer.filter(gbuffer, camera, &options)?;
    frame.image.write_exr(&job.out)?;
    if let Some(p) = &job.preview {
        frame.image.write_png(p)?;
    }
    let fstats = &frame.stats;
    if !args.quiet {
        eprintln!(
            "{}: filter baseline, {} pixels filtered ({} kernels integrated from \
             spreadlets), {} copied, in {:.0} ms on the {}",
            job.out.display(),
            fstats.filtered,
            frame.kernels_integrated,
            fstats.copied,
            fstats.total_ms,
            frame.device
        );
    }
    if let Some(p) = &job.stats {
        let json = serde_json::json!({
            "input": job.input, "output": job.out, "method": "filter", "backend": frame.device,
            "databases": frame.databases, "filter": fstats,
            "kernels_integrated_from_spreadlets": frame.kernels_integrated,
        });
        write_json(p, &json)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Wrapper {
        #[command(flatten)]
        synth: SynthArgs,
    }

    #[test]
    fn no_flags_give_the_library_defaults() {
        let parsed = Wrapper::parse_from(["spreadlet", "--input", "in.exr", "--out", "out.exr"]);
        assert_eq!(parsed.synth.synth_options(), SynthOptions::default());
        assert_eq!(parsed.synth.backend, Backend::default());
    }
}
