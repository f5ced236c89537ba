//! The CPU synthesis pipeline against independent references: the precompute's own
//! pre-filtered PSFs, energy conservation, the exact integrator, and the input itself.

mod support;

use formats::image::RgbaImage;
use poisson::Plane;
use precompute::{BuildConfig, BuildPlan, Profile};
use psf_db::{PsfDatabase, PsfModel};
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::pipeline::{
    classify, composite, integrate, splat, ClassifyOptions, CompositeOptions, Effects, Integrator,
    SplatOptions, SplatPath,
};
use spreadlet::synth::{synthesize, SynthOptions, SynthStats};
use support::{camera, depth_for_coc, one_pixel, physical_camera, raw_test_db, test_db};

/// A set of one database.
fn set(db: &PsfDatabase) -> DbSet {
    DbSet::single(db.clone()).expect("set")
}

/// Single layer, hard, no edge fix: the plain splat-and-integrate path.
fn plain_options(integrator: Integrator) -> SynthOptions {
    SynthOptions {
        classify: ClassifyOptions {
            layers: 1,
            soft_layers: None,
            edge_split: false,
            // One record per pixel, of the cell holding its parameters.
            continuous_lookup: false,
            // Each record drawn at its own turn from the database's own PSF (a frame's few
            // sparse records are otherwise drawn from images turned for the frame).
            shared_turns: false,
            // And every sparse record splatted as spreadlets, however few.
            few_sparse_images: false,
            ..ClassifyOptions::default()
        },
        integrator,
        ..SynthOptions::default()
    }
}

/// Integrated primal plane of channel `c` of layer 0 (padded), for a one-pixel input.
fn splat_one(
    g: &GBuffer,
    cam: &Camera,
    db: &PsfDatabase,
    integrator: Integrator,
) -> (Plane, u32, spreadlet::pipeline::types::SplatRecord) {
    let opts = plain_options(integrator);
    let dbs = set(db);
    let c = classify(g, cam, &dbs, &opts.classify).expect("classify");
    assert_eq!(c.records.len(), 1, "one record for one pixel");
    let rec = c.records[0];
    let stack = splat(
        &c,
        c.database_or(dbs.combined.as_ref()),
        &SplatOptions::default(),
    );
    let layers = integrate(&stack, integrator);
    (layers.planes[0].clone(), c.frame.pad, rec)
}

/// L1 (sum of |a - b| over pixels) between the integrated splat around `(cx, cy)` of `plane`
/// and the PSF image `psf` (channel `ch`) placed with its centre there, rotated by
/// `quarter_turns` x 90 degrees (y down), plus the plane's mass outside the PSF image.
fn l1_against_psf(
    plane: &Plane,
    cx: usize,
    cy: usize,
    psf: &precompute::PsfImage,
    ch: usize,
    quarter_turns: u32,
) -> f64 {
    let mut covered = vec![false; plane.data.len()];
    let mut l1 = 0.0f64;
    for v in 0..psf.height {
        for u in 0..psf.width {
            let (mut dx, mut dy) = (
                u as i64 - psf.centre[0] as i64,
                v as i64 - psf.centre[1] as i64,
            );
            for _ in 0..quarter_turns {
                // (x, y) -> (-y, x): +x turns to +y (y down).
                (dx, dy) = (-dy, dx);
            }
            let (x, y) = (cx as i64 + dx, cy as i64 + dy);
            let expected = f64::from(psf.planes[ch][v * psf.width + u]);
            if x < 0 || y < 0 || x >= plane.width as i64 || y >= plane.height as i64 {
                l1 += expected.abs();
                continue;
            }
            let i = y as usize * plane.width + x as usize;
            covered[i] = true;
            l1 += (f64::from(plane.data[i]) - expected).abs();
        }
    }
    for (i, &v) in plane.data.iter().enumerate() {
        if !covered[i] {
            l1 += f64::from(v).abs();
        }
    }
    l1
}

/// One bright pixel of PSF `index` (thin-lens or lens-motion) reproduces the pre-filtered PSF
/// within the database's recorded L1 (plus a small allowance for f32 accumulation).
fn check_one_pixel(model: PsfModel, index: u32, quarter_turns: u32) {
    let db = test_db(model);
    let raw = raw_test_db(model);
    let plan = BuildPlan::new(&BuildConfig::new(model, Profile::Test)).expect("plan");
    let s = plan.space.cell_center(index).expect("cell");
    let processed = plan.process(index).expect("process");
    let recorded_l1 = f64::from(raw.header().stats[index as usize].l1);
    let dense = db.dense(index as usize).is_some();

    let (w, h) = (48usize, 48usize);
    let cam = camera(w as u32, h as u32, true, 1.0);
    let depth = depth_for_coc(&cam, s[0]) as f32;
    let len = s[1] as f32;
    let motion = match quarter_turns {
        0 => [len, 0.0],
        1 => [0.0, len],
        2 => [-len, 0.0],
        _ => [0.0, -len],
    };
    let (px, py) = (w / 2, h / 2);
    let g = one_pixel(w, h, px, py, [1.0, 1.0, 1.0, 1.0], depth, motion);
    let (plane, pad, rec) = splat_one(&g, &cam, db, Integrator::Exact);
    if rec.path == SplatPath::Copy as u32 {
        return; // a PSF under a pixel: nothing to compare
    }
    assert_eq!(
        rec.psf_index, index,
        "lookup of the cell centre gives the cell"
    );
    let l1 = l1_against_psf(
        &plane,
        px + pad as usize,
        py + pad as usize,
        &processed.image,
        0,
        quarter_turns,
    );
    // Conditioning (moments, energy) moves the splat slightly away from the precompute's own
    // reconstruction on its small domain; dense PSFs are stored (or analytic) images.
    let bound = if dense {
        recorded_l1.max(0.05) * 1.5 + 0.02
    } else {
        recorded_l1 * 1.25 + 0.02
    };
    assert!(
        l1 <= bound,
        "{} PSF {index} (s = {s:?}, dense {dense}, turns {quarter_turns}): L1 {l1:.5} > bound \
         {bound:.5} (recorded {recorded_l1:.5})",
        model.name()
    );
}

