//! Issue 9: frame sequences. `synth --frames A-B` with # in the paths gives every frame the
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
    let options = scene::RenderOptions::default();
    let gbuffer = scene::render_gbuffer(&scene, 4, &options).expect("render");
    std::fs::create_dir_all(d("frames")).expect("dir");
    for f in 1..=3 {
        gbuffer
            .write_exr(&dir.path().join(format!("frames/{f:04}.exr")))
            .expect("write");
    }
    std::fs::write(d("camera.json"), scene.camera_json()).expect("camera");
    let common = [
        "--camera",
        &d("camera.json"),
        "--db-profile",
        "test",
        "--backend",
        "cpu",
        "-q",
    ];
    let cache = cache_dir();

    let seq = [
        &[
            "synth",
            "--input",
            &d("frames/####.exr"),
            "--frames",
            "1-3",
            "--out",
            &d("out/####.exr"),
        ][..],
        &common[..],
    ]
    .concat();
    std::fs::create_dir_all(d("out")).expect("dir");
    assert_success(&run("spreadlet", &seq, &cache));
    let single = [
        &[
            "synth",
            "--input",
            &d("frames/0002.exr"),
            "--out",
            &d("single.exr"),
        ][..],
        &common[..],
    ]
    .concat();
    assert_success(&run("spreadlet", &single, &cache));
    let a = std::fs::read(d("out/0002.exr")).expect("frame 2");
    let b = std::fs::read(d("single.exr")).expect("single");
    assert!(
        a == b,
        "frame 2 of the sequence differs from a single-frame run"
    );
    for f in 1..=3 {
        assert!(dir.path().join(format!("out/{f:04}.exr")).exists());
    }

    // Shard 1 of 3 of frames 1-3 is frame 2 alone.
    std::fs::create_dir_all(d("shard")).expect("dir");
    let shard = [
        &[
            "synth",
            "--input",
            &d("frames/####.exr"),
            "--frames",
            "1-3",
            "--shard",
            "1/3",
            "--out",
            &d("shard/####.exr"),
        ][..],
        &common[..],
    ]
    .concat();
    assert_success(&run("spreadlet", &shard, &cache));
    let written: Vec<_> = std::fs::read_dir(d("shard"))
        .expect("dir")
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert_eq!(written, vec![std::ffi::OsString::from("0002.exr")]);

    // A frame missing from the range.
    let missing = [
        &[
            "synth",
            "--input",
            &d("frames/####.exr"),
            "--frames",
            "1-4",
            "--out",
            &d("out/####.exr"),
        ][..],
        &common[..],
    ]
    .concat();
    assert_clean_failure(&run("spreadlet", &missing, &cache), "0004.exr");
    let no_range = [
        &[
            "synth",
            "--input",
            &d("frames/####.exr"),
            "--out",
            &d("out/####.exr"),
        ][..],
        &common[..],
    ]
    .concat();
    assert_clean_failure(&run("spreadlet", &no_range, &cache), "--frames");
}
