//! Moving silhouettes as a box shutter makes them: an object's coverage falls off linearly on
//! both sides of its motion, over whatever lies behind it.
//!
//! A bright slab crosses a dark wall, still and sharp, at about 27 px per frame: the centre of
//! a cell of the quick lens-motion database, so that one PSF draws it. The reference is
//! analytic: at each pixel the slab's share of the shutter (found by sampling the shutter
//! time) mixes slab and wall, averaged over the motion lengths the cell's PSF is pre-filtered
//! over, so that what is compared is the silhouette, not the pre-filter. A pinhole image holds
//! no wall behind the slab: where the slab's smear is half transparent inside its silhouette,
//! nothing showed through, compositing made the slab opaque up to its silhouette, and the
//! smear ended there in a hard edge.

mod support;

use psf_db::PsfModel;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::synth::{synthesize, SynthOptions};
use support::{camera, quick_db};

/// Frame width and height, pixels.
const W: usize = 320;
const H: usize = 32;
/// The slab's columns at the frame time, `[LEFT, RIGHT)`.
const LEFT: f64 = 100.0;
const RIGHT: f64 = 196.0;
/// About the motion over the shutter, pixels (along +x); the test takes its cell's centre.
const MOTION_NEAR: f32 = 27.0;
const SLAB: f32 = 0.8;
const WALL: f32 = 0.2;

/// The slab's share of the shutter at column `x` for a motion of `motion` px over it: the
/// fraction of times `t` in `[-1/2, 1/2]` at which the pixel centre lies in the moved slab.
fn coverage(x: usize, motion: f64) -> f64 {
    let samples = 2000;
    let centre = x as f64 + 0.5;
    (0..samples)
        .filter(|k| {
            let t = (*k as f64 + 0.5) / samples as f64 - 0.5;
            centre >= LEFT + motion * t && centre < RIGHT + motion * t
        })
        .count() as f64
        / samples as f64
}

/// The largest error of the middle row against the analytic box-shutter profile, relative to
/// it, and where: the slab at depth `slab_depth` over the wall at `wall_depth` (scene units;
/// the camera has no lens, so depth only decides the layers). With `widen`, the first and last
/// rows lie at 1.5 and 50 units, which spreads the eight depth layers so thin that slab and
/// wall at nearby depths share one.
fn slab_profile_error(slab_depth: f32, wall_depth: f32, widen: bool, fill: bool) -> (usize, f64) {
    let camera = camera(W as u32, H as u32, false, 1.0);
    let db = quick_db(PsfModel::LensMotion);
    let space = db.space().clone();
    let cell = db.lookup([0.0, MOTION_NEAR]).0;
    let motion_px = space.cell_center(cell).expect("cell")[1];
    // The motion lengths the cell's PSF is pre-filtered over: uniform in grid units.
    let grid_box = space.grid().cell_box(cell).expect("cell");
    let lengths: Vec<f64> = (0..64)
        .map(|k| {
            let u = grid_box.min[1] + (grid_box.max[1] - grid_box.min[1]) * (k as f64 + 0.5) / 64.0;
            space.from_grid([0.0, u])[1]
        })
        .collect();
    let dbs = DbSet::new(None, Some(db)).expect("db set");
    let mut color = Vec::with_capacity(W * H);
    let mut depth = Vec::with_capacity(W * H);
    let mut motion = Vec::with_capacity(W * H);
    for y in 0..H {
        for x in 0..W {
            let on_slab = (x as f64) >= LEFT && (x as f64) < RIGHT && y > 0 && y < H - 1;
            let v = if on_slab { SLAB } else { WALL };
            color.push([v, v, v, 1.0]);
            depth.push(match (on_slab, y) {
                (true, _) => slab_depth,
                (false, 0) if widen => 1.5,
                (false, y) if widen && y == H - 1 => 50.0,
                _ => wall_depth,
            });
            motion.push(if on_slab {
                [motion_px as f32, 0.0]
            } else {
                [0.0, 0.0]
            });
        }
    }
    let g = GBuffer::from_planes(W, H, color, Some(depth), Some(motion)).expect("g-buffer");
    let mut options = SynthOptions::default();
    options.classify.fill_hidden = fill;
    let (image, _) = synthesize(&g, &camera, &dbs, &options).expect("synth");
    let y = H / 2;
    let mut worst = (0usize, 0.0f64);
    for x in 40..W - 40 {
        let c = lengths.iter().map(|&l| coverage(x, l)).sum::<f64>() / lengths.len() as f64;
        let want = f64::from(SLAB) * c + f64::from(WALL) * (1.0 - c);
        let got = f64::from(image.pixels[y * W + x][0]);
        let err = (got - want).abs() / want;
        if err > worst.1 {
            worst = (x, err);
        }
    }
    worst
}

