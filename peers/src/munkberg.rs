//! Munkberg, Vaidyanathan, Hasselgren, Clarberg, Akenine-Möller 2014, "Layered reconstruction
//! for defocus and motion blur": Vaidyanathan's layered reconstruction with, per layer, a
//! motion frame (rotation by the mean motion), a time shear, a choice of clip plane
//! (lens, shutter or pixel bandlimit) and a rotated separable screen filter.
//!
//! Choices where the paper leaves a detail open (see `docs/PEERS.md`):
//! - per-sample slopes: `k_u = coc` (px per unit of the papers' lens coordinate `u = -lens`)
//!   and `k_t = -(motion . a)` (px per frame along the frame's axis `a`), so one slope pair
//!   reprojects a sample to its pinhole position at t = 0
//!   (`pixel centre + jitter - coc lens - motion t`);
//! - motion frame: `psi = atan2` of the layer's mean motion (0 when the mean moves less than
//!   0.05 px over the shutter); the motion range `[d_min, d_max]` of the along components is
//!   widened on both sides by the largest perpendicular component (Fig. 4, right);
//! - variance test (unstated threshold): the motion filter is disabled when the motion
//!   spread over the shutter, `sqrt(var_x + var_y) * shutter`, exceeds both 0.5 px and
//!   `motion_spread_limit` times the mean motion length over the shutter; the layer then
//!   gets a small filter: pixel-sized screen Gaussian, lens shear at the mean CoC,
//!   Vaidyanathan's small-shear lens weight, flat in time (Sec. 8: "we revert to a small
//!   axis-aligned filter");
//! - clip plane: the corner ray uses the smallest |c| and |d| in the layer's ranges (0 when a
//!   range crosses 0); the plane hit first is the one with the largest of
//!   `sigma_lens |c|_min`, `sigma_t |d|_min`, `sigma_pixel` (ties: lens, then shutter);
//! - clip-plane formulas: Appendix B for the lens plane; the shutter plane swaps the roles of
//!   u and t; the pixel plane is Vaidyanathan's small-shear filter in both u and t
//!   (`sigma_u = 2 sigma_pix / (c_max - c_min)`, `sigma_t = 2 sigma_pix / (d_max - d_min)`,
//!   shears at the mid-range slopes);
//! - clamping (Appendix C): `s_x >= 1 / sigma_clamp` (as Vaidyanathan's clamp of sigma_x),
//!   `sigma_clamp = (window - tile) / 4`, and the other scale (`s_t` for the lens plane,
//!   `s_u` for the shutter plane) grows by the ratio of the parallelogram's reach along
//!   Omega_x (`|alpha| s + s_x`) after and before; beta is left as is;
//! - the y-v filter is [`crate::vaidyanathan::layer_filter`] on the layer's CoC range;
//! - Gaussian shutter: `sigma_t = sigma_shutter * shutter_frames` with `sigma_shutter =
//!   1/sqrt(12)` (the standard deviation of the box shutter our samples use; the paper
//!   renders with a Gaussian shutter of 2/3); `sigma_lens = 1/2`, `sigma_pixel = 1/3`;
//! - partitions: [`Partitions::default`], as Vaidyanathan (the paper adds layers around
//!   the focus plane "following Vaidyanathan"); the screen filter along rotated axes reads the
//!   reprojection grid bilinearly.

use crate::inputs::{Image, Sample, SampleView};
use crate::layered::{reconstruct, FilterCase, LayerFilter, LayerReport, Partitions, Tiling};
use crate::vaidyanathan::{coc_range, layer_filter};
use crate::PeerError;

