//! The `spreadlet-scene` binary: renders files that read back, writes camera.json, and fails
//! cleanly (non-zero exit, no output file) on bad input.

use std::process::Command;

use scene::{GBuffer, RgbaImage, StochasticFrames};

/// Fails the test with the command's error output unless it succeeded.
fn assert_succeeded(output: &std::process::Output) {
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

fn binary() -> Command {
    Command::new(env!("CARGO_BIN_EXE_spreadlet-scene"))
}

#[test]
fn renders_every_output_and_camera_json() {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = |name: &str| dir.path().join(name);
    let output = binary()
        .args([
            "render", "rotating", "--width", "20", "--quiet", "--seed", "4",
        ])
        .args(["--spp", "2", "--ref-spp", "4", "--aa", "2", "--png"])
        .arg("--gbuffer")
        .arg(p("g.exr"))
        .arg("--stochastic")
        .arg(p("s.exr"))
        .arg("--reference")
        .arg(p("r.exr"))
        .arg("--camera-out")
        .arg(p("camera.json"))
        .output()
        .expect("run");
    assert_succeeded(&output);
    let g = GBuffer::read_exr(&p("g.exr")).expect("gbuffer");
    assert_eq!((g.width, g.height), (20, 20));
    let s = StochasticFrames::read_exr(&p("s.exr")).expect("frames");
    assert_eq!((s.width, s.height, s.spp), (20, 20, 2));
    let r = RgbaImage::read_exr(&p("r.exr")).expect("reference");
    assert_eq!((r.width, r.height), (20, 20));
    assert!(p("g.png").exists() && p("r.png").exists());
    let text = std::fs::read_to_string(p("camera.json")).expect("camera.json");
    let camera = scene::camera::camera_from_json(&text, "camera.json").expect("valid camera.json");
    assert_eq!((camera.width, camera.height), (20, 20));
    assert_eq!(camera.f_stop, Some(5.6));
    assert!(text.contains("\"scene\": \"rotating\""));
}

/// A built-in scene's name renders the built-in scene even where a folder of that name lies in
/// the working directory (the natural place for its renders).
#[test]
fn a_folder_named_like_a_builtin_scene_does_not_hide_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::create_dir(dir.path().join("rotating")).expect("folder");
    let output = binary()
        .current_dir(dir.path())
        .args([
            "render", "rotating", "--width", "16", "--quiet", "--aa", "1",
        ])
        .args(["--gbuffer", "rotating/g.exr"])
        .output()
        .expect("run");
    assert_succeeded(&output);
    assert!(dir.path().join("rotating/g.exr").exists());
}

#[test]
fn bad_input_fails_cleanly() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene_path = dir.path().join("bad.json");
    std::fs::write(&scene_path, r#"{"name": "x", "camera": {"width": 8}}"#).expect("write");
    let out = dir.path().join("out.exr");
    for args in [
        vec![scene_path.to_string_lossy().to_string()],
        vec!["no-such-scene.json".to_string()],
        vec!["bokeh".to_string(), "--spp".to_string(), "0".to_string()],
    ] {
        let output = binary()
            .arg("render")
            .args(&args)
            .arg("--stochastic")
            .arg(&out)
            .arg("--quiet")
            .output()
            .expect("run");
        assert!(!output.status.success(), "{args:?} succeeded");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert!(!out.exists(), "{args:?} left an output file");
    }
}
