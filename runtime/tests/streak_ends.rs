//! A streak ends where the motion says: a thin bright line moving along x over a black wall,
//! in focus, against the analytic streak of a box shutter (the line's pixel smeared over the
//! motion, then averaged over the output pixel).

mod support;

use psf_db::PsfModel;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::synth::{synthesize, SynthOptions};
use support::{camera, quick_db};

/// Frame width and height, pixels.
const W: usize = 160;
const H: usize = 32;
/// The bright column.
const LINE_X: usize = 70;

/// Every pixel moving `motion_px` along x; black and opaque but for one white column.
fn moving_line(motion_px: f32) -> GBuffer {
    let color = (0..W * H)
        .map(|i| {
            if i % W == LINE_X {
                [1.0, 1.0, 1.0, 1.0]
            } else {
                [0.0, 0.0, 0.0, 1.0]
            }
        })
        .collect();
    GBuffer::from_planes(
        W,
        H,
        color,
        Some(vec![2.0; W * H]),
        Some(vec![[motion_px, 0.0]; W * H]),
    )
    .expect("valid g-buffer")
}

/// The analytic row: a 1 px column swept over `motion_px` (box shutter), averaged over each
/// output pixel, by midpoint integration over the sweep and the pixel.
fn analytic_row(motion_px: f64) -> Vec<f64> {
    const STEPS: usize = 400;
    (0..W)
        .map(|x| {
            let mut covered = 0.0;
            for i in 0..STEPS {
                // A point of the output pixel, and where the column is at time t.
                let px = x as f64 + (i as f64 + 0.5) / STEPS as f64;
                for j in 0..STEPS {
                    let t = (j as f64 + 0.5) / STEPS as f64 - 0.5;
                    let left = LINE_X as f64 + t * motion_px;
                    if px >= left && px < left + 1.0 {
                        covered += 1.0;
                    }
                }
            }
            covered / (STEPS * STEPS) as f64
        })
        .collect()
}

/// The middle rows' mean grey, per column.
fn row(image: &spreadlet::RgbaImage) -> Vec<f64> {
    let rows = H / 2 - 4..H / 2 + 4;
    (0..W)
        .map(|x| {
            rows.clone()
                .map(|y| {
                    let p = image.pixels[y * W + x];
                    (f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])) / 3.0
                })
                .sum::<f64>()
                / rows.len() as f64
        })
        .collect()
}

/// The largest distance of `got` from `want`, over the streak's plateau height.
fn largest_error(got: &[f64], want: &[f64], motion_px: f64) -> (usize, f64) {
    let plateau = 1.0 / motion_px;
    got.iter()
        .zip(want)
        .enumerate()
        .map(|(x, (g, w))| (x, (g - w).abs() / plateau))
        .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a })
}

#[test]
fn a_streak_ends_where_the_motion_does() {
    let camera = camera(W as u32, H as u32, false, 1.0);
    let dbs = DbSet::new(
        Some(quick_db(PsfModel::ThinLens)),
        Some(quick_db(PsfModel::LensMotion)),
    )
    .expect("db set");
    let mut database = SynthOptions::default();
    database.classify.smear_motion = false;
    // Lengths inside a quick lens-motion cell and near its edges.
    for motion in [9.5f32, 23.0, 36.0, 57.0] {
        let g = moving_line(motion);
        let want = analytic_row(f64::from(motion));
        let (smeared, stats) =
            synthesize(&g, &camera, &dbs, &SynthOptions::default()).expect("synth");
        assert!(stats.counts.smeared > 0, "nothing smeared");
        let (at, err) = largest_error(&row(&smeared), &want, f64::from(motion));
        let (from_cells, _) = synthesize(&g, &camera, &dbs, &database).expect("synth");
        let (cat, cerr) = largest_error(&row(&from_cells), &want, f64::from(motion));
        eprintln!(
            "motion {motion} px: largest error {:.1} % of the streak's level at x = {at} \
             (the lens-motion cell's PSF: {:.1} % at x = {cat})",
            100.0 * err,
            100.0 * cerr
        );
        assert!(
            err < 0.05,
            "motion {motion} px: the streak is {:.1} % off at x = {at}",
            100.0 * err
        );
    }
}

