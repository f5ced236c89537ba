//! The benchmark module runs end to end on a small frame, and on its synthetic frame (every
//! PSF size, rotations, copies, several layers) the GPU image matches the CPU's.
#![cfg(feature = "gpu")]

use spreadlet_harness::bench;

#[path = "../../runtime/tests/gpu_support/mod.rs"]
mod gpu_support;

use gpu_support::{context, max_diff};
use psf_db::PsfModel;
use spreadlet::gpu::{GpuSynthOptions, GpuSynthesizer};
use spreadlet::pipeline::{
    composite, integrate, splat, CompositeOptions, Integrator, SplatOptions,
};

fn lens_motion_db() -> psf_db::PsfDatabase {
    let cfg = precompute::BuildConfig::new(PsfModel::LensMotion, precompute::Profile::Test);
    precompute::build_database(&cfg, false)
        .expect("test database")
        .0
}

#[test]
fn bench_reports_both_backends_as_markdown() {
    let db = lens_motion_db();
    let config = bench::BenchConfig {
        sizes: vec![40, 64],
        runs: 2,
        layers: 3,
        ..Default::default()
    };
    let report = bench::run_bench(&db, &config).expect("bench");
    let backends = if context().is_some() { 2 } else { 1 };
    assert_eq!(report.rows.len(), 2 * backends);
    for r in &report.rows {
        assert!(
            r.total_ms > 0.0 && r.splat_ms >= 0.0 && r.integrate_ms > 0.0,
            "{r:?}"
        );
        assert_eq!(r.records, (r.size * r.size) as usize);
    }
    let md = report.to_markdown();
    eprintln!("{md}");
    assert!(md.contains("| backend |") && md.contains("64x64"));
    assert!(bench::run_bench(
        &db,
        &bench::BenchConfig {
            sizes: vec![],
            ..config
        }
    )
    .is_err());
}

#[test]
fn synthetic_frame_gpu_matches_cpu() {
    let Some(ctx) = context() else { return };
    let db = lens_motion_db();
    let frame = bench::synthetic_frame(&db, 160, 5);
    assert!(
        frame.counts.sparse > 0 && frame.counts.copied > 0,
        "{:?}",
        frame.counts
    );
    let cpu = composite(
        &integrate(
            &splat(&frame, Some(&db), &SplatOptions::default()),
            Integrator::Pyramid,
        ),
        &CompositeOptions::default(),
    );
    let mut gpu = GpuSynthesizer::new(ctx, &db, GpuSynthOptions::default()).expect("synth");
    let (img, _) = gpu
        .run(&frame.frame, &frame.records, Integrator::Pyramid)
        .expect("run");
    let a: Vec<f32> = img.pixels.iter().flatten().copied().collect();
    let b: Vec<f32> = cpu.pixels.iter().flatten().copied().collect();
    let ssim = metrics::ssim_rgb(&a, &b, 160, 160).expect("ssim");
    let (d, m) = max_diff(&a, &b);
    eprintln!("synthetic 160x160: SSIM {ssim:.6}, max diff {d:.2e} (max {m:.3})");
    assert!(ssim >= 0.999 && d <= 1e-5, "SSIM {ssim}, max diff {d}");
}

/// The figures for docs/BENCHMARKS.md (slow: run on demand):
/// `SPREADLET_BENCH_SIZES=512,1024 cargo test -p runtime --release --test gpu_bench -- --ignored --nocapture`
#[test]
#[ignore]
fn bench_figures() {
    let sizes: Vec<u32> = std::env::var("SPREADLET_BENCH_SIZES")
        .unwrap_or_else(|_| "512,1024".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let runs = std::env::var("SPREADLET_BENCH_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3);
    let db = lens_motion_db();
    let config = bench::BenchConfig {
        sizes,
        runs,
        ..Default::default()
    };
    let report = bench::run_bench(&db, &config).expect("bench");
    println!("{}", report.to_markdown());
}
