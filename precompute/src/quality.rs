//! How well spreadlets reproduce their PSF: integrate them exactly (`poisson::integrate_exact`)
//! and compare with the pre-filtered PSF by L1 and SSIM.
//!
//! Similarity is `metrics::ssim_plane` (Wang et al. 2004, Gaussian window sigma 1.5) on the
//! linear values, both images divided by the PSF's maximum (so the PSF spans [0, 1]) and a
//! dynamic range of 1, as the paper compares PSFs.

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

/// SSIM of `recon` against `psf` (planar channels, `width x height`): `metrics::ssim_plane`
/// (linear values, dynamic range 1) after dividing both by the PSF's maximum, averaged over
/// channels. Images smaller than the 11 x 11 SSIM window are zero-padded to it (a PSF image's
/// border is zero anyway).
pub fn similarity(recon: &[Vec<f32>], psf: &[Vec<f32>], width: usize, height: usize) -> f64 {
    let max = psf
        .iter()
        .flat_map(|p| p.iter().copied())
        .fold(0.0f32, f32::max);
    if max.is_nan() || max <= 0.0 {
        return 1.0;
    }
    let scale = 1.0 / max;
    let (w, h) = (width.max(11), height.max(11));
    let pad = |src: &[f32]| -> Vec<f32> {
        let mut out = vec![0.0; w * h];
        for y in 0..height {
            for x in 0..width {
                out[y * w + x] = src[y * width + x] * scale;
            }
        }
        out
    };
    let mut total = 0.0;
    for (r, p) in recon.iter().zip(psf) {
        // Sizes match by construction; a metrics error would mean a bug: count it as 0.
        total += metrics::ssim_plane(&pad(r), &pad(p), w, h, 1.0).unwrap_or(0.0);
    }
    total / recon.len().max(1) as f64
}