/// Parameters of [`munkberg`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MunkbergParams {
    /// Inner tile side N, pixels. Default 16.
    pub tile: usize,
    /// Search window side N_s, pixels (32 default, 44 the paper's high-quality setting).
    pub window: usize,
    /// Pixel Gaussian sigma, pixels. Default 1/3.
    pub sigma_pixel: f32,
    /// Aperture Gaussian sigma, unit-disk lens units. Default 1/2.
    pub sigma_lens: f32,
    /// Shutter Gaussian sigma as a fraction of the shutter length. Default 1/sqrt(12).
    pub sigma_shutter: f32,
    /// Clamp of the pre-shear screen sigma, pixels; `None`: `(window - tile) / 4`.
    pub sigma_clamp: Option<f32>,
    /// Largest motion spread, relative to the mean motion, before the motion filter is
    /// disabled. Default 0.5.
    pub motion_spread_limit: f32,
    /// Depth partitions in signed CoC.
    pub partitions: Partitions,
}

impl Default for MunkbergParams {
    fn default() -> Self {
        MunkbergParams {
            tile: 16,
            window: 32,
            sigma_pixel: 1.0 / 3.0,
            sigma_lens: 0.5,
            sigma_shutter: 1.0 / 12f32.sqrt(),
            sigma_clamp: None,
            motion_spread_limit: 0.5,
            partitions: Partitions::default(),
        }
    }
}

impl MunkbergParams {
    /// The paper's high-quality setting: a 44-pixel search window.
    pub fn window_44() -> Self {
        MunkbergParams {
            window: 44,
            ..Default::default()
        }
    }

    fn validate(&self) -> Result<(), PeerError> {
        if self.tile == 0 || self.window < self.tile || self.window > 2048 {
            return Err(PeerError::BadParam {
                name: "window",
                why: "need 1 <= tile <= window <= 2048",
            });
        }
        for (name, v) in [
            ("sigma_pixel", self.sigma_pixel),
            ("sigma_lens", self.sigma_lens),
            ("sigma_shutter", self.sigma_shutter),
            ("motion_spread_limit", self.motion_spread_limit),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(PeerError::BadParam {
                    name,
                    why: "must be finite and > 0",
                });
            }
        }
        if let Some(c) = self.sigma_clamp {
            if c.is_nan() || c <= 0.0 {
                return Err(PeerError::BadParam {
                    name: "sigma_clamp",
                    why: "must be > 0",
                });
            }
        }
        self.partitions.validate()
    }

    fn clamp(&self) -> f32 {
        self.sigma_clamp
            .unwrap_or(((self.window - self.tile) as f32 / 4.0).max(self.sigma_pixel))
    }
}

/// Smallest magnitude in `[lo, hi]` (0 when the range contains 0).
fn min_abs(lo: f32, hi: f32) -> f32 {
    if lo <= 0.0 && hi >= 0.0 {
        0.0
    } else {
        lo.abs().min(hi.abs())
    }
}

fn inv(s: f32) -> f32 {
    if s > 0.0 {
        1.0 / s
    } else {
        f32::INFINITY
    }
}

