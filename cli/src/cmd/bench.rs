//! `spreadlet bench`: per-stage times of both devices, the growth with size and blur
//! (`--scaling`) and the one-shot device check (`--device-check`).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use spreadlet::dbcache;
use spreadlet::pipeline::RotationSampling;

#[derive(Args, Debug)]
pub(crate) struct BenchArgs {
    /// Square frame sizes, pixels, comma-separated.
    #[arg(long, default_value = "512,1024", value_delimiter = ',')]
    pub(crate) sizes: Vec<u32>,
    /// Runs per backend and size (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub(crate) runs: usize,
    /// Profile of the lens-motion database (built on demand into the cache).
    #[arg(long, default_value = "quick")]
    pub(crate) db_profile: String,
    /// Skip the CPU backend.
    #[arg(long)]
    pub(crate) no_cpu: bool,
    /// Skip the GPU backend.
    #[arg(long)]
    pub(crate) no_gpu: bool,
    /// Instead: CPU time of spreadlet and dense splatting against image size (--sizes,
    /// default 256,512,1024,2048) and against PSF size (--coc-radii), thin-lens database.
    #[arg(long)]
    pub(crate) scaling: bool,
    /// CoC radii of the --scaling PSF-size sweep, px.
    #[arg(long, default_value = "2,4,8,16,32,64", value_delimiter = ',')]
    pub(crate) coc_radii: Vec<f32>,
    /// Largest size the dense splat is timed at in the --scaling size sweep, px.
    #[arg(long, default_value_t = 1024)]
    pub(crate) dense_max_size: u32,
    /// Placement of rotated (motion-aligned) spreadlets.
    #[arg(long, value_enum, default_value_t = RotationSampling::Bspline)]
    pub(crate) rotation: RotationSampling,
    /// Splat stage of the GPU path.
    #[arg(long, value_enum, default_value_t = spreadlet::gpu::SplatMode::Tiled)]
    pub(crate) splat: spreadlet::gpu::SplatMode,
    /// Instead: the device check (micro-benchmarks of the GPU's limits, then thin lens, lens
    /// and motion, and motion only at 1024x1024, 1920x1080 and 3840x2160 with both splat
    /// stages), written to device-check.json and device-check.md in this folder.
    #[arg(long)]
    pub(crate) device_check: Option<PathBuf>,
    /// With --device-check: small sizes and few runs (to test the check on a software device).
    #[arg(long)]
    pub(crate) quick: bool,
}

/// Runs `spreadlet bench`.
pub(crate) fn run(args: BenchArgs) -> Result<()> {
    let profile: precompute::Profile = args.db_profile.parse()?;
    if let Some(dir) = &args.device_check {
        let (json, md) = spreadlet_harness::device_check::run_to_folder(
            dir,
            args.quick,
            profile,
            args.rotation,
        )?;
        println!("wrote {} and {}", json.display(), md.display());
        return Ok(());
    }
    if args.scaling {
        let cfg = dbcache::build_config(psf_db::PsfModel::ThinLens, profile, 0);
        let load = |cfg: &precompute::BuildConfig| -> Result<psf_db::PsfDatabase> {
            let (db, _) = dbcache::cached_database(
                cfg,
                &dbcache::cache_dir(),
                true,
                &spreadlet_harness::print_cache_event,
            )?;
            Ok(spreadlet::condition::condition(&db)?.0)
        };
        let sparse = load(&cfg)?;
        let dense = load(&spreadlet::baseline::dense_build_config(&cfg))?;
        let sizes = if args.sizes == [512, 1024] {
            vec![256, 512, 1024, 2048]
        } else {
            args.sizes.clone()
        };
        let config = spreadlet_harness::bench::ScalingConfig {
            sizes,
            coc_radii: args.coc_radii.clone(),
            dense_max_size: args.dense_max_size,
            runs: args.runs.max(1),
            rotation: args.rotation,
            ..Default::default()
        };
        let rows = spreadlet_harness::bench::run_scaling(&sparse, &dense, &config, true)?;
        let database = format!(
            "thin-lens {} ({} PSFs, {} spreadlets, max extent {} px)",
            profile,
            sparse.psf_count(),
            sparse.spreadlet_count(),
            sparse.max_extent_px()
        );
        println!(
            "{}",
            spreadlet_harness::bench::scaling_markdown(&rows, &database)
        );
        return Ok(());
    }
    let cfg = dbcache::build_config(psf_db::PsfModel::LensMotion, profile, 0);
    let (db, _) = dbcache::cached_database(
        &cfg,
        &dbcache::cache_dir(),
        true,
        &spreadlet_harness::print_cache_event,
    )?;
    let config = spreadlet_harness::bench::BenchConfig {
        sizes: args.sizes,
        runs: args.runs.max(1),
        cpu: !args.no_cpu,
        gpu: !args.no_gpu,
        rotation: args.rotation,
        global_atomic_splat: args.splat == spreadlet::gpu::SplatMode::GlobalAtomic,
        ..Default::default()
    };
    // As `DbSet` hands it to the pipeline: spreadlets in row order.
    let db = db.into_spreadlets_in_row_order();
    let report = spreadlet_harness::bench::run_bench(&db, &config)?;
    println!("{}", report.to_markdown());
    Ok(())
}
