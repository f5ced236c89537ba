//! Vaidyanathan 2015: the sheared filter reduces to reprojection on a one-depth layer; the
//! layered reconstruction reduces noise against a box filter.

mod support;

use peers::{vaidyanathan, vaidyanathan_with_report, LensModel, Partitions, VaidyanathanParams};
use support::*;

/// One textured plane at a single depth filling the frame.
fn one_plane(coc: f32) -> (Scene, Plane) {
    let lens = LensModel {
        coc_scale: 40.0,
        focus_depth: 4.0,
    };
    // depth with lens.coc(depth) = coc: 1/z = 1/F - coc/K.
    let depth = 1.0 / (1.0 / lens.focus_depth - coc / lens.coc_scale);
    let plane = Plane {
        depth,
        motion: [0.0; 2],
        mask: Mask::All,
        base: [0.5, 0.5, 0.5],
        amp: 0.3,
        period: 16.0,
    };
    (
        Scene {
            width: 64,
            height: 64,
            planes: vec![plane],
            lens,
            shutter_frames: 0.0,
        },
        plane,
    )
}

#[test]
fn one_depth_layer_is_reprojected_then_blurred_by_the_aperture_gaussian() {
    let spp = 16;
    for coc in [-4.0f32, 3.0, 6.0] {
        let (scene, plane) = one_plane(coc);
        let samples = scene.render(spp, 11);
        let p = VaidyanathanParams {
            sigma_x_max: f32::INFINITY,
            ..Default::default()
        };
        let (out, report) = vaidyanathan_with_report(&scene.view(spp, &samples), &p).expect("runs");
        assert_eq!(report.sheared, report.layers, "{report:?}");
        // Expected: the pinhole texture, box-averaged over the pixel (nearest-bin splat) and
        // blurred by a Gaussian of sigma_lens |c|.
        let k = 2.0 * std::f32::consts::PI / plane.period;
        let (kx, ky) = (k, 0.7 * k);
        let sigma = p.sigma_lens * coc.abs();
        let sinc = |a: f32| (a / 2.0).sin() / (a / 2.0);
        let atten = (-0.5 * sigma * sigma * (kx * kx + ky * ky)).exp() * sinc(kx) * sinc(ky);
        let mut worst = 0.0f32;
        for y in 10..54 {
            for x in 10..54 {
                let (cx, cy) = (x as f32 + 0.5, y as f32 + 0.5);
                let s = plane.amp * atten * (kx * cx).sin() * (ky * cy).cos();
                let expect = plane.base[0] + s;
                worst = worst.max((out[y * 64 + x][0] - expect).abs());
            }
        }
        eprintln!("coc {coc}: max error against reprojection + Gaussian {worst:.4} (texture amplitude {})", plane.amp);
        assert!(worst < 0.02, "coc {coc}: max error {worst}");
        // The box-filtered input is far from it (the disk blur is not the reprojected image).
        let boxed = scene.box_filter(spp, &samples);
        let noisy =
            (10..54)
                .flat_map(|y| (10..54).map(move |x| (x, y)))
                .fold(0.0f32, |m, (x, y)| {
                    let (cx, cy) = (x as f32 + 0.5, y as f32 + 0.5);
                    let e = plane.base[0] + plane.amp * atten * (kx * cx).sin() * (ky * cy).cos();
                    m.max((boxed[y * 64 + x][0] - e).abs())
                });
        assert!(noisy > 2.0 * worst, "box {noisy} vs layered {worst}");
    }
}

#[test]
fn layered_reconstruction_reduces_noise() {
    let scene = defocus_scene();
    let reference = scene.box_filter(256, &scene.render(256, 99));
    let spp = 8;
    let samples = scene.render(spp, 5);
    let view = scene.view(spp, &samples);
    let boxed = rmse(&scene.box_filter(spp, &samples), &reference);
    let (out, report) =
        vaidyanathan_with_report(&view, &VaidyanathanParams::default()).expect("runs");
    let e = rmse(&out, &reference);
    eprintln!("vaidyanathan 8 spp: RMSE {e:.4} vs 1x1 box {boxed:.4}; {report:?}");
    assert!(e < 0.8 * boxed, "RMSE {e} not below box {boxed}");
    assert!(report.sheared > 0 && report.small_shear > 0);
    // Deterministic.
    assert_eq!(
        out,
        vaidyanathan(&view, &VaidyanathanParams::default()).expect("runs")
    );
}

#[test]
fn bad_parameters_are_errors() {
    let scene = defocus_scene();
    let samples = scene.render(1, 1);
    let view = scene.view(1, &samples);
    let bad = VaidyanathanParams {
        partitions: Partitions {
            boundaries: vec![1.0, 0.0],
        },
        ..Default::default()
    };
    assert!(vaidyanathan(&view, &bad).is_err());
    let bad = VaidyanathanParams {
        sigma_lens: 0.0,
        ..Default::default()
    };
    assert!(vaidyanathan(&view, &bad).is_err());
    let bad = VaidyanathanParams {
        tile: 0,
        ..Default::default()
    };
    assert!(vaidyanathan(&view, &bad).is_err());
}