/// The x-u-t filter of a layer (Sec. 5, Appendix B and C), in the frame of its mean motion.
/// `c` and `d` are the ranges of `k_u` (px per lens unit) and `k_t` (px per frame); `sigma_t`
/// in frames (0: no shutter). Returns (case, eta, xi, sigma_along, sigma_u, sigma_t).
pub fn xut_filter(
    c: (f32, f32),
    d: (f32, f32),
    sigma_pixel: f32,
    sigma_lens: f32,
    sigma_t: f32,
    sigma_clamp: f32,
) -> (FilterCase, f32, f32, f32, f32, f32) {
    let (c_min, c_max) = c;
    let (d_min, d_max) = if sigma_t > 0.0 { d } else { (0.0, 0.0) };
    let c_lo = min_abs(c_min, c_max);
    let d_lo = min_abs(d_min, d_max);
    let reach_u = sigma_lens * c_lo;
    let reach_t = if sigma_t > 0.0 { sigma_t * d_lo } else { 0.0 };
    if reach_u >= reach_t && reach_u >= sigma_pixel && c_lo > 0.0 {
        // Clip against Omega_u (Appendix B); 2 pi Omega_u^max = 1 / sigma_lens.
        let s_u = 1.0 / sigma_lens;
        let mut s_x = ((c_max - c_min) / (2.0 * c_min * c_max)).abs() * s_u;
        let mut s_t = ((d_max - d_min) / (2.0 * c_lo)).abs() * s_u;
        let alpha = (c_max + c_min) / (2.0 * c_min * c_max);
        let beta = 0.5 * (d_max + d_min);
        if s_x < 1.0 / sigma_clamp {
            let new_s_x = 1.0 / sigma_clamp;
            s_t *= (alpha.abs() * s_u + new_s_x) / (alpha.abs() * s_u + s_x);
            s_x = new_s_x;
        }
        let gamma = (s_x * s_x + alpha * alpha * s_u * s_u).sqrt();
        let eta = alpha * s_u * s_u / (gamma * gamma);
        let sigma_u = inv(s_x * s_u / gamma);
        let sig_t = if s_t > 0.0 { 1.0 / s_t } else { f32::INFINITY };
        return (FilterCase::Sheared, eta, beta, 1.0 / gamma, sigma_u, sig_t);
    }
    if reach_t >= sigma_pixel && d_lo > 0.0 {
        // Clip against Omega_t: Appendix B with u and t swapped.
        let s_t = 1.0 / sigma_t;
        let mut s_x = ((d_max - d_min) / (2.0 * d_min * d_max)).abs() * s_t;
        let mut s_u = ((c_max - c_min) / (2.0 * d_lo)).abs() * s_t;
        let alpha = (d_max + d_min) / (2.0 * d_min * d_max);
        let beta = 0.5 * (c_max + c_min);
        if s_x < 1.0 / sigma_clamp {
            let new_s_x = 1.0 / sigma_clamp;
            s_u *= (alpha.abs() * s_t + new_s_x) / (alpha.abs() * s_t + s_x);
            s_x = new_s_x;
        }
        let gamma = (s_x * s_x + alpha * alpha * s_t * s_t).sqrt();
        let xi = alpha * s_t * s_t / (gamma * gamma);
        let sig_t = inv(s_x * s_t / gamma);
        let sigma_u = if s_u > 0.0 { 1.0 / s_u } else { f32::INFINITY };
        return (
            FilterCase::TimeSheared,
            beta,
            xi,
            1.0 / gamma,
            sigma_u,
            sig_t,
        );
    }
    // Clip against Omega_x: small shears in u and t.
    let su = if c_max > c_min {
        2.0 * sigma_pixel / (c_max - c_min)
    } else {
        f32::INFINITY
    };
    let st = if d_max > d_min {
        2.0 * sigma_pixel / (d_max - d_min)
    } else {
        f32::INFINITY
    };
    (
        FilterCase::SmallShear,
        0.5 * (c_min + c_max),
        0.5 * (d_min + d_max),
        sigma_pixel,
        su,
        st,
    )
}

