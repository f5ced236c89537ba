//! Guertin, McGuire, Nowrouzezahrai 2014, "A fast and stable feature-aware motion blur
//! filter" (Guertin's thesis, chapter 3 and the pseudocode of Annexe I).
//!
//! Choices where the text leaves a detail open (each one a parameter or a documented
//! constant; see `docs/PEERS.md`):
//! - `halton(-1, 1)` is the Halton number of index (linear pixel index + 1) in base
//!   `halton_base`, mapped to [-1, 1);
//! - `sOffset`: the pixel's distance d (pixels) from its centre to the nearest vertical and
//!   horizontal tile border gives a probability `P(d) = 0.5 * max(0, 1 - 2 d / (tau r))` of
//!   looking up the neighbour tile across that border (0.5 at the border, so both sides of
//!   a border agree; 0 at `tau r / 2`); one uniform number `u = (j + 1) / 2` picks x with
//!   probability P_x, else y with P_y, else no offset: never a diagonal tile;
//! - the sampling directions `d` are unit vectors (`w_n = norm(v_max)` on even taps, `w_c` on
//!   odd taps) and both are walked over the same length: `S = round(p + T d)`,
//!   `T = t |v_max|` (the pseudocode mixes vectors and directions; with unit `d` the dot
//!   products `w_A`, `w_B` are cosines as Sec. 3.4.1 describes);
//! - `w_A` and `w_B` are absolute values of the cosines: the blur is symmetric, and a sample
//!   moving against the sampling direction blurs along the same line;
//! - the depth test uses positive planar depths: `f` (sample in front of p) is
//!   `zCompare(Z[S], Z[p])`, `b` is `zCompare(Z[p], Z[S])`;
//! - the `T` of the cone and cylinder weights is the distance from p to the pixel actually
//!   fetched, `|S - p|`, not the unrounded `t |v_max|`: with the unrounded value a still pixel
//!   takes part of a neighbour's colour through the cylinder term whenever a tap lands at
//!   `T` in [0.5, 0.525), contradicting the still-pixel property of Sec. 3.4.3;
//! - taps falling outside the image are skipped; the tap nearest p is kept (Sec. 3.4.3);
//! - samples are split evenly between the two directions (the variance-driven split of
//!   Sec. 3.4.1 was disabled for all the thesis's results but one).

use crate::halton::halton;
use crate::inputs::{GBufferView, Image};
use crate::mcguire::DepthCompare;
use crate::tiles::{cone, cylinder, half_velocities, len2, neighbor_max, tile_max};
use crate::PeerError;
use rayon::prelude::*;

/// Parameters of [`guertin`]. Defaults are the thesis's
/// `(N, r, tau, kappa, eta, gamma, phi) = (35, 40, 1, 40, 0.95, 1.5, 27)`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GuertinParams {
    /// Taps per pixel N.
    pub n: usize,
    /// Tile size and largest blur radius r, pixels.
    pub r: usize,
    /// Slope of the stochastic tile-lookup fall-off (Sec. 3.4.2), in units of half a tile.
    pub tau: f32,
    /// Centre weight bias kappa (Sec. 3.4.3): centre weight `N / (kappa |v_c|)`.
    pub kappa: f32,
    /// Largest jitter eta in tap spacings (Sec. 3.4.5).
    pub eta: f32,
    /// Velocity length (px) over which the centre direction turns from the perpendicular of
    /// v_max to the pixel's own velocity (Eq. 3.1).
    pub gamma: f32,
    /// Baseline jitter phi: the jitter is `j eta phi / N`.
    pub phi: f32,
    /// NeighborMax diagonal test threshold (cosine); `None` keeps all 8 neighbours as McGuire.
    pub diagonal_cos: Option<f32>,
    /// Soft depth comparison; the thesis's relative one by default.
    pub depth_compare: DepthCompare,
    /// Base of the Halton sequence. Default 2.
    pub halton_base: u64,
    /// Stochastic NeighborMax lookup near tile borders (Sec. 3.4.2). Default on.
    pub tile_jitter: bool,
    /// How the N taps are split between `v_max` and the centre direction. Default even
    /// (as all the thesis's results but Fig. 3.7).
    pub split: SampleSplit,
}

/// Split of the taps between the dominant direction and the centre direction (Sec. 3.4.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum SampleSplit {
    /// Odd taps along the centre direction, even taps along `v_max` (N/2 each).
    Even,
    /// `v N` taps along the centre direction, with the tile variance `v` of Eq. 3.2
    /// (TileMax directions against the 3x3 neighbourhood, bilinearly interpolated between
    /// tile centres as in Sec. 3.5); a zero TileMax counts as agreeing with its neighbours.
    TileVariance,
}

impl Default for GuertinParams {
    fn default() -> Self {
        GuertinParams {
            n: 35,
            r: 40,
            tau: 1.0,
            kappa: 40.0,
            eta: 0.95,
            gamma: 1.5,
            phi: 27.0,
            diagonal_cos: Some(std::f32::consts::FRAC_1_SQRT_2),
            depth_compare: DepthCompare::Relative,
            halton_base: 2,
            tile_jitter: true,
            split: SampleSplit::Even,
        }
    }
}

