//! The library is fit to embed: what `cargo tree -p spreadlet` resolves holds no code built by a
//! C or C++ compiler (`cc`), no terminal or command-line crate, and the crate declares no
//! dependency its source does not use.

use std::path::{Path, PathBuf};
use std::process::Command;

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("runtime/ sits in the workspace")
        .to_path_buf()
}

/// The names of the packages `cargo tree` resolves for the library with its default features,
/// normal and build dependencies, for the host.
fn resolved_packages() -> Vec<String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(workspace_root())
        .args([
            "tree",
            "-p",
            "spreadlet",
            "-e",
            "normal,build",
            "--prefix",
            "none",
        ])
        .output()
        .expect("cargo tree runs");
    assert!(
        out.status.success(),
        "cargo tree failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut names: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .collect();
    names.sort();
    names.dedup();
    names
}

#[test]
fn the_library_pulls_in_no_cpp_build_and_no_terminal_crates() {
    let names = resolved_packages();
    assert!(
        names.iter().any(|n| n == "spreadlet"),
        "the tree lists the library itself: {names:?}"
    );
    let forbidden = [
        // Compiles C or C++ in a build script: an embedder would need a C++ toolchain.
        "cc",
        "cmake",
        "nv-flip",
        "nv-flip-sys",
        // Command-line and terminal crates belong to the binaries.
        "indicatif",
        "console",
        "clap",
        "anyhow",
    ];
    let found: Vec<&String> = names
        .iter()
        .filter(|n| forbidden.contains(&n.as_str()))
        .collect();
    assert!(
        found.is_empty(),
        "`cargo tree -p spreadlet -e normal,build` has {found:?}; see `cargo tree -p spreadlet \
         -e normal,build -i NAME` for who pulls it in"
    );
}

/// The `[dependencies]` of `runtime/Cargo.toml`, by the name the source uses.
fn declared_dependencies() -> Vec<String> {
    let manifest =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml"))
            .expect("runtime/Cargo.toml");
    let mut in_deps = false;
    let mut names = Vec::new();
    for line in manifest.lines() {
        let line = line.trim();
        if line.starts_with('[') {
            in_deps = line == "[dependencies]";
            continue;
        }
        if !in_deps || line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(name) = line.split(['=', '.', ' ']).next() {
            names.push(name.trim().replace('-', "_"));
        }
    }
    names
}

fn rust_sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("source folder").flatten() {
        let path = entry.path();
        if path.is_dir() {
            rust_sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn every_declared_dependency_is_used() {
    let mut files = Vec::new();
    rust_sources(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("src"),
        &mut files,
    );
    let source: String = files
        .iter()
        .map(|f| std::fs::read_to_string(f).expect("source file"))
        .collect();
    let declared = declared_dependencies();
    assert!(declared.len() >= 5, "parsed {declared:?}");
    let unused: Vec<&String> = declared
        .iter()
        .filter(|name| {
            !(source.contains(&format!("{name}::")) || source.contains(&format!("use {name}")))
        })
        .collect();
    assert!(
        unused.is_empty(),
        "runtime/Cargo.toml declares {unused:?}, which runtime/src never uses"
    );
}
