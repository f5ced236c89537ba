//! The peer study on a tiny configuration: two built-in scenes at 40 px, a few
//! methods, the `test` database profile. Checks the table's shape and what holds by
//! construction: on a scene with a closed shutter the G-buffer motion-blur peers return the
//! G-buffer itself (equal scores, flagged as ignoring depth of field), defocus-only peers are
//! flagged on a moving scene, and the crops pick the best rows and the worst region.

use spreadlet_harness::peer_study::{
    hardest_region, run_with, PeerStudyConfig, PeerStudyOptions, RowKind, COLUMNS,
};

#[test]
fn tiny_study_writes_a_consistent_table_and_crops() {
    let dir = tempfile::tempdir().expect("temp dir");
    let options = PeerStudyOptions {
        out_dir: dir.path().join("peers"),
        full: false,
        db_profile: "test".into(),
        quiet: true,
    };
    let config = PeerStudyConfig {
        // rain's camera is a real lens: skipped, with the reason.
        scenes: vec!["bokeh".into(), "crossing".into(), "rain".into()],
        size: 40,
        reference_spp: 128,
        sample_peers: vec![
            (peers::PeerMethod::Shirley, 4),
            (peers::PeerMethod::Vaidyanathan, 4),
        ],
        spreadlet_spp: vec![1],
        gbuffer_methods: true,
        examples_dir: None,
        example_crop: None,
        seed: 2,
    };
    let report = run_with(&options, &config).expect("study runs");
    assert!(
        report.skipped.iter().any(|s| s.starts_with("rain:")),
        "{:?}",
        report.skipped
    );

    // Per scene: spreadlet synth, mcguire, guertin; spreadlet at 1 and 4 spp; the two peers;
    // averages at 1 and 4 spp.
    assert_eq!(report.rows.len(), 2 * 9, "{:#?}", report.rows);
    for scene in ["bokeh", "crossing"] {
        let rows: Vec<_> = report.rows.iter().filter(|r| r.scene == scene).collect();
        let names: Vec<String> = rows
            .iter()
            .map(|r| format!("{}@{:?}", r.method, r.spp))
            .collect();
        assert_eq!(
            names,
            [
                "spreadlet@None",
                "mcguire@None",
                "guertin@None",
                "spreadlet@Some(1)",
                "spreadlet@Some(4)",
                "shirley@Some(4)",
                "vaidyanathan@Some(4)",
                "average@Some(1)",
                "average@Some(4)",
            ]
        );
        for r in &rows {
            assert!(r.ssim > 0.0 && r.ssim <= 1.0, "{r:?}");
            assert!(r.psnr > 10.0, "{r:?}");
            assert!(r.ms.is_some_and(|m| m >= 0.0), "{r:?}");
        }
        // mcguire and guertin ignore defocus; both builtin scenes are defocused.
        for r in rows
            .iter()
            .filter(|r| r.input == "G-buffer" && r.kind == RowKind::Peer)
        {
            assert!(r.ignored.contains(&"depth of field"), "{r:?}");
        }
        // The crop shows the best spreadlet row and the best peer row.
        let crop = report
            .crops
            .iter()
            .find(|c| c.scene == scene)
            .expect("a crop per scene");
        let (ours, peer) = (&report.rows[crop.ours], &report.rows[crop.peer]);
        assert_eq!((ours.kind, peer.kind), (RowKind::Ours, RowKind::Peer));
        for r in &rows {
            match r.kind {
                RowKind::Ours => assert!(r.ssim <= ours.ssim),
                RowKind::Peer => assert!(r.ssim <= peer.ssim),
                RowKind::Baseline => {}
            }
        }
        assert!(dir.path().join("peers").join(&crop.file).exists());
    }
    // bokeh has a closed shutter: both motion-blur peers return the G-buffer unchanged.
    let bokeh = |m: &str| {
        report
            .rows
            .iter()
            .find(|r| r.scene == "bokeh" && r.method == m)
            .expect("row")
    };
    assert_eq!(bokeh("mcguire").ssim, bokeh("guertin").ssim);
    assert!(bokeh("vaidyanathan").ignored.is_empty());
    // crossing moves: vaidyanathan ignores its motion blur and says so.
    let crossing_v = report
        .rows
        .iter()
        .find(|r| r.scene == "crossing" && r.method == "vaidyanathan")
        .expect("row");
    assert_eq!(crossing_v.ignored, vec!["motion blur"]);

    // The files: a Markdown table with the columns and one line per row, a CSV likewise.
    let md = std::fs::read_to_string(dir.path().join("peers/peers.md")).expect("peers.md");
    let header = format!("| {} |", COLUMNS.join(" | "));
    assert!(md.contains(&header), "{md}");
    let table_rows = md
        .lines()
        .filter(|l| l.starts_with("| bokeh |") || l.starts_with("| crossing |"))
        .count();
    assert_eq!(table_rows, report.rows.len(), "{md}");
    assert!(md.contains("vaidyanathan †"), "{md}");
    assert!(md.contains("mcguire ‡"), "{md}");
    let csv = std::fs::read_to_string(dir.path().join("peers/peers.csv")).expect("peers.csv");
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines[0], format!("{},ignores", COLUMNS.join(",")));
    assert_eq!(lines.len(), report.rows.len() + 1);
    assert!(lines
        .iter()
        .all(|l| l.split(',').count() == COLUMNS.len() + 1));
}

