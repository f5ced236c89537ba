//! Blur beyond the database's range (a 4K frame's background bokeh through a database built
//! for smaller CoCs): drawn at a reduced resolution, it keeps its size, its light and its
//! smoothness where it crosses from the frame's resolution to the coarse one.

mod support;

use psf_db::PsfModel;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::pipeline::ClassifyOptions;
use spreadlet::synth::{synthesize, SynthOptions};
use support::{camera, depth_for_coc, one_pixel, quick_db, test_db};

/// The Test profile's thin-lens database reaches CoC 12 px.
const DB_MAX_COC: f64 = 12.0;

fn options(reduced_resolution: bool) -> SynthOptions {
    SynthOptions {
        classify: ClassifyOptions {
            reduced_resolution,
            ..ClassifyOptions::default()
        },
        ..SynthOptions::default()
    }
}

/// Total light, centroid (px) and RMS radius (px, about the centroid) of channel R.
fn moments(pixels: &[[f32; 4]], w: usize) -> (f64, [f64; 2], f64) {
    let (mut sum, mut mx, mut my) = (0.0f64, 0.0f64, 0.0f64);
    for (i, p) in pixels.iter().enumerate() {
        let v = f64::from(p[0]);
        sum += v;
        mx += v * (i % w) as f64;
        my += v * (i / w) as f64;
    }
    let centre = [mx / sum, my / sum];
    let mut r2 = 0.0f64;
    for (i, p) in pixels.iter().enumerate() {
        let (dx, dy) = ((i % w) as f64 - centre[0], (i / w) as f64 - centre[1]);
        r2 += f64::from(p[0]) * (dx * dx + dy * dy);
    }
    (sum, centre, (r2 / sum).sqrt())
}

/// A single lit pixel whose CoC is 2.5 times the database's largest spreads into a disc of its
/// own CoC (a uniform disc of radius r has RMS radius r / sqrt 2), with its light kept, centred
/// on the 4 x 4 block of frame pixels its coarse pixel covers (up to 1.5 px from the pixel
/// itself at this scale). Drawn with the largest PSF instead, it comes out 2.5 times too
/// small.
#[test]
fn a_point_beyond_the_database_blurs_to_its_own_coc() {
    let db = test_db(PsfModel::ThinLens);
    let dbs = DbSet::single(db.clone()).expect("set");
    let (w, h) = (128usize, 128usize);
    let cam = camera(w as u32, h as u32, true, 0.0);
    let coc = 2.5 * DB_MAX_COC;
    let depth = depth_for_coc(&cam, coc) as f32;
    let (px, py) = (w / 2, h / 2);
    let g = one_pixel(w, h, px, py, [1.0, 1.0, 1.0, 1.0], depth, [0.0, 0.0]);
    let expected_rms = coc / 2f64.sqrt();

    let (image, stats) = synthesize(&g, &cam, &dbs, &options(true)).expect("synthesize");
    assert_eq!(stats.counts.clamped, 0, "in range at a reduced resolution");
    assert!(stats.counts.reduced > 0, "drawn at a reduced resolution");
    let (energy, centre, rms) = moments(&image.pixels, w);
    let block_centre = [(px / 4 * 4) as f64 + 1.5, (py / 4 * 4) as f64 + 1.5];
    assert!(
        (centre[0] - block_centre[0]).hypot(centre[1] - block_centre[1]) < 0.25,
        "centred at {centre:?}, its coarse pixel's centre is {block_centre:?}"
    );
    assert!(
        (energy - 1.0).abs() < 0.01,
        "the point's light is kept: {energy:.4}"
    );
    assert!(
        (rms / expected_rms - 1.0).abs() < 0.1,
        "RMS radius {rms:.2} px, a disc of CoC {coc} px has {expected_rms:.2}"
    );

    // Without the reduced resolution the largest PSF is drawn: the test above would fail.
    let (image, stats) = synthesize(&g, &cam, &dbs, &options(false)).expect("synthesize");
    assert!(stats.counts.clamped > 0);
    let (_, _, clamped_rms) = moments(&image.pixels, w);
    assert!(
        clamped_rms < 0.6 * expected_rms,
        "clamped RMS radius {clamped_rms:.2} px"
    );
}

