//! The `spreadlet` binary as a user runs it: its commands are listed, a pinhole frame that does
//! not move comes back unchanged without any database, `compare` scores an image against
//! itself as identical, and bad input is a clean failure. (Running here also makes `cargo test`
//! build the binary that the end-to-end tests in `tests/` run.)

use std::path::Path;
use std::process::Command;

use formats::RgbaImage;

fn spreadlet() -> Command {
    Command::new(env!("CARGO_BIN_EXE_spreadlet"))
}

/// A 16 x 12 G-buffer (colour and depth, Blender's layout) and a pinhole camera for it.
fn pinhole_input(dir: &Path) -> (RgbaImage, std::path::PathBuf, std::path::PathBuf) {
    let (w, h) = (16usize, 12usize);
    let color: Vec<[f32; 4]> = (0..w * h)
        .map(|i| [0.05 * (i % w) as f32, 0.08 * (i / w) as f32, 0.5, 1.0])
        .collect();
    let plane = |k: usize| color.iter().map(|c| c[k]).collect::<Vec<f32>>();
    let input = dir.join("input.exr");
    formats::exr_io::write_channels(
        &input,
        w,
        h,
        vec![
            ("ViewLayer.Combined.R".into(), plane(0)),
            ("ViewLayer.Combined.G".into(), plane(1)),
            ("ViewLayer.Combined.B".into(), plane(2)),
            ("ViewLayer.Combined.A".into(), plane(3)),
            ("ViewLayer.Depth.Z".into(), vec![2.0; w * h]),
        ],
        None,
    )
    .expect("write the G-buffer");
    let camera = dir.join("camera.json");
    std::fs::write(
        &camera,
        r#"{"width": 16, "height": 12, "focal_length_mm": 50, "sensor_width_mm": 36}"#,
    )
    .expect("write camera.json");
    let image = RgbaImage {
        width: w,
        height: h,
        pixels: color,
    };
    (image, input, camera)
}

fn assert_success(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn help_lists_every_command() {
    let out = spreadlet().arg("--help").output().expect("runs");
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for command in ["synth", "reconstruct", "compare", "demo", "bench", "study"] {
        assert!(text.contains(command), "--help lacks {command}:\n{text}");
    }
}

#[test]
fn a_still_pinhole_frame_comes_back_unchanged_and_scores_as_identical() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (image, input, camera) = pinhole_input(dir.path());
    let out_path = dir.path().join("out.exr");
    let empty_cache = dir.path().join("cache");
    let out = spreadlet()
        .args(["synth", "-q", "--backend", "cpu", "--input"])
        .arg(&input)
        .arg("--camera")
        .arg(&camera)
        .arg("--out")
        .arg(&out_path)
        .env("SPREADLET_CACHE", &empty_cache)
        .output()
        .expect("runs");
    assert_success(&out);
    let result = RgbaImage::read_exr(&out_path).expect("the output reads back");
    assert_eq!(
        result.pixels, image.pixels,
        "nothing to simulate: the input"
    );
    assert!(
        !empty_cache.join("thin-lens").exists() && std::fs::read_dir(&empty_cache).is_err(),
        "no database was built"
    );
    let out = spreadlet()
        .args(["compare", "--json"])
        .arg(&out_path)
        .arg(&input)
        .output()
        .expect("runs");
    assert_success(&out);
    let scores: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("compare --json prints JSON");
    assert_eq!(scores["ssim"].as_f64(), Some(1.0), "{scores}");
    assert_eq!(scores["flip_mean"].as_f64(), Some(0.0), "{scores}");
}

#[test]
fn a_missing_input_is_a_clean_failure() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out_path = dir.path().join("out.exr");
    let out = spreadlet()
        .args(["synth", "-q", "--input"])
        .arg(dir.path().join("missing.exr"))
        .arg("--out")
        .arg(&out_path)
        .args(["--width", "8", "--height", "8"])
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("missing.exr"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(!out_path.exists(), "no output on failure");
}
