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

#[test]
fn a_moving_slab_smears_both_ways_over_the_wall() {
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
    for _ in 0..H {
        for x in 0..W {
            let on_slab = (x as f64) >= LEFT && (x as f64) < RIGHT;
            let v = if on_slab { SLAB } else { WALL };
            color.push([v, v, v, 1.0]);
            depth.push(if on_slab { 2.0 } else { 4.0 });
            motion.push(if on_slab {
                [motion_px as f32, 0.0]
            } else {
                [0.0, 0.0]
            });
        }
    }
    let g = GBuffer::from_planes(W, H, color, Some(depth), Some(motion)).expect("g-buffer");
    let largest_error = |options: &SynthOptions| -> (usize, f64) {
        let (image, _) = synthesize(&g, &camera, &dbs, options).expect("synth");
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
    };
    // Without the wall continued behind the slab, the smear inside the silhouette is opaque.
    let mut unfilled = SynthOptions::default();
    unfilled.classify.fill_hidden = false;
    let (at, err) = largest_error(&unfilled);
    eprintln!(
        "without the hidden wall: {:.2} % off the reference at x = {at}",
        100.0 * err
    );
    assert!(err > 0.05, "the test must see the hard edge");
    let worst = largest_error(&SynthOptions::default());
    eprintln!(
        "largest error {:.2} % of the reference at x = {}",
        100.0 * worst.1,
        worst.0
    );
    assert!(
        worst.1 < 0.02,
        "{:.2} % off the reference at x = {}",
        100.0 * worst.1,
        worst.0
    );
}
