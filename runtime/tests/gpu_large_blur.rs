//! Blur beyond the database's range on the GPU: the coarse levels are drawn and integrated on
//! the device, upsampled into the frame's layers and composited as on the CPU, and the image
//! is the CPU's.
#![cfg(feature = "gpu")]

mod gpu_support;
mod support;

use gpu_support::{context, max_diff, synthesize_gpu};
use psf_db::PsfModel;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::gpu::{GpuSynthOptions, GpuSynthesizer};
use spreadlet::synth::{synthesize, SynthOptions};

#[test]
fn coarse_levels_on_the_gpu_give_the_cpu_image() {
    let Some(ctx) = context() else { return };
    let db = support::test_db(PsfModel::ThinLens);
    let dbs = DbSet::single(db.clone()).expect("set");
    let (w, h) = (96usize, 64usize);
    let cam = support::camera(w as u32, h as u32, true, 0.0);
    // A checkered wall, CoC 5 px on the left (the frame's resolution) and 30 px on the right
    // (2.5 times the Test database's largest: a quarter of it), with a bright pixel in each.
    let coc_at = |x: usize| if x < w / 2 { 5.0 } else { 30.0 };
    let mut color: Vec<[f32; 4]> = (0..w * h)
        .map(|i| {
            let v = if (i % w / 8 + i / w / 8) % 2 == 0 {
                0.2
            } else {
                0.6
            };
            [v, v * 0.8, v * 0.5, 1.0]
        })
        .collect();
    color[20 * w + 20] = [8.0, 6.0, 4.0, 1.0];
    color[40 * w + 70] = [4.0, 6.0, 8.0, 1.0];
    let depths = (0..w * h)
        .map(|i| support::depth_for_coc(&cam, coc_at(i % w)) as f32)
        .collect();
    let g = GBuffer::from_planes(w, h, color, Some(depths), None).expect("g-buffer");
    let options = SynthOptions::default();

    let (cpu, cpu_stats) = synthesize(&g, &cam, &dbs, &options).expect("CPU");
    assert!(
        cpu_stats.counts.reduced > 0,
        "the right half is drawn coarse"
    );
    let mut gpu = GpuSynthesizer::for_database(
        ctx,
        dbs.combined.as_ref(),
        GpuSynthOptions::from_synth(&options),
    )
    .expect("GPU synthesizer");
    let (image, stats, _) = synthesize_gpu(&mut gpu, &g, &cam, &dbs, &options).expect("GPU");
    assert_eq!(stats.counts, cpu_stats.counts);
    let flat =
        |i: &spreadlet::RgbaImage| -> Vec<f32> { i.pixels.iter().flatten().copied().collect() };
    let (d, m) = max_diff(&flat(&image), &flat(&cpu));
    assert!(d <= 1e-3 * m.max(1.0), "GPU vs CPU: {d} (max {m})");
}
