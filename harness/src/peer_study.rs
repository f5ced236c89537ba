//! Peer methods side by side: SSIM, PSNR and time of every peer method and of
//! spreadlet on the shipped scenes and the shared Blender examples, as `spreadlet study --peers`
//! writes them into docs/PEERS.md.
//!
//! Per built-in scene (`scene::builtin`), rendered at one small size: a pinhole G-buffer, 16-spp
//! stochastic frames (the lower sample counts are their first samples) and a converged
//! reference. Every method runs on those same inputs with the same camera:
//!
//! - ours: `spreadlet synth` from the G-buffer, `spreadlet reconstruct` at 1 spp and at every
//!   sample count a peer uses;
//! - the G-buffer peers (`mcguire`, `guertin`: motion blur only) on the G-buffer;
//! - the sample peers at their papers' sample counts: `shirley`, `shirley4`, `shirley-layered`
//!   at 16, `vaidyanathan` at 8, `munkberg`, `munkberg44` at 4 and 8;
//! - baselines: the plain per-pixel average of the samples at 1 and 16 spp.
//!
//! On the shared Blender examples the G-buffer methods run (plus Blender's own compositor
//! output, `blender_post.exr`, as a baseline), and, where an example has Cycles stochastic
//! frames (`stochastic/`), spreadlet reconstructs from them beside Cycles + OIDN at the same
//! paths per pixel.
//!
//! A method that ignores an effect of the input (`vaidyanathan` and `shirley-layered` on moving
//! scenes, `mcguire` and `guertin` on any defocused scene) runs anyway and is flagged.
//!
//! Outputs in `out_dir`: `peers.md` (one table: scene, method, input, spp, ssim, psnr, ms,
//! then where a peer wins and the crops), `peers.csv` (the same rows plus the ignored effects),
//! and `crop_<scene>.png`: the hardest region (largest mean sRGB error over all methods) of the
//! reference | the best spreadlet row | the best peer row, enlarged.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use spreadlet::synth::ms_since;

use anyhow::{Context, Result};
use peers::{InputKind, PeerMethod};

use crate::demo::cached_dbs;
use crate::peer::{reconstruct_peer, synthesize_peer, unhandled_effects};
use formats::{srgb_encode as linear_to_srgb, Error as WriteError, RgbaImage, StochasticFrames};
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};
use spreadlet::pipeline::{Effects, Integrator};
use spreadlet::reconstruct::{effects_of, reconstruct};
use spreadlet::synth::{synthesize, SynthOptions};

/// What `spreadlet study --peers` asks for.
#[derive(Clone, Debug)]
pub struct PeerStudyOptions {
    /// Folder the table (Markdown, CSV) and the side-by-side crops are written to.
    pub out_dir: PathBuf,
    /// Larger images and sample counts (takes longer).
    pub full: bool,
    /// Profile of databases built on demand (`quick` or `paper`).
    pub db_profile: String,
    /// Print no progress.
    pub quiet: bool,
}

/// Sizes, sample counts and inputs of one study run ([`PeerStudyConfig::for_options`] gives
/// the default and the `--full` ones).
#[derive(Clone, Debug, PartialEq)]
pub struct PeerStudyConfig {
    /// Built-in scenes (`scene::BUILTIN_NAMES`).
    pub scenes: Vec<String>,
    /// Square size the built-in scenes are rendered at, pixels (field of view kept).
    pub size: u32,
    /// Samples per pixel of the built-in scenes' references.
    pub reference_spp: usize,
    /// The sample methods and the samples per pixel each runs at.
    pub sample_peers: Vec<(PeerMethod, usize)>,
    /// Sample counts spreadlet reconstructs from (besides those of `sample_peers`).
    pub spreadlet_spp: Vec<usize>,
    /// Whether the G-buffer methods (spreadlet synth, mcguire, guertin) run on the scenes.
    pub gbuffer_methods: bool,
    /// Folder of the shared Blender examples (`comets/`, `fence/`), `None` to skip them.
    pub examples_dir: Option<PathBuf>,
    /// Centre crop of the examples, pixels (square; `None`: the whole 512 x 512 frame). A crop
    /// loses the blur that objects outside it spread into it, which the references keep, so
    /// every method scores lower on it (spreadlet on comets: SSIM 0.915 cropped to the centre
    /// 256 px, 0.969 whole).
    pub example_crop: Option<usize>,
    /// Seed of the renders.
    pub seed: u64,
}

