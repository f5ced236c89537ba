//! The shared Blender examples against their Cycles references. Ignored by default: the first
//! run builds the quick databases (about a minute on 2 cores; cached in `$SPREADLET_CACHE` or
//! `./.spreadlet-cache`). Run with `cargo test --release -p runtime --test examples -- --ignored`.

use std::path::{Path, PathBuf};

use psf_db::PsfModel;
use spreadlet::camera::Camera;
use spreadlet::dbcache::{build_config, cache_dir, cached_database};
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};
use spreadlet::pipeline::{Effects, Integrator};
use spreadlet::synth::{synthesize, SynthOptions};

fn ssim_against(image: &[[f32; 4]], reference: &Path, w: usize, h: usize) -> f64 {
    let r = GBuffer::read_exr(reference, &ChannelOptions::default()).expect("reference");
    metrics::ssim_rgb(
        bytemuck::cast_slice(image),
        bytemuck::cast_slice(&r.color),
        w,
        h,
    )
    .expect("ssim")
}

fn run(scene: &str, min_ssim: f64) {
    let dir = std::env::var_os("SPREADLET_EXAMPLES")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/examples"))
        .join(scene);
    let g = GBuffer::read_exr(&dir.join("input.exr"), &ChannelOptions::default()).expect("input");
    let cam = Camera::from_json_file(&dir.join("camera.json")).expect("camera");
    let effects = Effects::of(&cam, &g);
    let load = |m| {
        let cfg = build_config(m, precompute::Profile::Quick, cam.aperture_blades);
        // Tests run in runtime/: share the workspace root's cache unless one is set.
        let dir = if std::env::var_os(spreadlet::dbcache::CACHE_ENV).is_some() {
            cache_dir()
        } else {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../.spreadlet-cache")
        };
        let db = cached_database(&cfg, &dir, true, &|_| {}).expect("db").0;
        spreadlet::condition::condition(&db).expect("condition").0
    };
    let main = (effects.cheapest_model() == Some(PsfModel::LensMotion))
        .then(|| load(PsfModel::LensMotion));
    let dbs = DbSet::new(Some(load(PsfModel::ThinLens)), main).expect("set");
    let options = SynthOptions {
        integrator: Integrator::Exact,
        ..SynthOptions::default()
    };
    let (out, _) = synthesize(&g, &cam, &dbs, &options).expect("synth");
    let ours = ssim_against(&out.pixels, &dir.join("reference.exr"), g.width, g.height);
    let blender = GBuffer::read_exr(&dir.join("blender_post.exr"), &ChannelOptions::default())
        .expect("blender_post");
    let theirs = ssim_against(
        &blender.color,
        &dir.join("reference.exr"),
        g.width,
        g.height,
    );
    println!("{scene}: ours {ours:.4}, blender_post {theirs:.4}");
    assert!(ours >= min_ssim, "{scene}: SSIM {ours:.4} < {min_ssim}");
    // Both examples must also beat Blender's own compositor.
    assert!(
        ours > theirs,
        "{scene}: SSIM {ours:.4} does not beat blender_post {theirs:.4}"
    );
}

#[test]
#[ignore = "builds the quick databases on first use (minutes on 2 cores)"]
fn fence_reaches_its_ssim_target() {
    run("fence", 0.925);
}

#[test]
#[ignore = "builds the quick databases on first use (minutes on 2 cores)"]
fn comets_reaches_its_ssim_target() {
    run("comets", 0.965);
}
