//! Files: stochastic frames and G-buffers round-trip, the same seed gives the same bytes for
//! any thread count, bad files give errors, and the builtin scenes render.

use std::path::Path;

use scene::{
    builtin, render_gbuffer, render_reference, render_stochastic, GBuffer, RenderOptions,
    RgbaImage, StochasticFrames, BUILTIN_NAMES,
};

fn small(name: &str) -> scene::Scene {
    builtin(name)
        .and_then(|s| s.with_size(24, 16))
        .expect("builtin scene")
}

fn render_all(dir: &Path, tag: &str, seed: u64) -> Vec<Vec<u8>> {
    let scene = small("crossing");
    let options = RenderOptions {
        seed,
        ..Default::default()
    };
    let paths = ["g", "s", "r"].map(|p| dir.join(format!("{tag}-{p}.exr")));
    render_gbuffer(&scene, 4, &options)
        .and_then(|g| g.write_exr(&paths[0]))
        .expect("gbuffer");
    render_stochastic(&scene, 3, &options)
        .and_then(|s| Ok(s.write_exr(&paths[1])?))
        .expect("stochastic");
    render_reference(&scene, 16, &options)
        .and_then(|r| Ok(r.write_exr(&paths[2])?))
        .expect("reference");
    paths
        .iter()
        .map(|p| std::fs::read(p).expect("written file"))
        .collect()
}

#[test]
fn same_seed_same_bytes_for_any_thread_count() {
    let dir = tempfile::tempdir().expect("temp dir");
    let a = render_all(dir.path(), "a", 42);
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let b = one_thread.install(|| render_all(dir.path(), "b", 42));
    assert_eq!(a, b, "same seed, different bytes");
    let c = render_all(dir.path(), "c", 43);
    for i in 0..3 {
        assert_ne!(a[i], c[i], "file {i} ignores the seed");
    }
    // No temporary files left behind.
    let leftovers: Vec<_> = std::fs::read_dir(dir.path())
        .expect("list")
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty());
}

#[test]
fn stochastic_reader_round_trips_the_writer() {
    let scene = small("rotating");
    let frames = render_stochastic(
        &scene,
        5,
        &RenderOptions {
            seed: 1,
            ..Default::default()
        },
    )
    .expect("render");
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("frames.exr");
    frames.write_exr(&path).expect("write");
    let back = StochasticFrames::read_exr(&path).expect("read");
    assert_eq!(back, frames);
    // Sample k of a pixel sits in row k * height + y of the file (docs/STOCHASTIC.md).
    let mut channels = scene::exr_io::read_channels(&path).expect("channels");
    assert_eq!((channels.width, channels.height), (24, 16 * 5));
    let time = channels.take("time", &path).expect("time");
    let (x, y, k) = (7, 11, 3);
    assert_eq!(time[(k * 16 + y) * 24 + x], frames.pixel(x, y)[k].time);
    // Stochastic samples are spread over the shutter and the lens.
    let shutter = scene.camera.spec.shutter_frames as f32;
    assert!(frames.samples.iter().all(|s| s.time.abs() <= 0.5 * shutter));
    assert!(frames.samples.iter().any(|s| s.time > 0.3 * shutter));
    assert!(frames.samples.iter().any(|s| s.time < -0.3 * shutter));
}

#[test]
fn gbuffer_and_reference_round_trip() {
    let scene = small("occluder");
    let options = RenderOptions::default();
    let dir = tempfile::tempdir().expect("temp dir");
    let g = render_gbuffer(&scene, 4, &options).expect("gbuffer");
    let path = dir.path().join("g.exr");
    g.write_exr(&path).expect("write");
    assert_eq!(GBuffer::read_exr(&path).expect("read"), g);
    let names: Vec<String> = scene::exr_io::read_channels(&path)
        .expect("channels")
        .data
        .into_keys()
        .collect();
    for c in [
        "ViewLayer.Combined.R",
        "ViewLayer.Combined.A",
        "ViewLayer.Depth.Z",
        "ViewLayer.Vector.X",
        "ViewLayer.Vector.W",
    ] {
        assert!(names.iter().any(|n| n == c), "missing {c} in {names:?}");
    }
    let r = render_reference(&scene, 4, &options).expect("reference");
    let path = dir.path().join("r.exr");
    r.write_exr(&path).expect("write");
    assert_eq!(RgbaImage::read_exr(&path).expect("read"), r);
}

#[test]
fn wrong_files_are_errors_not_panics() {
    let dir = tempfile::tempdir().expect("temp dir");
    let garbage = dir.path().join("garbage.exr");
    std::fs::write(&garbage, b"not an exr at all").expect("write");
    assert!(StochasticFrames::read_exr(&garbage).is_err());
    assert!(GBuffer::read_exr(&garbage).is_err());
    // A G-buffer is not a stochastic-frames file.
    let scene = small("bokeh");
    let g = render_gbuffer(&scene, 1, &RenderOptions::default()).expect("gbuffer");
    let path = dir.path().join("g.exr");
    g.write_exr(&path).expect("write");
    let err = StochasticFrames::read_exr(&path).expect_err("not stochastic");
    assert!(err.to_string().contains("spreadlet"), "{err}");
    // A truncated stochastic file.
    let frames = render_stochastic(&scene, 2, &RenderOptions::default()).expect("render");
    let path = dir.path().join("s.exr");
    frames.write_exr(&path).expect("write");
    let bytes = std::fs::read(&path).expect("read");
    std::fs::write(&path, &bytes[..bytes.len() / 2]).expect("truncate");
    assert!(StochasticFrames::read_exr(&path).is_err());
    assert!(render_stochastic(&scene, 0, &RenderOptions::default()).is_err());
}

#[test]
fn builtin_scenes_render_something() {
    for name in BUILTIN_NAMES {
        let scene = small(name);
        let r = render_reference(&scene, 8, &RenderOptions::default()).expect("render");
        let lit = r
            .pixels
            .iter()
            .filter(|p| p[0] + p[1] + p[2] > 0.01)
            .count();
        assert!(lit > r.pixels.len() / 4, "{name}: only {lit} lit pixels");
        assert!(r.pixels.iter().all(|p| p.iter().all(|v| v.is_finite())));
    }
}

#[test]
fn the_hard_case_scene_files_load_and_render() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/hard");
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .expect("scenes/hard")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    names.sort();
    assert!(names.len() >= 9, "{} scene files", names.len());
    for path in names {
        let scene = scene::Scene::load(&path)
            .and_then(|s| s.with_size(24, 24))
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let r = render_reference(&scene, 4, &RenderOptions::default()).expect("render");
        assert!(
            r.pixels.iter().all(|p| p.iter().all(|v| v.is_finite())),
            "{}",
            path.display()
        );
    }
}