#[test]
fn one_pixel_reproduces_every_thin_lens_psf() {
    let db = test_db(PsfModel::ThinLens);
    for i in 0..db.psf_count() as u32 {
        check_one_pixel(PsfModel::ThinLens, i, 0);
    }
}

#[test]
fn one_pixel_reproduces_lens_motion_psfs_in_all_four_directions() {
    let db = test_db(PsfModel::LensMotion);
    for i in 0..db.psf_count() as u32 {
        for turns in 0..4 {
            check_one_pixel(PsfModel::LensMotion, i, turns);
        }
    }
}

#[test]
fn one_pixel_reproduces_physical_lens_psfs() {
    let model = PsfModel::PhysicalLens;
    let db = test_db(model);
    let raw = raw_test_db(model);
    let plan = BuildPlan::new(&support::test_config(model)).expect("plan");
    let lens = db.header().lens.clone().expect("prescription");
    let ppm = f64::from(lens.image_width_px) / lens.sensor_width_mm;
    for index in 0..db.psf_count() as u32 {
        let s = plan.space.cell_center(index).expect("cell");
        let cell = plan.space.cell_box(index).expect("box");
        let processed = plan.process(index).expect("process");
        let recorded_l1 = f64::from(raw.header().stats[index as usize].l1);
        // A pixel on the row through the centre whose eccentricity lies in the cell, +x side.
        let (w, h) = (lens.image_width_px as usize, 8usize);
        let cam = physical_camera(db, h);
        let target_px = s[1] * ppm;
        let px = (w as f64 / 2.0 + target_px - 0.5).round().max(0.0) as usize;
        let px = px.min(w - 1);
        let ecc_mm = (px as f64 + 0.5 - w as f64 / 2.0).abs() / ppm;
        if ecc_mm < cell.min[1] || ecc_mm > cell.max[1] {
            continue; // no pixel centre inside this (thin) cell at this image size
        }
        let (py, h_even) = (h / 2, h);
        // The pixel sits half a pixel below the centre row: eccentricity is dominated by x.
        let g = one_pixel(
            w,
            h_even,
            px,
            py,
            [1.0, 1.0, 1.0, 1.0],
            (1.0 / s[0]) as f32,
            [0.0; 2],
        );
        let (plane_r, pad, rec) = splat_one(&g, &cam, db, Integrator::Exact);
        assert_eq!(rec.psf_index, index);
        let _ = plane_r;
        // Compare every colour channel (R, G, B planes of the layer).
        let opts = plain_options(Integrator::Exact);
        let dbs = set(db);
        let c = classify(&g, &cam, &dbs, &opts.classify).expect("classify");
        let stack = splat(
            &c,
            c.database_or(dbs.combined.as_ref()),
            &SplatOptions::default(),
        );
        let layers = integrate(&stack, Integrator::Exact);
        let mut l1 = 0.0;
        for ch in 0..3 {
            l1 += l1_against_psf(
                &layers.planes[ch],
                px + pad as usize,
                py + pad as usize,
                &processed.image,
                ch,
                0,
            );
        }
        l1 /= 3.0;
        // The record's rotation is towards the pixel, not exactly +x (half a pixel off the
        // centre row): allow for that small turn.
        let bound = recorded_l1 * 1.25 + 2e-2;
        assert!(
            l1 <= bound,
            "physical PSF {index} (s = {s:?}): L1 {l1:.5} > {bound:.5} (recorded {recorded_l1:.5})"
        );
    }
}

/// `g` synthesised with default options, shared turns on or off.
fn with_shared_turns(
    g: &GBuffer,
    cam: &Camera,
    db: &PsfDatabase,
    shared_turns: bool,
) -> (RgbaImage, SynthStats) {
    let options = SynthOptions {
        classify: ClassifyOptions {
            shared_turns,
            ..ClassifyOptions::default()
        },
        ..SynthOptions::default()
    };
    synthesize(g, cam, &set(db), &options).expect("synth")
}

/// The mean absolute difference of `b` from `a` over their colour channels, relative to `a`'s
/// mean level, and the largest difference.
fn colour_difference(a: &RgbaImage, b: &RgbaImage) -> (f64, f32) {
    let (mut diff, mut level, mut worst) = (0.0f64, 0.0f64, 0.0f32);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        for c in 0..3 {
            diff += f64::from((p[c] - q[c]).abs());
            level += f64::from(p[c].abs());
            worst = worst.max((p[c] - q[c]).abs());
        }
    }
    (diff / level, worst)
}

