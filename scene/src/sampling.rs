//! Random numbers and sample warps: deterministic per-pixel generators, the aperture (disk or
//! blade polygon) and Latin-hypercube sets for converged renders.

use std::f64::consts::PI;

use glam::DVec2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Which render a random stream belongs to, so that the G-buffer, stochastic frames and
/// reference never share random numbers for the same seed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stream {
    /// Anti-aliasing samples of the pinhole G-buffer.
    GBuffer = 1,
    /// Stochastic frames.
    Stochastic = 2,
    /// Converged reference.
    Reference = 3,
}

/// SplitMix64 finaliser: a cheap bijective hash used to derive independent seeds.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The generator of one pixel: depends only on (seed, stream, pixel index), never on the
/// thread that renders it, so renders are bit-identical for any thread count.
pub fn pixel_rng(seed: u64, stream: Stream, pixel_index: u64) -> ChaCha8Rng {
    let key = mix(mix(seed ^ mix(stream as u64)) ^ pixel_index);
    ChaCha8Rng::seed_from_u64(key)
}

/// The generator of the random choices made while shading `ray` (area light points, bounce
/// directions): a hash of the ray itself, so every ray of every render shades with its own
/// numbers, deterministically, without threading a generator through the tracer.
pub fn ray_rng(ray: &crate::camera::Ray) -> ChaCha8Rng {
    let words = [
        ray.origin.x,
        ray.origin.y,
        ray.origin.z,
        ray.direction.x,
        ray.direction.y,
        ray.direction.z,
        ray.time,
    ];
    let key = words
        .iter()
        .fold(mix(0x5348_4144_494e_4721), |h, w| mix(h ^ w.to_bits()));
    ChaCha8Rng::seed_from_u64(key)
}

/// The random numbers shading one ray draws (area light points, bounce directions): from
/// [`ray_rng`] of that ray, seeded the first time a number is needed, so scenes that draw
/// none pay nothing for it.
pub struct ShadingRng {
    ray: crate::camera::Ray,
    rng: Option<ChaCha8Rng>,
}

impl ShadingRng {
    /// The numbers of `ray`.
    pub fn new(ray: &crate::camera::Ray) -> Self {
        Self {
            ray: *ray,
            rng: None,
        }
    }

    /// Numbers drawn from `rng` instead (for estimates that shade one hit many times).
    pub fn from_rng(rng: ChaCha8Rng, ray: &crate::camera::Ray) -> Self {
        Self {
            ray: *ray,
            rng: Some(rng),
        }
    }

    /// A uniform number in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        let ray = &self.ray;
        uniform(self.rng.get_or_insert_with(|| ray_rng(ray)))
    }
}

/// A direction on the hemisphere around the unit `normal`, drawn with density `cos / pi`
/// (Malley's method: a uniform point of the unit disk lifted onto the hemisphere).
pub fn cosine_hemisphere(normal: glam::DVec3, u1: f64, u2: f64) -> glam::DVec3 {
    let r = u1.sqrt();
    let phi = 2.0 * std::f64::consts::PI * u2;
    let (x, y) = (r * phi.cos(), r * phi.sin());
    let z = (1.0 - u1).max(0.0).sqrt();
    let (t, b) = normal.any_orthonormal_pair();
    (t * x + b * y + normal * z).normalize()
}

/// Uniform number in [0, 1).
pub fn uniform(rng: &mut ChaCha8Rng) -> f64 {
    rng.random::<f64>()
}

/// Maps two uniform numbers in [0, 1) to the aperture in unit-radius lens coordinates (u right,
/// v down): the unit disk (Shirley-Chiu concentric map) for fewer than 3 blades, else the
/// regular polygon inscribed in the unit circle with vertex k at angle `2 pi k / blades -
/// rotation_rad` measured from +u towards +v (v is down, so `rotation_rad` turns the polygon
/// counter-clockwise as seen on the image, as the precompute's aperture does). Uniform in
/// area either way.
pub fn sample_aperture(blades: u32, rotation_rad: f64, xi: DVec2) -> DVec2 {
    if blades < 3 {
        return concentric_disk(xi);
    }
    let n = f64::from(blades);
    let scaled = xi.x * n;
    let k = scaled.floor().min(n - 1.0);
    let xr = (scaled - k).clamp(0.0, 1.0);
    let a0 = 2.0 * PI * k / n - rotation_rad;
    let a1 = 2.0 * PI * (k + 1.0) / n - rotation_rad;
    let v0 = DVec2::new(a0.cos(), a0.sin());
    let v1 = DVec2::new(a1.cos(), a1.sin());
    // Uniform in the triangle (centre, v0, v1): radial coordinate sqrt, then along the edge.
    let radial = xr.sqrt();
    radial * (v0 * (1.0 - xi.y) + v1 * xi.y)
}