impl GuertinParams {
    fn validate(&self) -> Result<(), PeerError> {
        self.depth_compare.validate()?;
        if self.n == 0 || self.n > 1024 {
            return Err(PeerError::BadParam {
                name: "n",
                why: "must be in 1..=1024",
            });
        }
        if self.r == 0 || self.r > 1024 {
            return Err(PeerError::BadParam {
                name: "r",
                why: "must be in 1..=1024",
            });
        }
        for (name, v) in [
            ("tau", self.tau),
            ("kappa", self.kappa),
            ("gamma", self.gamma),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(PeerError::BadParam {
                    name,
                    why: "must be finite and > 0",
                });
            }
        }
        for (name, v) in [("eta", self.eta), ("phi", self.phi)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(PeerError::BadParam {
                    name,
                    why: "must be finite and >= 0",
                });
            }
        }
        Ok(())
    }
}

fn normalize_min(v: [f32; 2], min_len: f32) -> [f32; 2] {
    let l = len2(v).max(min_len);
    if l <= 0.0 {
        return [0.0, 0.0];
    }
    [v[0] / l, v[1] / l]
}

/// `sOffset`: tile offset (-1, 0 or 1 on one axis only) for a pixel, from `u` in [0, 1).
fn tile_offset(x: usize, y: usize, r: usize, tau: f32, u: f32) -> (isize, isize) {
    let prob = |c: usize| -> (f32, isize) {
        let inside = (c % r) as f32 + 0.5;
        let (d, dir) = if inside < r as f32 - inside {
            (inside, -1)
        } else {
            (r as f32 - inside, 1)
        };
        (0.5 * (1.0 - 2.0 * d / (tau * r as f32)).max(0.0), dir)
    };
    let (px, dx) = prob(x);
    let (py, dy) = prob(y);
    if u < px {
        (dx, 0)
    } else if u < px + py {
        (0, dy)
    } else {
        (0, 0)
    }
}

/// Guertin 2014 motion blur of a pinhole G-buffer. Returns premultiplied RGBA, width x height.
pub fn guertin(g: &GBufferView, p: &GuertinParams) -> Result<Image, PeerError> {
    g.validate()?;
    p.validate()?;
    let (w, h) = (g.width, g.height);
    let r = p.r;
    let vel = half_velocities(g.motion, r as f32);
    let tm = tile_max(w, h, &vel, r);
    let nm = neighbor_max(&tm, p.diagonal_cos);
    let variance = match p.split {
        SampleSplit::Even => None,
        SampleSplit::TileVariance => Some(tile_variance(&tm)),
    };
    let n = p.n;
    let mut out = vec![[0.0f32; 4]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = y * w + x;
            let c = g.color[i];
            let j = halton(i as u64 + 1, p.halton_base, -1.0, 1.0);
            let (ox, oy) = if p.tile_jitter {
                tile_offset(x, y, r, p.tau, 0.5 * (j + 1.0))
            } else {
                (0, 0)
            };
            let tx = (x / r) as isize + ox;
            let ty = (y / r) as isize + oy;
            let tx = tx.clamp(0, nm.tw as isize - 1) as usize;
            let ty = ty.clamp(0, nm.th as isize - 1) as usize;
            let vmax = nm.v[ty * nm.tw + tx];
            let vmax_len = len2(vmax);
            if vmax_len <= 0.5 {
                *o = c;
                continue;
            }
            let wn = [vmax[0] / vmax_len, vmax[1] / vmax_len];
            let vc = vel[i];
            let vc_len = len2(vc).max(0.5);
            let mut wp = [-wn[1], wn[0]];
            if wp[0] * vc[0] + wp[1] * vc[1] < 0.0 {
                wp = [-wp[0], -wp[1]];
            }
            // rnmix: lerp then normalise, the weight clamped to [0, 1].
            let a = ((len2(vc) - 0.5) / p.gamma).clamp(0.0, 1.0);
            let nvc = normalize_min(vc, 0.0);
            let wc = normalize_min(
                [wp[0] + (nvc[0] - wp[0]) * a, wp[1] + (nvc[1] - wp[1]) * a],
                1e-12,
            );
            let wc = if len2(wc) > 0.0 { wc } else { wp };
            let zp = g.depth[i];
            let mut total = n as f32 / (p.kappa * vc_len);
            let mut sum = c.map(|v| v * total);
            let jp = j * p.eta * p.phi / n as f32;
            // Share of taps along the centre direction.
            let share = match &variance {
                None => 0.5,
                Some(v) => sample_bilinear(
                    v,
                    nm.tw,
                    nm.th,
                    (x as f32 + 0.5) / r as f32 - 0.5,
                    (y as f32 + 0.5) / r as f32 - 0.5,
                ),
            };
            for k in 0..n {
                let t = -1.0 + 2.0 * (k as f32 + jp + 1.0) / (n as f32 + 1.0);
                let centre_tap = match variance {
                    None => k % 2 == 1,
                    // Spread the centre taps evenly: tap k is one when floor((k+1) v) steps.
                    Some(_) => ((k + 1) as f32 * share).floor() > (k as f32 * share).floor(),
                };
                let d = if centre_tap { wc } else { wn };
                let big_t = t * vmax_len;
                let sx = (x as f32 + big_t * d[0]).round();
                let sy = (y as f32 + big_t * d[1]).round();
                if sx < 0.0 || sy < 0.0 || sx >= w as f32 || sy >= h as f32 {
                    continue;
                }
                let si = sy as usize * w + sx as usize;
                // Distance to the pixel actually fetched (see the module notes).
                let big_t = ((sx - x as f32).powi(2) + (sy - y as f32).powi(2)).sqrt();
                let vs = vel[si];
                let vs_len = len2(vs).max(0.5);
                let zs = g.depth[si];
                let f = p.depth_compare.in_front(zs, zp);
                let b = p.depth_compare.in_front(zp, zs);
                let wa = (wc[0] * d[0] + wc[1] * d[1]).abs();
                let nvs = normalize_min(vs, 0.5);
                let wb = (nvs[0] * d[0] + nvs[1] * d[1]).abs();
                let weight = f * cone(big_t, vs_len) * wb
                    + b * cone(big_t, vc_len) * wa
                    + cylinder(big_t, vs_len.min(vc_len)) * wa.max(wb) * 2.0;
                total += weight;
                let cs = g.color[si];
                for ch in 0..4 {
                    sum[ch] += weight * cs[ch];
                }
            }
            *o = sum.map(|v| v / total);
        }
    });
    Ok(out)
}

