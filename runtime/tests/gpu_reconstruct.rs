//! Reconstruction on the GPU (`spreadlet::gpu::render_gpu` of stochastic frames) matches the CPU path
//! (`spreadlet::reconstruct::reconstruct`) on a small built-in scene with defocus and motion:
//! the same records, SSIM >= 0.999 and a bounded largest difference.
#![cfg(feature = "gpu")]

mod gpu_support;

use gpu_support::{context, max_diff, render_gpu_fresh};
use psf_db::PsfModel;
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::reconstruct::reconstruct;
use spreadlet::synth::SynthOptions;
use spreadlet::{Input, Plan};

/// Frame edge, px (small: lavapipe in CI).
const SIZE: u32 = 96;
/// Largest difference allowed, relative to the image's largest value (atomic adds in another
/// order than the CPU's).
const MAX_REL_DIFF: f32 = 1e-4;

#[test]
fn gpu_reconstruction_matches_cpu() {
    matches_cpu(2, true);
}

/// From 8 spp the image is also leaned towards each pixel's own samples
/// (`spreadlet::sample_mean`), after the GPU's stages as after the CPU's.
#[test]
fn gpu_reconstruction_leaned_towards_the_samples_matches_cpu() {
    let (Some(leaned), Some(drawn)) = (matches_cpu(8, true), matches_cpu(8, false)) else {
        return;
    };
    assert_ne!(leaned, drawn, "the lean changed nothing at 8 spp");
}

/// Reconstructs `spp` samples per pixel of `crossing` on the CPU and the GPU, checks that they
/// match, and returns the GPU's image (`None` without a GPU).
fn matches_cpu(spp: usize, lean: bool) -> Option<Vec<f32>> {
    let ctx = context()?;
    let scene = scene::builtin("crossing")
        .and_then(|s| s.with_size(SIZE, SIZE))
        .expect("scene");
    let camera = Camera::from_json_str(&scene.camera_json()).expect("camera");
    let render = scene::RenderOptions {
        seed: 3,
        progress: false,
        ..Default::default()
    };
    let frames = scene::render_stochastic(&scene, spp, &render).expect("frames");
    let db = |m| {
        precompute::build_database(
            &precompute::BuildConfig::new(m, precompute::Profile::Test),
            false,
        )
        .expect("test database")
        .0
    };
    let dbs =
        DbSet::new(Some(db(PsfModel::ThinLens)), Some(db(PsfModel::LensMotion))).expect("db set");
    let mut options = SynthOptions::default();
    options.classify.lean_to_sample_means = lean;
    let (cpu, cpu_stats) = reconstruct(&frames, &camera, &dbs, &options).expect("CPU");
    let prepared = Plan::new(Input::samples(&frames), &camera, &options)
        .and_then(|plan| plan.prepare(&dbs))
        .expect("prepared");
    let (img, stats, _) = render_gpu_fresh(ctx, prepared, &dbs);
    assert_eq!(stats.counts, cpu_stats.counts);
    assert!(
        stats.defocus && stats.motion,
        "the scene calls for both effects"
    );
    assert!(
        stats.counts.sparse + stats.counts.dense > 0,
        "nothing splatted"
    );
    let a: Vec<f32> = img.pixels.iter().flatten().copied().collect();
    let b: Vec<f32> = cpu.pixels.iter().flatten().copied().collect();
    let n = SIZE as usize;
    let ssim = metrics::ssim_rgb(&a, &b, n, n).expect("ssim");
    let (d, m) = max_diff(&a, &b);
    eprintln!("reconstruction GPU vs CPU: SSIM {ssim:.6}, max diff {d:.2e} (max {m:.2})");
    assert!(ssim >= 0.999, "SSIM {ssim}");
    assert!(
        d <= MAX_REL_DIFF * m.max(1.0),
        "max difference {d} (max {m})"
    );
    Some(a)
}