/// Through a real lens most records of a frame share their PSF and, quantised, their turn
/// onto the radial direction: drawn upright from that PSF turned once, the frame is what each
/// record drawn at its own turn gives (the independent, slower path), to the quantisation's
/// rim shift of at most 1/4 px and the cubic turn.
#[test]
fn records_drawn_from_shared_turns_match_their_own_turns() {
    let db = test_db(PsfModel::PhysicalLens);
    let cam = physical_camera(db, 48);
    let (w, h) = (cam.width as usize, cam.height as usize);
    // A textured surface whose depth sweeps the database's inverse depths across the frame.
    let inv = db.space().dims()[0];
    let mut color = vec![[0.0f32; 4]; w * h];
    let mut depth = vec![1.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let t = (x as f32 * 0.37 + y as f32 * 0.23).sin() * 0.5 + 0.5;
            color[y * w + x] = [t, 1.0 - t, ((x + y) % 5) as f32 / 5.0, 1.0];
            let f = (x as f64 + 0.5) / w as f64;
            depth[y * w + x] = (1.0 / (inv.min + (inv.max - inv.min) * (0.1 + 0.8 * f))) as f32;
        }
    }
    let g = GBuffer::from_planes(w, h, color, Some(depth), None).expect("g");
    let (own, own_stats) = with_shared_turns(&g, &cam, db, false);
    let (shared, shared_stats) = with_shared_turns(&g, &cam, db, true);
    // The splat makes a layer's planes by its path counts: they follow the records redirected.
    let dbs = set(db);
    let c = classify(&g, &cam, &dbs, &ClassifyOptions::default()).expect("classify");
    for (l, info) in c.layers.iter().enumerate() {
        let layer = &c.records[info.first_record..info.first_record + info.record_count];
        let of = |p: SplatPath| layer.iter().filter(|r| r.path == p as u32).count();
        assert_eq!(
            (info.sparse, info.dense, info.copied),
            (
                of(SplatPath::Sparse),
                of(SplatPath::Dense),
                of(SplatPath::Copy)
            ),
            "layer {l}"
        );
        // What leaves classification is drawable as it is: blends emitted as one record are
        // premixed or split by then.
        for r in layer {
            assert!(
                r.path <= SplatPath::Copy as u32,
                "layer {l}: path {:#x}",
                r.path
            );
            assert_eq!(r.layer, l as u32, "a record's layer is its place");
        }
    }
    assert_eq!(own_stats.counts.turned, 0);
    // Sparse PSFs that many records share are integrated and turned once too.
    assert!(
        shared_stats.counts.sparse < own_stats.counts.sparse,
        "sparse records drawn from shared turns: {} left of {}",
        shared_stats.counts.sparse,
        own_stats.counts.sparse
    );
    // A still pixel blends two cells along inverse depth: where both are dense, one record
    // instead of two, premixed.
    let records = |c: &spreadlet::pipeline::PathCounts| c.sparse + c.dense + c.copied;
    assert!(
        records(&shared_stats.counts) < records(&own_stats.counts),
        "blended pairs premixed: {} records against {}",
        records(&shared_stats.counts),
        records(&own_stats.counts)
    );
    assert!(
        shared_stats.counts.turned * 2 > shared_stats.counts.dense,
        "most dense records share a turn: {:?}",
        shared_stats.counts
    );
    let (relative, worst) = colour_difference(&own, &shared);
    assert!(
        relative < 0.006,
        "mean difference {relative:.4} of the level"
    );
    assert!(worst < 0.04, "largest difference {worst}");
}

/// A frame through a real lens whose only sparse PSFs are a few drops off the axis: those
/// few sparse records are turned into images too, so that no layer needs the frame's
/// integration, and the frame is what drawing them sparse gives, to the turn's quantisation.
#[test]
fn a_few_sparse_records_are_drawn_from_turned_images() {
    let db = test_db(PsfModel::PhysicalLens);
    let cam = physical_camera(db, 160);
    let (w, h) = (cam.width as usize, cam.height as usize);
    // The test database's PSFs are dense at the near end of its inverse depths (the grey
    // wall), and sparse behind it where the field is far from the axis (the drops).
    let inv = db.space().dims()[0];
    let at = |t: f64| (1.0 / (inv.min + (inv.max - inv.min) * t)) as f32;
    let (wall, drop) = (at(0.95), at(0.65));
    let mut color = vec![[0.2f32, 0.2, 0.2, 1.0]; w * h];
    let mut depth = vec![wall; w * h];
    let drops = [
        (40, 30),
        (w - 40, 30),
        (40, h - 30),
        (w - 40, h - 30),
        (w - 60, h / 2),
    ];
    for &(x, y) in &drops {
        color[y * w + x] = [0.9, 0.7, 0.5, 1.0];
        depth[y * w + x] = drop;
    }
    let g = GBuffer::from_planes(w, h, color, Some(depth), None).expect("g");
    let (own, own_stats) = with_shared_turns(&g, &cam, db, false);
    let (shared, shared_stats) = with_shared_turns(&g, &cam, db, true);
    assert!(
        own_stats.counts.sparse > 0,
        "the drops are drawn sparse when each record is turned on its own: {:?}",
        own_stats.counts
    );
    assert_eq!(
        shared_stats.counts.sparse, 0,
        "every sparse record drawn from a turned image"
    );
    let (relative, worst) = colour_difference(&own, &shared);
    assert!(
        relative < 0.006,
        "mean difference {relative:.4} of the level"
    );
    assert!(worst < 0.08, "largest difference {worst}");
    assert!(
        shared.pixels.iter().all(|p| p.iter().all(|&v| v >= 0.0)),
        "no pixel below zero around the drops"
    );
}

/// A thin-lens frame through a five-bladed aperture whose sparse records are a few defocused
/// points, some behind the focus (upright PSFs) and some in front of it (the pentagon turned
/// half a turn): each layer's few sparse records are drawn from their PSF's image, so no layer
/// has a Laplacian plane to integrate, and the frame is what splatting them as spreadlets and
/// integrating gives (the independent path).
#[test]
fn a_layers_few_sparse_records_are_drawn_from_their_psfs_images() {
    let mut cfg = support::test_config(PsfModel::ThinLens);
    cfg.blades = 5;
    let (raw, _) = precompute::build_database(&cfg, false).expect("five-bladed database");
    let db = &spreadlet::condition::condition(&raw).expect("condition").0;
    // Wide enough for a CoC of several pixels behind the focus (at 512 px the thin lens's
    // CoC tends to 9.4 px far away).
    let (w, h) = (512usize, 80usize);
    let mut cam = camera(w as u32, h as u32, true, 0.0);
    cam.aperture_blades = 5;
    let mut color = vec![[0.0f32; 4]; w * h];
    let mut depth = vec![1.0f32; w * h];
    // (x, y, signed CoC in px: positive in front of the focus), a colour each.
    let points = [
        (60, 20, 6.0),
        (200, 22, 6.0),
        (300, 40, 4.5),
        (120, 60, -6.0),
        (400, 58, -6.0),
        (460, 30, -5.0),
    ];
    for (k, &(x, y, coc)) in points.iter().enumerate() {
        color[y * w + x] = [0.9, 0.3 + 0.1 * k as f32, 0.6, 1.0];
        depth[y * w + x] = depth_for_coc(&cam, coc) as f32;
    }
    let g = GBuffer::from_planes(w, h, color, Some(depth), None).expect("g");
    let run = |few_sparse_images: bool| {
        let options = SynthOptions {
            classify: ClassifyOptions {
                few_sparse_images,
                ..ClassifyOptions::default()
            },
            ..SynthOptions::default()
        };
        synthesize(&g, &cam, &set(db), &options).expect("synth")
    };
    let (sparse, sparse_stats) = run(false);
    let (imaged, imaged_stats) = run(true);
    assert!(
        sparse_stats.counts.sparse >= points.len(),
        "the test database stores these PSFs sparse: {:?}",
        sparse_stats.counts
    );
    assert_eq!(imaged_stats.counts.sparse, 0, "{:?}", imaged_stats.counts);
    assert_eq!(
        imaged_stats.counts.sparse_as_images, sparse_stats.counts.sparse,
        "every sparse record drawn from an image"
    );
    // No Laplacian plane is left to integrate.
    let dbs = set(db);
    let c = classify(&g, &cam, &dbs, &ClassifyOptions::default()).expect("classify");
    let stack = splat(
        &c,
        c.database_or(dbs.combined.as_ref()),
        &SplatOptions::default(),
    );
    assert!(stack.laplacian.iter().all(Plane::is_empty));
    // Around each point, to the sparse fit's negative residue (which the image clamps; the
    // Test profile's coarse fits leave about 1.5 %): a PSF landing mirrored differs by 9-16 %.
    for &(x, y, coc) in &points {
        let (mut diff, mut level) = (0.0f64, 0.0f64);
        for yy in y.saturating_sub(12)..(y + 12).min(h) {
            for xx in x - 12..x + 12 {
                let (p, q) = (sparse.pixels[yy * w + xx], imaged.pixels[yy * w + xx]);
                for c in 0..3 {
                    diff += f64::from((p[c] - q[c]).abs());
                    level += f64::from(p[c].abs());
                }
            }
        }
        assert!(
            diff < 0.03 * level,
            "point at ({x}, {y}), CoC {coc}: difference {:.4} of its level",
            diff / level
        );
    }
    let (_, worst) = colour_difference(&sparse, &imaged);
    assert!(worst < 0.01, "largest difference {worst}");
}

