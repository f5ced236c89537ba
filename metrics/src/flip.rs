//! FLIP (Andersson, Nilsson, Akenine-Möller, Oskarsson, Åström, Fairchild 2020, "FLIP: A
//! Difference Evaluator for Alternating Images"), NVIDIA's perceptual difference evaluator for
//! rendered images, through the reference implementation (`nv-flip`, which compiles NVIDIA's
//! C++ code).
//!
//! The project scores with FLIP's LDR mode on the same values as SSIM: linear RGB(A) is
//! sRGB-encoded and clamped to [0, 1], then quantised to 8 bits (the reference tool's LDR input
//! is an 8-bit image; the rounding, at most 1/510, is far below what FLIP can see), at the
//! default 67 pixels per degree. The per-pixel error lies in [0, 1]; lower is better.

use crate::ssim::{rgb_channels, srgb_encode};
use crate::MetricsError;

/// Pixels per degree of visual angle FLIP is evaluated at: the reference implementation's
/// default (a 0.7 m wide 4K monitor seen from 0.7 m).
pub const FLIP_PIXELS_PER_DEGREE: f32 = nv_flip::DEFAULT_PIXELS_PER_DEGREE;

/// The FLIP error map of a test image against a reference, and its summary statistics.
#[derive(Clone, Debug, PartialEq)]
pub struct FlipError {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Per-pixel FLIP error in [0, 1], row-major from the top-left pixel.
    pub map: Vec<f32>,
    /// Mean of `map`.
    pub mean: f64,
    /// 99th percentile of `map` (nearest rank: the value below which 99 % of the pixels lie).
    pub p99: f64,
}

impl FlipError {
    /// The error map coloured with FLIP's magma colour map (as the reference tool shows it),
    /// interleaved 8-bit RGB, row-major.
    pub fn magma_rgb8(&self) -> Vec<u8> {
        let map =
            nv_flip::FlipImageFloat::with_data(self.width as u32, self.height as u32, &self.map);
        map.apply_color_lut(&nv_flip::magma_lut()).to_vec()
    }
}

fn srgb8(img: &[f32], channels: usize) -> Vec<u8> {
    img.chunks_exact(channels)
        .flat_map(|p| (0..3).map(move |c| (srgb_encode(p[c]) * 255.0).round() as u8))
        .collect()
}

/// FLIP of a linear RGB or RGBA `test` image against `reference` (interleaved, `width * height
/// * 3` or `* 4` values, alpha ignored), in the LDR mode described in the module documentation.
pub fn flip_rgb(
    test: &[f32],
    reference: &[f32],
    width: usize,
    height: usize,
) -> Result<FlipError, MetricsError> {
    let channels = rgb_channels(test, reference, width, height)?;
    let (w, h) = (
        u32::try_from(width).map_err(|_| too_large(width, height))?,
        u32::try_from(height).map_err(|_| too_large(width, height))?,
    );
    let reference_image = nv_flip::FlipImageRgb8::with_data(w, h, &srgb8(reference, channels));
    let test_image = nv_flip::FlipImageRgb8::with_data(w, h, &srgb8(test, channels));
    let map = nv_flip::flip(reference_image, test_image, FLIP_PIXELS_PER_DEGREE).to_vec();
    let mean = map.iter().map(|&v| f64::from(v)).sum::<f64>() / map.len() as f64;
    let p99 = percentile(&map, 0.99);
    Ok(FlipError {
        width,
        height,
        map,
        mean,
        p99,
    })
}

fn too_large(width: usize, height: usize) -> MetricsError {
    MetricsError::Size {
        width,
        height,
        len: 0,
        expected: "a size that fits in 32 bits".into(),
    }
}

/// Nearest-rank percentile `q` in [0, 1] of `values` (NaN sorts last).
fn percentile(values: &[f32], q: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    f64::from(sorted[rank - 1])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_have_zero_error() {
        let img: Vec<f32> = (0..32 * 32 * 4).map(|i| (i % 7) as f32 / 7.0).collect();
        let f = flip_rgb(&img, &img, 32, 32).expect("flip");
        assert_eq!(f.mean, 0.0);
        assert_eq!(f.p99, 0.0);
    }

    #[test]
    fn percentile_is_nearest_rank() {
        let v: Vec<f32> = (1..=100).map(|i| i as f32).collect();
        assert_eq!(percentile(&v, 0.99), 99.0);
        assert_eq!(percentile(&v, 1.0), 100.0);
        assert_eq!(percentile(&[3.0], 0.99), 3.0);
    }
}
