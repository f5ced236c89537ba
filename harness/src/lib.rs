//! The harness around the `spreadlet` library, reached through the `spreadlet` binary's `demo`,
//! `study` and `bench` commands: the demo on built-in data, the accuracy-against-time study,
//! the benchmarks and the one-shot device check, and the peer methods (Blender-style and
//! published DoF and MB methods) for comparison. None of it is needed to embed the renderer.

pub mod bench;
pub mod demo;
#[cfg(feature = "gpu")]
pub mod device_check;
#[cfg(feature = "gpu")]
pub mod microbench;
pub mod peer;
pub mod peer_study;
pub mod study;

use precompute::{BuildConfig, Profile};
use psf_db::PsfDatabase;
use spreadlet::baseline::without_recorded_error;
use spreadlet::dbcache;
use spreadlet::dbset::DbSet;
use spreadlet::pipeline::Effects;

/// The databases `effects` call for, through the one loader ([`spreadlet::databases::load`]: from
/// the cache, built when missing, conditioned), with `build` applied to the runtime's build
/// settings for `profile`. With `keep_sparse`, the recorded errors are dropped before
/// conditioning (see [`without_recorded_error`](spreadlet::baseline::without_recorded_error)), so no sparse PSF is swapped for a dense
/// analytic one.
pub fn cached_dbs_with(
    effects: Effects,
    profile: Profile,
    aperture: psf_db::Aperture,
    progress: bool,
    keep_sparse: bool,
    build: &dyn Fn(BuildConfig) -> BuildConfig,
) -> Result<DbSet, spreadlet::Error> {
    let dir = dbcache::cache_dir();
    let strip = |db: PsfDatabase| -> Result<PsfDatabase, spreadlet::Error> {
        Ok(without_recorded_error(&db)?)
    };
    let request = spreadlet::databases::Request {
        source: spreadlet::databases::Source::Cache { dir: &dir, profile },
        needed: effects.cheapest_model(),
        aperture,
        mask: None,
        lens: None,
        condition: true,
        adjust: Some(build),
        transform: keep_sparse.then_some(&strip as &dyn Fn(_) -> _),
        progress,
        // The lens-motion database too: studies draw moving pixels either way.
        smear_motion: false,
    };
    let on_event = |e: dbcache::CacheEvent| {
        // The builder's own bar shows progress.
        if progress && e.fraction().is_none() {
            eprintln!("{e}");
        }
    };
    spreadlet::databases::load(&request, &on_event).map(|loaded| loaded.set)
}

/// The scores of `image` against `reference` as the project reports them (SSIM, PSNR, FLIP,
/// the frame edges' brightness; `DEVELOPERS.md`): the one scoring of images in the harness.
pub fn score_images(
    image: &formats::RgbaImage,
    reference: &formats::RgbaImage,
) -> Result<metrics::Scores, metrics::MetricsError> {
    let a: &[f32] = bytemuck::cast_slice(&image.pixels);
    let b: &[f32] = bytemuck::cast_slice(&reference.pixels);
    Ok(metrics::score_rgb(a, b, image.width, image.height)?.0)
}

/// Prints what the database cache does (builds, rebuilds) on stderr; a build's progress is
/// the builder's own bar.
pub fn print_cache_event(event: spreadlet::dbcache::CacheEvent) {
    if event.fraction().is_none() {
        eprintln!("{event}");
    }
}

/// The renderer's G-buffer of what the scene renderer made (colour, planar depth, motion at
/// the frame time in pixels per frame, as the file's reader takes it), validated like any
/// other input.
pub fn gbuffer_of(
    g: &scene::GBuffer,
) -> Result<spreadlet::GBuffer, spreadlet::gbuffer::GBufferError> {
    spreadlet::GBuffer::from_planes(
        g.width,
        g.height,
        g.color_image().pixels,
        Some(g.depth.clone()),
        Some(g.motion_plane()),
    )?
    .with_acceleration(g.acceleration_plane())
}
