//! Munkberg 2014: with zero motion it equals Vaidyanathan's sheared filtering; a single moving
//! layer is reprojected along its motion; the reconstruction reduces noise.

mod support;

use peers::{
    munkberg, munkberg_with_report, vaidyanathan_with_report, LensModel, MunkbergParams,
    VaidyanathanParams,
};
use support::*;

/// Three still planes, all well out of focus (|CoC| >= 2 px), so every layer is sheared.
fn out_of_focus_scene() -> Scene {
    let lens = LensModel {
        coc_scale: 40.0,
        focus_depth: 4.0,
    };
    Scene {
        width: 64,
        height: 64,
        planes: vec![
            Plane {
                depth: 2.5,
                motion: [0.0; 2],
                mask: Mask::Rect {
                    x0: 14.0,
                    y0: 0.0,
                    x1: 26.0,
                    y1: 64.0,
                },
                base: [0.8, 0.2, 0.1],
                amp: 0.1,
                period: 16.0,
            },
            Plane {
                depth: 6.0,
                motion: [0.0; 2],
                mask: Mask::Disc {
                    cx: 40.0,
                    cy: 30.0,
                    r: 13.0,
                },
                base: [0.3, 0.6, 0.3],
                amp: 0.25,
                period: 9.0,
            },
            // Two far planes in one partition ([7, 14) px): layers with a CoC range, not one CoC.
            Plane {
                depth: 20.0,
                motion: [0.0; 2],
                mask: Mask::Disc {
                    cx: 18.0,
                    cy: 48.0,
                    r: 10.0,
                },
                base: [0.7, 0.7, 0.2],
                amp: 0.2,
                period: 7.0,
            },
            Plane {
                depth: 30.0,
                motion: [0.0; 2],
                mask: Mask::All,
                base: [0.3, 0.3, 0.7],
                amp: 0.2,
                period: 20.0,
            },
        ],
        lens,
        shutter_frames: 0.0,
    }
}

#[test]
fn zero_motion_equals_vaidyanathan_sheared_filtering() {
    let scene = out_of_focus_scene();
    let spp = 6;
    let samples = scene.render(spp, 21);
    let view = scene.view(spp, &samples);
    let v = VaidyanathanParams::default();
    // The same tiling as Vaidyanathan's: 32 px tiles, 64 px window (clamp (64-32)/4 = 8 px).
    let m = MunkbergParams {
        tile: 32,
        window: 64,
        ..Default::default()
    };
    let (vi, vr) = vaidyanathan_with_report(&view, &v).expect("vaidyanathan");
    let (mi, mr) = munkberg_with_report(&view, &m).expect("munkberg");
    eprintln!("vaidyanathan {vr:?}\nmunkberg {mr:?}");
    assert_eq!(vr.sheared, vr.layers);
    assert_eq!(mr.sheared, mr.layers);
    assert_eq!(vr.layers, mr.layers);
    let d = max_abs_diff(&vi, &mi);
    eprintln!("max |munkberg - vaidyanathan| = {d:e}");
    assert!(d < 1e-4, "differ by {d}");
    // And both actually filter (far from the noisy box filter).
    assert!(max_abs_diff(&vi, &scene.box_filter(spp, &samples)) > 0.05);
}

/// One textured plane filling the frame, in focus, moving by `motion` px per frame.
fn moving_plane(motion: [f32; 2]) -> (Scene, Plane) {
    let lens = LensModel {
        coc_scale: 0.0,
        focus_depth: 4.0,
    };
    let plane = Plane {
        depth: 4.0,
        motion,
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
            shutter_frames: 1.0,
        },
        plane,
    )
}