/// Sharp pixels of several thin-lens cells moving alike share their smeared PSFs: each cell's
/// PSF trims to the one pixel it lights, and a streak is built once per length and angle, not
/// once per cell (an in-focus spinning disc built 6 % more streaks, each a box of mostly empty
/// pixels, one per cell it touched).
#[test]
fn sharp_pixels_of_several_cells_share_their_streaks() {
    let (w, h) = (64usize, 8usize);
    let camera = camera(w as u32, h as u32, true, 1.0);
    let dbs = DbSet::new(Some(quick_db(PsfModel::ThinLens)), None).expect("db set");
    let thin = dbs.thin_lens.as_ref().expect("thin lens");
    // CoCs across the sharpest cells, one per column band.
    let cocs: Vec<f64> = (0..w).map(|x| 0.01 + 0.1 * x as f64 / w as f64).collect();
    let cells: std::collections::BTreeSet<u32> = cocs
        .iter()
        .map(|&c| thin.lookup([c as f32, 0.0]).0)
        .collect();
    assert!(cells.len() >= 3, "the CoCs span {} cells", cells.len());
    // The frame's own database: the set's PSFs and what the frame adds, the streaks among them.
    let frame_psfs = |coc_of: &dyn Fn(usize) -> f64| -> usize {
        let mut color = Vec::new();
        let mut depth = Vec::new();
        for _ in 0..h {
            for x in 0..w {
                color.push([0.5, 0.5, 0.5, 1.0]);
                depth.push(support::depth_for_coc(&camera, coc_of(x)) as f32);
            }
        }
        let motion = vec![[20.0f32, 0.0]; w * h];
        let g = GBuffer::from_planes(w, h, color, Some(depth), Some(motion)).expect("g-buffer");
        let options = SynthOptions::default();
        let classified =
            spreadlet::pipeline::classify(&g, &camera, &dbs, &options.classify).expect("classify");
        classified
            .database
            .as_ref()
            .expect("frame database")
            .psf_count()
    };
    let one_cell = frame_psfs(&|_| cocs[0]);
    let several = frame_psfs(&|x| cocs[x]);
    eprintln!(
        "{} cells: {several} PSFs in the frame's database, {one_cell} with one cell",
        cells.len()
    );
    assert_eq!(several, one_cell, "{} cells", cells.len());
}