impl PeerStudyConfig {
    /// Default run: 160 px scenes, 2048-spp references, the whole examples (a few minutes on
    /// two cores). `full`: 256 px, 4096 spp.
    pub fn for_options(options: &PeerStudyOptions) -> Self {
        let (size, reference_spp) = if options.full {
            (256, 4096)
        } else {
            (160, 2048)
        };
        Self {
            scenes: scene::BUILTIN_NAMES.iter().map(|s| s.to_string()).collect(),
            size,
            reference_spp,
            sample_peers: default_sample_peers(),
            spreadlet_spp: vec![1],
            gbuffer_methods: true,
            examples_dir: find_examples(),
            example_crop: None,
            seed: 1,
        }
    }

    /// Every sample count the frames must hold.
    fn max_spp(&self) -> usize {
        self.sample_peers
            .iter()
            .map(|p| p.1)
            .chain(self.spreadlet_spp.iter().copied())
            .max()
            .unwrap_or(1)
    }

    /// The sample counts spreadlet reconstructs from: its own and every peer's, ascending.
    fn our_spp(&self) -> Vec<usize> {
        let mut v: Vec<usize> = self
            .spreadlet_spp
            .iter()
            .copied()
            .chain(self.sample_peers.iter().map(|p| p.1))
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    }
}

/// The sample peers at their papers' sample counts: Shirley 16, Vaidyanathan 8, Munkberg 4
/// and 8.
pub fn default_sample_peers() -> Vec<(PeerMethod, usize)> {
    vec![
        (PeerMethod::Shirley, 16),
        (PeerMethod::Shirley4, 16),
        (PeerMethod::ShirleyLayered, 16),
        (PeerMethod::Vaidyanathan, 8),
        (PeerMethod::Munkberg, 4),
        (PeerMethod::Munkberg, 8),
        (PeerMethod::Munkberg44, 4),
        (PeerMethod::Munkberg44, 8),
    ]
}

/// The shared examples: `$SPREADLET_EXAMPLES`, else `../shared/examples` from the working
/// directory or from the workspace; `None` when none exists.
fn find_examples() -> Option<PathBuf> {
    let candidates = [
        std::env::var_os("SPREADLET_EXAMPLES").map(PathBuf::from),
        Some(PathBuf::from("../shared/examples")),
        Some(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/examples")),
    ];
    candidates
        .into_iter()
        .flatten()
        .find(|p| p.join("comets").join("input.exr").exists())
}

/// Who a row is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RowKind {
    /// spreadlet (synthesis or reconstruction).
    Ours,
    /// A peer method.
    Peer,
    /// A baseline (plain average, Blender's compositor).
    Baseline,
}

/// One measured row of the table.
#[derive(Clone, Debug, PartialEq)]
pub struct StudyRow {
    /// Scene (built-in name or example folder).
    pub scene: String,
    /// Method name (`spreadlet`, a peer's `--method` name, `average`, `blender-post`).
    pub method: String,
    /// `G-buffer` or `samples`.
    pub input: &'static str,
    /// Samples per pixel read (`None` for G-buffer input).
    pub spp: Option<usize>,
    /// SSIM against the reference (project definition).
    pub ssim: f64,
    /// PSNR against the reference, dB (sRGB, peak 1).
    pub psnr: f64,
    /// Mean FLIP error against the reference (lower is better).
    pub flip_mean: f64,
    /// 99th percentile of the FLIP error.
    pub flip_p99: f64,
    /// Wall-clock time of the method, milliseconds (`None` when not run here); renders,
    /// database loading and input conversion excluded.
    pub ms: Option<f64>,
    /// Effects of the input the method ignored.
    pub ignored: Vec<&'static str>,
    /// Ours, a peer or a baseline.
    pub kind: RowKind,
}