#[test]
fn the_hardest_region_is_where_the_error_is() {
    let w = 32;
    let flat = |v: f32| formats::image::RgbaImage {
        width: w,
        height: w,
        pixels: vec![[v, v, v, 1.0]; w * w],
    };
    let reference = flat(0.2);
    let mut a = flat(0.2);
    let mut b = flat(0.2);
    // A wrong 3x3 block at (20, 5) in one image, a weaker one at (4, 24) in the other.
    for y in 5..8 {
        for x in 20..23 {
            a.pixels[y * w + x] = [0.9, 0.9, 0.9, 1.0];
        }
    }
    for y in 24..27 {
        for x in 4..7 {
            b.pixels[y * w + x] = [0.4, 0.4, 0.4, 1.0];
        }
    }
    let (x, y, edge) = hardest_region(&[&a, &b], &reference, 8);
    assert_eq!(edge, 8);
    assert!((15..=20).contains(&x) && (0..=5).contains(&y), "({x}, {y})");
}

/// An example folder with Cycles stochastic frames (`stochastic/`) gets spreadlet's
/// reconstruction beside Cycles + OIDN at the same paths per pixel; a set without its peer file
/// is left out.
#[test]
fn examples_with_stochastic_frames_get_reconstruction_beside_cycles_and_oidn() {
    let dir = tempfile::tempdir().expect("temp dir");
    let example = dir.path().join("examples").join("comets");
    std::fs::create_dir_all(example.join("stochastic")).expect("folders");
    let scene = scene::builtin("crossing")
        .and_then(|s| s.with_size(32, 32))
        .expect("scene");
    let render = scene::RenderOptions {
        seed: 3,
        ..Default::default()
    };
    scene::render_gbuffer(&scene, 4, &render)
        .and_then(|g| g.write_exr(&example.join("input.exr")))
        .expect("G-buffer");
    std::fs::write(example.join("camera.json"), scene.camera_json()).expect("camera");
    let reference = scene::render_reference(&scene, 64, &render).expect("reference");
    reference
        .write_exr(&example.join("reference.exr"))
        .expect("reference file");
    let frames = scene::render_stochastic(&scene, 1, &render).expect("frames");
    for name in ["stochastic_1spp.exr", "stochastic_1spp_1path.exr"] {
        frames
            .write_exr(&example.join("stochastic").join(name))
            .expect("frames file");
    }
    // The peer at 4 paths only: the reference itself stands in for it.
    reference
        .write_exr(&example.join("stochastic").join("cycles_4spp_oidn.exr"))
        .expect("peer file");
    let options = PeerStudyOptions {
        out_dir: dir.path().join("peers"),
        full: false,
        db_profile: "test".into(),
        quiet: true,
    };
    let config = PeerStudyConfig {
        scenes: vec![],
        size: 32,
        reference_spp: 64,
        sample_peers: vec![],
        spreadlet_spp: vec![1],
        gbuffer_methods: true,
        examples_dir: Some(dir.path().join("examples")),
        example_crop: None,
        seed: 3,
    };
    let report = run_with(&options, &config).expect("study runs");
    let cycles: Vec<_> = report
        .rows
        .iter()
        .filter(|r| r.input == "Cycles paths")
        .collect();
    let names: Vec<String> = cycles
        .iter()
        .map(|r| format!("{}@{:?}", r.method, r.spp))
        .collect();
    assert_eq!(names, ["spreadlet@Some(4)", "cycles+oidn@Some(4)"]);
    assert_eq!(cycles[0].kind, RowKind::Ours);
    assert!(
        cycles[0].ssim > 0.5 && cycles[0].ssim < 1.0,
        "{:?}",
        cycles[0]
    );
    assert!((cycles[1].ssim - 1.0).abs() < 1e-9, "{:?}", cycles[1]);
}
