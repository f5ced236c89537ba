//! Every figure the project reports for a result against a reference, in one place: SSIM,
//! PSNR, FLIP (mean and 99th percentile) and the brightness of the frame's edges.

#[cfg(feature = "flip")]
use crate::flip::{flip_rgb, FlipError};
use crate::ssim::rgb_channels;
#[cfg(feature = "flip")]
use crate::ssim::{psnr_rgb, ssim_rgb};
use crate::MetricsError;

/// Width of the band along each frame edge that [`edge_luminance_ratios`] measures, px.
pub const EDGE_BAND_PX: usize = 4;

/// Median luminance ratio test / reference over the outer band of each frame edge: 1 where
/// the edges are as bright as the reference's; a dark frame edge shows as a value well below 1.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct EdgeRatios {
    /// Left band.
    pub left: f64,
    /// Top band.
    pub top: f64,
    /// Right band.
    pub right: f64,
    /// Bottom band.
    pub bottom: f64,
}

impl EdgeRatios {
    /// The four ratios, left, top, right, bottom.
    pub fn as_array(&self) -> [f64; 4] {
        [self.left, self.top, self.right, self.bottom]
    }

    /// The ratio farthest from 1.
    pub fn worst(&self) -> f64 {
        self.as_array().into_iter().fold(1.0, |w, r| {
            if (r - 1.0).abs() > (w - 1.0).abs() {
                r
            } else {
                w
            }
        })
    }
}

/// The figures of a result against its reference.
#[cfg(feature = "flip")]
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Scores {
    /// SSIM (sRGB, clamped, sigma 1.5, mean over R, G, B); 1 is identical.
    pub ssim: f64,
    /// PSNR of the sRGB values in dB; `None` for identical images.
    pub psnr_db: Option<f64>,
    /// Mean FLIP error (LDR, 67 px per degree); 0 is identical.
    pub flip_mean: f64,
    /// 99th percentile of the FLIP error: where halos and dark edges show.
    pub flip_p99: f64,
    /// Median luminance ratio over the outer [`EDGE_BAND_PX`] of each edge.
    pub edge_luminance_ratio: EdgeRatios,
    /// The frame's mean linear luminance over the reference's ([`mean_luminance_ratio`]): 1
    /// where the energy is kept; added or lost light shows as a value away from 1.
    pub mean_luminance_ratio: f64,
}

/// Scores a linear RGB(A) `test` image against `reference` (interleaved, alpha ignored); also
/// returns the FLIP error map.
#[cfg(feature = "flip")]
pub fn score_rgb(
    test: &[f32],
    reference: &[f32],
    width: usize,
    height: usize,
) -> Result<(Scores, FlipError), MetricsError> {
    let ssim = ssim_rgb(test, reference, width, height)?;
    let psnr = psnr_rgb(test, reference, width, height)?;
    let flip = flip_rgb(test, reference, width, height)?;
    let edge = edge_luminance_ratios(test, reference, width, height, EDGE_BAND_PX)?;
    let mean_ratio = mean_luminance_ratio(test, reference, width, height)?;
    let scores = Scores {
        ssim,
        psnr_db: psnr.is_finite().then_some(psnr),
        flip_mean: flip.mean,
        flip_p99: flip.p99,
        edge_luminance_ratio: edge,
        mean_luminance_ratio: mean_ratio,
    };
    Ok((scores, flip))
}

/// Rec. 709 luminance of linear RGB.
fn luminance(p: &[f32]) -> f64 {
    0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2])
}

/// Mean linear Rec. 709 luminance of `test` over that of `reference` (RGB(A), interleaved,
/// alpha ignored), summed in f64; 1 when the reference is black everywhere and so is the test,
/// infinite when only the reference is.
pub fn mean_luminance_ratio(
    test: &[f32],
    reference: &[f32],
    width: usize,
    height: usize,
) -> Result<f64, MetricsError> {
    let channels = rgb_channels(test, reference, width, height)?;
    let sum = |img: &[f32]| -> f64 { img.chunks_exact(channels).map(luminance).sum() };
    let (t, r) = (sum(test), sum(reference));
    Ok(if r > 0.0 {
        t / r
    } else if t > 0.0 {
        f64::INFINITY
    } else {
        1.0
    })
}

/// Median luminance ratio `test / reference` over the outer `band_px` pixels of each edge
/// (left, top, right, bottom) of linear RGB(A) images. Pixels whose reference luminance is
/// below 1e-4 (black, where a ratio means nothing) are left out; a band without any pixel
/// left scores 1.
pub fn edge_luminance_ratios(
    test: &[f32],
    reference: &[f32],
    width: usize,
    height: usize,
    band_px: usize,
) -> Result<EdgeRatios, MetricsError> {
    let channels = rgb_channels(test, reference, width, height)?;
    let band_x = band_px.clamp(1, width);
    let band_y = band_px.clamp(1, height);
    let median_over = |inside: &dyn Fn(usize, usize) -> bool| -> f64 {
        let mut ratios = Vec::new();
        for y in 0..height {
            for x in 0..width {
                if !inside(x, y) {
                    continue;
                }
                let i = (y * width + x) * channels;
                let r = luminance(&reference[i..i + 3]);
                if r > 1e-4 {
                    ratios.push(luminance(&test[i..i + 3]) / r);
                }
            }
        }
        if ratios.is_empty() {
            return 1.0;
        }
        crate::stats::median(&mut ratios)
    };
    Ok(EdgeRatios {
        left: median_over(&|x, _| x < band_x),
        top: median_over(&|_, y| y < band_y),
        right: median_over(&|x, _| x + band_x >= width),
        bottom: median_over(&|_, y| y + band_y >= height),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_mean_ratio_is_the_ratio_of_summed_luminance() {
        let (w, h) = (4, 2);
        let reference = vec![0.5f32; w * h * 4];
        let mut test = reference.clone();
        // One pixel twice as bright: 9 halves over 8.
        test[..3].fill(1.0);
        let r = mean_luminance_ratio(&test, &reference, w, h).expect("ratio");
        assert!((r - 9.0 / 8.0).abs() < 1e-12, "{r}");
        let black = vec![0.0f32; w * h * 4];
        assert_eq!(
            mean_luminance_ratio(&black, &black, w, h).expect("ratio"),
            1.0
        );
    }

    #[test]
    fn a_darkened_left_edge_shows_only_on_the_left() {
        let (w, h) = (40, 30);
        let reference = vec![0.5f32; w * h * 3];
        let mut test = reference.clone();
        for y in 0..h {
            for x in 0..4 {
                for c in 0..3 {
                    test[(y * w + x) * 3 + c] = 0.3;
                }
            }
        }
        let e = edge_luminance_ratios(&test, &reference, w, h, 4).expect("ratios");
        assert!((e.left - 0.6).abs() < 1e-6, "{e:?}");
        assert!((e.right - 1.0).abs() < 1e-9, "{e:?}");
        // The top band is mostly interior pixels: the median stays at 1.
        assert!((e.top - 1.0).abs() < 1e-9, "{e:?}");
        assert!((e.worst() - 0.6).abs() < 1e-6);
        let (s, _) = score_rgb(&test, &reference, w, h).expect("scores");
        assert!(s.flip_mean > 0.0 && s.flip_p99 > s.flip_mean);
        assert!(s.ssim < 1.0);
    }
}
