//! A sharp wall seen part of the time behind a blurred surface: reconstruction from 4 spp
//! leaves the wall's share of each pixel as smooth as the blurred surface's veil, with no
//! grain from how many of the pixel's own samples happened to see the wall. Before, a pixel
//! all of whose samples hit the blurred surface showed it alone (a bright speck), its
//! neighbour with all four on the wall a dark one.

mod support;

use support::{luminance, reconstruct_scene};

/// A plain wall in focus at 4 m and a light box at 2 m crossing it at about 27 px per frame
/// (f/16: the box's CoC is a tenth of a pixel, so only its motion blurs it), its soft ends
/// about 20 px wide and 100 rows tall.
const MOVING_BOX: &str = include_str!("../../scene/scenes/hard/box-over-sharp-wall.json");

/// The same wall behind a still light bar at 0.5 m, f/1.2: a CoC radius of about 6.5 px, so
/// that the bar's edges are soft for about 13 px.
const DEFOCUSED_BAR: &str = include_str!("../../scene/scenes/hard/bar-before-sharp-wall.json");

/// How reconstruction from 4 spp of `scene` (a bright blurred surface over a dark sharp one)
/// errs against its reference where the blurred surface covers 15-97 % of a pixel (the sharp
/// one is seen for 3-85 % of the shutter or lens), in units of the two surfaces' contrast.
struct SoftEdgeErrors {
    pixels: usize,
    bias: f64,
    rms: f64,
    worst: f64,
    /// Pixels off by more than a tenth of the contrast.
    specks: usize,
}

fn soft_edge_errors(scene: &str) -> SoftEdgeErrors {
    let (_, _, reference, image) = reconstruct_scene(scene, 4, 5);
    let (got, want) = (luminance(&image), luminance(&reference));

    // The wall alone and the blurred surface alone: the reference's darkest and brightest.
    let wall = want.iter().copied().fold(f64::INFINITY, f64::min);
    let solid = want.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    assert!(
        solid - wall > 0.3,
        "precondition: the blurred surface stands out ({wall} .. {solid})"
    );
    let zone: Vec<usize> = (0..want.len())
        .filter(|&p| (0.15..=0.97).contains(&((want[p] - wall) / (solid - wall))))
        .collect();
    let (mut sum, mut sum_sq, mut worst, mut specks) = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for &p in &zone {
        let d = (got[p] - want[p]) / (solid - wall);
        sum += d;
        sum_sq += d * d;
        worst = worst.max(d.abs());
        specks += usize::from(d.abs() > 0.1);
    }
    let n = zone.len().max(1) as f64;
    let errors = SoftEdgeErrors {
        pixels: zone.len(),
        bias: sum / n,
        rms: (sum_sq / n).sqrt(),
        worst,
        specks,
    };
    eprintln!(
        "{} pixels in the soft edges: error against the reference, in units of the contrast: \
         mean {:+.4}, RMS {:.4}, worst {:.4}, {} pixels over 0.1",
        errors.pixels, errors.bias, errors.rms, errors.worst, errors.specks
    );
    errors
}

#[test]
fn a_sharp_wall_behind_a_moving_box_shows_no_grain_of_its_sample_counts() {
    let e = soft_edge_errors(MOVING_BOX);
    assert!(
        e.pixels > 1000,
        "precondition: {} pixels in the soft ends",
        e.pixels
    );
    // Before, the pixels that lost every sample to the box stood out: 14 pixels over 0.1, the
    // worst 0.33, RMS 0.0345 (now 3, 0.11 and 0.0289).
    assert!(
        e.specks <= 5,
        "{} specks in the streak's soft ends",
        e.specks
    );
    assert!(
        e.worst < 0.2,
        "a speck {:.4} of the box's contrast off",
        e.worst
    );
    assert!(
        e.rms < 0.032,
        "grain in the streak's soft ends: RMS {:.4}",
        e.rms
    );
    assert!(
        e.bias.abs() < 0.02,
        "the wall's share is off by {:+.4}",
        e.bias
    );
}

#[test]
fn a_sharp_wall_behind_a_defocused_bar_shows_no_grain_of_its_sample_counts() {
    let e = soft_edge_errors(DEFOCUSED_BAR);
    assert!(
        e.pixels > 1000,
        "precondition: {} pixels in the soft edges",
        e.pixels
    );
    // Before, the pixels that lost every sample to the bar stood out: 18 pixels over 0.1, the
    // worst 0.32, RMS 0.0346 (now none, 0.078 and 0.0246).
    assert!(e.specks <= 3, "{} specks in the bar's soft edges", e.specks);
    assert!(
        e.worst < 0.2,
        "a speck {:.4} of the bar's contrast off",
        e.worst
    );
    assert!(
        e.rms < 0.03,
        "grain in the bar's soft edges: RMS {:.4}",
        e.rms
    );
    assert!(
        e.bias.abs() < 0.02,
        "the wall's share is off by {:+.4}",
        e.bias
    );
}
