//! Bad input, end to end through the binaries. Every case gives a clear message that
//! names the problem, a non-zero exit, no panic, no hang (each run has a time limit) and leaves
//! no file in the output folder (no partial output, no temporary file). The policy where a
//! choice exists (docs/ROBUSTNESS.md): non-finite colour pixels are dropped and counted in the
//! stats; non-finite motion, NaN, zero or negative depth are errors naming the pixel; +inf depth
//! is a point at infinity; extra channels are ignored.

use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::Duration;

use psf_db::{DatabaseBuilder, DbHeader, ParamSpace, PsfDatabase, PsfModel};
use spreadlet_e2e::{assert_clean_failure, assert_success, cache_dir, files_in, run_with_timeout};

/// Longest a bad-input run may take (a hang fails the test).
const LIMIT: Duration = Duration::from_secs(120);

const W: usize = 12;
const H: usize = 10;

/// A temporary workspace: `in/` for inputs, `out/` for outputs (must stay empty on failure).
struct Fixture {
    dir: tempfile::TempDir,
}

impl Fixture {
    fn new() -> Self {
        let dir = tempfile::tempdir().expect("temp dir");
        for sub in ["in", "out"] {
            std::fs::create_dir_all(dir.path().join(sub)).expect("dir");
        }
        Fixture { dir }
    }
    fn input(&self, name: &str) -> PathBuf {
        self.dir.path().join("in").join(name)
    }
    fn output(&self, name: &str) -> PathBuf {
        self.dir.path().join("out").join(name)
    }
    fn out_dir(&self) -> PathBuf {
        self.dir.path().join("out")
    }
    /// Asserts a clean failure naming `needle` that left nothing in `out/`.
    fn assert_fails_cleanly(&self, what: &str, out: &Output, needle: &str) {
        eprintln!(
            "{what}: {}",
            String::from_utf8_lossy(&out.stderr).trim_end()
        );
        assert_clean_failure(out, needle);
        let left = files_in(&self.out_dir());
        assert!(left.is_empty(), "{what}: files left behind: {left:?}");
    }
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// Plain G-buffer channels: a gradient colour (opaque), depth `depth`, motion `motion`.
fn channels(depth: f32, motion: Option<[f32; 2]>) -> Vec<(String, Vec<f32>)> {
    let n = W * H;
    let mut c: Vec<(String, Vec<f32>)> = vec![
        ("R".into(), (0..n).map(|i| i as f32 / n as f32).collect()),
        ("G".into(), vec![0.5; n]),
        ("B".into(), vec![0.25; n]),
        ("A".into(), vec![1.0; n]),
        ("Z".into(), vec![depth; n]),
    ];
    if let Some(m) = motion {
        c.push(("forward.u".into(), vec![m[0]; n]));
        c.push(("forward.v".into(), vec![m[1]; n]));
    }
    c
}

fn set(chans: &mut [(String, Vec<f32>)], name: &str, i: usize, v: f32) {
    let c = chans.iter_mut().find(|(n, _)| n == name).expect("channel");
    c.1[i] = v;
}

fn write_exr(path: &Path, w: usize, h: usize, chans: Vec<(String, Vec<f32>)>) {
    scene::exr_io::write_channels(path, w, h, chans, None).expect("write EXR");
}

/// A camera.json text: `W x H`, 50 mm on 36 mm, f/2 at 2 m when `lens`, shutter `shutter`.
fn camera_json(lens: bool, shutter: f64) -> String {
    let (f, s) = if lens {
        ("2.0", "2.0")
    } else {
        ("null", "null")
    };
    format!(
        "{{\"width\": {W}, \"height\": {H}, \"focal_length_mm\": 50.0, \"sensor_width_mm\": 36.0, \
         \"f_stop\": {f}, \"focus_distance\": {s}, \"aperture_blades\": 0, \"shutter_frames\": {shutter}}}"
    )
}

/// A small hand-made database of `model` (one-spreadlet PSFs).
fn hand_db(model: PsfModel) -> PsfDatabase {
    let ranges: Vec<[f64; 2]> = match model {
        PsfModel::ThinLens => vec![[0.0, 16.0]],
        _ => vec![[0.0, 16.0], [0.0, 32.0]],
    };
    let space = ParamSpace::for_model(model, &ranges, 6).expect("space");
    let mut b = DatabaseBuilder::new(DbHeader::new(model, space.clone(), 64));
    for _ in 0..space.psf_count() {
        b.push_sparse(
            &[[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]],
            &[-4.0, 1.0, 1.0, 1.0, 1.0],
        )
        .expect("push");
    }
    b.finish().expect("db")
}

/// `spreadlet synth` on `input` with `camera` (a path), extra args, output and stats in
/// `out/`.
fn synth(f: &Fixture, input: &Path, camera: &Path, extra: &[&str]) -> Output {
    let (out, stats) = (s(&f.output("x.exr")), s(&f.output("stats.json")));
    let (input, camera) = (s(input), s(camera));
    let mut args = vec![
        "synth",
        "--input",
        &input,
        "--out",
        &out,
        "--stats",
        &stats,
        "--camera",
        &camera,
        "--db-profile",
        "test",
        "--backend",
        "cpu",
        "-q",
    ];
    args.extend_from_slice(extra);
    run_with_timeout("spreadlet", &args, &cache_dir(), LIMIT)
}

/// Writes the G-buffer and a camera and runs synth.
fn synth_gbuffer(
    f: &Fixture,
    chans: Vec<(String, Vec<f32>)>,
    lens: bool,
    shutter: f64,
    extra: &[&str],
) -> Output {
    let (g, c) = (f.input("g.exr"), f.input("camera.json"));
    write_exr(&g, W, H, chans);
    std::fs::write(&c, camera_json(lens, shutter)).expect("camera");
    synth(f, &g, &c, extra)
}

/// Rewrites the `dataWindow` of an EXR header to `(0, 0)..=(x_max, y_max)`.
fn with_data_window(bytes: &[u8], x_max: i32, y_max: i32) -> Vec<u8> {
    let key = b"dataWindow\0box2i\0";
    let at = bytes
        .windows(key.len())
        .position(|k| k == key)
        .expect("dataWindow attribute")
        + key.len()
        + 4;
    let mut out = bytes.to_vec();
    for (k, v) in [0i32, 0, x_max, y_max].iter().enumerate() {
        out[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
    }
    out
}

#[test]
fn non_finite_colour_is_dropped_and_counted() {
    let f = Fixture::new();
    let mut c = channels(3.0, None);
    set(&mut c, "R", 5, f32::NAN);
    set(&mut c, "G", 17, f32::INFINITY);
    set(&mut c, "A", 30, f32::NEG_INFINITY);
    let out = synth_gbuffer(&f, c, true, 0.0, &[]);
    assert_success(&out);
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(f.output("stats.json")).expect("stats"))
            .expect("stats JSON");
    assert_eq!(stats["synthesis"]["counts"]["dropped"], 3, "{stats}");
    assert!(f.output("x.exr").exists());
}

#[test]
fn bad_depth_is_an_error_naming_the_pixel() {
    for (v, needle) in [
        (f32::NAN, "depth at pixel (3, 1)"),
        (0.0, "depth at pixel (3, 1)"),
        (-2.0, "depth at pixel (3, 1)"),
        (f32::NEG_INFINITY, "depth at pixel (3, 1)"),
    ] {
        let f = Fixture::new();
        let mut c = channels(3.0, None);
        set(&mut c, "Z", W + 3, v);
        let out = synth_gbuffer(&f, c, true, 0.0, &[]);
        f.assert_fails_cleanly(&format!("depth {v}"), &out, needle);
    }
    // +inf is a point at infinity: accepted.
    let f = Fixture::new();
    let mut c = channels(3.0, None);
    set(&mut c, "Z", 7, f32::INFINITY);
    assert_success(&synth_gbuffer(&f, c, true, 0.0, &[]));
}

#[test]
fn non_finite_motion_is_an_error_naming_the_pixel() {
    for (ch, v) in [
        ("forward.u", f32::NAN),
        ("forward.v", f32::INFINITY),
        ("forward.u", f32::NEG_INFINITY),
    ] {
        let f = Fixture::new();
        let mut c = channels(3.0, Some([2.0, 1.0]));
        set(&mut c, ch, 2 * W + 4, v);
        let out = synth_gbuffer(&f, c, true, 0.5, &[]);
        f.assert_fails_cleanly(&format!("{ch} {v}"), &out, "motion at pixel (4, 2)");
    }
}

#[test]
fn missing_and_extra_channels() {
    // A colour channel missing: named, with the channels present.
    let f = Fixture::new();
    let c: Vec<_> = channels(3.0, None)
        .into_iter()
        .filter(|(n, _)| n != "G")
        .collect();
    let out = synth_gbuffer(&f, c, true, 0.0, &[]);
    f.assert_fails_cleanly("no G", &out, "missing channel G");
    // Depth missing while the camera has a lens.
    let f = Fixture::new();
    let c: Vec<_> = channels(3.0, None)
        .into_iter()
        .filter(|(n, _)| n != "Z")
        .collect();
    let out = synth_gbuffer(&f, c, true, 0.0, &[]);
    f.assert_fails_cleanly("no Z", &out, "depth");
    // Motion missing while the shutter is open.
    let f = Fixture::new();
    let out = synth_gbuffer(&f, channels(3.0, None), true, 0.5, &[]);
    f.assert_fails_cleanly("no motion", &out, "motion");
    // A named channel that is not there.
    let f = Fixture::new();
    let out = synth_gbuffer(
        &f,
        channels(3.0, None),
        true,
        0.0,
        &["--layout", "plain", "--depth-channel", "depth.W"],
    );
    f.assert_fails_cleanly("--depth-channel", &out, "depth.W");
    // Extra channels are ignored.
    let f = Fixture::new();
    let mut c = channels(3.0, None);
    c.push(("N.x".into(), vec![0.3; W * H]));
    c.push(("extra".into(), vec![f32::NAN; W * H]));
    assert_success(&synth_gbuffer(&f, c, true, 0.0, &[]));
}

#[test]
fn sizes_that_disagree_zero_size_and_huge_declared_size() {
    // The camera says another size than the image.
    let f = Fixture::new();
    let (g, c) = (f.input("g.exr"), f.input("camera.json"));
    write_exr(&g, W, H, channels(3.0, None));
    std::fs::write(
        &c,
        camera_json(true, 0.0).replace("\"width\": 12", "\"width\": 13"),
    )
    .expect("camera");
    let out = synth(&f, &g, &c, &[]);
    f.assert_fails_cleanly("camera 13 wide", &out, "13x10");
    // compare: two images of different sizes.
    let other = f.input("other.exr");
    write_exr(
        &other,
        W + 1,
        H,
        channels(3.0, None)
            .into_iter()
            .map(|(n, _)| (n, vec![0.5; (W + 1) * H]))
            .collect(),
    );
    let out = run_with_timeout(
        "spreadlet",
        &["compare", &s(&g), &s(&other)],
        &cache_dir(),
        LIMIT,
    );
    f.assert_fails_cleanly("compare sizes", &out, "size");

    let bytes = std::fs::read(&g).expect("bytes");
    // Zero size (an empty data window) and a huge declared size in a tiny file: errors naming
    // the file, fast, without allocating the declared image.
    for (what, x_max, y_max) in [
        ("empty window", -1, -1),
        ("8192x8192 declared", 8191, 8191),
        ("30000x30000 declared", 29_999, 29_999),
    ] {
        let f = Fixture::new();
        let bad = f.input("bad.exr");
        std::fs::write(&bad, with_data_window(&bytes, x_max, y_max)).expect("write");
        let cam = f.input("camera.json");
        std::fs::write(&cam, camera_json(true, 0.0)).expect("camera");
        let start = std::time::Instant::now();
        let out = synth(&f, &bad, &cam, &[]);
        f.assert_fails_cleanly(what, &out, "bad.exr");
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "{what}: {:?}",
            start.elapsed()
        );
    }
}

