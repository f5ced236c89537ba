//! A frame's own PSF images (lens PSFs smeared along each moving pixel's motion) kept packed,
//! as their rows' non-zero spans, draw the picture they draw from the frame's database.
//!
//! A disc spinning in front of a defocused wall: every pixel of the disc travels its own arc,
//! so nearly every pixel has a smeared PSF of its own, and the frame's blend pairs and edge
//! splits draw some of them two to a pixel. The reference is the same frame drawn from the
//! database's images; the two differ only in the rounding of a pair's sum.

mod support;

use psf_db::PsfModel;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::synth::{render_cpu, SynthOptions};
use spreadlet::{Input, Plan, RgbaImage};
use support::{camera, physical_camera, quick_db, test_db};

/// Side of the frame, px.
const FRAME: usize = 96;
/// The disc's radius, px.
const RADIUS: f64 = 36.0;
/// The disc's turn over the shutter, radians: its rim moves 18 px.
const TURN: f64 = 0.5;

/// A checkered disc at `disc_depth` spinning about the frame's centre, over a still wall
/// farther back (the camera of `support::camera` with a lens focuses at 1).
fn spinning_disc(disc_depth: f32) -> GBuffer {
    let c = FRAME as f64 / 2.0;
    let n = FRAME * FRAME;
    let (mut color, mut depth, mut motion) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for y in 0..FRAME {
        for x in 0..FRAME {
            let (dx, dy) = (x as f64 + 0.5 - c, y as f64 + 0.5 - c);
            let on_disc = dx.hypot(dy) < RADIUS;
            if on_disc {
                let check = ((x / 6) + (y / 6)) % 2 == 0;
                let v = if check { 0.9 } else { 0.2 };
                color.push([v, 0.6 * v, 0.1, 1.0]);
                depth.push(disc_depth);
                motion.push([(-TURN * dy) as f32, (TURN * dx) as f32]);
            } else {
                color.push([0.3, 0.3, 0.35, 1.0]);
                depth.push(3.0);
                motion.push([0.0, 0.0]);
            }
        }
    }
    GBuffer::from_planes(FRAME, FRAME, color, Some(depth), Some(motion)).expect("g-buffer")
}

/// The frame drawn on the CPU with its images packed or not, and how many images were packed.
fn draw(g: &GBuffer, dbs: &DbSet, pack: bool) -> (RgbaImage, usize) {
    draw_through(g, &camera(FRAME as u32, FRAME as u32, true, 1.0), dbs, pack)
}

fn draw_through(
    g: &GBuffer,
    camera: &spreadlet::camera::Camera,
    dbs: &DbSet,
    pack: bool,
) -> (RgbaImage, usize) {
    let mut options = SynthOptions::default();
    options.classify.pack_images = pack;
    let prepared = Plan::new(Input::Flat(g), camera, &options)
        .and_then(|plan| plan.prepare(dbs))
        .expect("prepare");
    let classified = prepared.classified().expect("records");
    assert!(classified.counts.smeared > 100, "{:?}", classified.counts);
    let packed = classified.packed.as_ref().map_or(0, |p| p.count());
    // A packed image's values are held once, packed: its place in the frame's database is
    // an empty image.
    if let (Some(images), Some(db)) = (&classified.packed, &classified.database) {
        for (psf, _) in images.images() {
            let held = db.dense(psf as usize).map_or(0, |d| d.data.len());
            assert_eq!(
                held, 0,
                "packed PSF {psf} also holds {held} values in the database"
            );
        }
    }
    (render_cpu(prepared, dbs).0, packed)
}

fn largest_difference(a: &RgbaImage, b: &RgbaImage) -> f32 {
    a.pixels
        .iter()
        .zip(&b.pixels)
        .flat_map(|(p, q)| p.iter().zip(q).map(|(x, y)| (x - y).abs()))
        .fold(0.0, f32::max)
}

#[test]
fn packed_images_draw_what_the_database_draws() {
    // Moving pixels smear the thin-lens PSFs: no lens-motion database is needed.
    let dbs = DbSet::new(Some(quick_db(PsfModel::ThinLens)), None).expect("db set");
    // In focus (each lens PSF a single pixel, the streak its taps alone), and defocused by a
    // few pixels (a disc of a PSF smeared).
    for disc_depth in [1.0, 1.25] {
        let g = spinning_disc(disc_depth);
        let (from_database, none) = draw(&g, &dbs, false);
        let (from_packed, packed) = draw(&g, &dbs, true);
        assert_eq!(none, 0);
        assert!(
            packed > 1000,
            "{packed} images packed at depth {disc_depth}"
        );
        let light: f32 = from_database.pixels.iter().map(|p| p[0]).sum();
        assert!(light > 0.0);
        let diff = largest_difference(&from_database, &from_packed);
        assert!(
            diff <= 1e-6,
            "packed images differ by {diff} at depth {disc_depth}"
        );
        // And the same bytes on every run.
        let (again, _) = draw(&g, &dbs, true);
        assert!(from_packed.pixels == again.pixels);
    }
}

/// Through a real lens every moving pixel's PSF is smeared too, and its turned lens PSFs are
/// appended to the frame's database after the packed images' places: the packed frame still
/// draws what the database's images draw.
#[test]
fn packed_images_through_a_real_lens_draw_what_the_database_draws() {
    let db = test_db(PsfModel::PhysicalLens);
    let mut cam = physical_camera(db, 40);
    cam.shutter_frames = 1.0;
    let (w, h) = (cam.width as usize, cam.height as usize);
    let inv = db.space().dims()[0];
    let (mut color, mut depth, mut motion) = (Vec::new(), Vec::new(), Vec::new());
    for y in 0..h {
        for x in 0..w {
            let t = (x as f32 * 0.37 + y as f32 * 0.23).sin() * 0.5 + 0.5;
            color.push([t, 1.0 - t, ((x + y) % 5) as f32 / 5.0, 1.0]);
            let f = (x as f64 + 0.5) / w as f64;
            depth.push((1.0 / (inv.min + (inv.max - inv.min) * (0.1 + 0.8 * f))) as f32);
            // A turn about the frame's centre: every pixel its own motion.
            let (dx, dy) = (x as f32 - w as f32 / 2.0, y as f32 - h as f32 / 2.0);
            motion.push([-0.3 * dy, 0.3 * dx]);
        }
    }
    let g = GBuffer::from_planes(w, h, color, Some(depth), Some(motion)).expect("g-buffer");
    let dbs = DbSet::single(db.clone()).expect("db set");
    let (from_database, none) = draw_through(&g, &cam, &dbs, false);
    let (from_packed, packed) = draw_through(&g, &cam, &dbs, true);
    assert_eq!(none, 0);
    assert!(packed > 100, "{packed} images packed");
    let largest = from_database
        .pixels
        .iter()
        .flatten()
        .fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(largest > 0.1);
    let diff = largest_difference(&from_database, &from_packed);
    assert!(diff <= 1e-5 * largest, "packed images differ by {diff}");
}