/// A uniform grey surface out of focus seen through a real lens stays even on the optical axis.
/// Each pixel's PSF is turned onto its radial direction, so a pixel on the axis receives only
/// its neighbours' PSFs along their radial direction, and a PSF that is not round (the first
/// eccentricity box's stands for eccentricities up to the box's edge, where the cat's eye
/// begins) left it short of light. Near the axis a pixel draws part of its PSF as the PSF's
/// rotational average, round like the lens's own PSF there. Without the averages the test sees
/// the dark spot.
#[test]
fn a_surface_through_a_real_lens_stays_even_on_the_axis() {
    let db = test_db(PsfModel::PhysicalLens);
    let cam = physical_camera(db, 64);
    let (w, h) = (cam.width as usize, cam.height as usize);
    let inv = db.space().dims()[0];
    let level = 0.5f32;
    let depth = (1.0 / (inv.min + 0.9 * (inv.max - inv.min))) as f32;
    let g = GBuffer::from_planes(
        w,
        h,
        vec![[level, level, level, 1.0]; w * h],
        Some(vec![depth; w * h]),
        None,
    )
    .expect("g");
    let options = SynthOptions {
        classify: ClassifyOptions {
            layers: 1,
            ..ClassifyOptions::default()
        },
        ..SynthOptions::default()
    };
    // The mean level within 3 px of the axis, and its largest departure there.
    let on_axis = |dbs: &DbSet| {
        let (out, _) = synthesize(&g, &cam, dbs, &options).expect("synth");
        let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
        let (mut sum, mut n, mut worst) = (0.0f64, 0usize, 0.0f32);
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (x as f32 + 0.5 - cx, y as f32 + 0.5 - cy);
                if dx * dx + dy * dy <= 9.0 {
                    let v = out.pixels[y * w + x][1] / level;
                    sum += f64::from(v);
                    n += 1;
                    worst = worst.max((v - 1.0).abs());
                }
            }
        }
        (sum / n as f64, worst)
    };
    let dbs = set(db);
    assert!(
        dbs.axis_round
            .iter()
            .any(|&i| i != spreadlet::dbset::NO_TWIN),
        "the first eccentricity box's PSFs have rotational averages"
    );
    let (mean, worst) = on_axis(&dbs);
    let mut turned_only = set(db);
    turned_only.axis_round.fill(spreadlet::dbset::NO_TWIN);
    let (mean_turned, worst_turned) = on_axis(&turned_only);
    assert!(
        worst < 0.015,
        "on the axis: mean {mean:.4}, worst {worst:.4} off the level"
    );
    assert!(
        worst_turned > 2.0 * worst,
        "turned only: mean {mean_turned:.4}, worst {worst_turned:.4} (with averages {worst:.4})"
    );
}