/// A frame whose streaks would need more smeared PSF images than its budget draws its longest
/// streaks at a reduced resolution instead of failing (a car driving at the camera, whose every
/// pixel streaks outwards at its own angle and length), keeps its light, and stays close to
/// the frame drawn without a budget; a budget too small even for the coarsest level is a clear
/// error.
#[test]
fn streaks_beyond_the_frames_budget_are_drawn_at_a_reduced_resolution() {
    let (w, h) = (96usize, 96usize);
    let camera = camera(w as u32, h as u32, true, 1.0);
    let dbs = DbSet::new(Some(quick_db(PsfModel::ThinLens)), None).expect("db set");
    // A textured plane slightly out of focus, every pixel moving away from the centre by up to
    // 30 px: a distinct angle and length nearly everywhere.
    let mut color = Vec::new();
    let mut motion = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let checker = ((x / 6 + y / 6) % 2) as f32;
            color.push([0.2 + 0.6 * checker, 0.3, 0.5 - 0.3 * checker, 1.0]);
            let (dx, dy) = (
                x as f32 + 0.5 - w as f32 / 2.0,
                y as f32 + 0.5 - h as f32 / 2.0,
            );
            motion.push([dx * 0.6, dy * 0.6]);
        }
    }
    let depth = vec![support::depth_for_coc(&camera, 1.5) as f32; w * h];
    let g = GBuffer::from_planes(w, h, color, Some(depth), Some(motion)).expect("g-buffer");
    let with_budget = |values: usize| {
        let mut options = SynthOptions::default();
        options.classify.smeared_values_budget = values;
        options
    };
    // The values the frame's smeared images hold when nothing limits them.
    let unlimited = with_budget(usize::MAX);
    let classified =
        spreadlet::pipeline::classify(&g, &camera, &dbs, &unlimited.classify).expect("classify");
    let database = classified.database.as_ref().expect("the frame's database");
    let first = dbs.combined.as_ref().expect("combined").psf_count();
    let values: usize = (first..database.psf_count())
        .filter_map(|i| database.dense(i))
        .map(|d| d.data.len())
        .sum();
    assert!(values > 0, "nothing smeared");
    let (full, full_stats) = synthesize(&g, &camera, &dbs, &unlimited).expect("synth");
    assert_eq!(full_stats.counts.reduced, 0, "{:?}", full_stats.counts);

    let (reduced, stats) = synthesize(&g, &camera, &dbs, &with_budget(values * 3 / 4))
        .expect("a frame over its budget is drawn, not refused");
    assert!(
        stats.counts.reduced > 0,
        "nothing reduced: {:?}",
        stats.counts
    );
    let light = |image: &spreadlet::RgbaImage| -> f64 {
        image
            .pixels
            .iter()
            .map(|p| f64::from(p[0] + p[1] + p[2]))
            .sum()
    };
    let (full_light, reduced_light) = (light(&full), light(&reduced));
    let mean_difference = full
        .pixels
        .iter()
        .zip(&reduced.pixels)
        .map(|(a, b)| (0..3).map(|c| f64::from((a[c] - b[c]).abs())).sum::<f64>())
        .sum::<f64>()
        / full_light;
    eprintln!(
        "budget {} of {values} values: {} of {} fragments reduced; light {:.4} of the \
         unlimited frame's, mean difference {:.4} of its mean",
        values * 3 / 4,
        stats.counts.reduced,
        w * h,
        reduced_light / full_light,
        mean_difference
    );
    assert!(
        (reduced_light / full_light - 1.0).abs() < 0.01,
        "light {reduced_light} against {full_light}"
    );
    assert!(mean_difference < 0.05, "mean difference {mean_difference}");

    let refused = synthesize(&g, &camera, &dbs, &with_budget(1000))
        .expect_err("a budget too small for the coarsest level is an error");
    let text = refused.to_string();
    assert!(
        text.contains("smeared PSFs") && text.contains("1000 values"),
        "{text}"
    );
}

/// The outline the sub-pixel model fills is the precompute's aperture: a point lies within the
/// outline scaled by `r` exactly where the light tracer's aperture holds it over `r` (turned
/// half a turn: the point reflected), for discs, rotated polygons and squeezed ones.
#[test]
fn the_sub_pixel_outline_is_the_precomputes_aperture() {
    use precompute::aperture::{ApertureShape, LensAperture};
    use spreadlet::subpixel_psf::Outline;
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for (blades, rotation) in [(0u32, 0.0f64), (5, 0.35), (6, 0.0), (9, 1.2)] {
        for ratio in [1.0f64, 2.0] {
            for half_turn in [false, true] {
                let outline = Outline::of(blades, rotation, ratio, half_turn);
                let aperture = LensAperture {
                    shape: ApertureShape::from_blades(blades, rotation),
                    ratio,
                    mask: None,
                };
                for r in [1.3f64, 2.7] {
                    for _ in 0..2000 {
                        let p = [
                            (2.0 * uniform() - 1.0) * 1.2 * r,
                            (2.0 * uniform() - 1.0) * 1.2 * r,
                        ];
                        let g = outline.gauge(p);
                        if (g - r).abs() < 1e-9 {
                            continue;
                        }
                        let sign = if half_turn { -1.0 } else { 1.0 };
                        let held = aperture.contains([sign * p[0] / r, sign * p[1] / r]);
                        assert_eq!(g <= r, held, "{blades} blades at {rotation}, ratio {ratio}, turned {half_turn}: {p:?}");
                    }
                }
            }
        }
    }
}
