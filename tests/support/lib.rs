//! Shared fixtures for the end-to-end tests in `tests/`: the workspace's binaries, run the way a
//! user runs them.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// The folder the test binary's profile writes executables to (`target/<profile>`).
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test binary knows its path");
    // target/<profile>/deps/<test binary>
    exe.parent()
        .and_then(Path::parent)
        .expect("test binaries live in target/<profile>/deps")
        .to_path_buf()
}

/// Path of the workspace binary `name` (`spreadlet`, `precompute`, `spreadlet-scene`), built
/// once per test process when `cargo test` did not build it already (as with `-p
/// spreadlet-e2e` alone). `cargo test --workspace` builds each of them for its own package's
/// `tests/cli.rs`, so they are never older than the library the tests link. With `-p
/// spreadlet-e2e` alone, a binary left from an earlier build is used as it is: after changing
/// the sources, run `cargo build --bins -p spreadlet-cli -p precompute -p scene` first. (Building
/// here every time would not find the workspace's build up to date: `cargo test --workspace`
/// resolves features across every package, so it would build the binaries a second time.)
pub fn binary(name: &str) -> PathBuf {
    static BUILT: OnceLock<()> = OnceLock::new();
    let path = profile_dir().join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    if !path.exists() {
        BUILT.get_or_init(|| {
            let release = profile_dir().ends_with("release");
            let mut cmd = Command::new(env!("CARGO"));
            cmd.args([
                "build",
                "--bins",
                "-p",
                "spreadlet-cli",
                "-p",
                "precompute",
                "-p",
                "scene",
            ]);
            if release {
                cmd.arg("--release");
            }
            let status = cmd
                .current_dir(env!("CARGO_MANIFEST_DIR"))
                .status()
                .expect("cargo runs");
            assert!(status.success(), "building the binaries failed");
        });
    }
    assert!(path.exists(), "{} was not built", path.display());
    path
}

/// Runs `name args...` with the database cache in `cache` and returns its output.
pub fn run(name: &str, args: &[&str], cache: &Path) -> Output {
    Command::new(binary(name))
        .args(args)
        .env("SPREADLET_CACHE", cache)
        .output()
        .expect("the binary starts")
}

/// The shared database cache of the test run (`$SPREADLET_CACHE`, else `target/spreadlet-cache`),
/// so databases are built once per run.
pub fn cache_dir() -> PathBuf {
    match std::env::var_os("SPREADLET_CACHE") {
        Some(v) if !v.is_empty() => PathBuf::from(v),
        _ => profile_dir()
            .parent()
            .map(|t| t.join("spreadlet-cache"))
            .unwrap_or_else(|| PathBuf::from("target/spreadlet-cache")),
    }
}

/// Asserts that a command failed cleanly: non-zero exit, a message on stderr naming `needle`,
/// and no panic.
pub fn assert_clean_failure(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "expected a failure, got success; stderr: {stderr}"
    );
    assert!(
        !stderr.contains("panicked"),
        "the program panicked instead of reporting an error: {stderr}"
    );
    assert!(
        stderr.to_lowercase().contains(&needle.to_lowercase()),
        "stderr does not mention {needle:?}: {stderr}"
    );
}

