//! Helpers shared by the GPU test binaries.
#![allow(dead_code)]

use std::sync::OnceLock;

use poisson::Plane;
use spreadlet::gpu::GpuContext;

/// The process-wide GPU context; `None` (test skipped, with a message) when there is no
/// adapter and `SPREADLET_REQUIRE_GPU` is not `1`; a panic (test failure) when it is.
pub fn context() -> Option<&'static GpuContext> {
    static CTX: OnceLock<Option<GpuContext>> = OnceLock::new();
    let ctx = CTX
        .get_or_init(|| match GpuContext::new() {
            Ok(c) => c,
            Err(e) => panic!("GPU required but unavailable: {e}"),
        })
        .as_ref();
    if ctx.is_none() {
        eprintln!("no GPU adapter: test skipped (SPREADLET_REQUIRE_GPU=1 makes this a failure)");
    }
    ctx
}

/// A deterministic pseudo-random plane with values in [-1, 1) (xorshift, seeded).
pub fn noise_plane(width: usize, height: usize, seed: u64) -> Plane {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    Plane::from_fn(width, height, |_, _| {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    })
}

/// Largest absolute difference and largest absolute value of `b`.
pub fn max_diff(a: &[f32], b: &[f32]) -> (f32, f32) {
    assert_eq!(a.len(), b.len());
    let d = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max);
    let m = b.iter().map(|v| v.abs()).fold(0.0, f32::max);
    (d, m)
}

/// The GPU device's image of a flat G-buffer, prepared as the CPU device's.
pub fn synthesize_gpu(
    gpu: &mut spreadlet::gpu::GpuSynthesizer,
    gbuffer: &spreadlet::GBuffer,
    camera: &spreadlet::Camera,
    dbs: &spreadlet::DbSet,
    options: &spreadlet::SynthOptions,
) -> Result<
    (
        spreadlet::RgbaImage,
        spreadlet::SynthStats,
        spreadlet::gpu::GpuStageTimes,
    ),
    spreadlet::Error,
> {
    let prepared =
        spreadlet::Plan::new(spreadlet::Input::Flat(gbuffer), camera, options)?.prepare(dbs)?;
    Ok(spreadlet::gpu::render_gpu(gpu, prepared, dbs)?)
}

/// The GPU device's image of a prepared frame, drawn by a synthesizer made for the database
/// its records index: the set's, or the frame's own where it has PSFs of its own (moving
/// pixels' PSFs smeared along their motion), as `Renderer` does.
pub fn render_gpu_fresh(
    ctx: &GpuContext,
    prepared: spreadlet::PreparedFrame,
    dbs: &spreadlet::DbSet,
) -> (
    spreadlet::RgbaImage,
    spreadlet::SynthStats,
    spreadlet::gpu::GpuStageTimes,
) {
    use spreadlet::gpu::{GpuSynthOptions, GpuSynthesizer};
    let mut gpu = GpuSynthesizer::for_database(
        ctx,
        prepared.database_or(dbs.combined.as_ref()),
        GpuSynthOptions::from_synth(prepared.options()),
    )
    .expect("GPU synthesizer");
    spreadlet::gpu::render_gpu(&mut gpu, prepared, dbs).expect("GPU synthesis")
}