/// The hardest region of one scene, as cropped into `file`.
#[derive(Clone, Debug, PartialEq)]
pub struct Crop {
    /// Scene.
    pub scene: String,
    /// PNG file name in the output folder.
    pub file: String,
    /// Left, top, edge of the region, pixels.
    pub rect: (usize, usize, usize),
    /// Index in [`PeerStudyReport::rows`] of the spreadlet panel's row.
    pub ours: usize,
    /// Index of the peer panel's row.
    pub peer: usize,
}

/// What a study run measured and wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct PeerStudyReport {
    /// Every row, grouped by scene.
    pub rows: Vec<StudyRow>,
    /// One crop per scene.
    pub crops: Vec<Crop>,
    /// The configuration that ran.
    pub config: PeerStudyConfig,
    /// Scenes that were skipped, with why (missing examples).
    pub skipped: Vec<String>,
}

/// Runs the peer comparison and writes its outputs into `options.out_dir`.
pub fn run(options: &PeerStudyOptions) -> anyhow::Result<()> {
    let report = run_with(options, &PeerStudyConfig::for_options(options))?;
    if !options.quiet {
        eprintln!(
            "wrote {} rows to {}",
            report.rows.len(),
            options.out_dir.join("peers.md").display()
        );
    }
    Ok(())
}

/// Databases loaded once per (effects, aperture blades and rotation).
struct DbCache {
    profile: precompute::Profile,
    progress: bool,
    sets: HashMap<(bool, bool, u32, u32), DbSet>,
}

impl DbCache {
    fn get(&mut self, effects: Effects, camera: &Camera) -> Result<&DbSet> {
        let aperture = spreadlet::databases::aperture_of(camera);
        let key = (
            effects.defocus,
            effects.motion,
            aperture.blades,
            aperture.rotation_rad.to_bits(),
        );
        if !self.sets.contains_key(&key) {
            let set = cached_dbs(effects, self.profile, aperture, self.progress)?;
            self.sets.insert(key, set);
        }
        self.sets
            .get(&key)
            .context("database set just inserted is missing")
    }
}

/// Runs the study with an explicit configuration (tests use a tiny one) and writes its
/// outputs into `options.out_dir`.
pub fn run_with(options: &PeerStudyOptions, config: &PeerStudyConfig) -> Result<PeerStudyReport> {
    let out = &options.out_dir;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut dbs = DbCache {
        profile: options.db_profile.parse()?,
        progress: !options.quiet,
        sets: HashMap::new(),
    };
    let mut report = PeerStudyReport {
        rows: Vec::new(),
        crops: Vec::new(),
        config: config.clone(),
        skipped: Vec::new(),
    };
    let say = |s: &str| {
        if !options.quiet {
            eprintln!("{s}");
        }
    };
    for name in &config.scenes {
        // The sample methods need stochastic frames, which a real lens has no labels for.
        if scene::builtin(name).is_ok_and(|s| s.camera_spec().lens.is_some()) {
            report.skipped.push(format!(
                "{name}: its camera is a real lens, which stochastic frames cannot label"
            ));
            continue;
        }
        say(&format!(
            "peer study: scene '{name}' at {0}x{0}, reference {1} spp",
            config.size, config.reference_spp
        ));
        let (rows, images, reference) = study_scene(name, config, &mut dbs, options)
            .with_context(|| format!("scene '{name}'"))?;
        add_scene(&mut report, rows, &images, &reference, out)?;
    }
    if let Some(dir) = &config.examples_dir {
        for name in ["comets", "fence"] {
            let path = dir.join(name);
            if !path.join("input.exr").exists() {
                report
                    .skipped
                    .push(format!("{name}: no input.exr in {}", path.display()));
                continue;
            }
            say(&format!("peer study: example '{name}'"));
            let (rows, images, reference) = study_example(name, &path, config, &mut dbs)
                .with_context(|| format!("example '{name}'"))?;
            add_scene(&mut report, rows, &images, &reference, out)?;
        }
    } else {
        report
            .skipped
            .push("the shared Blender examples (not found)".into());
    }
    write_text(&out.join("peers.md"), &markdown(&report))?;
    write_text(&out.join("peers.csv"), &csv(&report.rows))?;
    Ok(report)
}

