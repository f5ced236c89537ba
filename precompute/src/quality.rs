//! How well spreadlets reproduce their PSF: integrate them exactly (`poisson::integrate_exact`)
//! and compare with the pre-filtered PSF by L1 and SSIM.
//!
//! SSIM is the project's (DEVELOPERS.md): Wang et al. 2004 on sRGB-encoded values clamped to
//! [0, 1], Gaussian window sigma 1.5. Both images are scaled by the PSF's maximum first, so the
//! PSF spans [0, 1].

use poisson::{integrate_exact, Plane};

use crate::sparsify::Spreadlets;

/// The exact integration of spreadlets on a `width x height` image, one plane per channel.
pub fn integrate_spreadlets(s: &Spreadlets, width: usize, height: usize) -> Vec<Vec<f32>> {
    (0..s.channels)
        .map(|c| {
            let mut lap = vec![0.0f64; width * height];
            for (j, p) in s.positions.iter().enumerate() {
                let (x, y) = (p[0] as usize, p[1] as usize);
                if x < width && y < height {
                    lap[y * width + x] += s.value(j)[c];
                }
            }
            let plane = Plane {
                width,
                height,
                data: lap.iter().map(|&v| v as f32).collect(),
            };
            integrate_exact(&plane).data
        })
        .collect()
}

/// Mean over channels of `sum_px |a - b|` (each PSF channel sums to 1, so this is relative).
pub fn l1(a: &[Vec<f32>], b: &[Vec<f32>]) -> f64 {
    let total: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| {
            x.iter()
                .zip(y)
                .map(|(&u, &v)| f64::from((u - v).abs()))
                .sum::<f64>()
        })
        .sum();
    total / a.len().max(1) as f64
}

/// SSIM of `recon` against `psf` (planar channels, `width x height`), both divided by the
/// PSF's maximum, averaged over channels.
pub fn similarity(recon: &[Vec<f32>], psf: &[Vec<f32>], width: usize, height: usize) -> f64 {
    let max = psf
        .iter()
        .flat_map(|p| p.iter().copied())
        .fold(0.0f32, f32::max);
    if !(max > 0.0) {
        return 1.0;
    }
    let scale = 1.0 / max;
    let mut total = 0.0;
    for (r, p) in recon.iter().zip(psf) {
        let a: Vec<f32> = r.iter().map(|&v| v * scale).collect();
        let b: Vec<f32> = p.iter().map(|&v| v * scale).collect();
        total += ssim_plane_adapter(&a, &b, width, height);
    }
    total / recon.len().max(1) as f64
}

// ADAPTER (precompute-local): until `metrics::ssim_plane` is published, the same definition
// implemented here. Replace the body by the metrics call when it exists.
fn ssim_plane_adapter(a: &[f32], b: &[f32], w: usize, h: usize) -> f64 {
    fn srgb(v: f32) -> f64 {
        let v = f64::from(v).clamp(0.0, 1.0);
        if v <= 0.003_130_8 {
            12.92 * v
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        }
    }
    let x: Vec<f64> = a.iter().map(|&v| srgb(v)).collect();
    let y: Vec<f64> = b.iter().map(|&v| srgb(v)).collect();
    let radius = 5i64;
    let weights: Vec<f64> = (-radius..=radius)
        .map(|d| (-(d * d) as f64 / (2.0 * 1.5 * 1.5)).exp())
        .collect();
    // Separable Gaussian blur with the window renormalised at the border.
    let blur = |src: &[f64]| -> Vec<f64> {
        let mut tmp = vec![0.0; w * h];
        for yy in 0..h {
            for xx in 0..w {
                let (mut s, mut n) = (0.0, 0.0);
                for (k, &g) in weights.iter().enumerate() {
                    let sx = xx as i64 + k as i64 - radius;
                    if sx >= 0 && sx < w as i64 {
                        s += g * src[yy * w + sx as usize];
                        n += g;
                    }
                }
                tmp[yy * w + xx] = s / n;
            }
        }
        let mut out = vec![0.0; w * h];
        for yy in 0..h {
            for xx in 0..w {
                let (mut s, mut n) = (0.0, 0.0);
                for (k, &g) in weights.iter().enumerate() {
                    let sy = yy as i64 + k as i64 - radius;
                    if sy >= 0 && sy < h as i64 {
                        s += g * tmp[sy as usize * w + xx];
                        n += g;
                    }
                }
                out[yy * w + xx] = s / n;
            }
        }
        out
    };
    let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
    let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
    let xy: Vec<f64> = x.iter().zip(&y).map(|(a, b)| a * b).collect();
    let (mx, my, mxx, myy, mxy) = (blur(&x), blur(&y), blur(&xx), blur(&yy), blur(&xy));
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let mut total = 0.0;
    for i in 0..w * h {
        let (ux, uy) = (mx[i], my[i]);
        let sx = mxx[i] - ux * ux;
        let sy = myy[i] - uy * uy;
        let sxy = mxy[i] - ux * uy;
        total += ((2.0 * ux * uy + c1) * (2.0 * sxy + c2))
            / ((ux * ux + uy * uy + c1) * (sx + sy + c2));
    }
    total / (w * h).max(1) as f64
}
