//! SSIM and PSNR (see the crate documentation for the exact settings).

use rayon::prelude::*;

/// Gaussian window standard deviation, px.
pub const SSIM_SIGMA: f64 = 1.5;
/// Gaussian window radius, px (11 taps).
pub const SSIM_RADIUS: usize = 5;
/// Luminance stabiliser constant factor: `C1 = (K1 L)^2`.
pub const SSIM_K1: f64 = 0.01;
/// Contrast stabiliser constant factor: `C2 = (K2 L)^2`.
pub const SSIM_K2: f64 = 0.03;

/// Inputs the metrics cannot compare.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum MetricsError {
    /// Slice lengths do not match `width * height * channels` (RGB: 3 or 4 channels).
    #[error("image of {width}x{height} px: {len} values is not {expected}")]
    Size {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
        /// Values given.
        len: usize,
        /// What was expected, in words.
        expected: String,
    },
    /// The image is smaller than the 11x11 SSIM window.
    #[error("image of {width}x{height} px is smaller than the 11x11 SSIM window")]
    TooSmall {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    /// A dynamic range that is not finite and positive.
    #[error("dynamic range {0} is not finite and positive")]
    DynamicRange(f64),
}

pub use formats::srgb_encode;

fn gaussian_window() -> [f64; 2 * SSIM_RADIUS + 1] {
    let mut w = [0.0; 2 * SSIM_RADIUS + 1];
    for (i, v) in w.iter_mut().enumerate() {
        let d = i as f64 - SSIM_RADIUS as f64;
        *v = (-d * d / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= s);
    w
}

/// Mean SSIM of two `w x h` f64 planes with dynamic range `l` (valid region, see crate docs).
fn mean_ssim(a: &[f64], b: &[f64], w: usize, h: usize, l: f64) -> f64 {
    let win = gaussian_window();
    let n = win.len();
    let (vw, vh) = (w + 1 - n, h + 1 - n);
    let c1 = (SSIM_K1 * l).powi(2);
    let c2 = (SSIM_K2 * l).powi(2);
    // Horizontal pass of the five moments on every row, valid columns only.
    let mut horiz = vec![[0.0f64; 5]; vw * h];
    horiz.par_chunks_mut(vw).enumerate().for_each(|(y, out)| {
        let ra = &a[y * w..(y + 1) * w];
        let rb = &b[y * w..(y + 1) * w];
        for (x, o) in out.iter_mut().enumerate() {
            let mut m = [0.0; 5];
            for (k, &g) in win.iter().enumerate() {
                let (p, q) = (ra[x + k], rb[x + k]);
                m[0] += g * p;
                m[1] += g * q;
                m[2] += g * p * p;
                m[3] += g * q * q;
                m[4] += g * p * q;
            }
            *o = m;
        }
    });
    let row_sums: Vec<f64> = (0..vh)
        .into_par_iter()
        .map(|y| {
            let mut sum = 0.0;
            for x in 0..vw {
                let mut m = [0.0; 5];
                for (k, &g) in win.iter().enumerate() {
                    let hm = &horiz[(y + k) * vw + x];
                    for j in 0..5 {
                        m[j] += g * hm[j];
                    }
                }
                let (mu_a, mu_b) = (m[0], m[1]);
                let var_a = m[2] - mu_a * mu_a;
                let var_b = m[3] - mu_b * mu_b;
                let cov = m[4] - mu_a * mu_b;
                sum += ((2.0 * mu_a * mu_b + c1) * (2.0 * cov + c2))
                    / ((mu_a * mu_a + mu_b * mu_b + c1) * (var_a + var_b + c2));
            }
            sum
        })
        .collect();
    row_sums.iter().sum::<f64>() / (vw * vh) as f64
}

fn check_window(width: usize, height: usize) -> Result<(), MetricsError> {
    if width < 2 * SSIM_RADIUS + 1 || height < 2 * SSIM_RADIUS + 1 {
        return Err(MetricsError::TooSmall { width, height });
    }
    Ok(())
}

/// Channels per pixel (3 or 4) of two interleaved RGB(A) images of `width x height`.
pub(crate) fn rgb_channels(
    a: &[f32],
    b: &[f32],
    width: usize,
    height: usize,
) -> Result<usize, MetricsError> {
    let px = width * height;
    let err = |len| MetricsError::Size {
        width,
        height,
        len,
        expected: format!("{} (RGB) or {} (RGBA)", 3 * px, 4 * px),
    };
    let c = if px > 0 && a.len() == 3 * px {
        3
    } else if px > 0 && a.len() == 4 * px {
        4
    } else {
        return Err(err(a.len()));
    };
    if b.len() != a.len() {
        return Err(err(b.len()));
    }
    Ok(c)
}

/// Splits interleaved linear RGB(A) into three sRGB-encoded, clamped f64 planes.
fn srgb_planes(img: &[f32], channels: usize) -> [Vec<f64>; 3] {
    let mut out = [Vec::new(), Vec::new(), Vec::new()];
    for (c, plane) in out.iter_mut().enumerate() {
        *plane = img
            .chunks_exact(channels)
            .map(|p| srgb_encode(p[c]) as f64)
            .collect();
    }
    out
}

/// SSIM of two linear RGB or RGBA images (interleaved, `width * height * 3` or `* 4` values,
/// alpha ignored): sRGB-encoded, clamped to [0, 1], mean SSIM averaged over R, G and B.
/// 1 for identical images.
pub fn ssim_rgb(a: &[f32], b: &[f32], width: usize, height: usize) -> Result<f64, MetricsError> {
    let ch = rgb_channels(a, b, width, height)?;
    check_window(width, height)?;
    let pa = srgb_planes(a, ch);
    let pb = srgb_planes(b, ch);
    let s: f64 = (0..3)
        .map(|c| mean_ssim(&pa[c], &pb[c], width, height, 1.0))
        .sum();
    Ok(s / 3.0)
}

/// SSIM of one linear channel (`width * height` values) with the given dynamic range `L`
/// (no sRGB encoding, no clamping).
pub fn ssim_plane(
    a: &[f32],
    b: &[f32],
    width: usize,
    height: usize,
    dynamic_range: f32,
) -> Result<f64, MetricsError> {
    let a: Vec<f64> = a.iter().map(|&v| v as f64).collect();
    let b: Vec<f64> = b.iter().map(|&v| v as f64).collect();
    ssim_plane_f64(&a, &b, width, height, dynamic_range as f64)
}

/// [`ssim_plane`] on f64 values.
pub fn ssim_plane_f64(
    a: &[f64],
    b: &[f64],
    width: usize,
    height: usize,
    dynamic_range: f64,
) -> Result<f64, MetricsError> {
    for len in [a.len(), b.len()] {
        if Some(len) != width.checked_mul(height) {
            return Err(MetricsError::Size {
                width,
                height,
                len,
                expected: format!("{}", width * height),
            });
        }
    }
    check_window(width, height)?;
    if !(dynamic_range.is_finite() && dynamic_range > 0.0) {
        return Err(MetricsError::DynamicRange(dynamic_range));
    }
    Ok(mean_ssim(a, b, width, height, dynamic_range))
}

/// PSNR in dB of two linear RGB(A) images, on sRGB-encoded values clamped to [0, 1] (peak 1),
/// mean squared error over R, G and B. `f64::INFINITY` for identical images.
pub fn psnr_rgb(a: &[f32], b: &[f32], width: usize, height: usize) -> Result<f64, MetricsError> {
    let ch = rgb_channels(a, b, width, height)?;
    let mut se = 0.0f64;
    for (p, q) in a.chunks_exact(ch).zip(b.chunks_exact(ch)) {
        for c in 0..3 {
            let d = srgb_encode(p[c]) as f64 - srgb_encode(q[c]) as f64;
            se += d * d;
        }
    }
    let mse = se / (3 * width * height) as f64;
    Ok(if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    })
}
