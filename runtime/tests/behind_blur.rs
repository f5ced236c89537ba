//! A sharp wall seen part of the shutter behind a fast box: reconstruction from 4 spp leaves
//! the wall's share of each pixel as smooth as the box's streak, with no grain from how many of
//! the pixel's own samples happened to see the wall. Before, a pixel all of whose samples hit
//! the box showed the box's streak alone (a bright speck), its neighbour with all four on the
//! wall a dark one.

mod support;

use psf_db::PsfModel;
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::reconstruct::reconstruct;
use spreadlet::synth::SynthOptions;
use support::quick_db;

const WIDTH: usize = 128;
const HEIGHT: usize = 128;

/// A plain wall in focus at 4 m and a light box at 2 m crossing it at about 27 px per frame
/// (f/16: the box's CoC is a tenth of a pixel, so only its motion blurs it), its soft ends
/// about 20 px wide and 100 rows tall.
const SCENE: &str = include_str!("../../scene/scenes/hard/box-over-sharp-wall.json");

/// Luminance (mean of R, G, B) of every pixel.
fn luminance(image: &spreadlet::RgbaImage) -> Vec<f64> {
    image
        .pixels
        .iter()
        .map(|p| (f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])) / 3.0)
        .collect()
}

#[test]
fn a_sharp_wall_behind_a_moving_box_shows_no_grain_of_its_sample_counts() {
    let scene = scene::Scene::from_json(SCENE, "test scene").expect("scene");
    let camera = Camera::from_json_str(&scene.camera_json()).expect("camera");
    let render = scene::RenderOptions {
        seed: 5,
        ..Default::default()
    };
    let frames = scene::render_stochastic(&scene, 4, &render).expect("frames");
    let reference = scene::render_reference(&scene, 256, &render).expect("reference");
    let dbs = DbSet::new(
        Some(quick_db(PsfModel::ThinLens)),
        Some(quick_db(PsfModel::LensMotion)),
    )
    .expect("db set");
    let (image, _) = reconstruct(&frames, &camera, &dbs, &SynthOptions::default()).expect("recon");
    let (got, want) = (luminance(&image), luminance(&reference));

    // The wall alone and the box alone, from the reference's darkest and brightest pixels.
    let wall = want.iter().copied().fold(f64::INFINITY, f64::min);
    let solid = want.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    assert!(
        solid - wall > 0.3,
        "precondition: the box stands out ({wall} .. {solid})"
    );
    // The streak's soft ends: the wall seen for 3-85 % of the shutter (the box for 15-97 %).
    let zone: Vec<usize> = (0..WIDTH * HEIGHT)
        .filter(|&p| {
            let share = (want[p] - wall) / (solid - wall);
            (0.15..=0.97).contains(&share)
        })
        .collect();
    assert!(
        zone.len() > 300,
        "precondition: {} pixels in the soft ends",
        zone.len()
    );
    let (mut sum, mut sum_sq, mut worst, mut specks) = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for &p in &zone {
        let d = (got[p] - want[p]) / (solid - wall);
        sum += d;
        sum_sq += d * d;
        worst = worst.max(d.abs());
        specks += usize::from(d.abs() > 0.1);
    }
    let n = zone.len() as f64;
    let (bias, rms) = (sum / n, (sum_sq / n).sqrt());
    eprintln!(
        "{} pixels in the soft ends: error against the reference, in units of the box's \
         contrast: mean {bias:+.4}, RMS {rms:.4}, worst {worst:.4}, {specks} pixels over 0.1",
        zone.len()
    );
    // Before, the pixels that lost every sample to the box stood out: 14 pixels over 0.1, the
    // worst 0.33, RMS 0.0345 (now 3, 0.11 and 0.0289).
    assert!(specks <= 5, "{specks} specks in the streak's soft ends");
    assert!(worst < 0.2, "a speck {worst:.4} of the box's contrast off");
    assert!(rms < 0.032, "grain in the streak's soft ends: RMS {rms:.4}");
    assert!(bias.abs() < 0.02, "the wall's share is off by {bias:+.4}");
}
