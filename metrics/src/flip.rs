//! FLIP (Andersson, Nilsson, Akenine-Möller, Oskarsson, Åström, Fairchild 2020, "FLIP: A
//! Difference Evaluator for Alternating Images"), NVIDIA's perceptual difference evaluator for
//! rendered images, through the reference implementation (`nv-flip`, which compiles NVIDIA's
//! C++ code).
//!
//! The project scores with FLIP's LDR mode on the same values as SSIM: linear RGB(A) is
//! sRGB-encoded and clamped to [0, 1], then quantised to 8 bits (the binding takes 8-bit
//! images, as the reference tool reads PNGs), at the default 67 pixels per degree. The
//! per-pixel error lies in [0, 1]; lower is better. On 8-bit images it agrees with NVIDIA's
//! Python package to 2e-5 (tested). Given unquantised floats, that package's means come out
//! about 5 % lower on dark frames (comets: 0.0351 against 0.0367 here), because FLIP sees the
//! 8-bit steps in dark gradients; rankings between methods do not change.

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

/// FLIP of two 8-bit sRGB images (interleaved RGB, `width * height * 3` bytes): the error map
/// with its mean and 99th percentile.
fn flip_srgb8(test: &[u8], reference: &[u8], width: u32, height: u32) -> FlipError {
    let reference_image = nv_flip::FlipImageRgb8::with_data(width, height, reference);
    let test_image = nv_flip::FlipImageRgb8::with_data(width, height, test);
    let map = nv_flip::flip(reference_image, test_image, FLIP_PIXELS_PER_DEGREE).to_vec();
    let mean = map.iter().map(|&v| f64::from(v)).sum::<f64>() / map.len() as f64;
    let p99 = percentile(&map, 0.99);
    FlipError {
        width: width as usize,
        height: height as usize,
        map,
        mean,
        p99,
    }
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
    Ok(flip_srgb8(
        &srgb8(test, channels),
        &srgb8(reference, channels),
        w,
        h,
    ))
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

    /// NVIDIA's Python package (`flip-evaluator` 1.7, `evaluate(reference / 255, test / 255,
    /// "LDR")`) on the same two 8-bit images gives a mean of 0.2096124 (summed in f32) and a 99th percentile
    /// (nearest rank) of 0.8707105.
    #[test]
    fn agrees_with_nvidias_python_package() {
        let (w, h) = (64u32, 48u32);
        let mut reference = Vec::new();
        let mut test = Vec::new();
        for y in 0..h as i32 {
            for x in 0..w as i32 {
                let r = [(x * 4) % 256, (y * 5 + 30) % 256, ((x + y) * 3) % 256];
                let mut t = r;
                if (10..30).contains(&y) && (20..40).contains(&x) {
                    t = t.map(|v| v + 40);
                }
                if (35..40).contains(&y) && (5..60).contains(&x) {
                    t[1] -= 60;
                }
                reference.extend(r.map(|v| v as u8));
                test.extend(t.map(|v| v.clamp(0, 255) as u8));
            }
        }
        let f = flip_srgb8(&test, &reference, w, h);
        assert!((f.mean - 0.209_612_4).abs() < 5e-5, "mean {}", f.mean);
        assert!((f.p99 - 0.870_710_5).abs() < 1e-4, "p99 {}", f.p99);
    }

    #[test]
    fn percentile_is_nearest_rank() {
        let v: Vec<f32> = (1..=100).map(|i| i as f32).collect();
        assert_eq!(percentile(&v, 0.99), 99.0);
        assert_eq!(percentile(&v, 1.0), 100.0);
        assert_eq!(percentile(&[3.0], 0.99), 3.0);
    }
}
