//! metrics: the image-quality figures the project reports.
//!
//! SSIM is Wang, Bovik, Sheikh, Simoncelli 2004 with the authors' reference settings: an
//! 11x11 Gaussian window with sigma 1.5 (radius 5, i.e. truncated at 3.33 sigma; the same 11 taps
//! as scikit-image's `truncate=3.5`), normalised to sum 1, population (not sample) statistics,
//! `K1 = 0.01`, `K2 = 0.03`, and the mean of the SSIM map over the "valid" region (pixels whose
//! window lies inside the image: `(w - 10) x (h - 10)` values). This equals scikit-image's
//! `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
//! data_range=L)`, which crops the same border before averaging.
//!
//! FLIP (`flip_rgb`, feature `flip`, on by default) is NVIDIA's perceptual difference evaluator in its LDR mode on the same
//! sRGB values; `score_rgb` (feature `flip`) gives every figure the project reports at once (SSIM, PSNR, FLIP
//! mean and 99th percentile, the luminance of the frame's edges against the reference's).
//!
//! [`ssim_rgb`] and [`psnr_rgb`] take linear RGB(A) and compare sRGB-encoded values clamped to
//! [0, 1] (L = 1), averaged over R, G and B; alpha is ignored. [`ssim_plane`] compares one
//! linear channel as it is, with a caller-given dynamic range (used to score PSFs).

#[cfg(feature = "flip")]
pub mod flip;
pub mod score;
pub mod ssim;
pub mod stats;

#[cfg(feature = "flip")]
pub use flip::{flip_rgb, FlipError, FLIP_PIXELS_PER_DEGREE};
pub use score::{edge_luminance_ratios, mean_luminance_ratio, EdgeRatios, EDGE_BAND_PX};
#[cfg(feature = "flip")]
pub use score::{score_rgb, Scores};
pub use stats::median;

pub use ssim::{
    psnr_rgb, srgb_encode, ssim_plane, ssim_plane_f64, ssim_rgb, MetricsError, SSIM_K1, SSIM_K2,
    SSIM_RADIUS, SSIM_SIGMA,
};