#[test]
fn a_moving_slab_smears_both_ways_over_the_wall() {
    // Without the wall continued behind the slab, the smear inside the silhouette is opaque.
    let (at, err) = slab_profile_error(2.0, 4.0, false, false);
    eprintln!(
        "without the hidden wall: {:.2} % off the reference at x = {at}",
        100.0 * err
    );
    assert!(err > 0.05, "the test must see the hard edge");
    assert_within_two_percent(slab_profile_error(2.0, 4.0, false, true));
}

/// Asserts a largest error `(x, relative error)` of [`slab_profile_error`] under 2 %.
fn assert_within_two_percent((at, err): (usize, f64)) {
    eprintln!(
        "largest error {:.2} % of the reference at x = {at}",
        100.0 * err
    );
    assert!(
        err < 0.02,
        "{:.2} % off the reference at x = {at}",
        100.0 * err
    );
}

/// A car's body and the road beside its wheels lie at nearly one depth: in a frame deep
/// enough, in one depth layer. The road continued behind the body then shared the body's
/// layer, where it was hidden under the body's coverage, so the smear stopped in a hard edge
/// at the silhouette (a light block under the car's forward smear); and outside the
/// silhouette the smear and the road added up in the layer, the smear a fifth fainter than
/// over the road. The slab lies at the centre of its layer (parallax 1 / 2.606 between 1 / 50
/// and 1 / 1.5: layer coordinate 4.5 of 8), so that soft layering leaves it whole there, and
/// the wall in the same layer (coordinate 4.2).
#[test]
fn a_moving_slab_smears_both_ways_over_a_wall_in_its_own_depth_layer() {
    assert_within_two_percent(slab_profile_error(2.606, 2.78, true, true));
}

/// Side of the spinning disc's frame, px.
const DISC_FRAME: usize = 160;
/// The disc's radius, px.
const DISC_RADIUS: f64 = 50.0;
/// The disc's turn over the shutter, radians: its rim moves 30 px.
const DISC_TURN: f64 = 0.6;

/// The share of pixel `(x, y)` covered by the disc centred in the frame, from 8 x 8 samples.
fn disc_coverage(x: usize, y: usize) -> f64 {
    let c = DISC_FRAME as f64 / 2.0;
    let mut inside = 0;
    for j in 0..8 {
        for i in 0..8 {
            let (px, py) = (
                x as f64 + (i as f64 + 0.5) / 8.0,
                y as f64 + (j as f64 + 0.5) / 8.0,
            );
            inside += usize::from((px - c).hypot(py - c) < DISC_RADIUS);
        }
    }
    inside as f64 / 64.0
}

/// Mean luminance of the frame's pixels in rings half a pixel wide about the centre, from the
/// centre out.
fn ring_profile(image: &spreadlet::RgbaImage) -> Vec<f64> {
    let c = DISC_FRAME as f64 / 2.0;
    let rings = DISC_FRAME;
    let (mut sum, mut count) = (vec![0.0f64; rings], vec![0usize; rings]);
    for y in 0..DISC_FRAME {
        for x in 0..DISC_FRAME {
            let r = (x as f64 + 0.5 - c).hypot(y as f64 + 0.5 - c);
            let ring = (2.0 * r) as usize;
            if ring < rings {
                let p = image.pixels[y * DISC_FRAME + x];
                sum[ring] += f64::from(p[0] + p[1] + p[2]) / 3.0;
                count[ring] += 1;
            }
        }
    }
    sum.iter()
        .zip(&count)
        .map(|(s, &n)| s / n.max(1) as f64)
        .collect()
}

/// The radius (px) at which the ring profile, from half the disc's radius out, first falls
/// below halfway between `inside` and `outside`, interpolated between rings.
fn half_level_radius(profile: &[f64], inside: f64, outside: f64) -> f64 {
    let half = 0.5 * (inside + outside);
    for k in DISC_RADIUS as usize..profile.len() {
        if profile[k] < half && profile[k - 1] >= half {
            let f = (profile[k - 1] - half) / (profile[k - 1] - profile[k]);
            // Ring k spans radii [k / 2, (k + 1) / 2): its centre is (k + 1/2) / 2.
            return (k as f64 - 0.5 + f + 0.5) / 2.0;
        }
    }
    f64::NAN
}

