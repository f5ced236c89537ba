//! Shared fixtures of the runtime's integration tests: Test-profile databases built once per
//! test binary, and small G-buffers.

#![allow(dead_code)]

use std::sync::OnceLock;

use std::path::Path;

use precompute::{build_database, BuildConfig, Profile};
use psf_db::{PsfDatabase, PsfModel};
use spreadlet::camera::Camera;
use spreadlet::gbuffer::GBuffer;

/// The Test-profile database of `model`, built once per test binary and conditioned as the
/// `spreadlet` binary conditions it.
pub fn test_db(model: PsfModel) -> &'static PsfDatabase {
    static DBS: [OnceLock<PsfDatabase>; 3] = [OnceLock::new(), OnceLock::new(), OnceLock::new()];
    let slot = match model {
        PsfModel::ThinLens => &DBS[0],
        PsfModel::LensMotion => &DBS[1],
        PsfModel::PhysicalLens => &DBS[2],
    };
    slot.get_or_init(|| {
        spreadlet::condition::condition(raw_test_db(model))
            .expect("condition")
            .0
    })
}

/// The build settings of the Test-profile database of `model`.
pub fn test_config(model: PsfModel) -> BuildConfig {
    let mut cfg = BuildConfig::new(model, Profile::Test);
    if model == PsfModel::PhysicalLens {
        // The Test profile's space has two eccentricity boxes, each half the sensor: these
        // tests' frames were made with each box's PSF pre-filtered over it, which keeps their
        // sparse PSFs and the specks they look for (the profiles that ship trace each PSF at
        // the middle of its eccentricities).
        cfg.lens = Some(precompute::LensOptions {
            prefilter_eccentricity: true,
            ..precompute::LensOptions::default()
        });
    }
    cfg
}

/// The Test-profile database of `model` as the precompute built it, once per test binary.
pub fn raw_test_db(model: PsfModel) -> &'static PsfDatabase {
    static DBS: [OnceLock<PsfDatabase>; 3] = [OnceLock::new(), OnceLock::new(), OnceLock::new()];
    let slot = match model {
        PsfModel::ThinLens => &DBS[0],
        PsfModel::LensMotion => &DBS[1],
        PsfModel::PhysicalLens => &DBS[2],
    };
    slot.get_or_init(|| {
        let cfg = test_config(model);
        match build_database(&cfg, false) {
            Ok((db, _)) => db,
            Err(e) => panic!("building the {} test database failed: {e}", model.name()),
        }
    })
}

/// The database `spreadlet synth` and `reconstruct` use by default (quick profile, circular
/// aperture), conditioned, from the cache (built there once): the Test profile's coarse cells
/// would hide what these tests look at behind the PSF's own spread.
pub fn quick_db(model: PsfModel) -> PsfDatabase {
    use spreadlet::dbcache::{build_config, cache_dir, cached_database, CACHE_ENV};
    let cfg = build_config(model, Profile::Quick, 0);
    // Tests run in runtime/: share the workspace root's cache unless one is set.
    let dir = if std::env::var_os(CACHE_ENV).is_some() {
        cache_dir()
    } else {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../.spreadlet-cache")
    };
    let db = cached_database(&cfg, &dir, false, &|_| {})
        .expect("quick database")
        .0;
    spreadlet::condition::condition(&db).expect("condition").0
}

/// A camera of `w x h` pixels: 50 mm on a 36 mm sensor, f/2 focused at 1 m when `lens`.
pub fn camera(w: u32, h: u32, lens: bool, shutter: f64) -> Camera {
    Camera {
        width: w,
        height: h,
        focal_length_mm: 50.0,
        sensor_width_mm: 36.0,
        f_stop: lens.then_some(2.0),
        focus_distance: lens.then_some(1.0),
        aperture_blades: 0,
        aperture_rotation_deg: 0.0,
        aperture_ratio: 1.0,
        aperture_image: None,
        lens: None,
        shutter_frames: shutter,
        scene_unit_mm: 1000.0,
    }
}

/// The depth (scene units) at which `camera` gives a CoC radius of `coc_px` in front of the
/// focus plane (any radius is reachable there).
pub fn depth_for_coc(camera: &Camera, coc_px: f64) -> f64 {
    let lens = camera.thin_lens().expect("lens");
    // signed r = k (1 - s/d) = -coc  =>  d = s / (1 + coc/k)
    lens.focus_distance / (1.0 + coc_px / lens.coc_scale_px)
}