/// A bright drop through a real lens, its inverse depth between two cells' centres far from
/// the focus plane: the blend of the two cells' PSFs keeps one rim. Each PSF is scaled onto
/// the drop's own defocus before they are mixed (the premixed pair), so the bokeh's rim is as
/// steep as one PSF's; mixed as they are (`scaled_blends` off), they leave two rims a cell's
/// blur apart, each of part of the height. Both have the same size: a squared RMS radius is
/// linear in a mix, and so is the defocus between the cells. On the axis (the PSFs' rotational
/// averages: the squared gradient over the frame 1.34 times the unscaled mix's) and off it
/// (turned: 1.11 times, part of its rim being the vignetting's, which does not scale).
#[test]
fn a_real_lens_blend_of_two_cells_keeps_one_rim() {
    // The Test profile's rays, with 16 boxes along inverse depth from 0.2 to 10 m: the
    // nearest are far enough from the focus plane (1 m) to be scaled.
    let mut cfg = support::test_config(PsfModel::PhysicalLens);
    cfg.psf_count = Some(48);
    if let Some(lens) = cfg.lens.as_mut() {
        lens.depth_range = [0.2, 10.0];
    }
    let raw = precompute::build_database(&cfg, false).expect("build").0;
    let db = &spreadlet::condition::condition(&raw).expect("condition").0;
    let h = 96usize;
    let cam = physical_camera(db, h);
    let w = cam.width as usize;
    let lens = db.header().lens.clone().expect("prescription");
    let focus = 1.0 / lens.focus_distance;
    let space = db.space();
    let ppm = f64::from(lens.image_width_px) / lens.sensor_width_mm;
    // The pixel's eccentricity box, and in it the cell of largest blur whose next cell (away
    // from the focus plane) is scaled too, both dense, the bokeh within the frame.
    let drop_at = |x: usize| -> (usize, f64) {
        let ecc = ((x as f64 + 0.5 - w as f64 / 2.0).abs() + 0.5).hypot(0.5) / ppm;
        let in_box = |i: u32| {
            space
                .cell_box(i)
                .is_some_and(|b| b.min[1] <= ecc && ecc < b.max[1])
        };
        let usable = |i: u32| {
            in_box(i)
                && space.blend_scales_cell(i, focus)
                && db
                    .dense(i as usize)
                    .is_some_and(|d| d.width.max(d.height) < h - 8)
        };
        let (cell, inv) = (0..db.psf_count() as u32)
            .filter(|&i| usable(i))
            .filter_map(|i| {
                let b = space.cell_box(i)?;
                let c = space.cell_center(i)?;
                // Nine tenths of the way to the box's edge away from the focus plane.
                let away = if c[0] > focus { b.max[0] } else { b.min[0] };
                let inv = c[0] + 0.9 * (away - c[0]);
                let (next, _) = space.lookup([(inv + (away - c[0])) as f32, ecc as f32]);
                (next != i && usable(next)).then_some((i, inv))
            })
            .max_by(|a, b| (a.1 - focus).abs().total_cmp(&(b.1 - focus).abs()))
            .expect("two neighbouring scaled dense cells");
        assert!(in_box(cell));
        (cell as usize, 1.0 / inv)
    };
    // Light over the padded frame's pixels, its RMS radius and its squared gradient
    // (normalised to the image's squared light: larger for a steeper rim).
    let measure = |out: &RgbaImage| -> (f64, f64) {
        let g = |x: usize, y: usize| f64::from(out.pixels[y * w + x][1]);
        let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for y in 0..h {
            for x in 0..w {
                s += g(x, y);
                sx += g(x, y) * x as f64;
                sy += g(x, y) * y as f64;
            }
        }
        let (cx, cy) = (sx / s, sy / s);
        let (mut r2, mut grad, mut sq) = (0.0, 0.0, 0.0);
        for y in 0..h - 1 {
            for x in 0..w - 1 {
                let v = g(x, y);
                r2 += v * ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2));
                grad += (g(x + 1, y) - v).powi(2) + (g(x, y + 1) - v).powi(2);
                sq += v * v;
            }
        }
        ((r2 / s).sqrt(), grad / sq)
    };
    for (place, x, steeper) in [
        ("on the axis", w / 2, 1.25),
        ("off the axis", w / 2 + w / 3, 1.06),
    ] {
        let (cell, depth) = drop_at(x);
        let y = h / 2;
        let far = 1.0 / space.dims()[0].min;
        let mut color = vec![[0.0, 0.0, 0.0, 1.0]; w * h];
        let mut depths = vec![far as f32; w * h];
        color[y * w + x] = [40.0, 40.0, 40.0, 1.0];
        depths[y * w + x] = depth as f32;
        let g = GBuffer::from_planes(w, h, color, Some(depths), None).expect("g");
        let draw = |scaled_blends: bool| {
            let options = SynthOptions {
                classify: ClassifyOptions {
                    scaled_blends,
                    ..ClassifyOptions::default()
                },
                ..SynthOptions::default()
            };
            synthesize(&g, &cam, &set(db), &options).expect("synth").0
        };
        let ((r_one, rim_one), (r_two, rim_two)) = (measure(&draw(true)), measure(&draw(false)));
        println!(
            "{place}: cell {cell}, depth {depth:.4}: scaled, RMS {r_one:.3} px, rim {rim_one:.4}; \
             mixed as they are, RMS {r_two:.3} px, rim {rim_two:.4}"
        );
        assert!(
            (r_one / r_two - 1.0).abs() < 0.03,
            "{place}: RMS radius {r_one} against {r_two}"
        );
        assert!(
            rim_one > steeper * rim_two,
            "{place}: rim {rim_one} against {rim_two}"
        );
    }
}

/// A bright drop far off axis and far out of focus, over a dim backdrop seen through a real
/// lens: the drop's cat's-eye bokeh is drawn with its PSF's residue clamped (the dense twin),
/// so no pixel within 30 px of it is darker than 0.8 times the backdrop it lies on, let alone
/// negative. Drawn from the sparse PSF instead (no twins), the drop, 1,500 times the
/// backdrop, rings itself with specks the compositor clamps to black: the test sees them.
#[test]
fn a_bright_corner_drop_leaves_no_dark_specks() {
    let db = test_db(PsfModel::PhysicalLens);
    let h = 64usize;
    let cam = physical_camera(db, h);
    let w = cam.width as usize;
    let inv = db.space().dims()[0];
    let backdrop = 0.02f32;
    // The drop sits where the database draws a sparse PSF, the one farthest off axis.
    let lens = db.header().lens.clone().expect("prescription");
    let ppm = f64::from(lens.image_width_px) / lens.sensor_width_mm;
    let sparse_cell = (0..db.psf_count())
        .filter(|&i| db.dense(i).is_none())
        .filter_map(|i| db.space().cell_center(i as u32))
        .max_by(|a, b| a[1].total_cmp(&b[1]))
        .expect("a sparse PSF");
    let near = 1.0 / sparse_cell[0];
    let far = 1.0 / inv.min;
    let (cx, cy) = (
        (w as f64 / 2.0 + sparse_cell[1] * ppm).round() as usize,
        h / 2,
    );
    assert!(cx + 2 < w, "the drop fits in the frame");
    let mut color = vec![[backdrop, backdrop, backdrop, 1.0]; w * h];
    let mut depth = vec![far as f32; w * h];
    for y in cy - 1..=cy + 1 {
        for x in cx - 1..=cx + 1 {
            color[y * w + x] = [30.0, 30.0, 30.0, 1.0];
            depth[y * w + x] = near as f32;
        }
    }
    let g = GBuffer::from_planes(w, h, color, Some(depth), None).expect("g");
    // The darkest channel over pixels within `radius` of the drop, and the records drawn dense
    // twins.
    let darkest = |hdr_dense_threshold: f32| {
        let options = SynthOptions {
            classify: ClassifyOptions {
                hdr_dense_threshold,
                ..ClassifyOptions::default()
            },
            ..SynthOptions::default()
        };
        let (out, stats) = synthesize(&g, &cam, &set(db), &options).expect("synth");
        let radius = 30.0f32;
        let mut darkest = f32::INFINITY;
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (x as f32 - cx as f32, y as f32 - cy as f32);
                if dx * dx + dy * dy <= radius * radius {
                    let p = out.pixels[y * w + x];
                    darkest = darkest.min(p[0].min(p[1]).min(p[2]));
                }
            }
        }
        (darkest, stats.counts.hdr_dense)
    };
    let (clamped, twins) = darkest(ClassifyOptions::default().hdr_dense_threshold);
    let (sparse, no_twins) = darkest(f32::INFINITY);
    assert!(twins >= 9, "the drop's pixels are drawn as twins: {twins}");
    assert_eq!(no_twins, 0);
    assert!(
        clamped >= 0.8 * backdrop,
        "darkest pixel {clamped} around the drop, backdrop {backdrop}"
    );
    assert!(
        sparse < 0.8 * backdrop,
        "without twins the drop should ring dark specks: darkest {sparse}"
    );
}

