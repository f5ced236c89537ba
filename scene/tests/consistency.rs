//! Independent paths agree: the stochastic frames' plain average converges to the reference
//! (same lens, shutter and pixel distributions), and without lens or shutter the reference is
//! the G-buffer's anti-aliased colour.

use scene::{builtin, render_gbuffer, render_reference, render_stochastic, RenderOptions};

fn rms(a: &[[f32; 4]], b: &[[f32; 4]]) -> (f64, f64) {
    let (mut sq, mut mean) = (0.0, 0.0);
    for (p, q) in a.iter().zip(b) {
        for c in 0..4 {
            let d = f64::from(p[c] - q[c]);
            sq += d * d;
            mean += d;
        }
    }
    let n = (a.len() * 4) as f64;
    ((sq / n).sqrt(), mean / n)
}

#[test]
fn stochastic_average_converges_to_the_reference() {
    for name in ["crossing", "occluder"] {
        let scene = builtin(name)
            .and_then(|s| s.with_size(32, 32))
            .expect("scene");
        let options = RenderOptions {
            seed: 11,
            ..Default::default()
        };
        let reference = render_reference(&scene, 1024, &options).expect("reference");
        let average = render_stochastic(&scene, 256, &options)
            .expect("frames")
            .average();
        let (error, bias) = rms(&average.pixels, &reference.pixels);
        // With 256 independent samples the average's noise is a few percent where the
        // pixel is mixed; a wrong lens, shutter or pixel distribution shows as a bias.
        println!("{name}: RMS {error:.4}, mean difference {bias:.5}");
        assert!(error < 0.02, "{name}: RMS {error}");
        assert!(bias.abs() < 0.002, "{name}: bias {bias}");
    }
}

#[test]
fn pinhole_reference_equals_the_gbuffer_colour() {
    let scene = builtin("rotating")
        .and_then(|s| s.with_size(32, 32))
        .expect("scene");
    let mut spec = scene.camera.spec.clone();
    spec.f_stop = None;
    spec.shutter_frames = 0.0;
    let scene = scene.with_camera_spec(spec).expect("pinhole scene");
    let options = RenderOptions::default();
    let reference = render_reference(&scene, 256, &options).expect("reference");
    let gbuffer = render_gbuffer(&scene, 256, &options).expect("gbuffer");
    let (error, bias) = rms(&gbuffer.color, &reference.pixels);
    println!("pinhole: RMS {error:.5}, mean difference {bias:.6}");
    assert!(
        error < 0.006 && bias.abs() < 0.0005,
        "RMS {error}, bias {bias}"
    );
}