/// An opaque grey wall whose CoC grows gently across the frame, through the database's
/// largest (64 px, the quick database as shipped) and through twice that: the blurred wall
/// stays the same grey everywhere, with no step or dip where its pixels go from the frame's
/// resolution to half of it, nor from half to a quarter. (The Test profile's six cells are
/// too coarse to be even near their largest CoC. Where the CoC grows by more than a few
/// hundredths of a pixel per pixel, scattering each pixel's PSF leaves a dip of its own at
/// any resolution, so the growth here is slow.)
#[test]
fn a_wall_blurred_past_the_database_range_stays_even() {
    const GREY: f32 = 0.5;
    let dbs = DbSet::new(Some(quick_db(PsfModel::ThinLens)), None).expect("db set");
    let (w, h) = (1024usize, 8usize);
    let cam = camera(w as u32, h as u32, true, 0.0);
    for (from, to, scales) in [(52.0, 76.0, "1 and 2"), (112.0, 144.0, "2 and 4")] {
        // Steady over the first and last eighth (the frame's edges repeat their pixels
        // outwards), a smooth step between.
        let coc_at = |x: usize| {
            let t = ((x as f64 - 128.0) / 768.0).clamp(0.0, 1.0);
            from + (to - from) * t * t * (3.0 - 2.0 * t)
        };
        let depths: Vec<f32> = (0..w * h)
            .map(|i| depth_for_coc(&cam, coc_at(i % w)) as f32)
            .collect();
        let g = GBuffer::from_planes(
            w,
            h,
            vec![[GREY, GREY, GREY, 1.0]; w * h],
            Some(depths),
            None,
        )
        .expect("valid g-buffer");
        let (image, stats) = synthesize(&g, &cam, &dbs, &options(true)).expect("synthesize");
        assert!(stats.counts.reduced > 0, "part of the wall is coarse");
        assert_eq!(stats.counts.clamped, 0);
        let mut worst = (0usize, 0usize, 0.0f32);
        for (i, p) in image.pixels.iter().enumerate() {
            for &v in &p[..3] {
                let err = (v / GREY - 1.0).abs();
                if err > worst.2 {
                    worst = (i % w, i / w, err);
                }
            }
        }
        let (x, y, err) = worst;
        assert!(
            err < 0.01,
            "scales {scales}: the wall departs from its grey by {:.2} % at ({x}, {y}), CoC {:.1} px",
            err * 100.0,
            coc_at(x)
        );
    }
}

/// Below the database's largest CoC, `coarse_above_px` draws the larger CoCs at half the
/// resolution (faster for large blur): a point of CoC 40 px with the threshold at 24 px keeps
/// its light and its size, where the frame's resolution draws it the same. (The quick
/// database: the Test profile's cells are too wide for the two to compare.)
#[test]
fn a_threshold_below_the_range_draws_large_cocs_coarse() {
    let dbs = DbSet::new(Some(quick_db(PsfModel::ThinLens)), None).expect("db set");
    let (w, h) = (128usize, 128usize);
    let cam = camera(w as u32, h as u32, true, 0.0);
    let depth = depth_for_coc(&cam, 40.0) as f32;
    let g = one_pixel(w, h, 64, 64, [1.0, 1.0, 1.0, 1.0], depth, [0.0, 0.0]);
    let (fine, fine_stats) = synthesize(&g, &cam, &dbs, &options(true)).expect("fine");
    assert_eq!(fine_stats.counts.reduced, 0, "in range");
    let mut coarse_options = options(true);
    coarse_options.classify.coarse_above_px = 24.0;
    let (coarse, stats) = synthesize(&g, &cam, &dbs, &coarse_options).expect("coarse");
    assert!(stats.counts.reduced > 0, "above the threshold");
    let (e_fine, _, rms_fine) = moments(&fine.pixels, w);
    let (e_coarse, centre, rms_coarse) = moments(&coarse.pixels, w);
    assert!(
        (e_coarse / e_fine - 1.0).abs() < 0.01,
        "light {e_coarse} vs {e_fine}"
    );
    assert!(
        (rms_coarse / rms_fine - 1.0).abs() < 0.03,
        "RMS radius {rms_coarse:.2} px at half resolution, {rms_fine:.2} px at full"
    );
    // The coarse pixel (32, 32) covers frame pixels 64-65: its centre is at 64.5.
    assert!(
        (centre[0] - 64.5).hypot(centre[1] - 64.5) < 0.25,
        "{centre:?}"
    );
}
