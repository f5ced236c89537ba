//! The `precompute` binary: builds a database it can read back, and fails cleanly on bad input.

use std::process::Command;

fn precompute() -> Command {
    Command::new(env!("CARGO_BIN_EXE_precompute"))
}

#[test]
fn builds_a_test_database_and_a_report() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tl.sprdlt");
    let report = dir.path().join("tl.json");
    let status = precompute()
        .args([
            "--model",
            "thin-lens",
            "--profile",
            "test",
            "--blades",
            "6",
            "--out",
        ])
        .arg(&out)
        .arg("--report")
        .arg(&report)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let db = psf_db::PsfDatabase::read(&out).unwrap();
    assert_eq!(db.header().aperture.blades, 6);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(json["psfs"].as_array().unwrap().len(), db.psf_count());
    assert!(json["mean_sparsity"].as_f64().is_some());
    assert!(json["mean_similarity"].as_f64().is_some());
}

#[test]
fn bad_input_is_a_clear_error_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.sprdlt");
    for args in [
        vec!["--model", "pinhole", "--profile", "test"],
        vec!["--model", "thin-lens", "--profile", "huge"],
        vec![
            "--model",
            "thin-lens",
            "--profile",
            "test",
            "--spreadlet-budget",
            "-1",
        ],
        vec!["--model", "thin-lens", "--profile", "test", "--blades", "2"],
        vec!["--model", "thin-lens", "--profile", "test", "--rays", "0"],
        vec![
            "--model",
            "thin-lens",
            "--profile",
            "test",
            "--stop-diameter",
            "3",
        ],
        vec![
            "--model",
            "physical-lens",
            "--profile",
            "test",
            "--focus-distance",
            "0.01",
        ],
        vec![
            "--model",
            "physical-lens",
            "--profile",
            "test",
            "--lens-radius-back",
            "40",
        ],
    ] {
        let o = precompute()
            .args(&args)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(!o.status.success(), "{args:?} succeeded");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(err.contains("rror"), "{args:?}: {err}");
        assert!(!out.exists());
    }
}