/// Appends one scene's rows and writes its crop.
fn add_scene(
    report: &mut PeerStudyReport,
    rows: Vec<StudyRow>,
    images: &[RgbaImage],
    reference: &RgbaImage,
    out: &Path,
) -> Result<()> {
    let base = report.rows.len();
    if let Some(mut crop) = hardest_crop(&rows, images, reference, out)? {
        crop.ours += base;
        crop.peer += base;
        report.crops.push(crop);
    }
    report.rows.extend(rows);
    Ok(())
}

/// The scores of `image` against `reference`.
fn score(image: &RgbaImage, reference: &RgbaImage) -> Result<metrics::Scores> {
    crate::score_images(image, reference).context("scoring")
}

/// Collects rows and their images for one scene.
struct SceneRows<'a> {
    scene: &'a str,
    reference: &'a RgbaImage,
    rows: Vec<StudyRow>,
    images: Vec<RgbaImage>,
}

impl SceneRows<'_> {
    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        method: &str,
        input: &'static str,
        spp: Option<usize>,
        image: RgbaImage,
        ms: Option<f64>,
        ignored: Vec<&'static str>,
        kind: RowKind,
    ) -> Result<()> {
        let scores = score(&image, self.reference)?;
        self.rows.push(StudyRow {
            scene: self.scene.to_string(),
            method: method.to_string(),
            input,
            spp,
            ssim: scores.ssim,
            psnr: scores.psnr_db.unwrap_or(f64::INFINITY),
            flip_mean: scores.flip_mean,
            flip_p99: scores.flip_p99,
            ms,
            ignored,
            kind,
        });
        self.images.push(image);
        Ok(())
    }
}

/// The options `spreadlet synth` and `reconstruct` run with by default: exact integration
/// (`SynthOptions::default()` has the pyramid, which costs comets 0.10 SSIM).
fn cli_synth_options() -> SynthOptions {
    SynthOptions {
        integrator: Integrator::Exact,
        ..SynthOptions::default()
    }
}

type SceneResult = (Vec<StudyRow>, Vec<RgbaImage>, RgbaImage);

/// Renders one built-in scene and runs every method on it.
fn study_scene(
    name: &str,
    config: &PeerStudyConfig,
    dbs: &mut DbCache,
    options: &PeerStudyOptions,
) -> Result<SceneResult> {
    let scene = scene::builtin(name)?.with_size(config.size, config.size)?;
    let camera = Camera::from_json_str(&scene.camera_json())?;
    let render = scene::RenderOptions {
        seed: config.seed,
        progress: !options.quiet,
        ..Default::default()
    };
    let g = scene::render_gbuffer(&scene, 16, &render)?;
    let frames = scene::render_stochastic(&scene, config.max_spp(), &render)?;
    let reference = scene::render_reference(&scene, config.reference_spp, &render)?;
    let gbuffer = crate::gbuffer_of(&g)?;

    let mut acc = SceneRows {
        scene: name,
        reference: &reference,
        rows: Vec::new(),
        images: Vec::new(),
    };
    if config.gbuffer_methods {
        gbuffer_rows(&mut acc, &gbuffer, &camera, dbs)?;
    }
    let effects = effects_of(&camera, &frames);
    for spp in config.our_spp() {
        let sub = frames.first_samples(spp);
        let options = cli_synth_options();
        let set = dbs.get(effects, &camera)?;
        let t = Instant::now();
        let (image, _) = reconstruct(&sub, &camera, set, &options)?;
        let ms = ms_since(t);
        acc.push(
            "spreadlet",
            "samples",
            Some(spp),
            image,
            Some(ms),
            vec![],
            RowKind::Ours,
        )?;
    }
    for (method, spp) in &config.sample_peers {
        let sub = frames.first_samples(*spp);
        let run = reconstruct_peer(method.name(), &sub, &camera, true)?;
        acc.push(
            method.name(),
            "samples",
            Some(sub.spp),
            run.image,
            Some(run.ms),
            run.ignored,
            RowKind::Peer,
        )?;
    }
    let mut baselines: Vec<usize> = vec![1, frames.spp];
    baselines.dedup();
    for spp in baselines {
        let sub = frames.first_samples(spp);
        let t = Instant::now();
        let image = sub.average();
        let ms = ms_since(t);
        acc.push(
            "average",
            "samples",
            Some(spp),
            image,
            Some(ms),
            vec![],
            RowKind::Baseline,
        )?;
    }
    Ok((acc.rows, acc.images, reference))
}