#[test]
fn unreadable_and_corrupt_inputs() {
    let f = Fixture::new();
    let (g, cam) = (f.input("g.exr"), f.input("camera.json"));
    write_exr(&g, W, H, channels(3.0, None));
    std::fs::write(&cam, camera_json(true, 0.0)).expect("camera");
    let bytes = std::fs::read(&g).expect("bytes");
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("not an EXR", b"P6\n12 10\n255\n".to_vec()),
        ("empty file", Vec::new()),
        ("truncated to half", bytes[..bytes.len() / 2].to_vec()),
        ("truncated header", bytes[..40].to_vec()),
    ];
    for (what, data) in cases {
        let bad = f.input("bad.exr");
        std::fs::write(&bad, data).expect("write");
        let out = synth(&f, &bad, &cam, &[]);
        f.assert_fails_cleanly(what, &out, "bad.exr");
    }
    let out = synth(&f, &f.input("missing.exr"), &cam, &[]);
    f.assert_fails_cleanly("missing input", &out, "missing.exr");
}

#[test]
fn corrupt_foreign_and_mismatched_databases() {
    let f = Fixture::new();
    let (g, cam) = (f.input("g.exr"), f.input("camera.json"));
    write_exr(&g, W, H, channels(3.0, None));
    std::fs::write(&cam, camera_json(true, 0.0)).expect("camera");
    let good = hand_db(PsfModel::ThinLens).to_bytes().expect("bytes");
    let db = f.input("db.sprdlt");
    let dbs = s(&db);
    // The good database works (the cases below differ from it only by the corruption).
    std::fs::write(&db, &good).expect("db");
    assert_success(&synth(&f, &g, &cam, &["--db", &dbs]));
    for name in ["x.exr", "stats.json"] {
        std::fs::remove_file(f.output(name)).expect("clean");
    }
    let mut flipped = good.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x10;
    let mut version = good.clone();
    let magic = psf_db::MAGIC.len();
    version[magic..magic + 4].copy_from_slice(&(psf_db::FORMAT_VERSION + 1).to_le_bytes());
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("truncated", good[..good.len() - 9].to_vec(), "truncated"),
        ("bit flipped", flipped, "corrupt"),
        ("future version", version, "version"),
        (
            "not a database",
            b"hello, world".to_vec(),
            "not a spreadlet",
        ),
        ("empty", Vec::new(), "truncated"),
    ];
    for (what, data, needle) in cases {
        std::fs::write(&db, data).expect("db");
        let out = synth(&f, &g, &cam, &["--db", &dbs]);
        f.assert_fails_cleanly(what, &out, needle);
    }
    // A database of another model: thin-lens given where motion blur needs lens-motion.
    std::fs::write(&db, &good).expect("db");
    let gm = f.input("moving.exr");
    write_exr(&gm, W, H, channels(3.0, Some([3.0, 0.0])));
    let cam_m = f.input("camera_shutter.json");
    std::fs::write(&cam_m, camera_json(true, 0.5)).expect("camera");
    let out = synth(&f, &gm, &cam_m, &["--db", &dbs]);
    f.assert_fails_cleanly("another model", &out, "lens-motion");
    let out = synth(&f, &g, &cam, &["--db", &s(&f.input("nowhere.sprdlt"))]);
    f.assert_fails_cleanly("missing database", &out, "nowhere.sprdlt");
}

