//! Frame sequences. `synth --frames A-B` with # in the paths gives every frame the
//! same result as a single-frame run; `--shard K/N` takes its contiguous share of the range; a
//! missing frame is a clean error naming the file.

use spreadlet_e2e::{assert_clean_failure, assert_success, cache_dir, run};

#[test]
fn a_sequence_equals_single_frames_and_shards_split_the_range() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = |name: &str| dir.path().join(name).to_string_lossy().into_owned();
    let scene = scene::builtin("crossing")
        .and_then(|s| s.with_size(48, 48))
        .expect("scene");
    let gbuffer =
        scene::render_gbuffer(&scene, 4, &scene::RenderOptions::default()).expect("render");
    for sub in ["frames", "out", "shard"] {
        std::fs::create_dir_all(d(sub)).expect("dir");
    }
    for f in 1..=3 {
        gbuffer
            .write_exr(&dir.path().join(format!("frames/{f:04}.exr")))
            .expect("write");
    }
    std::fs::write(d("camera.json"), scene.camera_json()).expect("camera");
    let cache = cache_dir();
    // synth with `extra` arguments and the common ones.
    let synth = |extra: &[String]| {
        let mut args: Vec<String> = vec!["synth".into()];
        args.extend_from_slice(extra);
        for a in [
            "--camera",
            &d("camera.json"),
            "--db-profile",
            "test",
            "--backend",
            "cpu",
            "-q",
        ] {
            args.push(a.to_string());
        }
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        run("spreadlet", &refs, &cache)
    };
    let s = |v: &[&str]| -> Vec<String> { v.iter().map(|x| x.to_string()).collect() };

    let (frames, out) = (d("frames/####.exr"), d("out/####.exr"));
    assert_success(&synth(&s(&[
        "--input", &frames, "--frames", "1-3", "--out", &out,
    ])));
    let (frame2, single) = (d("frames/0002.exr"), d("single.exr"));
    assert_success(&synth(&s(&["--input", &frame2, "--out", &single])));
    let a = std::fs::read(d("out/0002.exr")).expect("frame 2");
    let b = std::fs::read(&single).expect("single");
    assert!(
        a == b,
        "frame 2 of the sequence differs from a single-frame run"
    );
    for f in 1..=3 {
        assert!(dir.path().join(format!("out/{f:04}.exr")).exists());
    }

    // Shard 1 of 3 of frames 1-3 is frame 2 alone.
    let shard_out = d("shard/####.exr");
    assert_success(&synth(&s(&[
        "--input", &frames, "--frames", "1-3", "--shard", "1/3", "--out", &shard_out,
    ])));
    let written: Vec<_> = std::fs::read_dir(d("shard"))
        .expect("dir")
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert_eq!(written, vec![std::ffi::OsString::from("0002.exr")]);

    // A frame missing from the range; # without a range.
    assert_clean_failure(
        &synth(&s(&["--input", &frames, "--frames", "1-4", "--out", &out])),
        "0004.exr",
    );
    assert_clean_failure(&synth(&s(&["--input", &frames, "--out", &out])), "--frames");
}

#[test]
fn reconstruct_takes_a_sequence_too() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = |name: &str| dir.path().join(name).to_string_lossy().into_owned();
    let scene = scene::builtin("crossing")
        .and_then(|s| s.with_size(40, 40))
        .expect("scene");
    std::fs::create_dir_all(d("out")).expect("dir");
    for f in 1..=2u64 {
        let options = scene::RenderOptions {
            seed: f,
            ..Default::default()
        };
        scene::render_stochastic(&scene, 2, &options)
            .expect("stochastic frames")
            .write_exr(&dir.path().join(format!("{f:04}.exr")))
            .expect("write stochastic frames");
    }
    std::fs::write(d("camera.json"), scene.camera_json()).expect("camera");
    let cache = cache_dir();
    let recon = |input: &str, out: &str, frames: Option<&str>| {
        let camera = d("camera.json");
        let mut args = vec!["reconstruct", "--input", input, "--out", out];
        args.extend(["--camera", camera.as_str(), "--db-profile", "test", "-q"]);
        if let Some(f) = frames {
            args.extend(["--frames", f]);
        }
        run("spreadlet", &args, &cache)
    };
    assert_success(&recon(&d("####.exr"), &d("out/####.exr"), Some("1-2")));
    assert_success(&recon(&d("0002.exr"), &d("single.exr"), None));
    let a = std::fs::read(d("out/0002.exr")).expect("frame 2");
    let b = std::fs::read(d("single.exr")).expect("single");
    assert!(
        a == b,
        "frame 2 of the sequence differs from a single-frame run"
    );
}
