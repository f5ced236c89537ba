//! A database built as one part and as three shards merged is the same file, byte for
//! byte; parts that do not belong together, or do not cover every PSF, are refused by name.

use spreadlet_e2e::{assert_clean_failure, assert_success, cache_dir, run};

fn precompute(args: &[&str]) -> std::process::Output {
    run("precompute", args, &cache_dir())
}

#[test]
fn three_shards_merge_to_the_single_build_bytes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = |name: &str| dir.path().join(name).to_string_lossy().into_owned();
    let base = ["--model", "lens-motion", "--profile", "test", "--seed", "5"];
    let single = p("single.sprdlt");
    assert_success(&precompute(&[&base[..], &["--out", &single]].concat()));
    for k in 0..3 {
        let shard = format!("{k}/3");
        let out = p(&format!("part-{k}.sprdlt"));
        assert_success(&precompute(
            &[&base[..], &["--shard", &shard, "--out", &out]].concat(),
        ));
    }
    let merged = p("merged.sprdlt");
    // Parts in another order than their index: merge sorts them.
    assert_success(&precompute(&[
        "merge",
        &p("part-2.sprdlt"),
        &p("part-0.sprdlt"),
        &p("part-1.sprdlt"),
        "--out",
        &merged,
    ]));
    let a = std::fs::read(&single).expect("single");
    let b = std::fs::read(&merged).expect("merged");
    assert!(
        a == b,
        "merged file differs from the single build ({} vs {} bytes)",
        b.len(),
        a.len()
    );

    // A part alone is not a database for the runtime.
    let part = psf_db::PsfDatabase::read(p("part-1.sprdlt")).expect("part reads");
    assert!(part.expect_model(psf_db::PsfModel::LensMotion).is_err());

    // Incomplete and mismatched parts.
    let out = p("bad.sprdlt");
    assert_clean_failure(
        &precompute(&[
            "merge",
            &p("part-0.sprdlt"),
            &p("part-2.sprdlt"),
            "--out",
            &out,
        ]),
        "missing part(s) 1/3",
    );
    let other = p("other-1.sprdlt");
    assert_success(&precompute(&[
        "--model",
        "lens-motion",
        "--profile",
        "test",
        "--seed",
        "6",
        "--shard",
        "1/3",
        "--out",
        &other,
    ]));
    assert_clean_failure(
        &precompute(&[
            "merge",
            &p("part-0.sprdlt"),
            &other,
            &p("part-2.sprdlt"),
            "--out",
            &out,
        ]),
        "seed differs",
    );
    assert!(
        !std::path::Path::new(&out).exists(),
        "a failed merge left a file"
    );
    assert_clean_failure(
        &precompute(&[&base[..], &["--shard", "3/3", "--out", &out]].concat()),
        "shard",
    );
}

#[test]
fn shard_auto_takes_the_index_from_the_batch_engine() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("p.sprdlt");
    let status = std::process::Command::new(spreadlet_e2e::binary("precompute"))
        .args([
            "--model",
            "thin-lens",
            "--profile",
            "test",
            "--shard",
            "auto/2",
            "--out",
        ])
        .arg(&out)
        .env_remove("SLURM_ARRAY_TASK_ID")
        .env("JOB_COMPLETION_INDEX", "1")
        .output()
        .expect("runs");
    assert_success(&status);
    let part = psf_db::PsfDatabase::read(&out).expect("part");
    let range = part.header().shard.expect("a partial file");
    assert_eq!((range.index, range.count), (1, 2));
}