/// A corrupt database given with `--db` is named in the message (today the loader's message
/// says what is wrong but not which file).
#[test]

fn a_corrupt_database_is_named() {
    let f = Fixture::new();
    let (g, cam) = (f.input("g.exr"), f.input("camera.json"));
    write_exr(&g, W, H, channels(3.0, None));
    std::fs::write(&cam, camera_json(true, 0.0)).expect("camera");
    let good = hand_db(PsfModel::ThinLens).to_bytes().expect("bytes");
    let db = f.input("db.sprdlt");
    std::fs::write(&db, &good[..good.len() - 9]).expect("db");
    let out = synth(&f, &g, &cam, &["--db", &s(&db)]);
    f.assert_fails_cleanly("truncated, named", &out, "db.sprdlt");
}

#[test]
fn camera_json_with_missing_or_absurd_fields() {
    let f = Fixture::new();
    let g = f.input("g.exr");
    write_exr(&g, W, H, channels(3.0, None));
    let good = camera_json(true, 0.0);
    let cases: Vec<(&str, String, &str)> = vec![
        ("no width", good.replace("\"width\": 12, ", ""), "width"),
        (
            "no focal length",
            good.replace("\"focal_length_mm\": 50.0, ", ""),
            "focal_length_mm",
        ),
        (
            "negative f-stop",
            good.replace("\"f_stop\": 2.0", "\"f_stop\": -2.0"),
            "f_stop",
        ),
        (
            "zero sensor",
            good.replace("\"sensor_width_mm\": 36.0", "\"sensor_width_mm\": 0"),
            "sensor_width_mm",
        ),
        (
            "focus inside the focal length",
            good.replace("\"focus_distance\": 2.0", "\"focus_distance\": 0.01"),
            "focus_distance",
        ),
        (
            "absurd width",
            good.replace("\"width\": 12", "\"width\": 4000000000"),
            "image size 4000000000x10",
        ),
        (
            "negative shutter",
            good.replace("\"shutter_frames\": 0", "\"shutter_frames\": -1"),
            "shutter_frames",
        ),
        (
            "two blades",
            good.replace("\"aperture_blades\": 0", "\"aperture_blades\": 2"),
            "aperture_blades",
        ),
        (
            "width as text",
            good.replace("\"width\": 12", "\"width\": \"twelve\""),
            "width",
        ),
        (
            "out-of-range number",
            good.replace("\"focal_length_mm\": 50.0", "\"focal_length_mm\": 1e999"),
            "camera",
        ),
        (
            "tiny f-stop",
            good.replace("\"f_stop\": 2.0", "\"f_stop\": 1e-300"),
            "f_stop",
        ),
        ("not JSON", "width = 12".to_string(), "camera"),
        ("a JSON array", "[1, 2, 3]".to_string(), "object"),
        ("empty", String::new(), "camera"),
    ];
    for (what, text, needle) in cases {
        let cam = f.input("camera.json");
        std::fs::write(&cam, text).expect("camera");
        let out = synth(&f, &g, &cam, &[]);
        f.assert_fails_cleanly(what, &out, needle);
    }
    let out = synth(&f, &g, &f.input("nope.json"), &[]);
    f.assert_fails_cleanly("missing camera file", &out, "nope.json");
}