/// spreadlet synth, mcguire and guertin on a G-buffer.
fn gbuffer_rows(
    acc: &mut SceneRows,
    gbuffer: &GBuffer,
    camera: &Camera,
    dbs: &mut DbCache,
) -> Result<()> {
    let effects = Effects::of(camera, gbuffer);
    let set = dbs.get(effects, camera)?;
    let t = Instant::now();
    let (image, _) = synthesize(gbuffer, camera, set, &cli_synth_options())?;
    let ms = ms_since(t);
    acc.push(
        "spreadlet",
        "G-buffer",
        None,
        image,
        Some(ms),
        vec![],
        RowKind::Ours,
    )?;
    for method in PeerMethod::ALL {
        if method.input_kind() != InputKind::GBuffer {
            continue;
        }
        let t = Instant::now();
        let image = synthesize_peer(method.name(), gbuffer, camera)?;
        let ms = ms_since(t);
        acc.push(
            method.name(),
            "G-buffer",
            None,
            image,
            Some(ms),
            unhandled_effects(method, effects),
            RowKind::Peer,
        )?;
    }
    Ok(())
}

/// The centre `edge x edge` of `g` and `reference`, with the camera's sensor narrowed to keep
/// its pixels per millimetre.
fn centre_crop(
    g: &GBuffer,
    images: &[&RgbaImage],
    camera: &Camera,
    edge: usize,
) -> (GBuffer, Vec<RgbaImage>, Camera) {
    let edge = edge.min(g.width).min(g.height);
    let (x0, y0) = ((g.width - edge) / 2, (g.height - edge) / 2);
    let pick = |i: usize| (y0 + i / edge) * g.width + x0 + i % edge;
    let n = edge * edge;
    let out = GBuffer {
        width: edge,
        height: edge,
        overscan: spreadlet::gbuffer::Overscan::NONE,
        color: (0..n).map(|i| g.color[pick(i)]).collect(),
        depth: g
            .depth
            .as_ref()
            .map(|d| (0..n).map(|i| d[pick(i)]).collect()),
        motion: g
            .motion
            .as_ref()
            .map(|m| (0..n).map(|i| m[pick(i)]).collect()),
        acceleration: g
            .acceleration
            .as_ref()
            .map(|a| (0..n).map(|i| a[pick(i)]).collect()),
        ..g.clone()
    };
    let images = images
        .iter()
        .map(|im| RgbaImage {
            width: edge,
            height: edge,
            pixels: (0..n).map(|i| im.pixels[pick(i)]).collect(),
        })
        .collect();
    let mut c = camera.clone();
    c.sensor_width_mm *= edge as f64 / f64::from(camera.width);
    c.width = edge as u32;
    c.height = edge as u32;
    (out, images, c)
}

fn read_color(path: &Path) -> Result<RgbaImage> {
    let g = GBuffer::read_exr(path, &ChannelOptions::default())
        .with_context(|| format!("reading {}", path.display()))?;
    Ok(RgbaImage {
        width: g.width,
        height: g.height,
        pixels: g.color,
    })
}

/// One shared Blender example: the G-buffer methods and Blender's compositor.
fn study_example(
    name: &str,
    dir: &Path,
    config: &PeerStudyConfig,
    dbs: &mut DbCache,
) -> Result<SceneResult> {
    let g = GBuffer::read_exr(&dir.join("input.exr"), &ChannelOptions::default())
        .with_context(|| format!("reading {}", dir.join("input.exr").display()))?;
    let camera = Camera::from_json_file(&dir.join("camera.json"))?;
    let reference = read_color(&dir.join("reference.exr"))?;
    let post_path = dir.join("blender_post.exr");
    let post = if post_path.exists() {
        Some(read_color(&post_path)?)
    } else {
        None
    };
    for (what, im) in std::iter::once(("reference.exr", &reference))
        .chain(post.iter().map(|p| ("blender_post.exr", p)))
    {
        if (im.width, im.height) != (g.width, g.height) {
            anyhow::bail!(
                "{what} is {}x{} but input.exr is {}x{}",
                im.width,
                im.height,
                g.width,
                g.height
            );
        }
    }
    let (g, reference, post, camera) = match config.example_crop {
        Some(edge) => {
            let mut list = vec![&reference];
            list.extend(post.iter());
            let (g, mut images, camera) = centre_crop(&g, &list, &camera, edge);
            let post = (images.len() > 1).then(|| images.remove(1));
            (g, images.remove(0), post, camera)
        }
        None => (g, reference, post, camera),
    };
    let mut acc = SceneRows {
        scene: name,
        reference: &reference,
        rows: Vec::new(),
        images: Vec::new(),
    };
    gbuffer_rows(&mut acc, &g, &camera, dbs)?;
    if config.example_crop.is_none() {
        cycles_sample_rows(&mut acc, &dir.join("stochastic"), &camera, dbs)?;
    }
    if let Some(post) = post {
        acc.push(
            "blender-post",
            "G-buffer",
            None,
            post,
            None,
            vec![],
            RowKind::Baseline,
        )?;
    }
    let (rows, images) = (acc.rows, acc.images);
    Ok((rows, images, reference))
}

