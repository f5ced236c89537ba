//! `spreadlet reconstruct`: depth of field and motion blur from noisy stochastic frames (each
//! sample labelled with its lens position and time), through [`spreadlet::Renderer`], or a peer
//! reconstruction method for comparison.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use spreadlet::{
    Backend, Camera, ClassifyOptions, Integrator, Method, Renderer, StochasticFrames, SynthOptions,
};

use super::camera_flags::{load_camera, CameraFlags};
use super::frames::{frame_jobs, FrameJob, FramePaths};
use super::{renderer_options, write_json};

#[derive(Args, Debug)]
pub(crate) struct ReconstructArgs {
    /// Stochastic frames (OpenEXR, docs/STOCHASTIC.md); a run of # stands for the frame number
    /// with --frames.
    #[arg(long)]
    pub(crate) input: PathBuf,
    /// Method: spreadlet, or a peer reconstruction method for comparison, on the same
    /// samples and camera (shirley, shirley4, shirley-layered, vaidyanathan, munkberg,
    /// munkberg44; docs/PEERS.md).
    #[arg(long, default_value = "spreadlet")]
    pub(crate) method: String,
    /// Run a peer method even when it does not reproduce an effect of the input
    /// (vaidyanathan and shirley-layered on moving samples ignore the motion blur); without
    /// it that is an error.
    #[arg(long)]
    pub(crate) allow_unhandled_effects: bool,
    /// Leave the shading noise in: ignore the denoiser's guides (albedo, normal) the frames
    /// carry. With guides, each sample's lighting is first averaged with its surface's
    /// neighbours at the lens and shutter centre (docs/STOCHASTIC.md).
    #[arg(long)]
    pub(crate) no_denoise: bool,
    /// Keep reconstruction as drawn: from 8 samples per pixel it is otherwise leaned, pixel by
    /// pixel, towards the plain mean of the pixel's samples where it departs from them by more
    /// than their noise explains (docs/STOCHASTIC.md).
    #[arg(long)]
    pub(crate) no_sample_mean: bool,
    /// Frame range A-B of a sequence (# in the paths is replaced by the frame number).
    #[arg(long)]
    pub(crate) frames: Option<String>,
    /// Only part K of N of the frame range (auto/N: K from SLURM_ARRAY_TASK_ID or
    /// JOB_COMPLETION_INDEX).
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
    /// Profile of databases built on demand.
    #[arg(long, default_value = "quick")]
    pub(crate) db_profile: String,
    /// Number of global depth layers (binned in constant parallax).
    #[arg(long, default_value_t = 8)]
    pub(crate) layers: u32,
    /// Poisson integrator (exact by default: the pyramid's small relative error becomes
    /// visible around HDR highlights).
    #[arg(long, value_enum, default_value_t = Integrator::default())]
    pub(crate) integrate: Integrator,
    /// Device for splatting, integration and compositing (`auto`: a hardware GPU when there is
    /// one, else the CPU).
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub(crate) backend: Backend,
    /// Write an sRGB PNG preview.
    #[arg(long)]
    pub(crate) preview: Option<PathBuf>,
    /// Write statistics (effects, counts per path, stage times) as JSON.
    #[arg(long)]
    pub(crate) stats: Option<PathBuf>,
    /// Draw moving samples with the lens-motion database's PSF of their cell instead of the
    /// thin-lens PSF smeared along their own motion (for comparison).
    #[arg(long)]
    pub(crate) motion_database: bool,
    /// Print no progress.
    #[arg(long, short)]
    pub(crate) quiet: bool,
}

/// Runs `spreadlet reconstruct`: every frame of the run through one renderer.
pub(crate) fn run(args: ReconstructArgs) -> Result<()> {
    let options = SynthOptions {
        classify: ClassifyOptions {
            layers: args.layers,
            smear_motion: !args.motion_database,
            lean_to_sample_means: !args.no_sample_mean,
            ..ClassifyOptions::default()
        },
        integrator: args.integrate,
        ..SynthOptions::default()
    };
    spreadlet_harness::peer::check_reconstruct_method(&args.method)?;
    let jobs = frame_jobs(&FramePaths {
        input: &args.input,
        out: &args.out,
        camera: &args.camera,
        preview: &args.preview,
        stats: &args.stats,
        frames: &args.frames,
        shard: &args.shard,
    })?;
    let mut renderer = Renderer::new(renderer_options(
        args.backend,
        None,
        &args.db_profile,
        Method::Spreadlet,
        true,
        args.quiet,
    )?)?;
    for job in &jobs {
        let camera = load_camera(job.camera.as_deref(), &args.camera_flags)?;
        super::keep_freed_memory_below(camera.width, camera.height);
        let mut frames = StochasticFrames::read_exr(&job.input)
            .with_context(|| format!("reading stochastic frames {}", job.input.display()))?;
        if args.no_denoise {
            frames.guides = None;
        }
        if args.method != "spreadlet" {
            reconstruct_frame_peer(&args, job, &frames, &camera)?;
            continue;
        }
        let frame = renderer.reconstruct(&frames, &camera, &options)?;
        let (image, stats) = (&frame.image, &frame.stats);
        image.write_exr(&job.out)?;
        if let Some(p) = &job.preview {
            image.write_png(p)?;
        }
        if !args.quiet {
            eprintln!(
                "{}: {}x{} from {} spp: {} sparse, {} dense, {} copied, {} dropped{}; {:.0} ms on the {}",
                job.out.display(),
                stats.width,
                stats.height,
                frames.spp,
                stats.counts.sparse,
                stats.counts.dense,
                stats.counts.copied,
                stats.counts.dropped,
                super::reduced_note(stats.counts.reduced),
                stats.times.total_ms,
                frame.device,
            );
        }
        if let Some(p) = &job.stats {
            #[cfg(feature = "gpu")]
            let gpu_stages = frame.gpu_stages.map(serde_json::to_value).transpose()?;
            #[cfg(not(feature = "gpu"))]
            let gpu_stages: Option<serde_json::Value> = None;
            let json = serde_json::json!({
                "input": job.input, "output": job.out, "spp": frames.spp, "backend": frame.device,
                "reconstruction": stats, "gpu_stages_ms": gpu_stages,
            });
            write_json(p, &json)?;
        }
    }
    Ok(())
}
/// One frame of `reconstruct --method PEER` (spreadlet_harness::peer::reconstruct_peer).
fn reconstruct_frame_peer(
    args: &ReconstructArgs,
    job: &FrameJob,
    frames: &StochasticFrames,
    camera: &Camera,
) -> Result<()> {
    let run = spreadlet_harness::peer::reconstruct_peer(
        &args.method,
        frames,
        camera,
        args.allow_unhandled_effects,
    )?;
    run.image.write_exr(&job.out)?;
    if let Some(p) = &job.preview {
        run.image.write_png(p)?;
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