#[test]
fn unwritable_outputs_leave_nothing_behind() {
    let f = Fixture::new();
    let (g, cam) = (f.input("g.exr"), f.input("camera.json"));
    write_exr(&g, W, H, channels(3.0, None));
    std::fs::write(&cam, camera_json(true, 0.0)).expect("camera");
    let blocker = f.output("a_file");
    std::fs::write(&blocker, b"x").expect("blocker");
    let (gs, cs) = (s(&g), s(&cam));
    for (what, out_path) in [
        ("missing folder", f.output("no/such/dir/x.exr")),
        ("parent is a file", blocker.join("x.exr")),
        ("output is a folder", f.out_dir()),
    ] {
        let o = s(&out_path);
        let out = run_with_timeout(
            "spreadlet",
            &[
                "synth",
                "--input",
                &gs,
                "--out",
                &o,
                "--camera",
                &cs,
                "--db-profile",
                "test",
                "--backend",
                "cpu",
                "-q",
            ],
            &cache_dir(),
            LIMIT,
        );
        eprintln!(
            "{what}: {}",
            String::from_utf8_lossy(&out.stderr).trim_end()
        );
        assert_clean_failure(
            &out,
            &s(out_path.file_name().map(Path::new).unwrap_or(&out_path)),
        );
        assert_eq!(files_in(&f.out_dir()), vec!["a_file".to_string()], "{what}");
    }
}