/// A white disc spinning about its centre in front of a dark wall keeps its silhouette: every
/// point of it travels an arc about the centre, so over the shutter it covers what it covers at
/// any instant, and the analytic image is the still one. Drawn along each pixel's chord, the
/// rim's streaks left the disc at both ends, pushing the rim outward by up to
/// `R / cos(theta / 2) - R` (2.3 px here) and thinning the disc inside it.
#[test]
fn a_spinning_disc_keeps_its_rim() {
    const DISC: f32 = 1.0;
    let camera = camera(DISC_FRAME as u32, DISC_FRAME as u32, false, 1.0);
    let dbs = DbSet::new(
        Some(quick_db(PsfModel::ThinLens)),
        Some(quick_db(PsfModel::LensMotion)),
    )
    .expect("db set");
    let c = DISC_FRAME as f64 / 2.0;
    let mut color = Vec::with_capacity(DISC_FRAME * DISC_FRAME);
    let mut depth = Vec::with_capacity(DISC_FRAME * DISC_FRAME);
    let mut motion = Vec::with_capacity(DISC_FRAME * DISC_FRAME);
    for y in 0..DISC_FRAME {
        for x in 0..DISC_FRAME {
            let cover = disc_coverage(x, y) as f32;
            let v = DISC * cover + WALL * (1.0 - cover);
            color.push([v, v, v, 1.0]);
            let on_disc = cover >= 0.5;
            depth.push(if on_disc { 2.0 } else { 4.0 });
            // x right, y down: the turn's field theta (-(y - c), x - c) at the pixel centre.
            let (dx, dy) = (x as f64 + 0.5 - c, y as f64 + 0.5 - c);
            motion.push(if on_disc {
                [(-DISC_TURN * dy) as f32, (DISC_TURN * dx) as f32]
            } else {
                [0.0, 0.0]
            });
        }
    }
    let g = GBuffer::from_planes(DISC_FRAME, DISC_FRAME, color, Some(depth), Some(motion))
        .expect("g-buffer");
    let (image, _) = synthesize(&g, &camera, &dbs, &SynthOptions::default()).expect("synth");
    let profile = ring_profile(&image);
    let still = ring_profile(&spreadlet::RgbaImage {
        width: DISC_FRAME,
        height: DISC_FRAME,
        pixels: g.color.clone(),
    });
    let (inside, outside) = (f64::from(DISC), f64::from(WALL));
    let rim = half_level_radius(&profile, inside, outside);
    let still_rim = half_level_radius(&still, inside, outside);
    // The mean level of the rings from `from` to `to` px off the rim (negative: inside), as a
    // share of the step from wall to disc.
    let level = |p: &[f64], from: f64, to: f64| {
        let rings = (2.0 * (DISC_RADIUS + from)) as usize..(2.0 * (DISC_RADIUS + to)) as usize;
        let n = rings.len() as f64;
        p[rings]
            .iter()
            .map(|v| (v - outside) / (inside - outside))
            .sum::<f64>()
            / n
    };
    // Light beyond the rim, over the wall, 2-8 px out; the disc just inside it, 2-8 px in.
    let outer = |p: &[f64]| level(p, 2.0, 8.0);
    let inner = |p: &[f64]| level(p, -8.0, -2.0);
    eprintln!(
        "rim at {rim:.2} px (still {still_rim:.2}); beyond it {:.4} of the step (still {:.4}); \
         inside {:.4} (still {:.4})",
        outer(&profile),
        outer(&still),
        inner(&profile),
        inner(&still)
    );
    // Drawn along the chords: 0.63 px out, 0.0047 beyond, 0.968 inside.
    assert!(
        (rim - still_rim).abs() < 0.25,
        "rim at {rim:.2} px, still at {still_rim:.2}"
    );
    assert!(
        outer(&profile) < 0.002,
        "light beyond the rim: {:.4}",
        outer(&profile)
    );
    assert!(
        inner(&profile) > 0.985,
        "the disc inside its rim: {:.4}",
        inner(&profile)
    );
}
