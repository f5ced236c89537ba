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
/// spreadlet-e2e` alone).
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
                "runtime",
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
