//! `spreadlet reconstruct --method PEER` end to end: the peer reconstruction methods
//! run through the binary on the same stochastic frames and camera as spreadlet's
//! reconstruction, give the `peers` crate's result bit for bit, beat the plain average of the
//! same samples, and refuse (cleanly) a method that ignores an effect of the input.

use std::path::Path;

use spreadlet::camera::Camera;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};
use spreadlet_e2e::{assert_clean_failure, assert_success, cache_dir, run};

fn read_rgba(path: &Path) -> Vec<f32> {
    let g = GBuffer::read_exr(path, &ChannelOptions::default()).expect("readable EXR");
    g.color.iter().flatten().copied().collect()
}

/// Renders a built-in scene with `spreadlet-scene` into `dir`: `frames.exr` (stochastic),
/// `reference.exr` and `camera.json`.
fn render(dir: &Path, scene: &str, size: usize, spp: usize, ref_spp: usize) {
    let s = |f: &str| dir.join(f).to_str().expect("utf-8 path").to_string();
    assert_success(&run(
        "spreadlet-scene",
        &[
            "render",
            scene,
            "--width",
            &size.to_string(),
            "--height",
            &size.to_string(),
            "--stochastic",
            &s("frames.exr"),
            "--spp",
            &spp.to_string(),
            "--reference",
            &s("reference.exr"),
            "--ref-spp",
            &ref_spp.to_string(),
            "--camera-out",
            &s("camera.json"),
            "--seed",
            "3",
            "--quiet",
        ],
        &cache_dir(),
    ));
}

#[test]
fn shirley_through_the_binary_equals_the_library_and_beats_the_plain_average() {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = |f: &str| dir.path().join(f);
    let s = |f: &str| p(f).to_str().expect("utf-8 path").to_string();
    let size = 128;
    // bokeh: large defocus disks (f/1.4), still; Shirley's paper count, 16 spp.
    render(dir.path(), "bokeh", size, 16, 512);
    assert_success(&run(
        "spreadlet",
        &[
            "reconstruct",
            "--method",
            "shirley",
            "--input",
            &s("frames.exr"),
            "--camera",
            &s("camera.json"),
            "--out",
            &s("shirley.exr"),
            "--stats",
            &s("stats.json"),
            "--quiet",
        ],
        &cache_dir(),
    ));

    // Bit for bit what the library gives on the same file and camera.
    let frames = scene::StochasticFrames::read_exr(&p("frames.exr")).expect("frames");
    let camera = Camera::from_json_file(&p("camera.json")).expect("camera");
    let direct = spreadlet_harness::peer::reconstruct_peer("shirley", &frames, &camera, false)
        .expect("library run");
    let from_binary = read_rgba(&p("shirley.exr"));
    let from_library: Vec<f32> = direct.image.pixels.iter().flatten().copied().collect();
    assert_eq!(from_binary, from_library);

    // Better than the plain average of the same 16 spp, against the reference.
    let reference = read_rgba(&p("reference.exr"));
    let average: Vec<f32> = frames.average().pixels.iter().flatten().copied().collect();
    let ssim = |a: &[f32]| metrics::ssim_rgb(a, &reference, size, size).expect("ssim");
    let (shirley, plain) = (ssim(&from_binary), ssim(&average));
    eprintln!("SSIM: shirley {shirley:.4}, 16-spp average {plain:.4}");
    assert!(
        shirley > plain + 0.05,
        "shirley {shirley:.4} vs 16-spp average {plain:.4}"
    );

    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(p("stats.json")).expect("stats"))
            .expect("JSON");
    assert_eq!(stats["method"], "shirley");
    assert_eq!(stats["spp"], 16);
}

#[test]
fn a_defocus_only_method_on_a_moving_scene_is_refused_unless_allowed() {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = |f: &str| dir.path().join(f);
    let s = |f: &str| p(f).to_str().expect("utf-8 path").to_string();
    // crossing: defocus (f/4) and motion blur (~20 px/frame at 256 px) in one frame.
    render(dir.path(), "crossing", 32, 4, 16);
    // vaidyanathan does defocus only: on moving samples it is an error unless allowed.
    let (frames_path, camera_path) = (s("frames.exr"), s("camera.json"));
    let (v_path, x_path) = (s("v.exr"), s("x.exr"));
    let vaidyanathan = |extra: &[&str]| {
        let mut args = vec![
            "reconstruct",
            "--method",
            "vaidyanathan",
            "--input",
            &frames_path,
            "--camera",
            &camera_path,
            "--out",
            &v_path,
        ];
        args.extend_from_slice(extra);
        run("spreadlet", &args, &cache_dir())
    };
    assert_clean_failure(&vaidyanathan(&[]), "does not handle motion blur");
    assert!(!p("v.exr").exists(), "no output written on refusal");
    let out = vaidyanathan(&["--allow-unhandled-effects"]);
    assert_success(&out);
    assert!(String::from_utf8_lossy(&out.stderr).contains("ignored motion blur"));
    assert!(p("v.exr").exists());

    // Unknown names and G-buffer methods are clean errors.
    let bad = |method: &str| {
        run(
            "spreadlet",
            &[
                "reconstruct",
                "--method",
                method,
                "--input",
                &frames_path,
                "--camera",
                &camera_path,
                "--out",
                &x_path,
            ],
            &cache_dir(),
        )
    };
    assert_clean_failure(&bad("nope"), "unknown method");
    assert_clean_failure(&bad("guertin"), "synth --method guertin");
}