/// A black, transparent `w x h` G-buffer with one pixel of colour `c` at `(x, y)`, all at
/// depth `depth`, motion `motion` everywhere.
pub fn one_pixel(
    w: usize,
    h: usize,
    x: usize,
    y: usize,
    c: [f32; 4],
    depth: f32,
    motion: [f32; 2],
) -> GBuffer {
    let mut color = vec![[0.0; 4]; w * h];
    color[y * w + x] = c;
    GBuffer::from_planes(
        w,
        h,
        color,
        Some(vec![depth; w * h]),
        Some(vec![motion; w * h]),
    )
    .expect("valid g-buffer")
}

/// The renderer's G-buffer of what the scene renderer made, validated like any other input.
#[allow(dead_code)]
pub fn gbuffer_of(g: &scene::GBuffer) -> GBuffer {
    GBuffer::from_planes(
        g.width,
        g.height,
        g.color_image().pixels,
        Some(g.depth.clone()),
        Some(g.motion_plane()),
    )
    .and_then(|g2| g2.with_acceleration(g.acceleration_plane()))
    .expect("a valid scene G-buffer")
}

/// A camera for the physical-lens database `db`: its lens, sensor and focus, `h` rows.
pub fn physical_camera(db: &PsfDatabase, h: usize) -> Camera {
    let lens = db.header().lens.clone().expect("prescription");
    Camera {
        width: lens.image_width_px,
        height: h as u32,
        focal_length_mm: lens.focal_length_mm,
        sensor_width_mm: lens.sensor_width_mm,
        f_stop: Some(4.0),
        focus_distance: Some(lens.focus_distance),
        aperture_blades: 0,
        aperture_rotation_deg: 0.0,
        aperture_ratio: 1.0,
        aperture_image: None,
        lens: None,
        shutter_frames: 0.0,
        scene_unit_mm: lens.scene_unit_mm,
    }
}

/// A scene renderer scene (JSON) rendered at `spp` samples per pixel with `seed`, its
/// 256-spp reference, and the frames reconstructed on the CPU with the Quick-profile
/// thin-lens and lens-motion databases: (camera, frames, reference, reconstruction).
pub fn reconstruct_scene(
    json: &str,
    spp: usize,
    seed: u64,
) -> (
    Camera,
    spreadlet::StochasticFrames,
    spreadlet::RgbaImage,
    spreadlet::RgbaImage,
) {
    let (scene, camera, frames) = scene_frames(json, spp, seed);
    let render = scene::RenderOptions {
        seed,
        ..Default::default()
    };
    let reference = scene::render_reference(&scene, 256, &render).expect("reference");
    let image = reconstruct_quick(&frames, &camera);
    (camera, frames, reference, image)
}

/// A scene renderer scene (JSON), its camera, and its stochastic frames at `spp` samples per
/// pixel with `seed`.
pub fn scene_frames(
    json: &str,
    spp: usize,
    seed: u64,
) -> (scene::Scene, Camera, spreadlet::StochasticFrames) {
    let scene = scene::Scene::from_json(json, "test scene").expect("scene");
    let camera = Camera::from_json_str(&scene.camera_json()).expect("camera");
    let render = scene::RenderOptions {
        seed,
        ..Default::default()
    };
    let frames = scene::render_stochastic(&scene, spp, &render).expect("frames");
    (scene, camera, frames)
}

/// `frames` reconstructed on the CPU with the Quick-profile thin-lens and lens-motion
/// databases and the default options.
pub fn reconstruct_quick(
    frames: &spreadlet::StochasticFrames,
    camera: &Camera,
) -> spreadlet::RgbaImage {
    reconstruct_quick_with_stats(frames, camera).0
}

/// [`reconstruct_quick`], with the call's statistics.
pub fn reconstruct_quick_with_stats(
    frames: &spreadlet::StochasticFrames,
    camera: &Camera,
) -> (spreadlet::RgbaImage, spreadlet::SynthStats) {
    let dbs = spreadlet::dbset::DbSet::new(
        Some(quick_db(PsfModel::ThinLens)),
        Some(quick_db(PsfModel::LensMotion)),
    )
    .expect("db set");
    spreadlet::reconstruct::reconstruct(
        frames,
        camera,
        &dbs,
        &spreadlet::synth::SynthOptions::default(),
    )
    .expect("reconstruction")
}

/// Luminance (mean of R, G, B) of every pixel of `image`.
pub fn luminance(image: &spreadlet::RgbaImage) -> Vec<f64> {
    image
        .pixels
        .iter()
        .map(|p| (f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])) / 3.0)
        .collect()
}