/// The stats file cannot be written after the image was: today the image stays (each file is
/// written atomically, the set is not). The policy asks for nothing left behind.
#[test]

fn an_unwritable_stats_path_leaves_no_image() {
    let f = Fixture::new();
    let (g, cam) = (f.input("g.exr"), f.input("camera.json"));
    write_exr(&g, W, H, channels(3.0, None));
    std::fs::write(&cam, camera_json(true, 0.0)).expect("camera");
    let (gs, cs, o) = (s(&g), s(&cam), s(&f.output("x.exr")));
    let st = s(&f.output("missing/stats.json"));
    let out = run_with_timeout(
        "spreadlet",
        &[
            "synth",
            "--input",
            &gs,
            "--out",
            &o,
            "--stats",
            &st,
            "--camera",
            &cs,
            "--db-profile",
            "test",
            "--backend",
            "cpu",
            "-q",
        ],
        &cache_dir(),
        LIMIT,
    );
    f.assert_fails_cleanly("stats path", &out, "stats.json");
}

#[test]
fn reconstruct_rejects_bad_stochastic_frames() {
    let f = Fixture::new();
    let scene = scene::builtin("crossing")
        .and_then(|s| s.with_size(16, 16))
        .expect("scene");
    let frames = scene::render_stochastic(&scene, 2, &scene::RenderOptions::default())
        .expect("stochastic frames");
    let cam = f.input("camera.json");
    std::fs::write(&cam, scene.camera_json()).expect("camera");
    let recon = |input: &Path| {
        let (i, o, c) = (s(input), s(&f.output("r.exr")), s(&cam));
        run_with_timeout(
            "spreadlet",
            &[
                "reconstruct",
                "--input",
                &i,
                "--out",
                &o,
                "--camera",
                &c,
                "--db-profile",
                "test",
                "-q",
            ],
            &cache_dir(),
            LIMIT,
        )
    };
    let good = f.input("s.exr");
    frames.write_exr(&good).expect("write");
    let bytes = std::fs::read(&good).expect("bytes");
    for (what, data) in [
        ("truncated", bytes[..bytes.len() / 3].to_vec()),
        ("not an EXR", b"nothing here".to_vec()),
    ] {
        let bad = f.input("bad.exr");
        std::fs::write(&bad, data).expect("write");
        let out = recon(&bad);
        f.assert_fails_cleanly(what, &out, "bad.exr");
    }
    // A G-buffer is not a stochastic frame: the missing channels are named.
    let g = f.input("g.exr");
    write_exr(
        &g,
        16,
        16,
        channels(3.0, None)
            .into_iter()
            .map(|(n, _)| (n, vec![0.5; 256]))
            .collect(),
    );
    let out = recon(&g);
    f.assert_fails_cleanly("a G-buffer", &out, "not a stochastic-frames file");
    // Policy for samples (docs/ROBUSTNESS.md): a sample with a non-finite label is dropped
    // and counted in the stats; the reconstruction goes on.
    let mut nan = frames.clone();
    nan.samples[5].depth = f32::NAN;
    nan.samples[9].color[1] = f32::INFINITY;
    let bad = f.input("nan.exr");
    nan.write_exr(&bad).expect("write");
    let (i, o, c, st) = (
        s(&bad),
        s(&f.output("r.exr")),
        s(&cam),
        s(&f.output("stats.json")),
    );
    let out = run_with_timeout(
        "spreadlet",
        &[
            "reconstruct",
            "--input",
            &i,
            "--out",
            &o,
            "--camera",
            &c,
            "--db-profile",
            "test",
            "-q",
            "--stats",
            &st,
        ],
        &cache_dir(),
        LIMIT,
    );
    assert_success(&out);
    let stats = std::fs::read_to_string(f.output("stats.json")).expect("stats");
    eprintln!("{stats}");
    assert!(stats.contains("\"dropped\": 2"), "{stats}");
    for name in ["r.exr", "stats.json"] {
        std::fs::remove_file(f.output(name)).expect("clean");
    }
    // A zero or negative depth in a sample is not a finite label problem: it must not give
    // garbage either (an error naming it, or the sample dropped and counted).
    for d in [0.0f32, -1.0] {
        let mut z = frames.clone();
        z.samples[7].depth = d;
        let bad = f.input("zero.exr");
        z.write_exr(&bad).expect("write");
        let out = recon(&bad);
        eprintln!("sample depth {d}: {}", String::from_utf8_lossy(&out.stderr));
        if out.status.success() {
            let mut ch = scene::exr_io::read_channels(&f.output("r.exr")).expect("output");
            for name in ["R", "G", "B", "A"] {
                let v = ch.take(name, &f.output("r.exr")).expect("channel");
                assert!(
                    v.iter().all(|x| x.is_finite() && *x >= 0.0),
                    "sample depth {d}: {name} not finite"
                );
            }
            std::fs::remove_file(f.output("r.exr")).expect("clean");
        } else {
            f.assert_fails_cleanly(&format!("sample depth {d}"), &out, "depth");
        }
    }
}

