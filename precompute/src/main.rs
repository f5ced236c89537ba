//! `precompute`: builds a PSF database (spreadlets) and its report.
//!
//! ```text
//! precompute --model lens-motion --profile quick --out lens-motion.sprdlt --report report.json
//! precompute --model lens-motion --profile paper --shard 3/32 --out part-3.sprdlt
//! precompute merge part-*.sprdlt --out lens-motion.sprdlt
//! ```
//!
//! A sharded build (`--shard K/N`, K from 0; `auto/N` takes K from `SLURM_ARRAY_TASK_ID` or
//! `JOB_COMPLETION_INDEX`) writes a partial file; `merge` joins the parts into the database,
//! byte-identical to a single build (docs/BATCH.md).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Parser;
use precompute::{build::build_database_part, BuildConfig, LensOptions, Procedure, Profile};
use psf_db::PsfModel;

/// Light-trace, pre-filter and sparsify every PSF of a model into a spreadlet database.
#[derive(Debug, Parser)]
#[command(name = "precompute", version, about)]
struct Args {
    /// PSF model: thin-lens, lens-motion or physical-lens.
    #[arg(long)]
    model: String,
    /// Profile: test (seconds), quick (minutes), paper (the paper's sample counts; slow).
    #[arg(long, default_value = "quick")]
    profile: String,
    /// Output database file (written atomically).
    #[arg(long)]
    out: PathBuf,
    /// Output report (JSON), optional.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Rays per PSF (default: scaled with the PSF's area by the profile).
    #[arg(long)]
    rays: Option<u64>,
    /// Spreadlet density: 1.0 default, 0.5 and 2.0 the paper's other operating points.
    #[arg(long, default_value_t = 1.0)]
    spreadlet_budget: f32,
    /// Trace every PSF at its cell centre instead of over its cell.
    #[arg(long)]
    no_prefilter: bool,
    /// physical-lens: pre-filter each PSF over its cell's eccentricities (by default traced
    /// at the middle of them).
    #[arg(long)]
    prefilter_eccentricity: bool,
    /// physical-lens: pre-filter each PSF over its cell's inverse depths (by default traced
    /// at the middle of them; the runtime scales a blend of two cells onto each pixel's
    /// depth).
    #[arg(long)]
    prefilter_inverse_depth: bool,
    /// Aperture blades (0 = circular) for thin-lens and lens-motion.
    #[arg(long, default_value_t = 0)]
    blades: u32,
    /// Rotation of the bladed aperture, radians.
    #[arg(long, default_value_t = 0.0)]
    blade_rotation: f32,
    /// Anamorphic squeeze for thin-lens and lens-motion: the aperture's width divided by it
    /// after the rotation (Blender's aperture_ratio; 1 = round, at least 1).
    #[arg(long, default_value_t = 1.0)]
    aperture_ratio: f32,
    /// A user-drawn aperture for thin-lens and lens-motion: a greyscale PNG whose brightness
    /// is the lens' transmission (replaces the blades).
    #[arg(long)]
    aperture_image: Option<std::path::PathBuf>,
    /// Sparsification: refit (default: the paper's steps, then least-squares values), paper,
    /// or improved (sign-separated cells + least-squares values).
    #[arg(long, default_value = "refit")]
    procedure: String,
    /// Per-PSF density: keep, among budgets 0.35x-4x `--spreadlet-budget`, the spreadlets
    /// maximising similarity - LAMBDA * sparsity (default 0.3).
    #[arg(long)]
    budget_tradeoff: Option<f32>,
    /// One spreadlet budget for every PSF (the paper), no per-PSF density ladder.
    #[arg(long, conflicts_with = "budget_tradeoff")]
    fixed_budget: bool,
    /// The paper's method throughout: --procedure paper --fixed-budget --sampled-shutter.
    #[arg(long, conflicts_with_all = ["procedure", "budget_tradeoff"])]
    paper_method: bool,
    /// lens-motion: sample the shutter time per ray like the paper instead of integrating
    /// each lens sample's motion segment exactly (noisier PSFs).
    #[arg(long)]
    sampled_shutter: bool,
    /// Also measure the ablation (darts / +Lloyd / +annealing / full); slower.
    #[arg(long)]
    ablation: bool,
    /// Override the profile's number of PSFs.
    #[arg(long)]
    psfs: Option<u32>,
    /// physical-lens: a lens prescription, a built-in name (singlet-51mm, double-gauss-50mm,
    /// wide-angle-22mm) or a file (JSON, or pbrt's `radius thickness index aperture [abbe]`
    /// table); without it, the singlet of the --lens-* options.
    #[arg(long)]
    lens: Option<String>,
    /// physical-lens: stop the lens down to this f-number (default: wide open).
    #[arg(long)]
    f_stop: Option<f64>,
    /// physical-lens: front radius, mm.
    #[arg(long)]
    lens_radius_front: Option<f64>,
    /// physical-lens: back radius, mm (negative).
    #[arg(long, allow_hyphen_values = true)]
    lens_radius_back: Option<f64>,
    /// physical-lens: centre thickness, mm.
    #[arg(long)]
    lens_thickness: Option<f64>,
    /// physical-lens: lens clear diameter, mm.
    #[arg(long)]
    lens_diameter: Option<f64>,
    /// physical-lens: aperture stop diameter, mm.
    #[arg(long)]
    stop_diameter: Option<f64>,
    /// physical-lens: stop position relative to the front vertex, mm (negative: in front).
    #[arg(long, allow_hyphen_values = true)]
    stop_position: Option<f64>,
    /// physical-lens: focus distance, scene units.
    #[arg(long)]
    focus_distance: Option<f64>,
    /// physical-lens: millimetres per scene unit.
    #[arg(long)]
    scene_unit_mm: Option<f64>,
    /// physical-lens: sensor width, mm.
    #[arg(long)]
    sensor_width_mm: Option<f64>,
    /// physical-lens: image width, pixels.
    #[arg(long)]
    image_width: Option<u32>,
    /// physical-lens: nearest depth sampled, scene units.
    #[arg(long)]
    depth_near: Option<f64>,
    /// physical-lens: farthest depth sampled, scene units.
    #[arg(long)]
    depth_far: Option<f64>,
    /// physical-lens: largest eccentricity sampled, mm.
    #[arg(long)]
    max_eccentricity: Option<f64>,
    /// Build only part K of N (0-based) into a partial file for `precompute merge`; `auto/N`
    /// takes K from SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX.
    #[arg(long)]
    shard: Option<String>,
}