/// Asserts success and returns stdout.
pub fn assert_success(out: &Output) -> String {
    assert!(
        out.status.success(),
        "command failed ({}): {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Renders `scene` (a built-in name or a file) at 128 x 128 into `dir`: the flat G-buffer
/// `g.exr`, the 256-spp reference `ref.exr` and the camera `cam.json`, plus whatever `extra`
/// asks for (`--deep F`, `--view-layers F --foreground NAMES`).
pub fn render_scene_128(dir: &Path, scene: &str, extra: &[&str]) {
    render_128(dir, scene, extra, true);
}

/// [`render_scene_128`] without the reference: the G-buffer `g.exr`, the camera `cam.json` and
/// whatever `extra` asks for (`--stochastic F --spp N` too).
pub fn render_inputs_128(dir: &Path, scene: &str, extra: &[&str]) {
    render_128(dir, scene, extra, false);
}

fn render_128(dir: &Path, scene: &str, extra: &[&str], with_reference: bool) {
    let d = |n: &str| dir.join(n).to_str().expect("utf-8 path").to_string();
    let (g, reference, camera) = (d("g.exr"), d("ref.exr"), d("cam.json"));
    let mut args = vec![
        "render",
        scene,
        "--width",
        "128",
        "--height",
        "128",
        "--gbuffer",
        &g,
    ];
    args.extend_from_slice(extra);
    if with_reference {
        args.extend(["--reference", &reference, "--ref-spp", "256"]);
    }
    args.extend(["--camera-out", &camera, "--quiet"]);
    assert_success(&run("spreadlet-scene", &args, &cache_dir()));
}

/// SSIM and FLIP mean of `image` against `reference`, by `spreadlet compare --json`.
pub fn compare_scores(image: &Path, reference: &Path) -> (f64, f64) {
    let path = |p: &Path| p.to_str().expect("utf-8 path").to_string();
    let out = run(
        "spreadlet",
        &["compare", &path(image), &path(reference), "--json"],
        &cache_dir(),
    );
    let json: serde_json::Value =
        serde_json::from_str(&assert_success(&out)).expect("compare writes JSON");
    (
        json["ssim"].as_f64().expect("ssim"),
        json["flip_mean"].as_f64().expect("flip"),
    )
}

/// Checks a `spreadlet synth --backend gpu` run (`ran`, which wrote `gpu`) against the CPU's
/// image of the same frame (`cpu`): every channel of every pixel within 1e-4 (relative above
/// 1). Without a usable GPU the run may fail, unless `SPREADLET_REQUIRE_GPU=1`; `what` names
/// the case that then goes unchecked.
pub fn assert_gpu_run_matches(ran: &Output, gpu: &Path, cpu: &Path, what: &str) {
    if ran.status.success() {
        let read = |p: &Path| formats::RgbaImage::read_exr(p).expect("an output image");
        let (a, b) = (read(gpu), read(cpu));
        assert_eq!((a.width, a.height), (b.width, b.height));
        let worst = a
            .pixels
            .iter()
            .zip(&b.pixels)
            .flat_map(|(x, y)| (0..4).map(move |k| (x[k] - y[k]).abs() / y[k].abs().max(1.0)))
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "{what}: GPU and CPU differ by {worst}");
    } else {
        assert!(
            std::env::var("SPREADLET_REQUIRE_GPU").as_deref() != Ok("1"),
            "SPREADLET_REQUIRE_GPU=1 but the GPU run failed: {}",
            String::from_utf8_lossy(&ran.stderr)
        );
        eprintln!("no GPU: {what} is not checked on the GPU");
    }
}

/// Runs `name args...` like [`run`], but kills it after `limit` and fails the test then (a
/// hang is a failure). Returns its output.
pub fn run_with_timeout(
    name: &str,
    args: &[&str],
    cache: &Path,
    limit: std::time::Duration,
) -> Output {
    use std::io::Read;
    use std::process::Stdio;
    let mut child = Command::new(binary(name))
        .args(args)
        .env("SPREADLET_CACHE", cache)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the binary starts");
    // Drain the pipes on threads so a chatty child cannot block on a full pipe.
    let drain = |pipe: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            if let Some(mut p) = pipe {
                let _ = p.read_to_end(&mut buf);
            }
            buf
        })
    };
    let out_thread = drain(
        child
            .stdout
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let err_thread = drain(
        child
            .stderr
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait on the child") {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{name} {args:?} did not finish within {limit:?} (a hang)");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    Output {
        status,
        stdout: out_thread.join().unwrap_or_default(),
        stderr: err_thread.join().unwrap_or_default(),
    }
}

/// The files in `dir` (names), sorted: to check that a failed command left nothing behind
/// (no output, no temporary file).
pub fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

/// The shared Blender examples (`$SPREADLET_EXAMPLES`, else `../shared/examples` beside the
/// checkout), or `None` when this checkout has none; with `SPREADLET_REQUIRE_SHARED=1` a missing folder is a
/// failure.
pub fn shared_examples() -> Option<PathBuf> {
    let beside = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/examples");
    let found = [
        std::env::var_os("SPREADLET_EXAMPLES").map(PathBuf::from),
        Some(beside),
    ]
    .into_iter()
    .flatten()
    .find(|p| p.join("fence/layers.exr").exists());
    if found.is_none() {
        assert!(
            std::env::var("SPREADLET_REQUIRE_SHARED").as_deref() != Ok("1"),
            "SPREADLET_REQUIRE_SHARED=1 but ../shared/examples is missing"
        );
    }
    found
}