/// Shirley-Chiu concentric map from the unit square to the unit disk (area preserving).
pub fn concentric_disk(xi: DVec2) -> DVec2 {
    let a = 2.0 * xi - DVec2::ONE;
    if a.x == 0.0 && a.y == 0.0 {
        return DVec2::ZERO;
    }
    let (r, theta) = if a.x.abs() > a.y.abs() {
        (a.x, PI / 4.0 * (a.y / a.x))
    } else {
        (a.y, PI / 2.0 - PI / 4.0 * (a.x / a.y))
    };
    DVec2::new(r * theta.cos(), r * theta.sin())
}

/// Latin hypercube set: `n` points in [0, 1)^dims, each dimension stratified into `n` strata
/// and shuffled independently. Returned dimension-major: `out[d * n + i]`.
pub fn latin_hypercube(rng: &mut ChaCha8Rng, n: usize, dims: usize) -> Vec<f64> {
    let mut out = vec![0.0; n * dims];
    let inv = 1.0 / n as f64;
    for d in 0..dims {
        let column = &mut out[d * n..(d + 1) * n];
        for (i, value) in column.iter_mut().enumerate() {
            *value = ((i as f64) + uniform(rng)) * inv;
        }
        // Fisher-Yates with our own generator (deterministic).
        for i in (1..n).rev() {
            let j = rng.random_range(0..=i);
            column.swap(i, j);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aperture_samples_stay_inside_and_fill_the_area() {
        let mut rng = pixel_rng(7, Stream::Reference, 0);
        for blades in [0, 5, 6] {
            let n = 20000;
            let mut inside_half = 0usize;
            let mut mean = DVec2::ZERO;
            for _ in 0..n {
                let p = sample_aperture(
                    blades,
                    0.0,
                    DVec2::new(uniform(&mut rng), uniform(&mut rng)),
                );
                assert!(p.length() <= 1.0 + 1e-12);
                if p.length() < 0.5 {
                    inside_half += 1;
                }
                mean += p;
            }
            // Uniform in area: the fraction within radius 1/2 is that circle's area over the
            // aperture's (pi for the disk, (N/2) sin(2 pi / N) for the inscribed polygon).
            let area = if blades < 3 {
                PI
            } else {
                0.5 * f64::from(blades) * (2.0 * PI / f64::from(blades)).sin()
            };
            let frac = inside_half as f64 / n as f64;
            let expected = PI * 0.25 / area;
            assert!(
                (frac - expected).abs() < 0.015,
                "blades {blades}: {frac} vs {expected}"
            );
            assert!((mean / n as f64).length() < 0.02);
        }
    }

    #[test]
    fn a_rotation_turns_the_polygon_counter_clockwise_on_the_image() {
        // A triangle turned by 30 degrees has a vertex at 30 degrees counter-clockwise from +u
        // as seen on the image, which is (cos 30, -sin 30) with v down; the unturned triangle's
        // vertex at 0 degrees and the mirror image of the turned one are outside it.
        let mut rng = pixel_rng(3, Stream::Reference, 0);
        let turn = 30f64.to_radians();
        let (mut near_vertex, mut near_mirror, mut near_unturned) = (0, 0, 0);
        for _ in 0..20000 {
            let p = sample_aperture(3, turn, DVec2::new(uniform(&mut rng), uniform(&mut rng)));
            near_vertex += usize::from((p - DVec2::new(turn.cos(), -turn.sin())).length() < 0.1);
            near_mirror += usize::from((p - DVec2::new(turn.cos(), turn.sin())).length() < 0.1);
            near_unturned += usize::from((p - DVec2::new(1.0, 0.0)).length() < 0.1);
        }
        assert!(near_vertex > 0, "no sample near the turned vertex");
        assert_eq!((near_mirror, near_unturned), (0, 0));
    }

    #[test]
    fn polygon_vertices_on_unit_circle() {
        // xi.x just below 1/6 with radial 1 and xi.y = 1 reaches vertex 1 of a hexagon.
        let p = sample_aperture(6, 0.0, DVec2::new(1.0 / 6.0 - 1e-12, 1.0));
        let a = 2.0 * PI / 6.0;
        assert!((p - DVec2::new(a.cos(), a.sin())).length() < 1e-5);
    }

    #[test]
    fn latin_hypercube_is_stratified() {
        let mut rng = pixel_rng(1, Stream::Reference, 3);
        let n = 64;
        let set = latin_hypercube(&mut rng, n, 3);
        for d in 0..3 {
            let mut strata: Vec<usize> = set[d * n..(d + 1) * n]
                .iter()
                .map(|v| (v * n as f64) as usize)
                .collect();
            strata.sort_unstable();
            assert_eq!(strata, (0..n).collect::<Vec<_>>());
        }
    }
}
