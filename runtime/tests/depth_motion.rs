//! A car driving at the camera with its lamps on: its image speeds up over the shutter, so
//! reconstruction moves each sample back along a path that speeds up as the car nears. Before,
//! samples from late in the shutter, moved back as if the path were even, drew streaks too
//! long, and each lamp's streak overshot where the lamp was when the shutter opened; and each
//! lamp's streak widens as it nears, its CoC growing with the time along it.

mod support;

use support::{luminance, reconstruct_quick_with_stats, reconstruct_scene, scene_frames};

/// A car a quarter nearer at the end of the frame than at its start, before the focus plane
/// at f/1.2, its lamps streaking outwards.
const APPROACHING_CAR: &str = include_str!("../../scene/scenes/hard/approaching-car.json");

#[test]
fn a_nearing_lamps_streaks_end_where_the_lamps_were() {
    let (_, _, reference, image) = reconstruct_scene(APPROACHING_CAR, 4, 3);
    let (got, want) = (luminance(&image), luminance(&reference));
    // As a display shows them: the lamps' streaks are the pixels at white.
    let shown = |v: f64| v.clamp(0.0, 1.0);
    let lamp: Vec<usize> = (0..want.len())
        .filter(|&p| shown(want[p]).max(shown(got[p])) > 0.9)
        .collect();
    let (mut sum_sq, mut wrong) = (0.0f64, 0usize);
    for &p in &lamp {
        let d = shown(got[p]) - shown(want[p]);
        sum_sq += d * d;
        wrong += usize::from(d.abs() > 0.25);
    }
    let rms = (sum_sq / lamp.len().max(1) as f64).sqrt();
    eprintln!(
        "{} pixels at white in either: RMS {rms:.4}, {wrong} off by over 0.25",
        lamp.len()
    );
    assert!(
        lamp.len() > 300,
        "precondition: the lamps' streaks ({} px)",
        lamp.len()
    );
    // Moved back as if the car's path were even: RMS 0.257, 173 pixels off by over a
    // quarter (1,082 pixels at white in either); along the path that speeds up: 0.088, 33
    // (0.076, 30 since); each lamp sample drawing the stratum of the path its time falls in,
    // at that time's width, so that the streak widens as the lamp nears: 0.058, 17.
    assert!(
        rms < 0.068 && wrong < 24,
        "the lamps' streaks: RMS {rms:.4}, {wrong} pixels off by over 0.25"
    );
}

#[test]
fn a_nearing_surfaces_samples_merge_at_their_depth_at_the_shutter_centre() {
    let (_, camera, frames) = scene_frames(APPROACHING_CAR, 4, 3);
    let (_, stats) = reconstruct_quick_with_stats(&frames, &camera);
    let smeared = stats.counts.smeared;
    eprintln!("{smeared} smeared fragments");
    // At their own depths (the car nears by a quarter within the frame) a pixel's samples of
    // the car from different times did not merge: 210,225 smeared fragments; at the
    // shutter centre's depth 130,653.
    assert!(smeared < 170_000, "{smeared} smeared fragments");
}