/// A test image: a smooth colourful pattern in the middle, black (but opaque) border wider
/// than the largest PSF, depths spread over the test database's CoC range.
fn pattern(w: usize, h: usize, border: usize, cam: &Camera, max_coc: f64) -> GBuffer {
    let mut color = vec![[0.0, 0.0, 0.0, 1.0]; w * h];
    let mut depth = vec![1.0f32; w * h];
    for y in border..h - border {
        for x in border..w - border {
            let i = y * w + x;
            let t = (x as f32 * 0.37 + y as f32 * 0.11).sin() * 0.5 + 0.5;
            color[i] = [t, 1.0 - t, (x % 7) as f32 / 7.0, 1.0];
            let coc = max_coc * ((x + 3 * y) % 17) as f64 / 17.0;
            depth[i] = depth_for_coc(cam, coc) as f32;
        }
    }
    GBuffer::from_planes(w, h, color, Some(depth), None).expect("g")
}

#[test]
fn single_layer_conserves_energy() {
    let db = test_db(PsfModel::ThinLens);
    let max_coc = db.space().dims()[0].max * 0.95;
    let border = db.max_extent_px() as usize + 2;
    let (w, h) = (2 * border + 24, 2 * border + 20);
    let cam = camera(w as u32, h as u32, true, 0.0);
    let mut g = pattern(w, h, border, &cam, max_coc);
    // Pure emission (premultiplied colour, zero alpha): compositing then only adds, so the
    // output is the integrated splats themselves (alpha renormalisation would rescale
    // wherever blurred coverage overlaps above one).
    for c in &mut g.color {
        c[3] = 0.0;
    }
    let (out, stats) =
        synthesize(&g, &cam, &set(db), &plain_options(Integrator::Exact)).expect("synth");
    assert!(stats.counts.sparse > 0, "{:?}", stats.counts);
    let input: f64 = g.color.iter().map(|c| f64::from(c[0] + c[1] + c[2])).sum();
    let output: f64 = out
        .pixels
        .iter()
        .map(|c| f64::from(c[0] + c[1] + c[2]))
        .sum();
    let rel = (output - input).abs() / input;
    assert!(
        rel < 1e-3,
        "energy: in {input}, out {output}, relative {rel:e}"
    );
}

#[test]
fn pyramid_stays_close_to_the_exact_integrator() {
    let db = test_db(PsfModel::ThinLens);
    let max_coc = db.space().dims()[0].max * 0.95;
    let border = db.max_extent_px() as usize + 2;
    let (w, h) = (2 * border + 40, 2 * border + 40);
    let cam = camera(w as u32, h as u32, true, 0.0);
    let g = pattern(w, h, border, &cam, max_coc);
    let (exact, _) = synthesize(&g, &cam, &set(db), &plain_options(Integrator::Exact)).expect("e");
    let (pyr, _) = synthesize(&g, &cam, &set(db), &plain_options(Integrator::Pyramid)).expect("p");
    let mut max = 0.0f32;
    let mut sum = 0.0f64;
    for (a, b) in exact.pixels.iter().zip(&pyr.pixels) {
        for c in 0..3 {
            let d = (a[c] - b[c]).abs();
            max = max.max(d);
            sum += f64::from(d);
        }
    }
    let mean = sum / (3 * w * h) as f64;
    // Colours are at most 1: the pyramid's documented error is ~0.004 mean, ~0.12 max on
    // impulse responses; on images of splats it averages out.
    assert!(
        mean < 0.01 && max < 0.15,
        "pyramid vs exact: mean {mean}, max {max}"
    );
}

#[test]
fn still_pinhole_input_returns_unchanged() {
    let (w, h) = (37, 23);
    let color: Vec<[f32; 4]> = (0..w * h)
        .map(|i| [i as f32 * 0.01, 1.0 / (1 + i) as f32, -0.5, 0.5])
        .collect();
    let depth: Vec<f32> = (0..w * h).map(|i| 0.1 + i as f32).collect();
    let motion = vec![[3.0f32, -2.0]; w * h];
    let g = GBuffer::from_planes(w, h, color.clone(), Some(depth), Some(motion)).expect("g");
    for shutter in [0.0, 0.5] {
        // Pinhole; with shutter 0.5 and motion it is not still, so only shutter 0 here.
        let cam = camera(w as u32, h as u32, false, shutter);
        if shutter > 0.0 {
            assert!(Effects::of(&cam, &g).motion);
            continue;
        }
        let (out, stats) =
            synthesize(&g, &cam, &DbSet::none(), &SynthOptions::default()).expect("synth");
        assert_eq!(out.pixels, color, "bit-identical");
        assert_eq!(stats.counts.copied, w * h);
        assert!(stats.models.is_empty());
    }
}

