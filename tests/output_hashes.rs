//! The CPU path's outputs, byte for byte, against hashes recorded in
//! `tests/data/output_hashes.txt`: a guard for changes that must not change a pixel (moving
//! code between modules, new entry points, a faster loop that claims the same result).
//!
//! Every built-in scene at 128 px as a flat G-buffer, one as deep input, one as view layers and
//! one as stochastic frames; with `../shared/examples`, both Blender examples flat and layered
//! at 512 px and the comets' stochastic frames. Inputs are hashed too, so a mismatch says
//! whether the scene renderer or the synthesis changed.
//!
//! A change that is meant to change pictures re-records the table:
//! `SPREADLET_RECORD_HASHES=1 cargo test -p spreadlet-e2e --test output_hashes`, and the
//! commit says why the bytes moved.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use spreadlet_e2e::{assert_success, cache_dir, render_inputs_128, run, shared_examples};

/// FNV-1a, 64 bits: small, stable across platforms and Rust versions, enough to tell bytes apart.
fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

fn hash_file(path: &Path) -> String {
    let bytes =
        std::fs::read(path).unwrap_or_else(|e| panic!("reading {} failed: {e}", path.display()));
    format!("{:016x}", fnv1a64(&bytes))
}

fn s(path: &Path) -> String {
    path.to_str().expect("utf-8 path").to_string()
}

fn table_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/output_hashes.txt")
}

fn read_table() -> BTreeMap<String, String> {
    let text = std::fs::read_to_string(table_path()).unwrap_or_default();
    text.lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .filter_map(|l| {
            let mut parts = l.split_whitespace();
            Some((parts.next()?.to_string(), parts.next()?.to_string()))
        })
        .collect()
}

/// `spreadlet <command>` on the CPU with `inputs`, `camera` and `extra`, into `out`.
fn spreadlet(command: &str, inputs: &[&Path], camera: &Path, out: &Path, extra: &[&str]) {
    let mut args: Vec<String> = vec![
        command.into(),
        "-q".into(),
        "--backend".into(),
        "cpu".into(),
    ];
    for input in inputs {
        args.extend(["--input".into(), s(input)]);
    }
    args.extend(["--camera".into(), s(camera), "--out".into(), s(out)]);
    args.extend(extra.iter().map(|a| a.to_string()));
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    assert_success(&run("spreadlet", &refs, &cache_dir()));
}

#[test]
fn cpu_outputs_match_their_recorded_hashes() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let mut got: BTreeMap<String, String> = BTreeMap::new();

    for scene in [
        "bokeh", "crossing", "occluder", "physical", "rain", "rotating", "studio",
    ] {
        let dir = tmp.path().join(scene);
        std::fs::create_dir_all(&dir).expect("scene dir");
        render_inputs_128(&dir, scene, &[]);
        let (g, cam, out) = (dir.join("g.exr"), dir.join("cam.json"), dir.join("out.exr"));
        spreadlet("synth", &[&g], &cam, &out, &[]);
        got.insert(format!("{scene}/input"), hash_file(&g));
        got.insert(format!("{scene}/synth"), hash_file(&out));
    }

    // Deep input: every deep sample blurred with its own depth and motion.
    let dir = tmp.path().join("occluder-deep");
    std::fs::create_dir_all(&dir).expect("deep dir");
    let deep = dir.join("deep.exr");
    render_inputs_128(&dir, "occluder", &["--deep", &s(&deep)]);
    let out = dir.join("out.exr");
    spreadlet("synth", &[&deep], &dir.join("cam.json"), &out, &[]);
    got.insert("occluder/deep-input".into(), hash_file(&deep));
    got.insert("occluder/deep-synth".into(), hash_file(&out));

    // View layers: a moving foreground over its background.
    let dir = tmp.path().join("crossing-layers");
    std::fs::create_dir_all(&dir).expect("layers dir");
    let layers = dir.join("layers.exr");
    render_inputs_128(
        &dir,
        "crossing",
        &["--view-layers", &s(&layers), "--foreground", "near sphere"],
    );
    let out = dir.join("out.exr");
    spreadlet("synth", &[&layers], &dir.join("cam.json"), &out, &[]);
    got.insert("crossing/layers-input".into(), hash_file(&layers));
    got.insert("crossing/layers-synth".into(), hash_file(&out));

    // Stochastic frames: reconstruction from 1 spp, and from 4 spp, where samples are split
    // over pixels rather than given footprints.
    let dir = tmp.path().join("bokeh-stochastic");
    std::fs::create_dir_all(&dir).expect("stochastic dir");
    for (spp, tag) in [("1", ""), ("4", "-4spp")] {
        let frames = dir.join(format!("frames{tag}.exr"));
        render_inputs_128(&dir, "bokeh", &["--stochastic", &s(&frames), "--spp", spp]);
        let out = dir.join(format!("out{tag}.exr"));
        spreadlet("reconstruct", &[&frames], &dir.join("cam.json"), &out, &[]);
        got.insert(format!("bokeh/stochastic-input{tag}"), hash_file(&frames));
        got.insert(format!("bokeh/reconstruct{tag}"), hash_file(&out));
    }

    if let Some(examples) = shared_examples() {
        for example in ["comets", "fence"] {
            let dir = examples.join(example);
            let cam = dir.join("camera.json");
            for (input, key) in [("input.exr", "synth"), ("layers.exr", "layers-synth")] {
                let out = tmp.path().join(format!("{example}-{key}.exr"));
                spreadlet("synth", &[&dir.join(input)], &cam, &out, &[]);
                got.insert(format!("shared-{example}/{key}"), hash_file(&out));
            }
        }
        let dir = examples.join("comets/stochastic");
        let out = tmp.path().join("comets-reconstruct.exr");
        spreadlet(
            "reconstruct",
            &[&dir.join("stochastic_1spp.exr")],
            &dir.join("camera.json"),
            &out,
            &[],
        );
        got.insert("shared-comets/reconstruct-1spp".into(), hash_file(&out));
    }

    if std::env::var("SPREADLET_RECORD_HASHES").as_deref() == Ok("1") {
        let mut text = String::from(
            "# FNV-1a 64 of each output file of tests/output_hashes.rs (CPU path, default \
             options).\n# Re-record with SPREADLET_RECORD_HASHES=1 only when pictures are \
             meant to change.\n",
        );
        let mut merged = read_table();
        merged.extend(got);
        for (name, hash) in merged {
            text.push_str(&format!("{name} {hash}\n"));
        }
        std::fs::create_dir_all(table_path().parent().expect("tests/data")).expect("mkdir");
        std::fs::write(table_path(), text).expect("write the table");
        return;
    }

    let recorded = read_table();
    let mut wrong = Vec::new();
    for (name, hash) in &got {
        match recorded.get(name) {
            Some(want) if want == hash => {}
            Some(want) => wrong.push(format!("{name}: {hash}, recorded {want}")),
            None => wrong.push(format!("{name}: {hash}, not recorded")),
        }
    }
    assert!(
        wrong.is_empty(),
        "outputs differ from tests/data/output_hashes.txt (a '/input' line means the scene \
         renderer changed):\n  {}",
        wrong.join("\n  ")
    );
}