/// The Cycles stochastic frames of a shared example (`stochastic/`, when it has them) beside
/// what a Cycles user does instead at the same number of paths per pixel: Cycles' own lens
/// and shutter, denoised by OIDN (`cycles_Nspp_oidn.exr`). Both rows give the paths per pixel
/// in the spp column.
fn cycles_sample_rows(
    acc: &mut SceneRows,
    dir: &Path,
    camera: &Camera,
    dbs: &mut DbCache,
) -> Result<()> {
    // (frames, Cycles paths per pixel they hold, the peer at those paths)
    let sets = [
        ("stochastic_1spp_1path.exr", 1, "cycles_1spp_oidn.exr"),
        ("stochastic_1spp.exr", 4, "cycles_4spp_oidn.exr"),
        ("stochastic_4spp.exr", 16, "cycles_16spp_oidn.exr"),
    ];
    for (frames_file, paths, peer_file) in sets {
        let (frames_path, peer_path) = (dir.join(frames_file), dir.join(peer_file));
        if !frames_path.exists() || !peer_path.exists() {
            continue;
        }
        let frames = StochasticFrames::read_exr(&frames_path)
            .with_context(|| format!("reading {}", frames_path.display()))?;
        let set = dbs.get(effects_of(camera, &frames), camera)?;
        let t = Instant::now();
        let (image, _) = reconstruct(&frames, camera, set, &cli_synth_options())?;
        let ms = ms_since(t);
        acc.push(
            "spreadlet",
            "Cycles paths",
            Some(paths),
            image,
            Some(ms),
            vec![],
            RowKind::Ours,
        )?;
        let peer = read_color(&peer_path)?;
        acc.push(
            "cycles+oidn",
            "Cycles paths",
            Some(paths),
            peer,
            None,
            vec![],
            RowKind::Baseline,
        )?;
    }
    Ok(())
}

/// Index of the highest-SSIM row of `kind`.
fn best_of(rows: &[StudyRow], kind: RowKind) -> Option<usize> {
    rows.iter()
        .enumerate()
        .filter(|(_, r)| r.kind == kind)
        .max_by(|a, b| a.1.ssim.total_cmp(&b.1.ssim))
        .map(|(i, _)| i)
}

/// The square window (edge a quarter of the image, at least 8 px) with the largest mean sRGB
/// error over the rows of spreadlet and the peers: its left, top and edge.
pub fn hardest_region(
    images: &[&RgbaImage],
    reference: &RgbaImage,
    edge: usize,
) -> (usize, usize, usize) {
    let (w, h) = (reference.width, reference.height);
    let edge = edge.clamp(1, w.min(h).max(1));
    // Per-pixel error summed over the images, then an integral image.
    let mut integral = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0f64;
        for x in 0..w {
            let r = reference.pixels[y * w + x];
            let e: f64 = images
                .iter()
                .map(|im| {
                    let p = im.pixels[y * w + x];
                    (0..3)
                        .map(|c| f64::from((linear_to_srgb(p[c]) - linear_to_srgb(r[c])).abs()))
                        .sum::<f64>()
                })
                .sum();
            row += e;
            integral[(y + 1) * (w + 1) + x + 1] = integral[y * (w + 1) + x + 1] + row;
        }
    }
    let sum = |x: usize, y: usize| {
        let at = |xx: usize, yy: usize| integral[yy * (w + 1) + xx];
        at(x + edge, y + edge) - at(x, y + edge) - at(x + edge, y) + at(x, y)
    };
    let mut best = (0, 0, f64::NEG_INFINITY);
    for y in 0..=h - edge {
        for x in 0..=w - edge {
            let s = sum(x, y);
            if s > best.2 {
                best = (x, y, s);
            }
        }
    }
    (best.0, best.1, edge)
}