/// Join the partial files of a sharded build into the database.
#[derive(Debug, Parser)]
#[command(name = "precompute merge")]
struct MergeArgs {
    /// The partial files (any order).
    #[arg(required = true)]
    parts: Vec<PathBuf>,
    /// Output database, written atomically.
    #[arg(long)]
    out: PathBuf,
}

/// The engine variables a batch job's index comes from, in the order they are tried.
const SHARD_INDEX_VARS: [&str; 2] = ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"];

fn parse_shard(spec: &str) -> Result<(u32, u32)> {
    let spec = match spec.strip_prefix("auto/") {
        Some(count) => {
            let Some((var, k)) = SHARD_INDEX_VARS
                .iter()
                .find_map(|v| std::env::var(v).ok().map(|k| (*v, k)))
            else {
                bail!(
                    "--shard auto/{count}: neither {} is set",
                    SHARD_INDEX_VARS.join(" nor ")
                );
            };
            eprintln!("shard index {k} from {var}");
            format!("{k}/{count}")
        }
        None => spec.to_string(),
    };
    Ok(psf_db::ShardRange::parse_spec(&spec)?)
}

fn merge(args: MergeArgs) -> Result<()> {
    let parts = args
        .parts
        .iter()
        .map(|p| psf_db::PsfDatabase::read(p).with_context(|| format!("reading {}", p.display())))
        .collect::<Result<Vec<_>>>()?;
    let db = psf_db::merge_shards(&parts)?;
    db.write_atomic(&args.out)
        .with_context(|| format!("writing {}", args.out.display()))?;
    eprintln!(
        "merged {} parts: {} {} PSFs -> {}",
        parts.len(),
        db.psf_count(),
        db.model(),
        args.out.display()
    );
    Ok(())
}