#[test]
fn precompute_merge_rejects_corrupt_parts() {
    let f = Fixture::new();
    let good = hand_db(PsfModel::ThinLens).to_bytes().expect("bytes");
    let mut flipped = good.clone();
    flipped[good.len() / 3] ^= 1;
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "truncated part",
            good[..good.len() / 2].to_vec(),
            "part.sprdlt",
        ),
        ("flipped part", flipped, "part.sprdlt"),
        ("garbage part", b"garbage".to_vec(), "part.sprdlt"),
    ];
    for (what, data, needle) in cases {
        let part = f.input("part.sprdlt");
        std::fs::write(&part, data).expect("part");
        let (p, o) = (s(&part), s(&f.output("merged.sprdlt")));
        let out = run_with_timeout(
            "precompute",
            &["merge", "--out", &o, &p],
            &cache_dir(),
            LIMIT,
        );
        f.assert_fails_cleanly(what, &out, needle);
    }
    // An output folder that does not exist.
    let o = s(&f.output("no/dir/db.sprdlt"));
    let out = run_with_timeout(
        "precompute",
        &[
            "--model",
            "thin-lens",
            "--profile",
            "test",
            "--psfs",
            "4",
            "--out",
            &o,
        ],
        &cache_dir(),
        LIMIT,
    );
    f.assert_fails_cleanly("precompute into a missing folder", &out, "db.sprdlt");
}