/// Writes `crop_<scene>.png` (reference | best spreadlet | best peer over the hardest region).
fn hardest_crop(
    rows: &[StudyRow],
    images: &[RgbaImage],
    reference: &RgbaImage,
    out: &Path,
) -> Result<Option<Crop>> {
    let (Some(ours), Some(peer)) = (best_of(rows, RowKind::Ours), best_of(rows, RowKind::Peer))
    else {
        return Ok(None);
    };
    let scored: Vec<&RgbaImage> = rows
        .iter()
        .zip(images)
        .filter(|(r, _)| r.kind != RowKind::Baseline)
        .map(|(_, im)| im)
        .collect();
    let edge = (reference.width.min(reference.height) / 4).max(8);
    let rect = hardest_region(&scored, reference, edge);
    let scene = rows[ours].scene.clone();
    let file = format!("crop_{scene}.png");
    write_crop_strip(
        &out.join(&file),
        &[reference, &images[ours], &images[peer]],
        rect,
    )?;
    Ok(Some(Crop {
        scene,
        file,
        rect,
        ours,
        peer,
    }))
}

/// The square `rect` of each image, enlarged by an integer factor to about 160 px, side by
/// side with a 4-pixel grey gap, as an sRGB PNG.
fn write_crop_strip(
    path: &Path,
    images: &[&RgbaImage],
    rect: (usize, usize, usize),
) -> Result<(), WriteError> {
    let (x0, y0, edge) = rect;
    let zoom = (160 / edge.max(1)).max(1);
    let side = edge * zoom;
    let gap = 4;
    let w = images.len() * (side + gap) - gap;
    let mut strip = RgbaImage {
        width: w,
        height: side,
        pixels: vec![[0.5, 0.5, 0.5, 1.0]; w * side],
    };
    for (k, image) in images.iter().enumerate() {
        let left = k * (side + gap);
        for y in 0..side {
            for x in 0..side {
                let p = image.at(x0 + x / zoom, y0 + y / zoom);
                strip.pixels[y * w + left + x] = [p[0], p[1], p[2], 1.0];
            }
        }
    }
    strip.write_png(path)
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    formats::atomic::write_bytes_atomically(path, text.as_bytes())?;
    Ok(())
}

/// The method as the table shows it: a dagger when it ignored an effect of the input.
fn method_label(row: &StudyRow) -> String {
    let mut s = row.method.clone();
    if row.ignored.contains(&"motion blur") {
        s.push_str(" †");
    }
    if row.ignored.contains(&"depth of field") {
        s.push_str(" ‡");
    }
    s
}

fn fmt_spp(spp: Option<usize>) -> String {
    spp.map_or_else(|| "-".into(), |s| s.to_string())
}

fn fmt_ms(ms: Option<f64>) -> String {
    ms.map_or_else(|| "-".into(), |m| format!("{m:.0}"))
}

fn fmt_psnr(psnr: f64) -> String {
    if psnr.is_finite() {
        format!("{psnr:.2}")
    } else {
        "inf".into()
    }
}

/// Column names of the table (Markdown and CSV; the CSV adds `ignores`).
pub const COLUMNS: [&str; 9] = [
    "scene",
    "method",
    "input",
    "spp",
    "ssim",
    "psnr",
    "flip_mean",
    "flip_p99",
    "ms",
];

