//! On the shared Blender examples (`../shared/examples`, centre crops), the GPU synthesis
//! matches the CPU path: SSIM >= 0.999 and a bounded largest difference. Databases: the
//! precompute's `test` profile (small, so PSFs are clamped: that changes both paths alike).
#![cfg(feature = "gpu")]

mod gpu_support;

use std::path::{Path, PathBuf};

use gpu_support::{context, max_diff, render_gpu_fresh};
use psf_db::{PsfDatabase, PsfModel};
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};
use spreadlet::synth::{synthesize, SynthOptions};

/// Centre crop edge, px (the examples are 512 x 512; lavapipe in CI stays fast at this size).
const CROP: usize = 256;
/// Largest difference allowed, relative to the image's largest value (HDR highlights).
const MAX_REL_DIFF: f32 = 1e-5;

fn examples_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/examples")
}

fn test_db(model: PsfModel) -> PsfDatabase {
    let cfg = precompute::BuildConfig::new(model, precompute::Profile::Test);
    precompute::build_database(&cfg, false)
        .expect("test database")
        .0
}

/// The centre `CROP x CROP` of `g`, with the camera's sensor narrowed to keep pixels per mm.
fn crop(g: &GBuffer, cam: &Camera) -> (GBuffer, Camera) {
    let (x0, y0) = ((g.width - CROP) / 2, (g.height - CROP) / 2);
    let pick = |i: usize| (y0 + i / CROP) * g.width + x0 + i % CROP;
    let color = (0..CROP * CROP).map(|i| g.color[pick(i)]).collect();
    let depth = g
        .depth
        .as_ref()
        .map(|d| (0..CROP * CROP).map(|i| d[pick(i)]).collect());
    let motion = g
        .motion
        .as_ref()
        .map(|m| (0..CROP * CROP).map(|i| m[pick(i)]).collect());
    let out = GBuffer {
        width: CROP,
        height: CROP,
        color,
        depth,
        motion,
        acceleration: None,
        ..g.clone()
    };
    let mut c = cam.clone();
    c.sensor_width_mm *= CROP as f64 / cam.width as f64;
    c.width = CROP as u32;
    c.height = CROP as u32;
    (out, c)
}

#[test]
fn shared_examples_gpu_matches_cpu() {
    let Some(ctx) = context() else { return };
    let dir = examples_dir();
    if !dir.join("comets/input.exr").exists() {
        // The examples live outside the repository; say so loudly rather than pass silently.
        assert!(
            std::env::var("SPREADLET_REQUIRE_EXAMPLES").is_err(),
            "shared examples missing at {}",
            dir.display()
        );
        eprintln!("shared examples not found at {}: skipped", dir.display());
        return;
    }
    let thin = test_db(PsfModel::ThinLens);
    let motion = test_db(PsfModel::LensMotion);
    for name in ["comets", "fence"] {
        let g = GBuffer::read_exr(
            &dir.join(name).join("input.exr"),
            &ChannelOptions::default(),
        )
        .expect("input.exr");
        let cam = Camera::from_json_file(&dir.join(name).join("camera.json")).expect("camera");
        let (g, cam) = crop(&g, &cam);
        let dbs = if cam.has_shutter() && g.motion.is_some() {
            // The thin-lens + lens-motion pair when `DbSet` can combine them, else lens-motion
            // alone (both paths read the same combined database either way).
            DbSet::new(Some(thin.clone()), Some(motion.clone()))
                .or_else(|_| DbSet::single(motion.clone()))
                .expect("db set")
        } else {
            DbSet::single(thin.clone()).expect("db set")
        };
        let options = SynthOptions::default();
        let (cpu, cpu_stats) = synthesize(&g, &cam, &dbs, &options).expect("CPU synthesis");
        let prepared = spreadlet::Plan::new(spreadlet::Input::Flat(&g), &cam, &options)
            .and_then(|plan| plan.prepare(&dbs))
            .expect("prepared");
        let (img, stats, times) = render_gpu_fresh(ctx, prepared, &dbs);
        assert_eq!(stats.counts, cpu_stats.counts);
        let a: Vec<f32> = img.pixels.iter().flatten().copied().collect();
        let b: Vec<f32> = cpu.pixels.iter().flatten().copied().collect();
        let ssim = metrics::ssim_rgb(&a, &b, CROP, CROP).expect("ssim");
        let (d, m) = max_diff(&a, &b);
        eprintln!(
            "{name} {CROP}x{CROP}: SSIM {ssim:.6}, max diff {d:.2e} (max value {m:.2}); \
             {} sparse / {} dense / {} copied; CPU {:.0} ms, GPU {:.0} ms (splat {:.0}, integrate {:.0}, composite {:.0})",
            stats.counts.sparse, stats.counts.dense, stats.counts.copied,
            cpu_stats.times.total_ms, times.total_ms, times.splat_ms, times.integrate_ms, times.composite_ms
        );
        assert!(
            stats.counts.sparse + stats.counts.dense > 0,
            "{name}: nothing was splatted"
        );
        assert!(ssim >= 0.999, "{name}: SSIM {ssim}");
        assert!(
            d <= MAX_REL_DIFF * m.max(1.0),
            "{name}: max difference {d} (max value {m})"
        );
    }
}
