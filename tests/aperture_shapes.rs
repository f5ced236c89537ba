//! Aperture shapes end to end: one bright pixel, defocused, splats to the aperture's shape.
//! An anamorphic ratio of 2 gives an ellipse half as wide as tall (second moments r^2 / 16
//! and r^2 / 4 for CoC radius r); a rotated pentagon reaches as far along x and y as the
//! rotated polygon does. Measured on the synthesised image, through the quick databases.

use spreadlet::{Backend, Camera, GBuffer, Renderer, RendererOptions, SynthOptions};
use spreadlet_e2e::cache_dir;

const SIZE: usize = 192;
/// Depth of the bright pixel, metres (the camera focuses at 1 m): a CoC of about 15 px.
const DEPTH: f32 = 0.5;

fn camera(extra: &str) -> Camera {
    Camera::from_json_str(&format!(
        r#"{{"width": {SIZE}, "height": {SIZE}, "focal_length_mm": 85, "sensor_width_mm": 36,
            "f_stop": 1.4, "focus_distance": 1.0 {extra}}}"#
    ))
    .expect("camera")
}

/// The image of one bright pixel at the frame's centre, everything else transparent black at
/// the same depth, and the CoC radius in pixels there.
fn splat(camera: &Camera) -> (Vec<[f32; 4]>, f64) {
    let n = SIZE * SIZE;
    let mut color = vec![[0.0f32; 4]; n];
    color[(SIZE / 2) * SIZE + SIZE / 2] = [100.0, 100.0, 100.0, 1.0];
    let g = GBuffer::from_planes(SIZE, SIZE, color, Some(vec![DEPTH; n]), None).expect("g");
    let mut renderer = Renderer::new(RendererOptions {
        backend: Backend::Cpu,
        databases: spreadlet::DbSource::Cache {
            dir: cache_dir(),
            profile: precompute::Profile::Quick,
        },
        ..Default::default()
    })
    .expect("renderer");
    let frame = renderer
        .synthesize(&g, camera, &SynthOptions::default())
        .expect("synthesis");
    let lens = camera.thin_lens().expect("a lens");
    (
        frame.image.pixels,
        lens.signed_coc_px(f64::from(DEPTH)).abs(),
    )
}

/// Mean-centred second moments (x, y) of the red channel, pixels^2.
fn second_moments(pixels: &[[f32; 4]]) -> (f64, f64) {
    let (mut m, mut mx, mut my, mut mxx, mut myy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (i, p) in pixels.iter().enumerate() {
        let v = f64::from(p[0].max(0.0));
        let (x, y) = ((i % SIZE) as f64, (i / SIZE) as f64);
        m += v;
        mx += v * x;
        my += v * y;
        mxx += v * x * x;
        myy += v * y * y;
    }
    let (cx, cy) = (mx / m, my / m);
    (mxx / m - cx * cx, myy / m - cy * cy)
}

/// The farthest lit pixel from the centre along +x, -x, +y (down) and -y, pixels: lit is above
/// a quarter of the splat's mean over its support.
fn reach(pixels: &[[f32; 4]]) -> [f64; 4] {
    let lit: Vec<f64> = pixels.iter().map(|p| f64::from(p[0])).collect();
    let support: Vec<f64> = lit.iter().copied().filter(|&v| v > 1e-3).collect();
    let mean = support.iter().sum::<f64>() / support.len() as f64;
    let c = (SIZE / 2) as f64;
    let mut out = [0.0f64; 4];
    for (i, &v) in lit.iter().enumerate() {
        if v < 0.25 * mean {
            continue;
        }
        let (dx, dy) = ((i % SIZE) as f64 - c, (i / SIZE) as f64 - c);
        out[0] = out[0].max(dx);
        out[1] = out[1].max(-dx);
        out[2] = out[2].max(dy);
        out[3] = out[3].max(-dy);
    }
    out
}

#[test]
fn an_anamorphic_ratio_of_two_splats_an_ellipse_half_as_wide() {
    let (round, r) = splat(&camera(""));
    let (squeezed, r2) = splat(&camera(r#", "aperture_ratio": 2.0"#));
    assert_eq!(r, r2);
    assert!(r > 12.0, "CoC {r} px is too small to measure a shape");
    let (rx, ry) = second_moments(&round);
    let (sx, sy) = second_moments(&squeezed);
    eprintln!(
        "CoC {r:.2} px; round var {rx:.2} / {ry:.2}, squeezed {sx:.2} / {sy:.2} \
         (analytic {:.2} / {:.2} and {:.2} / {:.2})",
        r * r / 4.0,
        r * r / 4.0,
        r * r / 16.0,
        r * r / 4.0
    );
    // The PSFs are pre-filtered over their database cell and sparsified: a few per cent.
    let near = |v: f64, expected: f64| (v - expected).abs() < 0.08 * expected + 0.5;
    assert!(
        near(rx, r * r / 4.0) && near(ry, r * r / 4.0),
        "round {rx} {ry}"
    );
    assert!(
        near(sx, r * r / 16.0) && near(sy, r * r / 4.0),
        "squeezed {sx} {sy}"
    );
    // Energy stays where it was.
    let total = |p: &[[f32; 4]]| p.iter().map(|c| f64::from(c[0])).sum::<f64>();
    assert!((total(&squeezed) - total(&round)).abs() < 0.01 * total(&round));
}

#[test]
fn a_rotated_pentagon_reaches_as_far_as_the_rotated_polygon() {
    for rotation in [0.0f64, 20.0] {
        let (image, r) = splat(&camera(&format!(
            r#", "aperture_blades": 5, "aperture_rotation_deg": {rotation}"#
        )));
        // Vertices at angles rotation + 72 k degrees, counter-clockwise on the image (y down):
        // the polygon's extent along each axis is the largest vertex projection.
        let vertices: Vec<(f64, f64)> = (0..5)
            .map(|k| {
                let a = (rotation + 72.0 * f64::from(k)).to_radians();
                (r * a.cos(), -r * a.sin())
            })
            .collect();
        let analytic = [
            vertices.iter().map(|v| v.0).fold(f64::MIN, f64::max),
            vertices.iter().map(|v| -v.0).fold(f64::MIN, f64::max),
            vertices.iter().map(|v| v.1).fold(f64::MIN, f64::max),
            vertices.iter().map(|v| -v.1).fold(f64::MIN, f64::max),
        ];
        let measured = reach(&image);
        eprintln!(
            "pentagon at {rotation} deg, CoC {r:.2}: reach {measured:?}, analytic {analytic:?}"
        );
        for (m, a) in measured.iter().zip(&analytic) {
            assert!((m - a).abs() <= 1.5, "reach {measured:?} vs {analytic:?}");
        }
    }
}
