//! The light-traced thin-lens PSF converges to the analytic disk as the ray count grows.
//!
//! The reference is independent of the tracer: the exact area of each pixel covered by the
//! disk of radius r (pixel-area integral of the indicator), estimated by 96 x 96 midpoint
//! supersampling per pixel, normalised to sum 1.

use precompute::aperture::{ApertureShape, LensAperture};
use precompute::prefilter::ParamBox;
use precompute::sampler::psf_rng;
use precompute::trace::thin_lens::ThinLensTracer;
use precompute::trace::{trace_psf, RayCount};
use psf_db::{ParamSpace, PsfModel};

fn analytic_disk(r: f64, width: usize, height: usize, centre: [usize; 2]) -> Vec<f64> {
    let sub = 96;
    let mut out = vec![0.0; width * height];
    for y in 0..height {
        for x in 0..width {
            let (cx, cy) = (x as f64 - centre[0] as f64, y as f64 - centre[1] as f64);
            // Pixels wholly inside or outside need no supersampling.
            let near = (cx.abs() + 0.75).hypot(cy.abs() + 0.75);
            let far = ((cx.abs() - 0.75).max(0.0)).hypot((cy.abs() - 0.75).max(0.0));
            out[y * width + x] = if near <= r {
                1.0
            } else if far > r {
                0.0
            } else {
                let mut inside = 0;
                for j in 0..sub {
                    for i in 0..sub {
                        let px = cx - 0.5 + (i as f64 + 0.5) / sub as f64;
                        let py = cy - 0.5 + (j as f64 + 0.5) / sub as f64;
                        if px * px + py * py <= r * r {
                            inside += 1;
                        }
                    }
                }
                f64::from(inside) / f64::from(sub * sub)
            };
        }
    }
    let s: f64 = out.iter().sum();
    out.iter().map(|v| v / s).collect()
}

#[test]
fn thin_lens_psf_converges_to_the_analytic_disk() {
    let r = 9.3;
    let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 16.0]], 20).unwrap();
    let params = ParamBox::fixed(&space, [r, 0.0]);
    let tracer = ThinLensTracer {
        aperture: LensAperture::round(),
    };
    let mut errors = Vec::new();
    for rays in [4_000u64, 40_000, 400_000, 4_000_000] {
        let mut rng = psf_rng(3, 0, 0);
        let (img, stats) = trace_psf(&tracer, &params, RayCount::Fixed(rays), &mut rng, 0).unwrap();
        assert_eq!(stats.outside, 0);
        assert_eq!(stats.blocked, 0);
        let reference = analytic_disk(r, img.width, img.height, img.centre);
        let l1: f64 = img.planes[0]
            .iter()
            .zip(&reference)
            .map(|(&a, &b)| (f64::from(a) - b).abs())
            .sum();
        errors.push(l1);
    }
    println!("L1 error vs rays (4e3, 4e4, 4e5, 4e6): {errors:?}");
    for w in errors.windows(2) {
        assert!(w[1] < 0.7 * w[0], "error did not decrease: {errors:?}");
    }
    // Bounded: at 4 million rays the PSF is within 1 % (L1) of the analytic disk.
    assert!(errors[3] < 0.01, "{errors:?}");
}

#[test]
fn bladed_aperture_is_a_polygon() {
    // A hexagonal aperture: no light beyond the circumradius, none outside the apothem along
    // an edge normal, and its support area matches the hexagon's.
    let r = 12.0;
    let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 16.0]], 20).unwrap();
    let params = ParamBox::fixed(&space, [r, 0.0]);
    let shape = ApertureShape::from_blades(6, 0.0);
    let tracer = ThinLensTracer {
        aperture: LensAperture {
            shape,
            ..LensAperture::round()
        },
    };
    let mut rng = psf_rng(3, 0, 0);
    let (img, _) = trace_psf(&tracer, &params, RayCount::Fixed(1_000_000), &mut rng, 0).unwrap();
    // Pixels at least half covered approximate the area (the support also counts the
    // partly covered rim).
    let full = img.max_value();
    let area = img.planes[0].iter().filter(|&&v| v >= 0.5 * full).count() as f64;
    let expected = shape.area() * r * r;
    assert!(
        (area - expected).abs() < 0.05 * expected,
        "{area} vs {expected}"
    );
    // Vertex at angle 0 (+x) reaches r; the edge normal at 30 degrees stops at the apothem.
    let at = |dx: i64, dy: i64| {
        img.planes[0][(img.centre[1] as i64 + dy) as usize * img.width
            + (img.centre[0] as i64 + dx) as usize]
    };
    assert!(at(11, 0) > 0.0);
    let apothem = r * (std::f64::consts::PI / 6.0).cos();
    let (s, c) = (std::f64::consts::PI / 6.0).sin_cos();
    let d = apothem + 1.5;
    assert_eq!(at((d * c).round() as i64, -(d * s).round() as i64), 0.0);
}

#[test]
fn anamorphic_aperture_is_an_ellipse_squeezed_in_x() {
    // Ratio 2 on a round aperture: an ellipse of semi-axes r / 2 (x) and r (y), whose uniform
    // light has second moments r^2 / 16 and r^2 / 4 and area pi r^2 / 2.
    let r = 12.0;
    let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 16.0]], 20).unwrap();
    let params = ParamBox::fixed(&space, [r, 0.0]);
    let tracer = ThinLensTracer {
        aperture: LensAperture {
            ratio: 2.0,
            ..LensAperture::round()
        },
    };
    let mut rng = psf_rng(3, 0, 0);
    let (img, _) = trace_psf(&tracer, &params, RayCount::Fixed(1_000_000), &mut rng, 0).unwrap();
    let (mut m, mut mx, mut my, mut mxx, mut myy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for y in 0..img.height {
        for x in 0..img.width {
            let v = f64::from(img.planes[0][y * img.width + x]);
            let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
            m += v;
            mx += v * px;
            my += v * py;
            mxx += v * px * px;
            myy += v * py * py;
        }
    }
    let (cx, cy) = (mx / m, my / m);
    let var_x = mxx / m - cx * cx;
    let var_y = myy / m - cy * cy;
    // A pixel's own width adds 1/12 to each (the light is binned into pixels).
    let (ex, ey) = (r * r / 16.0 + 1.0 / 12.0, r * r / 4.0 + 1.0 / 12.0);
    assert!((var_x - ex).abs() < 0.03 * ex, "var x {var_x} vs {ex}");
    assert!((var_y - ey).abs() < 0.03 * ey, "var y {var_y} vs {ey}");
    let full = img.max_value();
    let area = img.planes[0].iter().filter(|&&v| v >= 0.5 * full).count() as f64;
    let expected = std::f64::consts::PI * r * r / 2.0;
    assert!(
        (area - expected).abs() < 0.06 * expected,
        "{area} vs {expected}"
    );
}