/// The CSV: [`COLUMNS`] plus `ignores` (the effects a method ignored, `;`-separated).
pub fn csv(rows: &[StudyRow]) -> String {
    let mut s = COLUMNS.join(",");
    s.push_str(",ignores\n");
    for r in rows {
        s.push_str(&format!(
            "{},{},{},{},{:.4},{},{:.4},{:.4},{},{}\n",
            r.scene,
            r.method,
            r.input,
            fmt_spp(r.spp),
            r.ssim,
            fmt_psnr(r.psnr),
            r.flip_mean,
            r.flip_p99,
            fmt_ms(r.ms),
            r.ignored.join(";")
        ));
    }
    s
}

/// For each peer row, the spreadlet row it is measured against: on samples, spreadlet at the
/// same sample count; on a G-buffer, spreadlet synth.
fn matching_ours(rows: &[StudyRow], peer: &StudyRow) -> Option<usize> {
    rows.iter().position(|r| {
        r.kind == RowKind::Ours
            && r.scene == peer.scene
            && r.input == peer.input
            && r.spp == peer.spp
    })
}

/// The Markdown page: the table, the peers that beat spreadlet on the same input, the crops.
pub fn markdown(report: &PeerStudyReport) -> String {
    let c = &report.config;
    let mut s = String::new();
    s.push_str(&format!(
        "Built-in scenes at {0} x {0} px, references {1} spp (Latin hypercube), stochastic \
         frames {2} spp (lower counts are their first samples), seed {3}; shared Blender \
         examples {4} against their 2048-spp Cycles references. SSIM, PSNR and FLIP (LDR, 67 \
         px per degree; mean and 99th percentile, lower is better) on sRGB values clamped to \
         [0, 1]; ms: wall-clock time of the method alone on the CPU (renders, \
         database loading and input conversion excluded; a shared machine, so rough). \
         † ignores the scene's motion blur, ‡ ignores its depth of field (run anyway).\n\n",
        c.size,
        c.reference_spp,
        c.max_spp(),
        c.seed,
        match c.example_crop {
            Some(e) => format!("cropped to their centre {e} x {e} px"),
            None => "at full size".into(),
        }
    ));
    s.push_str(&format!("| {} |\n", COLUMNS.join(" | ")));
    s.push_str(&format!("|{}\n", " --- |".repeat(COLUMNS.len())));
    for r in &report.rows {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {:.4} | {} | {:.4} | {:.4} | {} |\n",
            r.scene,
            method_label(r),
            r.input,
            fmt_spp(r.spp),
            r.ssim,
            fmt_psnr(r.psnr),
            r.flip_mean,
            r.flip_p99,
            fmt_ms(r.ms)
        ));
    }
    s.push_str("\nWhere a peer beats spreadlet on the same input (same samples, or the same G-buffer), by SSIM:\n\n");
    let mut any = false;
    for r in report.rows.iter().filter(|r| r.kind == RowKind::Peer) {
        let Some(o) = matching_ours(&report.rows, r) else {
            continue;
        };
        let ours = &report.rows[o];
        if r.ssim > ours.ssim {
            any = true;
            s.push_str(&format!(
                "- {}: {} ({} {}) SSIM {:.4} vs spreadlet {:.4} (PSNR {} vs {} dB)\n",
                r.scene,
                method_label(r),
                r.input,
                fmt_spp(r.spp),
                r.ssim,
                ours.ssim,
                fmt_psnr(r.psnr),
                fmt_psnr(ours.psnr)
            ));
        }
    }
    if !any {
        s.push_str("- none\n");
    }
    if !report.crops.is_empty() {
        s.push_str("\nHardest regions (largest mean sRGB error over all methods), enlarged: reference | best spreadlet row | best peer row.\n\n");
        for crop in &report.crops {
            let (o, p) = (&report.rows[crop.ours], &report.rows[crop.peer]);
            s.push_str(&format!(
                "- {}: x {}, y {}, {} px: spreadlet ({} {}, SSIM {:.4}) | {} ({} {}, SSIM {:.4}): ![{}]({})\n",
                crop.scene,
                crop.rect.0,
                crop.rect.1,
                crop.rect.2,
                o.input,
                fmt_spp(o.spp),
                o.ssim,
                method_label(p),
                p.input,
                fmt_spp(p.spp),
                p.ssim,
                crop.scene,
                crop.file
            ));
        }
    }
    for k in &report.skipped {
        s.push_str(&format!("\nSkipped: {k}.\n"));
    }
    s
}