/// Writes the fuzzers' seed inputs (`fuzz/seeds/`): run once with `--ignored` when the
/// formats change.
#[test]
#[ignore = "regenerates fuzz/seeds; not a check"]
fn write_fuzz_seeds() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds");
    for sub in ["db_loader", "gbuffer_exr", "camera_json", "deep_exr"] {
        std::fs::create_dir_all(root.join(sub)).expect("dir");
    }
    for model in [PsfModel::ThinLens, PsfModel::LensMotion] {
        let bytes = hand_db(model).to_bytes().expect("bytes");
        std::fs::write(
            root.join(format!("db_loader/{}.sprdlt", model.name())),
            bytes,
        )
        .expect("w");
    }
    let (w, h) = (4usize, 3usize);
    let plain: Vec<(String, Vec<f32>)> = ["R", "G", "B", "A", "Z", "forward.u", "forward.v"]
        .iter()
        .map(|n| {
            (
                n.to_string(),
                vec![if *n == "Z" { 2.0 } else { 0.5 }; w * h],
            )
        })
        .collect();
    write_exr(&root.join("gbuffer_exr/plain.exr"), w, h, plain);
    let blender: Vec<(String, Vec<f32>)> = [
        "ViewLayer.Combined.R",
        "ViewLayer.Combined.G",
        "ViewLayer.Combined.B",
        "ViewLayer.Combined.A",
        "ViewLayer.Depth.Z",
        "ViewLayer.Vector.X",
        "ViewLayer.Vector.Y",
        "ViewLayer.Vector.Z",
        "ViewLayer.Vector.W",
    ]
    .iter()
    .map(|n| (n.to_string(), vec![1.0; w * h]))
    .collect();
    write_exr(&root.join("gbuffer_exr/blender.exr"), w, h, blender);
    std::fs::write(root.join("camera_json/lens.json"), camera_json(true, 0.5)).expect("w");
    std::fs::write(
        root.join("camera_json/pinhole.json"),
        camera_json(false, 0.0),
    )
    .expect("w");
    // 3x2 pixels holding 0 to 2 samples, with motion and one volume sample.
    let sample = |a: f32, z: f32| spreadlet::formats::DeepSample {
        color: [0.5 * a, 0.25 * a, 0.125 * a, a],
        depth: z,
        depth_back: z,
        motion: [1.0, -0.5],
    };
    let mut samples = vec![sample(0.5, 1.0), sample(1.0, 2.0), sample(1.0, 3.0)];
    samples.push(sample(0.25, 1.5));
    samples[3].depth_back = 1.75;
    samples.extend([sample(1.0, 2.5), sample(0.75, 4.0)]);
    let deep =
        spreadlet::formats::DeepImage::from_samples(3, 2, vec![0, 2, 3, 3, 5, 6, 6], samples, true)
            .expect("valid deep image");
    for (name, compression) in [
        ("none", spreadlet::formats::DeepCompression::None),
        ("rle", spreadlet::formats::DeepCompression::Rle),
        ("zips", spreadlet::formats::DeepCompression::Zips),
    ] {
        deep.write(&root.join(format!("deep_exr/{name}.exr")), compression)
            .expect("w");
    }
}
