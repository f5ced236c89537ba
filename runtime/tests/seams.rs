//! A surface whose blur varies smoothly must blur smoothly: no step or dip where the CoC or
//! the motion length crosses from one PSF cell to the next.
//!
//! Each case is a uniform grey surface whose blur ramps along x, so the right answer is the
//! grey itself everywhere; a cell boundary shows as a step or a dip in the row profile. The
//! databases are the quick profile's, as `spreadlet synth` uses them.

mod support;

use psf_db::PsfModel;
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::synth::{synthesize, SynthOptions};
use support::{camera, depth_for_coc, quick_db};

/// Frame width and height, pixels.
const W: usize = 384;
const H: usize = 48;
/// The surface's grey (linear).
const GREY: f32 = 0.5;
/// Columns at each side left out: the ramp's ends meet the frame's edges there.
const MARGIN: usize = 48;

/// Per column, the mean of the middle rows' luminance over the grey: 1 where the surface keeps
/// its level.
fn row_profile(image: &spreadlet::RgbaImage) -> Vec<f64> {
    let rows = H / 2 - 6..H / 2 + 6;
    (0..W)
        .map(|x| {
            let sum: f64 = rows
                .clone()
                .map(|y| {
                    let p = image.pixels[y * W + x];
                    (f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])) / 3.0
                })
                .sum();
            sum / rows.len() as f64 / f64::from(GREY)
        })
        .collect()
}

/// The profile's largest step or dip: how far a column lies from the straight line through
/// its neighbours `k` columns away, over the interior columns (relative to the level).
fn largest_step(profile: &[f64], k: usize) -> (usize, f64) {
    (MARGIN..W - MARGIN)
        .map(|x| {
            let line = 0.5 * (profile[x - k] + profile[x + k]);
            (x, (profile[x] - line).abs() / line)
        })
        .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a })
}

/// The largest distance of an interior column from the grey's level.
fn largest_drift(profile: &[f64]) -> f64 {
    profile[MARGIN..W - MARGIN]
        .iter()
        .map(|v| (v - 1.0).abs())
        .fold(0.0, f64::max)
}

fn grey_gbuffer(depth: impl Fn(usize) -> f32, motion: impl Fn(usize) -> [f32; 2]) -> GBuffer {
    let mut depths = Vec::with_capacity(W * H);
    let mut motions = Vec::with_capacity(W * H);
    for _ in 0..H {
        for x in 0..W {
            depths.push(depth(x));
            motions.push(motion(x));
        }
    }
    GBuffer::from_planes(
        W,
        H,
        vec![[GREY, GREY, GREY, 1.0]; W * H],
        Some(depths),
        Some(motions),
    )
    .expect("valid g-buffer")
}

/// The row profile as shipped, after printing for comparison the one of the lookup of the
/// single cell holding each pixel's parameters (`continuous_lookup` off).
fn synth_profile(gbuffer: &GBuffer, camera: &Camera, dbs: &DbSet, what: &str) -> Vec<f64> {
    let mut nearest = SynthOptions::default();
    nearest.classify.continuous_lookup = false;
    let (image, _) = synthesize(gbuffer, camera, dbs, &nearest).expect("synth");
    report(&format!("{what}, nearest cell"), &row_profile(&image));
    let (image, _) = synthesize(gbuffer, camera, dbs, &SynthOptions::default()).expect("synth");
    let profile = row_profile(&image);
    report(what, &profile);
    profile
}

fn report(what: &str, profile: &[f64]) -> (f64, f64) {
    let (at, step) = largest_step(profile, 4);
    let drift = largest_drift(profile);
    eprintln!(
        "{what}: largest step or dip {:.2} % at x = {at}, largest drift from the level {:.2} %",
        100.0 * step,
        100.0 * drift
    );
    let line: Vec<String> = profile[MARGIN..W - MARGIN]
        .iter()
        .map(|v| format!("{:.4}", v))
        .collect();
    eprintln!("{}", line.join(" "));
    (step, drift)
}

/// The ramp's value at column `x`: `from` at the left edge, `to` at the right.
fn ramp(x: usize, from: f32, to: f32) -> f32 {
    from + (to - from) * x as f32 / (W - 1) as f32
}