fn main() -> Result<()> {
    if std::env::args_os().nth(1).is_some_and(|a| a == "merge") {
        return merge(MergeArgs::parse_from(std::env::args_os().skip(1)));
    }
    let args = Args::parse();
    let shard = args.shard.as_deref().map(parse_shard).transpose()?;
    let model: PsfModel = args.model.parse()?;
    let profile: Profile = args.profile.parse()?;
    let procedure: Procedure = args
        .procedure
        .parse()
        .map_err(|e: String| anyhow::anyhow!(e))?;
    let mut cfg = BuildConfig::new(model, profile);
    cfg.seed = args.seed;
    cfg.rays_per_psf = args.rays;
    cfg.spreadlet_budget = args.spreadlet_budget;
    cfg.prefilter = !args.no_prefilter;
    cfg.blades = args.blades;
    cfg.blade_rotation_rad = args.blade_rotation;
    cfg.aperture_ratio = args.aperture_ratio;
    cfg.aperture_mask = args
        .aperture_image
        .as_deref()
        .map(formats::ApertureMask::read_png)
        .transpose()?;
    cfg.procedure = procedure;
    cfg.ablation = args.ablation;
    cfg.analytic_shutter = !args.sampled_shutter;
    if let Some(l) = args.budget_tradeoff {
        cfg.budget_tradeoff = Some(l);
    }
    if args.fixed_budget {
        cfg.budget_tradeoff = None;
    }
    if args.paper_method {
        cfg.procedure = Procedure::Paper;
        cfg.budget_tradeoff = None;
        cfg.analytic_shutter = false;
    }
    cfg.psf_count = args.psfs;
    let mut lens = LensOptions::default();
    let mut lens_set = false;
    let mut set = |dst: &mut f64, v: Option<f64>| {
        if let Some(v) = v {
            *dst = v;
            lens_set = true;
        }
    };
    set(&mut lens.radius_front_mm, args.lens_radius_front);
    set(&mut lens.radius_back_mm, args.lens_radius_back);
    set(&mut lens.thickness_mm, args.lens_thickness);
    set(&mut lens.lens_diameter_mm, args.lens_diameter);
    set(&mut lens.stop_diameter_mm, args.stop_diameter);
    set(&mut lens.stop_position_mm, args.stop_position);
    set(&mut lens.focus_distance, args.focus_distance);
    set(&mut lens.scene_unit_mm, args.scene_unit_mm);
    set(&mut lens.sensor_width_mm, args.sensor_width_mm);
    set(&mut lens.depth_range[0], args.depth_near);
    set(&mut lens.depth_range[1], args.depth_far);
    set(&mut lens.max_eccentricity_mm, args.max_eccentricity);
    if let Some(w) = args.image_width {
        lens.image_width_px = Some(w);
        lens_set = true;
    }
    if let Some(name) = &args.lens {
        let p = precompute::optics::Prescription::resolve(name, None)?;
        lens.prescription = Some(p);
        lens_set = true;
    }
    if let Some(n) = args.f_stop {
        lens.f_stop = Some(n);
        lens_set = true;
    }
    if args.prefilter_eccentricity {
        lens.prefilter_eccentricity = true;
        lens_set = true;
    }
    if args.prefilter_inverse_depth {
        lens.prefilter_inverse_depth = true;
        lens_set = true;
    }
    if lens_set {
        if model != PsfModel::PhysicalLens {
            bail!("lens options only apply to --model physical-lens");
        }
        cfg.lens = Some(lens);
    }
    cfg.validate()?;

    let (db, report) = build_database_part(&cfg, shard, true)
        .with_context(|| format!("building the {model} database ({profile} profile)"))?;
    db.write_atomic(&args.out)
        .with_context(|| format!("writing {}", args.out.display()))?;
    if let Some(path) = &args.report {
        let json = serde_json::to_string_pretty(&report)?;
        formats::atomic::write_bytes_atomically(path, json.as_bytes())?;
    }
    eprintln!(
        "{model} {profile}: {} PSFs ({} dense), {} spreadlets stored, mean sparsity {:.2} %, \
         mean similarity {:.4}, mean L1 {:.4} (stored sparse: {:.2} %, {:.4}; cost ratio \
         {:.2} %), {:.1} s -> {}",
        report.psfs.len(),
        report.dense_count,
        report.stored_spreadlets,
        100.0 * report.mean_sparsity,
        report.mean_similarity,
        report.mean_l1,
        100.0 * report.sparse_stored_mean_sparsity,
        report.sparse_stored_mean_similarity,
        100.0 * report.aggregate_cost_ratio,
        report.build_seconds,
        args.out.display()
    );
    if let Some(a) = &report.ablation {
        eprintln!(
            "ablation (mean L1, % of darts): darts {:.1}, +Lloyd {:.1}, +annealing {:.1}, full {:.1}, \
             full + re-fit {:.1}",
            a.percent_of_darts.darts,
            a.percent_of_darts.darts_lloyd,
            a.percent_of_darts.darts_annealing,
            a.percent_of_darts.full,
            a.percent_of_darts.refit
        );
    }
    Ok(())
}
