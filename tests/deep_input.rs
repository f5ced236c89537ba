//! Deep OpenEXR input. spreadlet's own deep scanline reader and writer are checked against the
//! OpenEXR library (its Python package, an independent implementation): the library's files
//! read back exactly, and the library reads ours exactly, in every compression the library
//! takes for deep data. A deep render of a built-in scene flattens to the flat G-buffer of the
//! same samples, and blurs better than it (each sub-pixel surface with its own depth). Bad
//! deep files are clean errors with no output.

use std::path::Path;
use std::process::Command;

use spreadlet::formats::{DeepCompression, DeepImage, DeepSample};
use spreadlet::GBuffer;
use spreadlet_e2e::{
    assert_clean_failure, assert_gpu_run_matches, assert_success, cache_dir, compare_scores,
    render_scene_128, run,
};

fn p(path: &Path) -> String {
    path.to_str().expect("utf-8 path").to_string()
}

/// The Python with the OpenEXR package, or `None` (a failure when CI requires Python).
fn python_with_openexr() -> Option<String> {
    let required = std::env::var("SPREADLET_REQUIRE_PYTHON").as_deref() == Ok("1");
    let Ok(python) = std::env::var("SPREADLET_PYTHON") else {
        assert!(
            !required,
            "SPREADLET_REQUIRE_PYTHON=1 but SPREADLET_PYTHON is not set"
        );
        eprintln!("SPREADLET_PYTHON is not set: the OpenEXR cross-check is skipped");
        return None;
    };
    let has = Command::new(&python)
        .args(["-c", "import OpenEXR"])
        .status()
        .is_ok_and(|s| s.success());
    if !has {
        assert!(
            !required,
            "SPREADLET_REQUIRE_PYTHON=1 but {python} has no OpenEXR package"
        );
        eprintln!("{python} has no OpenEXR package: the cross-check is skipped");
        return None;
    }
    Some(python)
}

fn script() -> String {
    p(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/support/deep_openexr.py"))
}

/// A pixel's samples as the script's JSON lists them (`channels` of R G B A Z ZBack
/// motion.x motion.y).
fn as_json_samples(samples: &[DeepSample], channels: &[String]) -> Vec<Vec<f64>> {
    samples
        .iter()
        .map(|s| {
            channels
                .iter()
                .map(|c| {
                    f64::from(match c.as_str() {
                        "R" => s.color[0],
                        "G" => s.color[1],
                        "B" => s.color[2],
                        "A" => s.color[3],
                        "Z" => s.depth,
                        "ZBack" => s.depth_back,
                        "motion.x" => s.motion[0],
                        "motion.y" => s.motion[1],
                        other => panic!("unexpected channel {other}"),
                    })
                })
                .collect()
        })
        .collect()
}

fn assert_same_as_json(image: &DeepImage, json: &serde_json::Value, what: &str) {
    assert_eq!(json["width"].as_u64(), Some(image.width as u64), "{what}");
    assert_eq!(json["height"].as_u64(), Some(image.height as u64), "{what}");
    let channels: Vec<String> = json["channels"]
        .as_array()
        .expect("channels")
        .iter()
        .map(|c| c.as_str().expect("name").to_string())
        .collect();
    let pixels = json["pixels"].as_array().expect("pixels");
    assert_eq!(pixels.len(), image.width * image.height, "{what}");
    for (i, pixel) in pixels.iter().enumerate() {
        let theirs: Vec<Vec<f64>> = serde_json::from_value(pixel.clone()).expect("samples");
        let ours = as_json_samples(image.pixel(i % image.width, i / image.width), &channels);
        assert_eq!(ours, theirs, "{what}: pixel {i}");
    }
}

#[test]
fn openexr_and_spreadlet_read_each_others_deep_files_exactly() {
    let Some(python) = python_with_openexr() else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let d = p(dir.path());
    let wrote = Command::new(&python)
        .args([script().as_str(), "write", d.as_str()])
        .output()
        .expect("python runs");
    assert!(
        wrote.status.success(),
        "{}",
        String::from_utf8_lossy(&wrote.stderr)
    );
    let expected: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("expected.json")).expect("expected.json"),
    )
    .expect("json");
    let files = expected.as_object().expect("files");
    assert_eq!(files.len(), 4);
    for (name, json) in files {
        let image = DeepImage::read(&dir.path().join(name)).unwrap_or_else(|e| panic!("{e}"));
        assert!(image.has_motion);
        assert_same_as_json(&image, json, name);
    }

    // Ours, in each compression, through the library.
    let ours = DeepImage::read(&dir.path().join("lib_none.exr")).expect("reads");
    for (name, compression) in [
        ("ours_none.exr", DeepCompression::None),
        ("ours_rle.exr", DeepCompression::Rle),
        ("ours_zips.exr", DeepCompression::Zips),
    ] {
        let path = dir.path().join(name);
        ours.write(&path, compression).expect("writes");
        let read = Command::new(&python)
            .args([script().as_str(), "read", p(&path).as_str()])
            .output()
            .expect("python runs");
        assert!(
            read.status.success(),
            "OpenEXR cannot read {name}: {}",
            String::from_utf8_lossy(&read.stderr)
        );
        let json: serde_json::Value = serde_json::from_slice(&read.stdout).expect("json");
        assert_same_as_json(&ours, &json, name);
    }
}

