//! The Blender add-on (`blender/spreadlet_blender`) in a real, headless Blender: it renders a
//! small scene as a pinhole, runs `spreadlet synth` on it and must come clearly closer to
//! Cycles' own depth of field and motion blur than its pinhole input, with the camera values
//! it read equal to the ones the scene set (`blender/tests/test_addon.py`). Without Blender the
//! test says so and passes, unless `SPREADLET_REQUIRE_BLENDER=1` (CI) makes that a failure.

use std::path::Path;
use std::process::Command;

use spreadlet_e2e::{binary, cache_dir};

#[test]
fn the_addon_adds_depth_of_field_and_motion_blur_in_blender() {
    let blender = std::env::var("BLENDER").unwrap_or_else(|_| "blender".into());
    let found = Command::new(&blender)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !found {
        assert!(
            std::env::var("SPREADLET_REQUIRE_BLENDER").as_deref() != Ok("1"),
            "SPREADLET_REQUIRE_BLENDER=1 but `{blender}` does not run (apt-get install blender)"
        );
        eprintln!("no Blender ({blender}): the add-on test is skipped");
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = tempfile::tempdir().expect("temp dir");
    let run = Command::new(&blender)
        .args([
            "-b",
            "--factory-startup",
            "--python-exit-code",
            "1",
            "--python",
        ])
        .arg(root.join("blender/tests/test_addon.py"))
        .arg("--")
        .arg(out.path())
        .env("SPREADLET_BIN", binary("spreadlet"))
        .env("SPREADLET_CACHE", cache_dir())
        .output()
        .expect("blender starts");
    let stdout = String::from_utf8_lossy(&run.stdout);
    let summary: Vec<&str> = stdout
        .lines()
        .filter(|l| l.contains("SSIM") || l.contains("Error") || l.contains("Traceback"))
        .collect();
    eprintln!("{}", summary.join("\n"));
    assert!(
        run.status.success(),
        "the add-on test failed in Blender:\n{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
}
