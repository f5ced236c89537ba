//! Vaidyanathan, Munkberg, Clarberg, Salvi 2015, "Layered light field reconstruction for
//! defocus blur" (defocus only; sample motion is ignored).
//!
//! Choices where the paper leaves a detail open (see `docs/PEERS.md`):
//! - `sigma_pixel = 1/3` px (the paper names no value; Munkberg 2014 uses 1/3);
//!   `sigma_lens = 1/2`: the paper renders with a Gaussian aperture (its lens samples are
//!   truncated at 3 sigma), ours are uniform on the unit disk, whose per-axis standard
//!   deviation is 1/2; a one-depth layer's output blur is `sigma_lens |c|`, so 1/2 matches
//!   the disk's second moment (1/3 would under-blur by a third);
//! - partitions: [`Partitions::default`] (constant worst-case filter energy, 15 per side,
//!   0.5 px quantum, `c_first = 1` px); the filter of a layer uses the actual CoC range of
//!   its samples in the window (Sec. 6.2);
//! - a layer whose samples share one CoC (`W = 0`) takes the analytic limit of the sheared
//!   filter (pure reprojection: `eta = c`, screen sigma `sigma_lens |c|`, flat lens weight)
//!   unless `sigma_x_max` clamps it;
//! - splats go to the pixel containing the reprojected position (nearest bin, as the paper);
//!   the screen kernel is truncated at `min(3 sigma, ring)` pixels;
//! - crossing the focus plane means `c_min * c_max <= 0`.

use crate::inputs::{Image, SampleView};
use crate::layered::{reconstruct, FilterCase, LayerFilter, LayerReport, Partitions, Tiling};
use crate::PeerError;

/// Parameters of [`vaidyanathan`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VaidyanathanParams {
    /// Inner tile side, pixels. Default 32.
    pub tile: usize,
    /// Ring of extra pixels around the tile whose samples take part. Default 16.
    pub ring: usize,
    /// Screen (pixel) Gaussian width sigma_pix, pixels. Default 1/3.
    pub sigma_pixel: f32,
    /// Aperture Gaussian width sigma_u, unit-disk lens units. Default 1/2.
    pub sigma_lens: f32,
    /// Clamp of the sheared filter's sigma_x (Eq. 16), pixels: a quarter of the largest filter
    /// width, 8 px in the paper. `f32::INFINITY` disables it.
    pub sigma_x_max: f32,
    /// Depth partitions in signed CoC.
    pub partitions: Partitions,
}

impl Default for VaidyanathanParams {
    fn default() -> Self {
        VaidyanathanParams {
            tile: 32,
            ring: 16,
            sigma_pixel: 1.0 / 3.0,
            sigma_lens: 0.5,
            sigma_x_max: 8.0,
            partitions: Partitions::default(),
        }
    }
}

impl VaidyanathanParams {
    pub(crate) fn validate(&self) -> Result<(), PeerError> {
        for (name, v) in [
            ("sigma_pixel", self.sigma_pixel),
            ("sigma_lens", self.sigma_lens),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(PeerError::BadParam {
                    name,
                    why: "must be finite and > 0",
                });
            }
        }
        if self.sigma_x_max.is_nan() || self.sigma_x_max <= 0.0 {
            return Err(PeerError::BadParam {
                name: "sigma_x_max",
                why: "must be > 0",
            });
        }
        self.partitions.validate()
    }
}

/// The 1D (x, u) filter of a layer with CoC range `[c_min, c_max]` (pixels), in the
/// axis-transformed form of Eq. 19/23: `w(x + eta u; sigma_screen) w(u; sigma_lens)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShearedFilter {
    /// Which of the three cases (Sec. 3.3, 3.6).
    pub case: FilterCase,
    /// Screen shift per lens unit, pixels.
    pub eta: f32,
    /// Screen Gaussian sigma'_x, pixels.
    pub sigma_screen: f32,
    /// Lens Gaussian sigma'_u (infinite: flat).
    pub sigma_lens: f32,
}

/// The three filter cases of Vaidyanathan 2015 for a CoC range (pixels), given sigma_pix,
/// sigma_u and the clamp of sigma_x.
pub fn layer_filter(
    c_min: f32,
    c_max: f32,
    sigma_pixel: f32,
    sigma_lens: f32,
    sigma_x_max: f32,
) -> ShearedFilter {
    // Omega_u^max / Omega_pix^max = sigma_pix / sigma_u.
    let small = sigma_pixel / sigma_lens;
    let max_abs = c_min.abs().max(c_max.abs());
    if max_abs < small {
        // Eq. 26-29.
        let spread = c_max - c_min;
        return ShearedFilter {
            case: FilterCase::SmallShear,
            eta: 0.5 * (c_min + c_max),
            sigma_screen: sigma_pixel,
            sigma_lens: if spread > 0.0 {
                2.0 * sigma_pixel / spread
            } else {
                f32::INFINITY
            },
        };
    }
    if c_min * c_max <= 0.0 {
        // Eq. 11.
        return ShearedFilter {
            case: FilterCase::AxisAligned,
            eta: 0.0,
            sigma_screen: sigma_pixel,
            sigma_lens,
        };
    }
    // Eq. 12-16: W = Omega_u (1/c_min - 1/c_max), sigma_x = 1 / (pi W).
    let omega_u = 1.0 / (2.0 * std::f32::consts::PI * sigma_lens);
    let width = omega_u * (1.0 / c_min - 1.0 / c_max).abs();
    let sigma_x = if width > 0.0 {
        (1.0 / (std::f32::consts::PI * width)).min(sigma_x_max)
    } else {
        sigma_x_max
    };
    let c_avg = 2.0 * c_min * c_max / (c_min + c_max);
    if sigma_x.is_infinite() {
        // Limit W -> 0 of Eq. 22: pure reprojection by c.
        return ShearedFilter {
            case: FilterCase::Sheared,
            eta: c_avg,
            sigma_screen: sigma_lens * c_avg.abs(),
            sigma_lens: f32::INFINITY,
        };
    }
    // Eq. 22.
    let gamma = (sigma_lens * sigma_lens + sigma_x * sigma_x / (c_avg * c_avg)).sqrt();
    ShearedFilter {
        case: FilterCase::Sheared,
        eta: sigma_x * sigma_x / (c_avg * gamma * gamma),
        sigma_screen: sigma_x * sigma_lens / gamma,
        sigma_lens: gamma,
    }
}

