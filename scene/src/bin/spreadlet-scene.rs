//! `spreadlet-scene`: renders the ground truth of an analytic scene (a JSON file or a builtin
//! name): pinhole G-buffer, stochastic frames, converged reference and `camera.json`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use scene::{
    estimate_reference_noise, render_gbuffer, render_reference, render_stochastic,
    render_view_layers, RenderOptions, Scene, BUILTIN_NAMES,
};

#[derive(Parser)]
#[command(name = "spreadlet-scene", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene's G-buffer, stochastic frames and/or reference.
    Render(RenderArgs),
    /// Estimate a reference's own noise from two independent half renders.
    Noise(NoiseArgs),
    /// List the builtin scenes.
    List,
    /// Print a builtin scene's JSON (a starting point for new scenes).
    Dump {
        /// Builtin scene name.
        name: String,
    },
}

#[derive(Args)]
struct SceneArgs {
    /// Scene JSON file, or a builtin name (bokeh, crossing, occluder, rotating, physical, rain,
    /// studio).
    scene: PathBuf,
    /// Image width in pixels (default: the scene's); the field of view is kept.
    #[arg(long)]
    width: Option<u32>,
    /// Image height in pixels (default: keeps the scene's aspect ratio).
    #[arg(long)]
    height: Option<u32>,
    /// Seed of every random number (same seed, same bytes).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

#[derive(Args)]
struct RenderArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Pinhole G-buffer EXR (Blender multilayer layout).
    #[arg(long)]
    gbuffer: Option<PathBuf>,
    /// Anti-aliasing samples per pixel of the G-buffer's colour.
    #[arg(long, default_value_t = 16)]
    aa: usize,
    /// Render the G-buffer this many pixels further on every side and declare them overscan
    /// (data window larger than the display window); the other outputs keep the frame.
    #[arg(long, default_value_t = 0)]
    overscan: u32,
    /// The G-buffer as two Blender view layers in one EXR, `Foreground` (the objects of
    /// --foreground, the rest held out) and `Background` (the rest; the foreground still
    /// casts its shadows), as a compositing artist renders them.
    #[arg(long, requires = "foreground")]
    view_layers: Option<PathBuf>,
    /// Objects of the foreground view layer, by name, comma-separated (`dump SCENE` lists
    /// them).
    #[arg(long, value_delimiter = ',')]
    foreground: Vec<String>,
    /// The G-buffer as a deep OpenEXR (deep scanline, ZIPS): each pixel's --aa sub-samples
    /// merged per surface into deep samples with their own colour, alpha, depth and motion,
    /// front to back; flattened it is the G-buffer's colour.
    #[arg(long)]
    deep: Option<PathBuf>,
    /// Stochastic frames EXR (docs/STOCHASTIC.md).
    #[arg(long)]
    stochastic: Option<PathBuf>,
    /// Samples per pixel of the stochastic frames.
    #[arg(long, default_value_t = 1)]
    spp: usize,
    /// Shoot stochastic samples through pixel centres instead of jittering them.
    #[arg(long)]
    no_jitter: bool,
    /// Converged reference EXR (channels R, G, B, A).
    #[arg(long)]
    reference: Option<PathBuf>,
    /// Samples per pixel of the reference.
    #[arg(long, default_value_t = 1024)]
    ref_spp: usize,
    /// Write the scene's camera.json here.
    #[arg(long)]
    camera_out: Option<PathBuf>,
    /// Also write an sRGB PNG next to the G-buffer and reference EXRs.
    #[arg(long)]
    png: bool,
}

#[derive(Args)]
struct NoiseArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Samples per pixel of the reference whose noise is estimated.
    #[arg(long, default_value_t = 1024)]
    ref_spp: usize,
}

fn load_scene(args: &SceneArgs) -> Result<Scene> {
    let scene = Scene::load(&args.scene)?;
    let spec = &scene.camera.spec;
    let width = args.width.unwrap_or(spec.width);
    let height = match (args.width, args.height) {
        (_, Some(h)) => h,
        (Some(w), None) => {
            ((f64::from(w) * f64::from(spec.height) / f64::from(spec.width)).round() as u32).max(1)
        }
        (None, None) => spec.height,
    };
    Ok(scene.with_size(width, height)?)
}

fn write_text_atomically(path: &Path, text: &str) -> Result<()> {
    Ok(formats::atomic::write_bytes_atomically(
        path,
        text.as_bytes(),
    )?)
}

fn png_beside(path: &Path) -> PathBuf {
    path.with_extension("png")
}

