//! The library as an embedder sees it: the `embed` example (the README's twenty lines) runs,
//! its output is byte-identical to `spreadlet synth` with no flags, and a renderer keeps its
//! databases across frames.

use std::path::{Path, PathBuf};

use spreadlet_e2e::{assert_success, cache_dir, run};

#[allow(dead_code)]
#[path = "../runtime/examples/embed.rs"]
mod embed;

/// A small built-in scene with defocus and motion, as a G-buffer file and its camera file.
fn scene_input(dir: &Path) -> (PathBuf, PathBuf) {
    let scene = scene::builtin("crossing")
        .and_then(|s| s.with_size(96, 96))
        .expect("scene");
    let options = scene::RenderOptions {
        seed: 3,
        ..Default::default()
    };
    let input = dir.join("input.exr");
    scene::render_gbuffer(&scene, 4, &options)
        .expect("render")
        .write_exr(&input)
        .expect("write G-buffer");
    let camera = dir.join("camera.json");
    std::fs::write(&camera, scene.camera_json()).expect("camera");
    (input, camera)
}

/// `spreadlet synth` with no flags and the library with default options write the same bytes.
fn assert_cli_equals_library(input: &Path, camera: &Path, dir: &Path) {
    let (cli_out, lib_out) = (dir.join("cli.exr"), dir.join("library.exr"));
    let p = |p: &Path| p.to_str().expect("utf-8 path").to_string();
    let out = run(
        "spreadlet",
        &[
            "synth",
            "-q",
            "--input",
            &p(input),
            "--camera",
            &p(camera),
            "--out",
            &p(&cli_out),
        ],
        &cache_dir(),
    );
    assert_success(&out);
    // The example reads the cache from $SPREADLET_CACHE as the binary does.
    std::env::set_var("SPREADLET_CACHE", cache_dir());
    embed::run(input, camera, &lib_out).expect("the embed example runs");
    let (a, b) = (
        std::fs::read(&cli_out).expect("CLI output"),
        std::fs::read(&lib_out).expect("library output"),
    );
    assert!(
        a == b,
        "{}: the CLI and the library differ ({} and {} bytes)",
        input.display(),
        a.len(),
        b.len()
    );
}

#[test]
fn the_embed_example_writes_what_the_cli_writes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (input, camera) = scene_input(dir.path());
    assert_cli_equals_library(&input, &camera, dir.path());
    // The shared Blender examples too, where this checkout has them.
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/examples");
    for name in ["fence", "comets"] {
        let folder = shared.join(name);
        if folder.join("input.exr").exists() {
            let out = dir.path().join(name);
            std::fs::create_dir_all(&out).expect("dir");
            assert_cli_equals_library(&folder.join("input.exr"), &folder.join("camera.json"), &out);
        }
    }
}

/// The scene input's G-buffer and camera (in a temporary folder, kept alive by the first
/// value), and a CPU renderer over the quick databases of the cache.
fn cpu_renderer_on_scene() -> (
    tempfile::TempDir,
    spreadlet::GBuffer,
    spreadlet::Camera,
    spreadlet::Renderer,
) {
    use spreadlet::{Backend, Camera, GBuffer, Renderer, RendererOptions};
    let dir = tempfile::tempdir().expect("temp dir");
    let (input, camera) = scene_input(dir.path());
    let gbuffer = GBuffer::read_exr(&input, &Default::default()).expect("G-buffer");
    let camera = Camera::from_json_file(&camera).expect("camera");
    let renderer = Renderer::new(RendererOptions {
        backend: Backend::Cpu,
        databases: spreadlet::DbSource::Cache {
            dir: cache_dir(),
            profile: precompute::Profile::Quick,
        },
        ..Default::default()
    })
    .expect("renderer");
    (dir, gbuffer, camera, renderer)
}

#[test]
fn a_renderer_loads_databases_once_for_a_sequence() {
    use spreadlet::SynthOptions;
    let (_dir, gbuffer, camera, mut renderer) = cpu_renderer_on_scene();
    let first = renderer
        .synthesize(&gbuffer, &camera, &SynthOptions::default())
        .expect("frame 1");
    assert!(
        !first.databases.is_empty(),
        "the first frame loads databases"
    );
    let second = renderer
        .synthesize(&gbuffer, &camera, &SynthOptions::default())
        .expect("frame 2");
    assert!(second.databases.is_empty(), "the second frame reloaded");
    assert_eq!(renderer.database_loads(), 1);
    assert_eq!(first.image, second.image, "the same frame twice differs");
    // A still frame after a moving one keeps the lens-motion set (it serves defocus alone).
    let mut still = gbuffer.clone();
    if let Some(m) = still.motion.as_mut() {
        m.iter_mut().for_each(|v| *v = [0.0, 0.0]);
    }
    renderer
        .synthesize(&still, &camera, &SynthOptions::default())
        .expect("still frame");
    assert_eq!(renderer.database_loads(), 1);
}

#[test]
fn a_moving_frame_loads_the_databases_it_draws_with() {
    use spreadlet::SynthOptions;
    let (_dir, gbuffer, camera, mut renderer) = cpu_renderer_on_scene();
    let models = |frame: &spreadlet::Frame| -> Vec<&str> {
        frame.databases.iter().map(|d| d.model).collect()
    };
    // Moving pixels smear the thin-lens PSF: no lens-motion database.
    let smeared = renderer
        .synthesize(&gbuffer, &camera, &SynthOptions::default())
        .expect("smeared");
    assert!(smeared.stats.counts.smeared > 0, "nothing smeared");
    assert_eq!(models(&smeared), ["thin-lens"]);
    // Asked for the lens-motion database's PSFs, the renderer loads it.
    let mut cells = SynthOptions::default();
    cells.classify.smear_motion = false;
    let from_cells = renderer
        .synthesize(&gbuffer, &camera, &cells)
        .expect("lens-motion cells");
    assert_eq!(from_cells.stats.counts.smeared, 0);
    assert_eq!(models(&from_cells), ["thin-lens", "lens-motion"]);
    assert_ne!(smeared.image, from_cells.image);
    // That set serves the smear too.
    let again = renderer
        .synthesize(&gbuffer, &camera, &SynthOptions::default())
        .expect("smeared again");
    assert!(again.databases.is_empty(), "reloaded");
    assert_eq!(again.image, smeared.image);
}

#[test]
fn options_out_of_range_are_errors_naming_the_option() {
    use spreadlet::ClassifyOptions;
    let mut options = spreadlet::SynthOptions {
        classify: ClassifyOptions {
            layers: 0,
            ..Default::default()
        },
        ..Default::default()
    };
    let e = options.validate().expect_err("0 layers").to_string();
    assert!(e.contains("--layers"), "{e}");
    options.classify.layers = 8;
    options.classify.soft_layers = Some(f32::NAN);
    let e = options.validate().expect_err("NaN soft layers").to_string();
    assert!(e.contains("--soft-layers"), "{e}");
    options.classify.soft_layers = Some(1.0);
    for bad in [0.0, 0.5, -3.0, f32::NAN] {
        options.classify.coarse_above_px = bad;
        let e = options.validate().expect_err("CoC threshold").to_string();
        assert!(e.contains("--coarse-above"), "{bad}: {e}");
    }
    options.classify.coarse_above_px = 32.0;
    options.validate().expect("a CoC of 32 px");
}