/// CoC range of a set of samples.
pub(crate) fn coc_range(samples: &[crate::Sample]) -> (f32, f32) {
    samples
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), s| {
            (lo.min(s.coc), hi.max(s.coc))
        })
}

/// Vaidyanathan 2015 reconstruction (defocus only; motion in the samples is ignored).
/// Returns premultiplied RGBA, width x height.
pub fn vaidyanathan(s: &SampleView, p: &VaidyanathanParams) -> Result<Image, PeerError> {
    vaidyanathan_with_report(s, p).map(|r| r.0)
}

/// [`vaidyanathan`] and how many layers used which filter.
pub fn vaidyanathan_with_report(
    s: &SampleView,
    p: &VaidyanathanParams,
) -> Result<(Image, LayerReport), PeerError> {
    p.validate()?;
    reconstruct(
        s,
        Tiling {
            tile: p.tile,
            ring: p.ring,
        },
        &p.partitions,
        |members| {
            let (c_min, c_max) = coc_range(members);
            let f = layer_filter(c_min, c_max, p.sigma_pixel, p.sigma_lens, p.sigma_x_max);
            LayerFilter {
                angle: 0.0,
                eta: f.eta,
                rho: f.eta,
                xi: 0.0,
                sigma_u: f.sigma_lens,
                sigma_v: f.sigma_lens,
                sigma_t: f32::INFINITY,
                sigma_along: f.sigma_screen,
                sigma_perp: f.sigma_screen,
                case: f.case,
            }
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_depth_layer_is_pure_reprojection() {
        for c in [-12.0f32, -3.0, 2.0, 9.5] {
            let f = layer_filter(c, c, 1.0 / 3.0, 1.0 / 3.0, f32::INFINITY);
            assert_eq!(f.case, FilterCase::Sheared);
            assert_eq!(f.eta, c);
            assert!(f.sigma_lens.is_infinite());
            assert!((f.sigma_screen - c.abs() / 3.0).abs() < 1e-6);
        }
    }

    #[test]
    fn sheared_filter_matches_its_untransformed_form() {
        // Eq. 23: w(x; sx) w(u + x / c_avg; su) == w(x + eta u; sx') w(u; su') up to a constant.
        let (c_min, c_max, su) = (3.0f32, 5.0f32, 1.0 / 3.0);
        let f = layer_filter(c_min, c_max, 1.0 / 3.0, su, 8.0);
        let omega_u = 1.0 / (2.0 * std::f32::consts::PI * su);
        let sx = 1.0 / (std::f32::consts::PI * omega_u * (1.0 / c_min - 1.0 / c_max));
        let c_avg = 2.0 * c_min * c_max / (c_min + c_max);
        let g = |x: f32, s: f32| (-0.5 * x * x / (s * s)).exp() as f64;
        let ratio0 = g(0.0, sx) * g(0.0, su) / (g(0.0, f.sigma_screen) * g(0.0, f.sigma_lens));
        for (x, u) in [(0.5f32, 0.1f32), (-1.0, 0.3), (2.0, -0.4), (0.0, 0.9)] {
            let a = g(x, sx) * g(u + x / c_avg, su);
            let b = g(x + f.eta * u, f.sigma_screen) * g(u, f.sigma_lens);
            assert!((a / b / ratio0 - 1.0).abs() < 1e-4, "({x},{u}): {a} vs {b}");
        }
    }

    #[test]
    fn cases_follow_the_coc_range() {
        let s = 1.0 / 3.0;
        assert_eq!(
            layer_filter(0.2, 0.6, s, s, 8.0).case,
            FilterCase::SmallShear
        );
        assert_eq!(
            layer_filter(-2.0, 3.0, s, s, 8.0).case,
            FilterCase::AxisAligned
        );
        assert_eq!(layer_filter(2.0, 3.0, s, s, 8.0).case, FilterCase::Sheared);
        assert_eq!(
            layer_filter(-3.0, -2.0, s, s, 8.0).case,
            FilterCase::Sheared
        );
    }
}