fn render(args: RenderArgs) -> Result<()> {
    if args.gbuffer.is_none()
        && args.view_layers.is_none()
        && args.deep.is_none()
        && args.stochastic.is_none()
        && args.reference.is_none()
        && args.camera_out.is_none()
    {
        bail!("nothing to do: give --gbuffer, --view-layers, --deep, --stochastic, --reference and/or --camera-out");
    }
    let scene = load_scene(&args.scene)?;
    let options = RenderOptions {
        seed: args.scene.seed,
        progress: !args.scene.quiet,
        jitter: !args.no_jitter,
    };
    let spec = &scene.camera.spec;
    eprintln!(
        "scene {}: {}x{} px, {} objects, seed {}",
        scene.name,
        spec.width,
        spec.height,
        scene.objects.len(),
        options.seed
    );
    if let Some(path) = &args.camera_out {
        write_text_atomically(path, &(scene.camera_json() + "\n"))?;
        eprintln!("camera: {}", path.display());
    }
    if let Some(path) = &args.view_layers {
        let start = Instant::now();
        let layers = render_view_layers(&scene, args.aa, &options, &args.foreground)?;
        scene::GBuffer::write_view_layers(path, &layers)?;
        eprintln!(
            "view layers Background, Foreground ({} aa): {} in {:.2} s",
            args.aa,
            path.display(),
            start.elapsed().as_secs_f64()
        );
    }
    if let Some(path) = &args.deep {
        let start = Instant::now();
        let deep = scene::render_deep(&scene, args.aa, &options)?;
        deep.write(path, formats::DeepCompression::Zips)?;
        eprintln!(
            "deep image ({} aa, {} samples, up to {} per pixel): {} in {:.2} s",
            args.aa,
            deep.samples.len(),
            deep.max_samples_per_pixel(),
            path.display(),
            start.elapsed().as_secs_f64()
        );
    }
    if let Some(path) = &args.gbuffer {
        let start = Instant::now();
        let gbuffer = render_gbuffer(&scene.with_overscan(args.overscan)?, args.aa, &options)?;
        gbuffer.write_exr_with_overscan(path, args.overscan as usize)?;
        if args.png {
            gbuffer.color_image().write_png(&png_beside(path))?;
        }
        eprintln!(
            "G-buffer ({} aa): {} in {:.2} s",
            args.aa,
            path.display(),
            start.elapsed().as_secs_f64()
        );
    }
    if let Some(path) = &args.stochastic {
        let start = Instant::now();
        let frames = render_stochastic(&scene, args.spp, &options)?;
        frames.write_exr(path)?;
        eprintln!(
            "stochastic frames ({} spp): {} in {:.2} s",
            args.spp,
            path.display(),
            start.elapsed().as_secs_f64()
        );
    }
    if let Some(path) = &args.reference {
        let start = Instant::now();
        let reference = render_reference(&scene, args.ref_spp, &options)?;
        reference.write_exr(path)?;
        if args.png {
            reference.write_png(&png_beside(path))?;
        }
        eprintln!(
            "reference ({} spp): {} in {:.2} s",
            args.ref_spp,
            path.display(),
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Render(args) => render(args),
        Command::Noise(args) => {
            let scene = load_scene(&args.scene)?;
            let options = RenderOptions {
                seed: args.scene.seed,
                progress: !args.scene.quiet,
                jitter: true,
            };
            let start = Instant::now();
            let noise = estimate_reference_noise(&scene, args.ref_spp, &options)?;
            println!(
                "{{\"scene\": \"{}\", \"width\": {}, \"height\": {}, \"spp\": {}, \"rms_linear\": {:.6}, \"rms_srgb\": {:.6}, \"max_srgb\": {:.6}, \"ssim_halves\": {:.5}, \"seconds\": {:.2}}}",
                scene.name,
                scene.camera.spec.width,
                scene.camera.spec.height,
                noise.spp,
                noise.rms_linear,
                noise.rms_srgb,
                noise.max_srgb,
                noise.ssim_halves,
                start.elapsed().as_secs_f64()
            );
            Ok(())
        }
        Command::List => {
            for name in BUILTIN_NAMES {
                let scene = scene::builtin(name)?;
                println!("{name:10} {}", scene.description().description);
            }
            Ok(())
        }
        Command::Dump { name } => {
            let text = scene::builtin_json(&name).with_context(|| {
                format!(
                    "no builtin scene {name:?} (known: {})",
                    BUILTIN_NAMES.join(", ")
                )
            })?;
            print!("{text}");
            Ok(())
        }
    }
}