#[test]
fn still_defocus_needs_only_the_thin_lens_model() {
    let g = GBuffer::from_planes(
        4,
        4,
        vec![[1.0; 4]; 16],
        Some(vec![2.0; 16]),
        Some(vec![[5.0, 1.0]; 16]),
    )
    .expect("g");
    // Shutter closed: motion vectors are ignored.
    let cam = camera(4, 4, true, 0.0);
    assert_eq!(
        Effects::of(&cam, &g).cheapest_model(),
        Some(PsfModel::ThinLens)
    );
    // Shutter open but nothing moves.
    let still =
        GBuffer::from_planes(4, 4, vec![[1.0; 4]; 16], Some(vec![2.0; 16]), None).expect("g");
    let still = GBuffer {
        motion: Some(vec![[0.0; 2]; 16]),
        acceleration: None,
        ..still
    };
    assert_eq!(
        Effects::of(&camera(4, 4, true, 1.0), &still).cheapest_model(),
        Some(PsfModel::ThinLens)
    );
    // And synthesis runs with the thin-lens database alone.
    let (_, stats) = synthesize(
        &g,
        &cam,
        &set(test_db(PsfModel::ThinLens)),
        &SynthOptions::default(),
    )
    .expect("synth");
    assert_eq!(stats.models, vec!["thin-lens"]);
}

#[test]
fn synthesis_is_bit_identical_across_runs_and_thread_counts() {
    let db = test_db(PsfModel::LensMotion);
    let (w, h) = (64usize, 48usize);
    let cam = camera(w as u32, h as u32, true, 1.0);
    let max_coc = db.space().dims()[0].max * 0.9;
    let mut g = pattern(w, h, 4, &cam, max_coc);
    g.motion = Some(
        (0..w * h)
            .map(|i| {
                let a = i as f32 * 0.1;
                [6.0 * a.cos(), 6.0 * a.sin()]
            })
            .collect(),
    );
    let dbs = DbSet::new(Some(test_db(PsfModel::ThinLens).clone()), Some(db.clone())).expect("set");
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        pool.install(|| synthesize(&g, &cam, &dbs, &SynthOptions::default()))
            .expect("synth")
            .0
    };
    let a = run(1);
    let b = run(2);
    let c = run(3);
    let bits = |img: &RgbaImage| {
        img.pixels
            .iter()
            .flat_map(|p| p.map(f32::to_bits))
            .collect::<Vec<u32>>()
    };
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(bits(&a), bits(&c));
}

#[test]
fn compositing_a_single_opaque_layer_of_copies_is_the_identity() {
    // The stages one by one on copies only: integrate adds the direct planes, composite crops.
    let (w, h) = (9usize, 7usize);
    let color: Vec<[f32; 4]> = (0..w * h).map(|i| [i as f32, 1.0, 2.0, 1.0]).collect();
    let g = GBuffer::from_planes(w, h, color.clone(), Some(vec![1.0; w * h]), None).expect("g");
    let cam = camera(w as u32, h as u32, false, 0.0);
    let c = classify(&g, &cam, &DbSet::none(), &ClassifyOptions::default()).expect("c");
    let stack = splat(&c, None, &SplatOptions::default());
    let layers = integrate(&stack, Integrator::Pyramid);
    let out = composite(&layers, &CompositeOptions::default());
    assert_eq!(out.pixels, color);
}

/// An HDR highlight (1e4) on a dim background (1e-3), both defocused: drawn with its PSF's
/// dense twin, the highlight leaves the dim side non-negative and within 50% of its level
/// (the background's own spreadlets err by far less); drawn with spreadlets
/// (`hdr_dense_threshold` infinite), their small relative error times 1e4 swamps the dim side,
/// which this test also checks, so that the twin path is shown to be what keeps it clean.
#[test]
fn hdr_highlight_keeps_the_dim_side_clean() {
    let (w, h) = (64usize, 64usize);
    let cam = camera(w as u32, h as u32, true, 0.0);
    let depth = depth_for_coc(&cam, 6.0) as f32;
    let dim = 1e-3f32;
    let mut color = vec![[dim, dim, dim, 1.0]; w * h];
    color[32 * w + 32] = [1e4, 1e4, 1e4, 1.0];
    let g = GBuffer::from_planes(w, h, color, Some(vec![depth; w * h]), None).expect("gbuffer");
    let dbs = set(test_db(PsfModel::ThinLens));
    let run = |threshold: f32| {
        let mut opts = plain_options(Integrator::Exact);
        opts.classify.hdr_dense_threshold = threshold;
        let (img, stats) = synthesize(&g, &cam, &dbs, &opts).expect("synthesis");
        // The dim side: pixels at least 16 px from the highlight, 8 px from the border.
        let mut lo = f32::INFINITY;
        for y in 8..h - 8 {
            for x in 8..w - 8 {
                let (dx, dy) = (x as f32 - 32.0, y as f32 - 32.0);
                if dx * dx + dy * dy >= 16.0 * 16.0 {
                    lo = lo.min(img.at(x, y)[0]);
                }
            }
        }
        let mut hi = 0.0f32;
        for y in 8..h - 8 {
            for x in 8..w - 8 {
                let (dx, dy) = (x as f32 - 32.0, y as f32 - 32.0);
                if dx * dx + dy * dy >= 16.0 * 16.0 {
                    hi = hi.max(img.at(x, y)[0]);
                }
            }
        }
        (lo, hi, stats.counts.hdr_dense)
    };
    let (lo, hi, twins) = run(ClassifyOptions::default().hdr_dense_threshold);
    assert_eq!(twins, 1, "the highlight takes its dense twin");
    assert!(
        lo >= 0.5 * dim && hi <= 1.5 * dim,
        "dim side with the twin: [{lo}, {hi}] around {dim}"
    );
    let (lo_sparse, hi_sparse, none) = run(f32::INFINITY);
    assert_eq!(none, 0);
    assert!(
        lo_sparse < 0.5 * dim || hi_sparse > 1.5 * dim,
        "spreadlets alone would keep the dim side clean too: [{lo_sparse}, {hi_sparse}]"
    );
}