/// Eq. 3.2: `v(t) = 1 - mean over the 3x3 neighbourhood (incl. t) of |cos(v_max(t), v_max(n))|`.
fn tile_variance(tm: &crate::tiles::TileGrid) -> Vec<f32> {
    let (tw, th) = (tm.tw as isize, tm.th as isize);
    let unit = |v: [f32; 2]| {
        let l = len2(v);
        if l > 0.0 {
            Some([v[0] / l, v[1] / l])
        } else {
            None
        }
    };
    let mut out = vec![0.0f32; tm.v.len()];
    for ty in 0..th {
        for tx in 0..tw {
            let Some(c) = unit(tm.v[(ty * tw + tx) as usize]) else {
                continue;
            };
            let (mut sum, mut count) = (0.0f32, 0.0f32);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (nx, ny) = (tx + dx, ty + dy);
                    if nx < 0 || ny < 0 || nx >= tw || ny >= th {
                        continue;
                    }
                    sum += unit(tm.v[(ny * tw + nx) as usize])
                        .map_or(1.0, |n| (c[0] * n[0] + c[1] * n[1]).abs());
                    count += 1.0;
                }
            }
            out[(ty * tw + tx) as usize] = (1.0 - sum / count).clamp(0.0, 1.0);
        }
    }
    out
}

/// Bilinear lookup in a tile grid at tile coordinates (tile centres at integers), clamped.
fn sample_bilinear(v: &[f32], tw: usize, th: usize, x: f32, y: f32) -> f32 {
    let x = x.clamp(0.0, (tw - 1) as f32);
    let y = y.clamp(0.0, (th - 1) as f32);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(tw - 1), (y0 + 1).min(th - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let top = v[y0 * tw + x0] * (1.0 - fx) + v[y0 * tw + x1] * fx;
    let bottom = v[y1 * tw + x0] * (1.0 - fx) + v[y1 * tw + x1] * fx;
    top * (1.0 - fy) + bottom * fy
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tile_variance_is_zero_for_one_direction_and_grows_with_disagreement() {
        let mut g = crate::tiles::TileGrid {
            r: 8,
            tw: 3,
            th: 3,
            v: vec![[5.0, 0.0]; 9],
        };
        assert!(tile_variance(&g).iter().all(|v| *v == 0.0));
        g.v[4] = [0.0, 5.0];
        let v = tile_variance(&g);
        // Centre: 8 perpendicular neighbours and itself: 1 - 1/9.
        assert!((v[4] - 8.0 / 9.0).abs() < 1e-6);
        assert!(v[0] > 0.0 && v[0] < v[4]);
    }

    #[test]
    fn tile_offset_never_diagonal_and_vanishes_mid_tile() {
        for u in [0.0, 0.2, 0.45, 0.7, 0.99] {
            for x in 0..40 {
                let (ox, oy) = tile_offset(x, 3, 40, 1.0, u);
                assert!(ox == 0 || oy == 0);
            }
        }
        for u in [0.03, 0.2, 0.7] {
            assert_eq!(tile_offset(20, 20, 40, 1.0, u), (0, 0));
        }
        // At the border the two sides look across with probability ~0.5.
        assert_eq!(tile_offset(39, 20, 40, 1.0, 0.1), (1, 0));
        assert_eq!(tile_offset(0, 20, 40, 1.0, 0.1), (-1, 0));
    }
}