fn synth(input: &Path, camera: &Path, out: &Path, backend: &str) -> std::process::Output {
    run(
        "spreadlet",
        &[
            "synth",
            "-q",
            "--backend",
            backend,
            "--input",
            &p(input),
            "--camera",
            &p(camera),
            "--out",
            &p(out),
        ],
        &cache_dir(),
    )
}

/// `synth` on the CPU from `dir`'s flat G-buffer (`g.exr`) and deep image (`deep.exr`) with
/// its camera, each scored against its reference (`ref.exr`): `[flat, deep]`, each (SSIM,
/// FLIP mean), printed under `what`.
fn flat_and_deep_scores(dir: &Path, what: &str) -> [(f64, f64); 2] {
    let camera = dir.join("cam.json");
    let reference = dir.join("ref.exr");
    let scores = ["g", "deep"].map(|input| {
        let out = dir.join(format!("{input}_out.exr"));
        assert_success(&synth(
            &dir.join(format!("{input}.exr")),
            &camera,
            &out,
            "cpu",
        ));
        compare_scores(&out, &reference)
    });
    let [(s1, f1), (s2, f2)] = scores;
    eprintln!("{what} 128 px: flat SSIM {s1:.4} FLIP {f1:.4}; deep SSIM {s2:.4} FLIP {f2:.4}");
    scores
}

#[test]
fn a_deep_render_flattens_to_its_gbuffer_and_blurs_better_than_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    // Small bright lights far behind and close in front of the focus plane around a sharp
    // sphere before a textured wall.
    let deep_path = p(&dir.path().join("deep.exr"));
    render_scene_128(dir.path(), "bokeh", &["--deep", &deep_path]);
    let deep = DeepImage::read(&dir.path().join("deep.exr")).expect("deep");
    let flat = GBuffer::read_exr(&dir.path().join("g.exr"), &Default::default()).expect("flat");
    assert!(
        deep.max_samples_per_pixel() >= 2,
        "no edge pixel was kept apart"
    );
    let worst = deep
        .flatten()
        .iter()
        .zip(&flat.color)
        .flat_map(|(a, b)| (0..4).map(move |k| (a[k] - b[k]).abs() / b[k].abs().max(1.0)))
        .fold(0.0f32, f32::max);
    assert!(
        worst < 1e-5,
        "the deep image flattens {worst} away from the G-buffer"
    );

    let [(s1, f1), (s2, f2)] = flat_and_deep_scores(dir.path(), "bokeh");
    assert!(s2 > s1 && f2 < f1, "flat {s1}/{f1}, deep {s2}/{f2}");

    // The GPU runs the same records through its stages (lavapipe in CI).
    let gpu = dir.path().join("gpu.exr");
    let (camera, from_deep) = (dir.path().join("cam.json"), dir.path().join("deep_out.exr"));
    let ran = synth(&dir.path().join("deep.exr"), &camera, &gpu, "gpu");
    assert_gpu_run_matches(&ran, &gpu, &from_deep, "the deep input");
}