/// A frame whose records are all dense images and copies is drawn band by band, splat and
/// composite at once, without its layers' planes: the image is the three stages' one by one
/// to the bit, through a real lens (turned and premixed records), with soft layers and
/// copies, compositing by either rule.
#[test]
fn a_frame_drawn_all_direct_is_the_three_stages_one_by_one_to_the_bit() {
    use spreadlet::pipeline::composite::{composite_with_sharpness, layer_sharpness};
    use spreadlet::pipeline::direct::{all_direct, splat_composite};
    use spreadlet::pipeline::integrate_owned;
    let db = test_db(PsfModel::PhysicalLens);
    let cam = physical_camera(db, 150);
    let (w, h) = (cam.width as usize, cam.height as usize);
    // A textured surface in front of a farther one, over the database's dense inverse depths,
    // with a pixel in focus here and there (a copy).
    let inv = db.space().dims()[0];
    let at = |t: f64| (1.0 / (inv.min + (inv.max - inv.min) * t)) as f32;
    let mut color = vec![[0.0f32; 4]; w * h];
    let mut depth = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let t = (x as f32 * 0.29 + y as f32 * 0.17).sin() * 0.5 + 0.5;
            color[y * w + x] = [t, 0.5 * t, 1.0 - t, 1.0];
            let near = (x as i32 - w as i32 / 2).abs() < 20 && y > h / 3;
            depth[y * w + x] = if near {
                at(0.98)
            } else {
                at(0.85 + 0.1 * t as f64)
            };
        }
    }
    let dbs = set(db);
    let options = ClassifyOptions::default();
    let c = classify(&g_of(w, h, color, depth), &cam, &dbs, &options).expect("classify");
    assert!(
        all_direct(&c),
        "every record dense or copied: {:?}",
        c.counts
    );
    assert!(
        c.layers.iter().filter(|l| l.record_count > 0).count() >= 2,
        "more than one layer"
    );
    let db_used = c.database_or(dbs.combined.as_ref());
    for restore_occluded in [false, true] {
        let composite_options = CompositeOptions {
            restore_occluded,
            ..CompositeOptions::default()
        };
        let sharpness = layer_sharpness(&c, db_used);
        let splat_options = SplatOptions::default();
        let stack = splat(&c, db_used, &splat_options);
        let layers = integrate_owned(stack, Integrator::Exact);
        let staged = composite_with_sharpness(&layers, &composite_options, &sharpness);
        let banded = splat_composite(&c, db_used, &splat_options, &composite_options, &sharpness);
        let bits = |img: &RgbaImage| -> Vec<u32> {
            img.pixels
                .iter()
                .flat_map(|p| p.map(f32::to_bits))
                .collect()
        };
        assert!(staged.pixels.iter().any(|p| p[0] > 0.0), "something drawn");
        assert_eq!(
            bits(&staged),
            bits(&banded),
            "restore_occluded {restore_occluded}"
        );
    }
}

/// A G-buffer of colour and depth.
fn g_of(w: usize, h: usize, color: Vec<[f32; 4]>, depth: Vec<f32>) -> GBuffer {
    GBuffer::from_planes(w, h, color, Some(depth), None).expect("g")
}

/// A flat wall through a real lens stays even across the outer edge of its first eccentricity
/// box, still or moving: that box, the widest, has its PSF traced at the middle of its
/// eccentricities, and where the next box's PSF took over, a ring ran round the axis, darker
/// than the wall. Near that edge a still pixel draws part of the other box's PSF, so the PSF
/// changes across a band, and a moving one is smeared from the other box's PSF for that share
/// of the pixels, dithered.
#[test]
fn a_wall_through_a_real_lens_has_no_ring_where_its_first_eccentricity_box_ends() {
    let db = test_db(PsfModel::PhysicalLens);
    let lens = db.header().lens.clone().expect("prescription");
    let w = lens.image_width_px as usize;
    let still = physical_camera(db, w);
    let pixels_per_mm = w as f64 / lens.sensor_width_mm;
    let space = db.space();
    let edges: Vec<f64> = (0..db.psf_count() as u32)
        .filter_map(|i| space.cell_box(i))
        .filter(|b| b.min[1] <= 0.0)
        .map(|b| b.max[1] * pixels_per_mm)
        .collect();
    let edge = edges.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(
        edge + 12.0 < w as f64 / 2.0,
        "the first box ends {edge:.1} px from the axis, inside the {w} px frame"
    );
    let inv = space.dims()[0];
    let level = 0.5f32;
    let depth = (1.0 / (inv.min + 0.9 * (inv.max - inv.min))) as f32;
    let options = SynthOptions {
        classify: ClassifyOptions {
            layers: 1,
            ..ClassifyOptions::default()
        },
        ..SynthOptions::default()
    };
    // The worst ring with each box's own PSF up to its edge: 0.0140 still, 0.0111 moving 12 px
    // across the frame; drawn across the band: 0.0065 and 0.0058.
    for (motion, most) in [(0.0f32, 0.01f64), (12.0, 0.008)] {
        let cam = Camera {
            shutter_frames: if motion > 0.0 { 1.0 } else { 0.0 },
            ..still.clone()
        };
        let g = GBuffer::from_planes(
            w,
            w,
            vec![[level, level, level, 1.0]; w * w],
            Some(vec![depth; w * w]),
            (motion > 0.0).then(|| vec![[motion, 0.0]; w * w]),
        )
        .expect("g");
        let (out, _) = synthesize(&g, &cam, &set(db), &options).expect("synth");
        // The mean of each one-pixel ring round the axis within 12 px of the edge.
        let c = w as f64 / 2.0;
        let mut rings = vec![(0.0f64, 0usize); 25];
        for y in 0..w {
            for x in 0..w {
                let r = (x as f64 + 0.5 - c).hypot(y as f64 + 0.5 - c);
                let k = (r - edge + 12.0).floor();
                if (0.0..25.0).contains(&k) {
                    let ring = &mut rings[k as usize];
                    ring.0 += f64::from(out.pixels[y * w + x][1] / level);
                    ring.1 += 1;
                }
            }
        }
        let worst = rings
            .iter()
            .map(|&(sum, n)| (sum / n as f64 - 1.0).abs())
            .fold(0.0, f64::max);
        assert!(
            worst < most,
            "moving {motion} px: a ring {worst:.4} off the level near {edge:.1} px"
        );
    }
}
