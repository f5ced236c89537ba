//! The exact integrator inverts the 5-point stencil.

use poisson::{
    integrate_exact, integrate_exact_f64, laplacian, laplacian_f64, ExactIntegrator, Plane,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A random image that is zero on its outer ring.
fn compact_random(w: usize, h: usize, seed: u64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut f = vec![0.0; w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            f[y * w + x] = rng.random_range(-1.0..1.0);
        }
    }
    f
}

#[test]
fn f64_round_trip_to_rounding_error() {
    for &(w, h, seed) in &[(37, 23, 1), (64, 64, 2), (3, 3, 3), (101, 7, 4)] {
        let f = compact_random(w, h, seed);
        let back = integrate_exact_f64(&laplacian_f64(&f, w, h), w, h);
        let err = f
            .iter()
            .zip(&back)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        println!("{w}x{h}: max error {err:e}");
        assert!(err < 1e-12, "{w}x{h}: max error {err:e}");
    }
}

#[test]
fn f32_round_trip_to_single_precision() {
    let (w, h) = (80, 50);
    let f = compact_random(w, h, 9);
    let fp = Plane::from_vec(w, h, f.iter().map(|&v| v as f32).collect()).unwrap();
    let back = integrate_exact(&laplacian(&fp));
    let max_abs = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let err = fp
        .data
        .iter()
        .zip(&back.data)
        .map(|(a, b)| (a - b).abs() as f64)
        .fold(0.0, f64::max);
    println!("f32 relative error {:e}", err / max_abs);
    assert!(err / max_abs < 1e-5, "relative error {:e}", err / max_abs);
}

#[test]
fn pair_equals_two_singles_and_margins_agree() {
    let (w, h) = (40, 30);
    let a = Plane::from_vec(
        w,
        h,
        compact_random(w, h, 5).iter().map(|&v| v as f32).collect(),
    )
    .unwrap();
    let b = Plane::from_vec(
        w,
        h,
        compact_random(w, h, 6).iter().map(|&v| v as f32).collect(),
    )
    .unwrap();
    let (la, lb) = (laplacian(&a), laplacian(&b));
    let ex = ExactIntegrator::new(w, h);
    let (pa, pb) = ex.integrate_pair(&la, &lb);
    let (sa, sb) = (ex.integrate(&la), ex.integrate(&lb));
    for (p, s) in pa
        .data
        .iter()
        .zip(&sa.data)
        .chain(pb.data.iter().zip(&sb.data))
    {
        assert!((p - s).abs() < 1e-6);
    }
    // Any margin gives the same answer for a compact image.
    let wide = ExactIntegrator::with_margin(w, h, 57).integrate(&la);
    for (p, s) in wide.data.iter().zip(&sa.data) {
        assert!((p - s).abs() < 1e-6);
    }
}

#[test]
fn quadratic_bump_analytic() {
    // f = (r^2 - d^2)_+ sampled on the lattice; its stencil Laplacian is 4 inside the disk
    // (away from the rim), which the FFT path must reproduce exactly after inversion.
    let (w, h) = (33, 33);
    let f: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64 - 16.0, (i / w) as f64 - 16.0);
            (100.0 - x * x - y * y).max(0.0)
        })
        .collect();
    let lap = laplacian_f64(&f, w, h);
    assert_eq!(lap[16 * w + 16], -4.0);
    let back = integrate_exact_f64(&lap, w, h);
    assert!((back[16 * w + 16] - 100.0).abs() < 1e-10);
    assert!(back[0].abs() < 1e-10);
}