#[test]
fn a_defocus_ramp_blurs_smoothly() {
    let camera = camera(W as u32, H as u32, true, 0.0);
    let dbs = DbSet::new(Some(quick_db(PsfModel::ThinLens)), None).expect("db set");
    let g = grey_gbuffer(
        |x| depth_for_coc(&camera, f64::from(ramp(x, 1.0, 24.0))) as f32,
        |_| [0.0, 0.0],
    );
    let (_, step) = largest_step(&synth_profile(&g, &camera, &dbs, "CoC 1-24 px"), 4);
    assert!(step < 0.01, "a step or dip of {:.2} %", 100.0 * step);
}

/// Where both PSFs of a blend are dense (CoC up to about 8 px), the blend is drawn premixed,
/// one record a pixel instead of two, and stays smooth.
#[test]
fn a_dense_defocus_ramp_blurs_smoothly_one_record_a_pixel() {
    let camera = camera(W as u32, H as u32, true, 0.0);
    let dbs = DbSet::new(Some(quick_db(PsfModel::ThinLens)), None).expect("db set");
    let g = grey_gbuffer(
        |x| depth_for_coc(&camera, f64::from(ramp(x, 0.7, 6.0))) as f32,
        |_| [0.0, 0.0],
    );
    let (_, step) = largest_step(&synth_profile(&g, &camera, &dbs, "CoC 0.7-6 px"), 4);
    assert!(step < 0.01, "a step or dip of {:.2} %", 100.0 * step);
    // As many records inside the frame as the lookup of each pixel's one nearest cell makes
    // (the records repeated beyond the frame's edges follow each PSF's reach).
    let records = |continuous_lookup: bool| {
        let mut options = SynthOptions::default();
        options.classify.continuous_lookup = continuous_lookup;
        let (_, stats) = synthesize(&g, &camera, &dbs, &options).expect("synth");
        assert_eq!(stats.counts.sparse, 0, "all dense");
        stats.counts.dense - stats.counts.edge_extended
    };
    let (blended, nearest) = (records(true), records(false));
    assert_eq!(
        blended, nearest,
        "records: {blended} blended, {nearest} nearest"
    );
}

#[test]
fn a_motion_ramp_along_the_motion_blurs_smoothly() {
    let camera = camera(W as u32, H as u32, false, 1.0);
    let dbs = DbSet::new(None, Some(quick_db(PsfModel::LensMotion))).expect("db set");
    let g = grey_gbuffer(|_| 2.0, |x| [ramp(x, 2.0, 40.0), 0.0]);
    let profile = synth_profile(&g, &camera, &dbs, "motion 2-40 px along x");
    let (_, step) = largest_step(&profile, 4);
    assert!(step < 0.01, "a step or dip of {:.2} %", 100.0 * step);
}

#[test]
fn a_motion_ramp_across_the_motion_blurs_smoothly() {
    let camera = camera(W as u32, H as u32, false, 1.0);
    let dbs = DbSet::new(None, Some(quick_db(PsfModel::LensMotion))).expect("db set");
    let g = grey_gbuffer(|_| 2.0, |x| [0.0, ramp(x, 2.0, 40.0)]);
    let profile = synth_profile(&g, &camera, &dbs, "motion 2-40 px along y");
    let (_, step) = largest_step(&profile, 4);
    assert!(step < 0.01, "a step or dip of {:.2} %", 100.0 * step);
}

#[test]
fn a_motion_ramp_along_the_motion_blurs_smoothly_smeared_from_the_thin_lens() {
    let camera = camera(W as u32, H as u32, false, 1.0);
    let dbs = DbSet::new(
        Some(quick_db(PsfModel::ThinLens)),
        Some(quick_db(PsfModel::LensMotion)),
    )
    .expect("db set");
    let g = grey_gbuffer(|_| 2.0, |x| [ramp(x, 2.0, 40.0), 0.0]);
    let (image, stats) = synthesize(&g, &camera, &dbs, &SynthOptions::default()).expect("synth");
    assert!(
        stats.counts.smeared > W * H / 2,
        "{} of {} pixels smeared",
        stats.counts.smeared,
        W * H
    );
    let (step, _) = report(
        "motion 2-40 px along x, thin-lens PSFs smeared",
        &row_profile(&image),
    );
    assert!(step < 0.01, "a step or dip of {:.2} %", 100.0 * step);
}
