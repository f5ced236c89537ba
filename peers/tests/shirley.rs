//! Shirley 2011: the layered defocus shortcut equals the sorted sweep; in-focus pixels get the
//! plain box filter; the sweep reduces noise against a 1x1 box filter.

mod support;

use peers::{
    shirley, shirley_layered_defocus, PeerError, ShirleyParams, ShirleyVariant, TwoScaleBlend,
};
use support::*;

fn variants() -> [ShirleyParams; 2] {
    [
        ShirleyParams {
            variant: ShirleyVariant::FourScale,
            smooth_motion: true,
        },
        ShirleyParams {
            variant: ShirleyVariant::TwoScale(TwoScaleBlend::Step { threshold: 5.0 }),
            smooth_motion: true,
        },
    ]
}

#[test]
fn layered_defocus_shortcut_equals_sorted_sweep() {
    let scene = defocus_scene();
    let spp = 8;
    let samples = scene.render(spp, 7);
    let view = scene.view(spp, &samples);
    for p in variants() {
        let sweep = shirley(&view, &p).expect("sweep");
        let layered = shirley_layered_defocus(&view, &p).expect("layered");
        let d = max_abs_diff(&sweep, &layered);
        eprintln!("{:?}: max |sweep - layered| = {d:e}", p.variant);
        assert!(
            d <= 1e-5,
            "{:?}: layered differs from sweep by {d}",
            p.variant
        );
        // Not trivially equal to the box filter: the scene is blurred and the sweep smooths it.
        assert!(max_abs_diff(&sweep, &scene.box_filter(spp, &samples)) > 0.05);
    }
}

#[test]
fn in_focus_still_samples_get_the_pixel_box_filter() {
    let mut scene = defocus_scene();
    scene.lens.coc_scale = 0.0; // pinhole: every CoC is 0
    let spp = 4;
    let samples = scene.render(spp, 3);
    let view = scene.view(spp, &samples);
    let boxed = scene.box_filter(spp, &samples);
    for p in variants().into_iter().chain([ShirleyParams::default()]) {
        let out = shirley(&view, &p).expect("sweep");
        let d = max_abs_diff(&out, &boxed);
        assert!(
            d <= 1e-5,
            "{:?}: in-focus output differs from the box filter by {d}",
            p.variant
        );
    }
}

#[test]
fn sweep_reduces_noise_against_the_box_filter() {
    let scene = defocus_scene();
    let reference = scene.box_filter(256, &scene.render(256, 99));
    let spp = 16;
    let samples = scene.render(spp, 5);
    let view = scene.view(spp, &samples);
    let boxed = rmse(&scene.box_filter(spp, &samples), &reference);
    for p in variants().into_iter().chain([ShirleyParams::default()]) {
        let e = rmse(&shirley(&view, &p).expect("sweep"), &reference);
        eprintln!("{:?}: RMSE {e:.4} vs 1x1 box {boxed:.4}", p.variant);
        assert!(
            e < 0.8 * boxed,
            "{:?}: RMSE {e} not below box {boxed}",
            p.variant
        );
    }
}

#[test]
fn layered_shortcut_refuses_motion_and_linear_blend() {
    let mut scene = defocus_scene();
    scene.planes[0].motion = [4.0, 0.0];
    scene.shutter_frames = 0.5;
    let samples = scene.render(2, 1);
    let view = scene.view(2, &samples);
    let p = variants()[0];
    assert!(matches!(
        shirley_layered_defocus(&view, &p),
        Err(PeerError::Unsupported(_))
    ));
    assert!(shirley(&view, &p).is_ok());
    let still = defocus_scene();
    let samples = still.render(2, 1);
    assert!(matches!(
        shirley_layered_defocus(&still.view(2, &samples), &ShirleyParams::default()),
        Err(PeerError::Unsupported(_))
    ));
}