#[test]
fn one_moving_layer_is_reprojected_along_its_motion() {
    let spp = 8;
    for (motion, tol) in [
        ([8.0f32, 0.0f32], 0.012f32),
        ([0.0, -6.0], 0.012),
        ([5.0, 5.0], 0.015),
    ] {
        let (scene, plane) = moving_plane(motion);
        let samples = scene.render(spp, 17);
        let p = MunkbergParams {
            window: 44,
            sigma_clamp: Some(f32::INFINITY),
            ..Default::default()
        };
        let (out, report) = munkberg_with_report(&scene.view(spp, &samples), &p).expect("runs");
        assert_eq!(report.time_sheared, report.layers, "{report:?}");
        // Expected: the texture at t = 0, box-averaged over the pixel, blurred by a Gaussian of
        // sigma_shutter * |motion| along the motion and sigma_pixel across it.
        let len = motion[0].hypot(motion[1]);
        let a = [motion[0] / len, motion[1] / len];
        let (sa, sp) = (p.sigma_shutter * len, p.sigma_pixel);
        let k = 2.0 * std::f32::consts::PI / plane.period;
        let (kx, ky) = (k, 0.7 * k);
        let sinc = |v: f32| {
            if v == 0.0 {
                1.0
            } else {
                (v / 2.0).sin() / (v / 2.0)
            }
        };
        let wave = |x: f32, y: f32, wx: f32, wy: f32| {
            let along = wx * a[0] + wy * a[1];
            let across = -wx * a[1] + wy * a[0];
            let att = (-0.5 * (sa * sa * along * along + sp * sp * across * across)).exp()
                * sinc(wx)
                * sinc(wy);
            att * (wx * x + wy * y).sin()
        };
        // Fit the output's signal to the prediction (gain 1 expected) and measure the RMS error.
        let (mut vp, mut pp, mut err2, mut n) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for y in 12..52 {
            for x in 12..52 {
                let (cx, cy) = (x as f32 + 0.5, y as f32 + 0.5);
                // sin(kx x) cos(ky y) as two plane waves.
                let pred =
                    (plane.amp * 0.5 * (wave(cx, cy, kx, ky) + wave(cx, cy, kx, -ky))) as f64;
                let v = (out[y * 64 + x][0] - plane.base[0]) as f64;
                vp += v * pred;
                pp += pred * pred;
                err2 += (v - pred).powi(2);
                n += 1.0;
            }
        }
        let gain = vp / pp;
        let rms = (err2 / n).sqrt();
        eprintln!("motion {motion:?}: gain {gain:.4}, RMS error {rms:.4}");
        assert!((gain - 1.0).abs() < 0.05, "motion {motion:?}: gain {gain}");
        assert!(rms < tol as f64, "motion {motion:?}: RMS error {rms}");
    }
}

fn defocus_and_motion_scene() -> Scene {
    let mut s = defocus_scene();
    s.planes[0].motion = [0.0, 10.0];
    s.planes[1].motion = [6.0, 0.0];
    s.shutter_frames = 1.0;
    s
}

#[test]
fn reconstruction_reduces_noise_with_defocus_and_motion() {
    let scene = defocus_and_motion_scene();
    let reference = scene.box_filter(256, &scene.render(256, 99));
    let spp = 4;
    let samples = scene.render(spp, 5);
    let view = scene.view(spp, &samples);
    let boxed = rmse(&scene.box_filter(spp, &samples), &reference);
    for p in [MunkbergParams::default(), MunkbergParams::window_44()] {
        let (out, report) = munkberg_with_report(&view, &p).expect("runs");
        let e = rmse(&out, &reference);
        eprintln!(
            "munkberg window {}: RMSE {e:.4} vs 1x1 box {boxed:.4}; {report:?}",
            p.window
        );
        assert!(
            e < 0.8 * boxed,
            "window {}: RMSE {e} not below box {boxed}",
            p.window
        );
        assert_eq!(out, munkberg(&view, &p).expect("runs"));
    }
}

#[test]
fn bad_parameters_are_errors() {
    let scene = defocus_scene();
    let samples = scene.render(1, 1);
    let view = scene.view(1, &samples);
    for p in [
        MunkbergParams {
            window: 8,
            ..Default::default()
        },
        MunkbergParams {
            sigma_shutter: f32::NAN,
            ..Default::default()
        },
        MunkbergParams {
            sigma_clamp: Some(0.0),
            ..Default::default()
        },
    ] {
        assert!(munkberg(&view, &p).is_err(), "{p:?}");
    }
}

#[test]
fn motion_handling_pays_off_on_a_moving_scene() {
    // Same samples, same reference: every sample method beats the box filter, and Munkberg's
    // motion frame and time shear beat Vaidyanathan's defocus-only filter.
    let scene = defocus_and_motion_scene();
    let reference = scene.box_filter(256, &scene.render(256, 99));
    let spp = 4;
    let samples = scene.render(spp, 5);
    let view = scene.view(spp, &samples);
    let boxed = rmse(&scene.box_filter(spp, &samples), &reference);
    let mut errors = Vec::new();
    for m in peers::PeerMethod::ALL {
        if m.input_kind() != peers::InputKind::Samples || !m.handles_motion() {
            if m == peers::PeerMethod::Vaidyanathan {
                let out = m.run(&peers::PeerInput::Samples(view)).expect("runs");
                errors.push((m, rmse(&out, &reference)));
            }
            continue;
        }
        let out = m.run(&peers::PeerInput::Samples(view)).expect("runs");
        errors.push((m, rmse(&out, &reference)));
    }
    for (m, e) in &errors {
        eprintln!("{:>13}: RMSE {e:.4} (1x1 box {boxed:.4})", m.name());
        assert!(
            *e < boxed,
            "{}: {e} not below the box filter's {boxed}",
            m.name()
        );
    }
    let get = |n: peers::PeerMethod| {
        errors
            .iter()
            .find(|(m, _)| *m == n)
            .map(|x| x.1)
            .unwrap_or(f32::NAN)
    };
    assert!(get(peers::PeerMethod::Munkberg) < get(peers::PeerMethod::Vaidyanathan));
}
