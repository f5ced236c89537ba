//! `spreadlet study` end to end on a tiny input (built-in 'bokeh' at 64x64): the CSV has the documented
//! columns, every method appears, the dense splat (the method's quality upper bound) scores at
//! least as well as the sparsest spreadlet database, the Pareto front is consistent, and the
//! Markdown table and the PNG plot are written.

use spreadlet_harness::study::{findings, mark_pareto, run, StudyOptions, StudyRow, CSV_COLUMNS};

#[test]
fn tiny_study_writes_csv_markdown_and_plot() {
    let dir = tempfile::tempdir().expect("tempdir");
    let options = StudyOptions {
        out_dir: dir.path().to_path_buf(),
        scene: "bokeh".into(),
        size: Some(64),
        tiny: true,
        profile: precompute::Profile::Test,
        runs: 1,
        reference_spp: 64,
        gpu: false,
        quiet: true,
        ..StudyOptions::default()
    };
    let rows = run(&options).expect("study");

    let csv = std::fs::read_to_string(dir.path().join("study.csv")).expect("csv");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    assert_eq!(header, CSV_COLUMNS);
    for needed in ["method", "knob", "value", "ssim", "psnr", "ms"] {
        assert!(header.contains(&needed), "{needed}");
    }
    let records: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(records.len(), rows.len());
    assert!(records.iter().all(|r| r.len() == CSV_COLUMNS.len()));
    for m in ["spreadlet", "dense", "filter"] {
        assert!(records.iter().any(|r| r[0].contains(m)), "no {m} row");
    }
    for r in &rows {
        assert!(r.ssim > 0.0 && r.ssim <= 1.0, "{r:?}");
        assert!(r.ms > 0.0, "{r:?}");
    }

    let at = |method: &str, knob: &str, value: &str| -> &StudyRow {
        rows.iter()
            .find(|r| r.method == method && r.knob == knob && r.value == value)
            .unwrap_or_else(|| panic!("no row {method} {knob}={value}"))
    };
    let dense = at("dense", "baseline", "dense");
    let sparse = at("spreadlet-sparse", "budget", "0.5");
    assert_eq!(dense.sparse, 0, "the dense baseline draws no spreadlets");
    assert_eq!(dense.db_spreadlets, 0);
    assert!(sparse.sparse > 0, "the spreadlet row draws spreadlets");
    // The dense splat is the method's upper bound: the sparsest spreadlets do no better, up to
    // the "equal SSIM" tolerance of 0.005 (measured: 0.8836 dense, 0.8838 spreadlets
    // at budget 0.5; 0.852 before the conditioning changes of the same day).
    assert!(
        dense.ssim >= sparse.ssim - 0.005,
        "dense {} < spreadlet at budget 0.5 {}",
        dense.ssim,
        sparse.ssim
    );
    let f = findings(&rows);
    assert!(f.dense.is_some() && f.filter.is_some() && f.spreadlet_base.is_some());
    // Every method does better than the pinhole input itself.
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("study.json")).expect("json"),
    )
    .expect("json parses");
    let pinhole = json["findings"]["pinhole_ssim"]
        .as_f64()
        .expect("pinhole ssim");
    for r in &rows {
        assert!(
            r.ssim > pinhole + 0.01,
            "{} {}={}: {} vs pinhole {pinhole}",
            r.method,
            r.knob,
            r.value,
            r.ssim
        );
    }

    // The front holds the fastest and the best row, and no front row is dominated.
    let fastest = rows
        .iter()
        .min_by(|a, b| a.ms.total_cmp(&b.ms))
        .expect("rows");
    let best = rows
        .iter()
        .max_by(|a, b| a.ssim.total_cmp(&b.ssim))
        .expect("rows");
    // (Ties: some row of the best SSIM and some row of the lowest time.)
    assert!(rows.iter().any(|r| r.pareto && r.ms == fastest.ms));
    assert!(rows.iter().any(|r| r.pareto && r.ssim == best.ssim));
    assert!(rows
        .iter()
        .filter(|r| r.pareto)
        .all(|r| !rows.iter().any(|o| o.ssim > r.ssim && o.ms < r.ms)));

    let md = std::fs::read_to_string(dir.path().join("study.md")).expect("md");
    assert!(md.contains("| method | knob | value |"));
    assert!(md.contains("Dense splat"));
    let png = image::open(dir.path().join("study.png")).expect("png");
    assert_eq!((png.width(), png.height()), (960, 640));
}

#[test]
fn pareto_front_keeps_only_undominated_rows() {
    let row = |ssim: f64, ms: f64| StudyRow {
        ssim,
        ms,
        ..StudyRow::default()
    };
    let mut rows = vec![
        row(0.9, 10.0),
        row(0.95, 20.0),
        row(0.93, 30.0),
        row(0.99, 100.0),
    ];
    mark_pareto(&mut rows);
    let flags: Vec<bool> = rows.iter().map(|r| r.pareto).collect();
    assert_eq!(flags, vec![true, true, false, true]);
}

/// The speed-up at equal SSIM compares rows that layer like the dense splat: a faster row
/// with fewer layers does not count, a row with fewer spreadlets does; rows that draw most
/// records through the fast track do not count either.
#[test]
fn equal_ssim_speedup_compares_like_with_like() {
    let row = |method: &str, knob: &str, value: &str, ssim: f64, ms: f64, sparse: usize| StudyRow {
        method: method.into(),
        knob: knob.into(),
        value: value.into(),
        backend: "cpu".into(),
        ssim,
        ms,
        sparse,
        dense: 10,
        ..StudyRow::default()
    };
    let rows = vec![
        row("dense", "baseline", "dense", 0.90, 100.0, 0),
        row("spreadlet", "base", "-", 0.90, 40.0, 100),
        row("spreadlet", "layers", "1", 0.899, 5.0, 100),
        row(
            "spreadlet",
            "joint",
            "budget=1; layers=2; integration=pyramid",
            0.899,
            6.0,
            100,
        ),
        row("spreadlet", "fast_track", "1", 0.90, 8.0, 1),
        row("spreadlet", "budget_pyramid", "0.5", 0.896, 20.0, 100),
        row("spreadlet-sparse", "budget", "0.5", 0.80, 2.0, 100),
    ];
    let f = findings(&rows);
    let (cfg, ssim, ms) = f.spreadlet_at_dense_ssim.expect("a row within 0.005");
    assert_eq!(cfg, "spreadlet budget_pyramid=0.5");
    assert_eq!((ssim, ms), (0.896, 20.0));
    assert_eq!(f.speedup_at_equal_ssim, Some(5.0));
    assert_eq!(f.speedup_base, Some(2.5));
}
