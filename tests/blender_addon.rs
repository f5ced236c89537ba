//! The Blender add-on (`blender/spreadlet_blender`) in a real, headless Blender: it renders a
//! small scene as a pinhole, runs `spreadlet synth` on it and must come clearly closer to
//! Cycles' own depth of field and motion blur than its pinhole input, with the camera values
//! it read equal to the ones the scene set; "Every render" must finish animation and still
//! renders; its camera reading must match `../shared/examples/*/camera.json`
//! (`blender/tests/test_addon.py`). Twice: in the Blender application on the PATH (Debian's
//! 3.4) and in the current Blender as the `bpy` module (`pip install bpy`) in the Python that
//! `SPREADLET_BPY_PYTHON` names. Without either the test says so and passes, unless
//! `SPREADLET_REQUIRE_BLENDER=1` or `SPREADLET_REQUIRE_BPY=1` (CI) makes that a failure.

use std::path::Path;
use std::process::Command;

use spreadlet_e2e::{binary, cache_dir};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Runs the add-on's test script with `command` (a Blender or a Python with `bpy`, the
/// script's path and `--` already given), writing into a fresh folder.
fn run_addon_test(mut command: Command, which: &str) {
    let out = tempfile::tempdir().expect("temp dir");
    let run = command
        .arg(out.path())
        .env("SPREADLET_BIN", binary("spreadlet"))
        .env("SPREADLET_CACHE", cache_dir())
        .output()
        .expect("blender starts");
    let stdout = String::from_utf8_lossy(&run.stdout);
    let summary: Vec<&str> = stdout
        .lines()
        .filter(|l| {
            l.contains("SSIM")
                || l.contains("PSNR")
                || l.contains("camera.json")
                || l.contains("Error")
                || l.contains("Traceback")
        })
        .collect();
    eprintln!("{which}:\n{}", summary.join("\n"));
    assert!(
        run.status.success(),
        "the add-on test failed in {which}:\n{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
}

fn required(flag: &str) -> bool {
    std::env::var(flag).as_deref() == Ok("1")
}

#[test]
fn the_addon_adds_depth_of_field_and_motion_blur_in_blender() {
    let blender = std::env::var("BLENDER").unwrap_or_else(|_| "blender".into());
    let found = Command::new(&blender)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !found {
        assert!(
            !required("SPREADLET_REQUIRE_BLENDER"),
            "SPREADLET_REQUIRE_BLENDER=1 but `{blender}` does not run (apt-get install blender)"
        );
        eprintln!("no Blender ({blender}): the add-on test is skipped");
        return;
    }
    let mut command = Command::new(&blender);
    command
        .args([
            "-b",
            "--factory-startup",
            "--python-exit-code",
            "1",
            "--python",
        ])
        .arg(root().join("blender/tests/test_addon.py"))
        .arg("--");
    run_addon_test(command, &format!("Blender ({blender})"));
}

#[test]
fn the_addon_works_in_current_blender_as_the_bpy_module() {
    let Ok(python) = std::env::var("SPREADLET_BPY_PYTHON") else {
        assert!(
            !required("SPREADLET_REQUIRE_BPY"),
            "SPREADLET_REQUIRE_BPY=1 but SPREADLET_BPY_PYTHON names no Python with bpy"
        );
        eprintln!("SPREADLET_BPY_PYTHON is not set: the add-on test in current Blender is skipped");
        return;
    };
    let version = Command::new(&python)
        .args(["-c", "import bpy; print(bpy.app.version_string)"])
        .output()
        .expect("python starts");
    assert!(
        version.status.success(),
        "{python} cannot import bpy: {}",
        String::from_utf8_lossy(&version.stderr)
    );
    let mut command = Command::new(&python);
    command
        .arg(root().join("blender/tests/test_addon.py"))
        .arg("--");
    run_addon_test(
        command,
        &format!(
            "Blender {} (bpy module)",
            String::from_utf8_lossy(&version.stdout).trim()
        ),
    );
}
