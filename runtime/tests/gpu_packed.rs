//! A frame whose smeared PSF images are kept packed (for the CPU splat alone) is refused by the
//! GPU path with an error that says so, and the same frame classified for the GPU draws there
//! what the CPU draws from the packed images.
#![cfg(feature = "gpu")]

mod gpu_support;

use gpu_support::{context, max_diff, render_gpu_fresh};
use psf_db::PsfModel;
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::gpu::{GpuSynthOptions, GpuSynthesizer};
use spreadlet::synth::{render_cpu, SynthOptions};
use spreadlet::{Input, Plan};

/// Frame edge, px (small: lavapipe in CI).
const SIZE: usize = 64;

/// A checkered disc spinning about the frame's centre at the focus distance, over a still wall.
fn spinning_disc() -> GBuffer {
    let c = SIZE as f64 / 2.0;
    let (mut color, mut depth, mut motion) = (Vec::new(), Vec::new(), Vec::new());
    for y in 0..SIZE {
        for x in 0..SIZE {
            let (dx, dy) = (x as f64 + 0.5 - c, y as f64 + 0.5 - c);
            if dx.hypot(dy) < 24.0 {
                let v = if (x / 4 + y / 4) % 2 == 0 { 0.9 } else { 0.2 };
                color.push([v, 0.5 * v, 0.1, 1.0]);
                depth.push(1.0);
                motion.push([(-0.5 * dy) as f32, (0.5 * dx) as f32]);
            } else {
                color.push([0.3, 0.3, 0.35, 1.0]);
                depth.push(3.0);
                motion.push([0.0, 0.0]);
            }
        }
    }
    GBuffer::from_planes(SIZE, SIZE, color, Some(depth), Some(motion)).expect("g-buffer")
}

#[test]
fn packed_images_are_for_the_cpu_alone() {
    let Some(ctx) = context() else { return };
    let camera = Camera::from_json_str(
        r#"{"width": 64, "height": 64, "focal_length_mm": 50, "sensor_width_mm": 36,
            "f_stop": 2.0, "focus_distance": 1.0, "shutter_frames": 1.0}"#,
    )
    .expect("camera");
    let thin = precompute::build_database(
        &precompute::BuildConfig::new(PsfModel::ThinLens, precompute::Profile::Test),
        false,
    )
    .expect("test database")
    .0;
    let dbs = DbSet::new(Some(thin), None).expect("db set");
    let g = spinning_disc();
    let prepare = |pack: bool| {
        let mut options = SynthOptions::default();
        options.classify.pack_images = pack;
        Plan::new(Input::Flat(&g), &camera, &options)
            .and_then(|plan| plan.prepare(&dbs))
            .expect("prepared")
    };

    let packed = prepare(true);
    let classified = packed.classified().expect("records");
    assert!(classified.counts.smeared > 500, "{:?}", classified.counts);
    assert!(classified.packed.is_some(), "nothing packed");
    let mut gpu = GpuSynthesizer::for_database(
        ctx,
        packed.database_or(dbs.combined.as_ref()),
        GpuSynthOptions::from_synth(packed.options()),
    )
    .expect("GPU synthesizer");
    let (cpu, _) = render_cpu(packed.clone(), &dbs);
    match spreadlet::gpu::render_gpu(&mut gpu, packed, &dbs) {
        Ok(_) => panic!("the GPU path drew a frame whose images it cannot read"),
        Err(e) => assert!(e.to_string().contains("packed"), "{e}"),
    }

    let (drawn, _, _) = render_gpu_fresh(ctx, prepare(false), &dbs);
    let a: Vec<f32> = drawn.pixels.iter().flatten().copied().collect();
    let b: Vec<f32> = cpu.pixels.iter().flatten().copied().collect();
    let (diff, largest) = max_diff(&a, &b);
    assert!(largest > 0.1, "an empty frame");
    assert!(
        diff <= 1e-4 * largest,
        "GPU and packed CPU differ by {diff}"
    );
}