/// A moving opaque occluder in a deep image streaks beyond its silhouette as it does from the
/// flat G-buffer of the same render: the background it uncovers over the shutter, which a
/// deep image at the frame time does not hold, is continued from beside it. Without that the
/// car's streaks stopped at its outline (a hard silhouette; deep SSIM 0.9913 against the flat
/// input's 0.9934 here).
#[test]
fn a_moving_occluder_in_a_deep_image_streaks_past_its_outline() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scene/scenes/hard/car-on-road.json");
    let deep_path = p(&dir.path().join("deep.exr"));
    render_scene_128(dir.path(), &p(&scene), &["--deep", &deep_path]);
    let [(s1, f1), (s2, f2)] = flat_and_deep_scores(dir.path(), "car-on-road");
    assert!(s2 >= s1 && f2 <= f1, "flat {s1}/{f1}, deep {s2}/{f2}");
}

fn sample(a: f32, z: f32) -> DeepSample {
    DeepSample {
        color: [0.5 * a, 0.5 * a, 0.5 * a, a],
        depth: z,
        depth_back: z,
        motion: [0.0; 2],
    }
}

#[test]
fn bad_deep_files_are_clean_errors_without_output() {
    let dir = tempfile::tempdir().expect("temp dir");
    let camera = dir.path().join("cam.json");
    std::fs::write(
        &camera,
        r#"{"width": 4, "height": 2, "focal_length_mm": 50, "f_stop": 2,
            "focus_distance": 2, "sensor_width_mm": 36, "scene_unit_mm": 1000,
            "shutter_frames": 0}"#,
    )
    .expect("camera");
    let good = |depths: [f32; 2]| DeepImage {
        width: 4,
        height: 2,
        overscan: Default::default(),
        offsets: vec![0, 2, 3, 4, 5, 6, 7, 8, 9],
        samples: std::iter::once(sample(0.5, depths[0]))
            .chain(std::iter::once(sample(1.0, depths[1])))
            .chain((0..7).map(|_| sample(1.0, 3.0)))
            .collect(),
        has_motion: false,
        dropped_samples: 0,
        channels_present: Vec::new(),
    };
    // A valid file renders.
    let valid = dir.path().join("valid.exr");
    good([1.0, 2.0])
        .write(&valid, DeepCompression::Zips)
        .expect("writes");
    assert_success(&synth(&valid, &camera, &dir.path().join("ok.exr"), "cpu"));

    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "unsorted.exr",
            good([2.0, 1.0]).to_bytes(DeepCompression::Rle),
            "sorted front to back",
        ),
        (
            "negative.exr",
            good([-1.0, 2.0]).to_bytes(DeepCompression::None),
            "depth must be positive",
        ),
        (
            "truncated.exr",
            {
                let bytes = good([1.0, 2.0]).to_bytes(DeepCompression::None);
                bytes[..bytes.len() - 6].to_vec()
            },
            "bytes, but the file has",
        ),
        (
            "overstated.exr",
            {
                // The first scanline's last cumulative count, one more than the samples held.
                let mut bytes = good([1.0, 2.0]).to_bytes(DeepCompression::None);
                // The chunks end the file: 28 bytes of sizes, 16 of counts and 20 per sample each.
                let first_chunk = bytes.len() - 2 * 28 - 2 * 16 - (5 + 4) * 20;
                let at = first_chunk + 28 + 12;
                let count = i32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
                bytes[at..at + 4].copy_from_slice(&(count + 1).to_le_bytes());
                bytes
            },
            "samples of 20 bytes need",
        ),
    ];
    for (name, bytes, needle) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).expect("write");
        let out = dir.path().join(format!("out-{name}"));
        let ran = synth(&path, &camera, &out, "cpu");
        assert_clean_failure(&ran, needle);
        assert!(!out.exists(), "{name}: a failed run left an output");
    }
    // A deep file is the frame's only input.
    let ran = run(
        "spreadlet",
        &[
            "synth",
            "-q",
            "--input",
            &p(&valid),
            "--input",
            &p(&valid),
            "--camera",
            &p(&camera),
            "--out",
            &p(&dir.path().join("two.exr")),
        ],
        &cache_dir(),
    );
    assert_clean_failure(&ran, "only --input");
}