fn build_filter(members: &[Sample], p: &MunkbergParams, shutter: f32) -> LayerFilter {
    let (c_min, c_max) = coc_range(members);
    let clamp = p.clamp();
    let yv = layer_filter(c_min, c_max, p.sigma_pixel, p.sigma_lens, clamp);
    let n = members.len().max(1) as f64;
    let mean = members.iter().fold([0.0f64; 2], |a, s| {
        [a[0] + s.motion[0] as f64 / n, a[1] + s.motion[1] as f64 / n]
    });
    let var = members.iter().fold(0.0f64, |a, s| {
        a + ((s.motion[0] as f64 - mean[0]).powi(2) + (s.motion[1] as f64 - mean[1]).powi(2)) / n
    });
    let mean_len = (mean[0] * mean[0] + mean[1] * mean[1]).sqrt() as f32;
    let spread_px = var.sqrt() as f32 * shutter;
    let sigma_t = p.sigma_shutter * shutter;
    if spread_px > 0.5 && spread_px > p.motion_spread_limit * mean_len * shutter {
        let small = layer_filter(c_min, c_max, p.sigma_pixel, p.sigma_lens, clamp);
        let eta = 0.5 * (c_min + c_max);
        let su = if small.case == FilterCase::SmallShear {
            small.sigma_lens
        } else {
            p.sigma_lens
        };
        return LayerFilter {
            angle: 0.0,
            eta,
            rho: eta,
            xi: 0.0,
            sigma_u: su,
            sigma_v: su,
            sigma_t: f32::INFINITY,
            sigma_along: p.sigma_pixel,
            sigma_perp: p.sigma_pixel,
            case: FilterCase::MotionDisabled,
        };
    }
    let angle = if mean_len * shutter > 0.05 {
        (mean[1] as f32).atan2(mean[0] as f32)
    } else {
        0.0
    };
    let (ca, sa) = (angle.cos(), angle.sin());
    let mut d_lo = f32::INFINITY;
    let mut d_hi = f32::NEG_INFINITY;
    let mut perp_max = 0.0f32;
    for s in members {
        let along = -(s.motion[0] * ca + s.motion[1] * sa);
        let perp = -s.motion[0] * sa + s.motion[1] * ca;
        d_lo = d_lo.min(along);
        d_hi = d_hi.max(along);
        perp_max = perp_max.max(perp.abs());
    }
    let (case, eta, xi, sigma_along, sigma_u, sigma_t) = xut_filter(
        (c_min, c_max),
        (d_lo - perp_max, d_hi + perp_max),
        p.sigma_pixel,
        p.sigma_lens,
        sigma_t,
        clamp,
    );
    LayerFilter {
        angle,
        eta,
        rho: yv.eta,
        xi,
        sigma_u,
        sigma_v: yv.sigma_lens,
        sigma_t,
        sigma_along,
        sigma_perp: yv.sigma_screen,
        case,
    }
}

/// Munkberg 2014 reconstruction (defocus and motion blur). Returns premultiplied RGBA.
pub fn munkberg(s: &SampleView, p: &MunkbergParams) -> Result<Image, PeerError> {
    munkberg_with_report(s, p).map(|r| r.0)
}

/// [`munkberg`] and how many layers used which filter.
pub fn munkberg_with_report(
    s: &SampleView,
    p: &MunkbergParams,
) -> Result<(Image, LayerReport), PeerError> {
    p.validate()?;
    let ring = (p.window - p.tile) / 2;
    let shutter = s.shutter_frames;
    reconstruct(s, Tiling { tile: p.tile, ring }, &p.partitions, |members| {
        build_filter(members, p, shutter)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn single_slopes_reproject_exactly() {
        // One CoC and one motion: the filter shears by exactly (c, d) whichever plane clips.
        for (c, d) in [(4.0f32, 0.0f32), (4.0, -6.0), (0.3, -12.0), (-5.0, 3.0)] {
            let (_, eta, xi, _, _, _) =
                xut_filter((c, c), (d, d), 1.0 / 3.0, 0.5, 0.3, f32::INFINITY);
            assert!(
                (eta - c).abs() < 1e-5 && (xi - d).abs() < 1e-5,
                "({c},{d}) -> ({eta},{xi})"
            );
        }
    }

    #[test]
    fn clip_plane_follows_the_dominant_blur() {
        let s = (1.0 / 3.0, 0.5, 0.3, 8.0);
        assert_eq!(
            xut_filter((6.0, 8.0), (-1.0, -0.5), s.0, s.1, s.2, s.3).0,
            FilterCase::Sheared
        );
        assert_eq!(
            xut_filter((0.1, 0.3), (-20.0, -16.0), s.0, s.1, s.2, s.3).0,
            FilterCase::TimeSheared
        );
        assert_eq!(
            xut_filter((0.1, 0.3), (-0.2, 0.1), s.0, s.1, s.2, s.3).0,
            FilterCase::SmallShear
        );
    }
}
