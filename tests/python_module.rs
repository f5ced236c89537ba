//! The Python module (`python/`) built and installed the way a user installs it (`pip install
//! ./python`, maturin) into the Python that `SPREADLET_PYTHON` names (with pytest and numpy),
//! then its tests (`python/tests`): the module's result equals the CLI's bit for bit, a second
//! call reuses the databases, bad input raises `ValueError`. Without that Python the test says
//! so and passes, unless `SPREADLET_REQUIRE_PYTHON=1` (CI) makes that a failure.

use std::path::Path;
use std::process::Command;

use spreadlet_e2e::{binary, cache_dir};

#[test]
fn the_python_module_installs_and_passes_its_tests() {
    let Ok(python) = std::env::var("SPREADLET_PYTHON") else {
        assert!(
            std::env::var("SPREADLET_REQUIRE_PYTHON").as_deref() != Ok("1"),
            "SPREADLET_REQUIRE_PYTHON=1 but SPREADLET_PYTHON names no Python"
        );
        eprintln!("SPREADLET_PYTHON is not set: the Python module's test is skipped");
        return;
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // Its own target folder: the build runs while this test process holds the workspace's.
    // CI builds it without the GPU backend (the CPU path is what the tests compare).
    let target = root.join("target/python-module");
    // The build backend runs `maturin` from the environment's scripts folder.
    let scripts = Path::new(&python).parent().unwrap_or(Path::new("."));
    let path = match std::env::var_os("PATH") {
        Some(p) => std::env::join_paths(
            std::iter::once(scripts.to_path_buf()).chain(std::env::split_paths(&p)),
        )
        .unwrap_or(p),
        None => scripts.as_os_str().to_owned(),
    };
    let install = Command::new(&python)
        .args(["-m", "pip", "install", "--quiet", "--no-build-isolation"])
        .arg(root.join("python"))
        .env("CARGO_TARGET_DIR", &target)
        .env("PATH", &path)
        .env(
            "MATURIN_PEP517_ARGS",
            std::env::var("SPREADLET_PYTHON_BUILD_ARGS").unwrap_or_default(),
        )
        .output()
        .expect("python starts");
    assert!(
        install.status.success(),
        "pip install ./python failed:\n{}\n{}",
        String::from_utf8_lossy(&install.stdout),
        String::from_utf8_lossy(&install.stderr)
    );
    let tests = Command::new(&python)
        .args(["-m", "pytest", "-q"])
        .arg(root.join("python/tests"))
        .env("SPREADLET_BIN", binary("spreadlet"))
        .env("SPREADLET_SCENE_BIN", binary("spreadlet-scene"))
        .env("SPREADLET_CACHE", cache_dir())
        .output()
        .expect("pytest starts");
    let out = String::from_utf8_lossy(&tests.stdout);
    eprintln!("{}", out.lines().last().unwrap_or_default());
    assert!(
        tests.status.success(),
        "the Python module's tests failed:\n{out}\n{}",
        String::from_utf8_lossy(&tests.stderr)
    );
}
