//! Footprints stretched along the image's edges, for samples put back on the pixel grid one or
//! two to a pixel.
//!
//! Moved back to the lens and shutter centre, a frame's samples are exact point samples of the
//! sharp image, scattered: the lens offsets undo the renderer's one-per-pixel stratification,
//! so some pixels hold none and some two. Spread by an isotropic Gaussian footprint and
//! normalised, a texture's straight edge then comes out torn, with teeth of a pixel or two
//! where a pixel's nearest samples all lie on the far side (docs/BENCHMARKS.md, "Where 1 spp
//! loses FLIP to the 16-spp average").
//!
//! A footprint stretched along the local edge averages the samples along it and keeps the
//! edge as sharp across it as before (the "steering kernel" of Takeda, Farsiu and Milanfar
//! 2007). The edge's direction and strength come from the structure tensor of a first
//! estimate: the samples' tone-mapped luminance `l / (1 + l)` (so that an emitter does not
//! outweigh every texture edge) binned per pixel, spread by the footprint's Gaussian and
//! normalised, its Sobel gradient `g`, and
//!
//! ```text
//! J = G_s * (g g^T),
//! coherence = (lambda_1 - lambda_2) / (lambda_1 + lambda_2)
//!             * lambda_1 / (lambda_1 + EDGE_CONTRAST^2)
//! ```
//!
//! with `G_s` a Gaussian of [`TENSOR_SIGMA_PX`] and `lambda_1 >= lambda_2` the eigenvalues of
//! `J` (the second factor: a faint gradient is the estimate's noise, not an edge). The
//! footprint keeps its standard deviation `sigma` across the edge (along the eigenvector of
//! `lambda_1`) and takes `sigma (1 + STRETCH coherence)` along it: a flat region (coherence
//! near 0) keeps the isotropic footprint, a strong straight edge (near 1) the longest.

use rayon::prelude::*;

use crate::grid::gaussian_blur;
use crate::reconstruct::{push_normalized, tap_span};

/// How much longer than across it a footprint grows along a perfectly straight edge, minus
/// one: `sigma_along = sigma (1 + STRETCH coherence)`. At 1 spp, 1 keeps SSIM, FLIP mean and
/// p99 at least as good as round footprints on `studio`, `crossing`, `occluder` and `bokeh`;
/// 2 and 3 straighten edges further but cost FLIP where corners round off.
pub const STRETCH: f32 = 1.0;

/// Standard deviation of the Gaussian that smooths the structure tensor, pixels: the edge's
/// direction is read over about three pixels each way.
pub const TENSOR_SIGMA_PX: f32 = 1.5;

/// Gradient magnitude of the tensor (its larger eigenvalue's square root, tone-mapped
/// luminance per pixel through the Sobel operator) at which an edge counts half: a checker's
/// edge of a fifth in tone-mapped luminance reads about 0.4, the residual noise of denoised
/// samples a few hundredths.
pub const EDGE_CONTRAST: f32 = 0.1;

/// Taps under this fraction of the footprint's peak are left out (each tap is a fragment).
const TAP_CUTOFF: f32 = 1e-2;

/// Most taps along one axis of a steered footprint's box.
const MAX_TAPS_PER_AXIS: usize = 48;

/// Per pixel, the direction across the local edge (unit, x right, y down) and the edge's
/// coherence weighed by its strength, in `[0, 1]` (see the module's documentation).
pub struct EdgeField {
    width: usize,
    height: usize,
    /// `(across_x, across_y, coherence)` per pixel, row-major.
    cells: Vec<[f32; 3]>,
}

impl EdgeField {
    /// The field of the samples at continuous sensor positions `positions` (pixels, pixel
    /// centres at +0.5; `None`: not placed) with linear colours `colors`, on a `width x height`
    /// grid; the first estimate bins them per pixel and spreads the bins by a Gaussian of
    /// `sigma_px`.
    pub fn from_samples(
        width: usize,
        height: usize,
        positions: &[Option<[f32; 2]>],
        colors: &[[f32; 4]],
        sigma_px: f32,
    ) -> Self {
        if width == 0 || height == 0 {
            return EdgeField {
                width,
                height,
                cells: Vec::new(),
            };
        }
        // Each sample binned into its pixel, then the bins spread by the footprint's
        // Gaussian: a scatter of one add per sample, the rest on every thread.
        // Per pixel, the tone-mapped luminance summed and the sample count.
        let mut bins = vec![[0.0f32; 2]; width * height];
        for (q, c) in positions.iter().zip(colors) {
            let Some([qx, qy]) = *q else { continue };
            let l = 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
            if !(l.is_finite() && qx >= 0.0 && qy >= 0.0) {
                continue;
            }
            let (x, y) = (qx as usize, qy as usize);
            if x < width && y < height {
                let tone = l.max(0.0) / (1.0 + l.max(0.0));
                let bin = &mut bins[y * width + x];
                bin[0] += tone;
                bin[1] += 1.0;
            }
        }
        gaussian_blur(&mut bins, width, height, sigma_px);
        // Pixels no sample's spread reaches are unknown (NaN), not dark: a gradient that reads
        // one is left out (a hole between scattered samples is not an edge).
        let estimate: Vec<f32> = bins
            .iter()
            .map(|&[s, w]| if w > 0.0 { s / w } else { f32::NAN })
            .collect();
        drop(bins);
        let at = |x: isize, y: isize| -> Option<f32> {
            let x = x.clamp(0, width as isize - 1) as usize;
            let y = y.clamp(0, height as isize - 1) as usize;
            Some(estimate[y * width + x]).filter(|v| !v.is_nan())
        };
        // Sobel gradient, and the tensor's three components per pixel.
        let mut tensor: Vec<[f32; 3]> = (0..width * height)
            .into_par_iter()
            .map(|i| {
                let (x, y) = ((i % width) as isize, (i / width) as isize);
                let mut w = [[0.0f32; 3]; 3];
                for (j, row) in w.iter_mut().enumerate() {
                    for (k, v) in row.iter_mut().enumerate() {
                        match at(x + k as isize - 1, y + j as isize - 1) {
                            Some(known) => *v = known,
                            None => return [0.0; 3],
                        }
                    }
                }
                let gx = (w[0][2] + 2.0 * w[1][2] + w[2][2]) - (w[0][0] + 2.0 * w[1][0] + w[2][0]);
                let gy = (w[2][0] + 2.0 * w[2][1] + w[2][2]) - (w[0][0] + 2.0 * w[0][1] + w[0][2]);
                [gx * gx, gx * gy, gy * gy]
            })
            .collect();
        drop(estimate);
        gaussian_blur(&mut tensor, width, height, TENSOR_SIGMA_PX);
        // Each pixel's tensor becomes its cell, in place.
        tensor
            .par_iter_mut()
            .for_each(|cell| *cell = cell_of(*cell));
        let cells = tensor;
        EdgeField {
            width,
            height,
            cells,
        }
    }

    /// The direction across the edge and the coherence at continuous position `(qx, qy)`
    /// (its pixel's; the nearest pixel's outside the grid).
    pub fn at(&self, qx: f32, qy: f32) -> ([f32; 2], f32) {
        if self.cells.is_empty() {
            return ([1.0, 0.0], 0.0);
        }
        let clamp = |v: f32, n: usize| {
            if v.is_finite() {
                (v.floor().max(0.0) as usize).min(n - 1)
            } else {
                0
            }
        };
        let [x, y, coherence] =
            self.cells[clamp(qy, self.height) * self.width + clamp(qx, self.width)];
        ([x, y], coherence)
    }

    /// Calls `push(x, y, share)` for each pixel under the footprint of standard deviation
    /// `sigma_px` across the edge at `(qx, qy)` and `sigma_px (1 + STRETCH coherence)` along
    /// it, centred there; the shares sum to 1.
    pub fn push_steered(&self, qx: f32, qy: f32, sigma_px: f32, push: impl FnMut(f32, f32, f32)) {
        let (across, coherence) = self.at(qx, qy);
        push_footprint(
            qx,
            qy,
            sigma_px,
            sigma_px * (1.0 + STRETCH * coherence),
            across,
            push,
        );
    }
}

/// Calls `push(x, y, share)` for each pixel `(x, y)` (column and row, as floats) under a
/// normalised Gaussian of standard deviation `sigma_across` along unit direction `across` and
/// `sigma_along` perpendicular to it, centred at `(qx, qy)` (pixel centres at +0.5); taps under
/// [`TAP_CUTOFF`] of the peak are left out.
fn push_footprint(
    qx: f32,
    qy: f32,
    sigma_across: f32,
    sigma_along: f32,
    across: [f32; 2],
    push: impl FnMut(f32, f32, f32),
) {
    let positive = |v: f32| v.is_finite() && v > 0.0;
    if !(qx.is_finite() && qy.is_finite() && positive(sigma_across) && positive(sigma_along)) {
        return;
    }
    let reach = sigma_across.max(sigma_along) * (2.0 * (1.0 / TAP_CUTOFF).ln()).sqrt();
    let span = |q: f32| tap_span(q, reach, MAX_TAPS_PER_AXIS);
    let ((x0, nx), (y0, ny)) = (span(qx), span(qy));
    let (inv_across, inv_along) = (
        1.0 / (2.0 * sigma_across * sigma_across),
        1.0 / (2.0 * sigma_along * sigma_along),
    );
    let tap = |i: usize, j: usize| -> f32 {
        let (dx, dy) = (x0 + i as f32 + 0.5 - qx, y0 + j as f32 + 0.5 - qy);
        let u = dx * across[0] + dy * across[1];
        let t = -dx * across[1] + dy * across[0];
        let w = (-u * u * inv_across - t * t * inv_along).exp();
        if w >= TAP_CUTOFF {
            w
        } else {
            0.0
        }
    };
    push_normalized((x0, nx), (y0, ny), tap, push);
}

/// A pixel's smoothed structure tensor `[Jxx, Jxy, Jyy]` as its cell: the unit direction
/// across the edge and the coherence weighed by the edge's strength (round, `[1, 0, 0]`,
/// where there is no gradient).
fn cell_of([a, b, c]: [f32; 3]) -> [f32; 3] {
    let half_trace = 0.5 * (a + c);
    let root = (0.25 * (a - c) * (a - c) + b * b).sqrt();
    let (l1, l2) = (half_trace + root, half_trace - root);
    if !(l1.is_finite() && l1 > 0.0) {
        return [1.0, 0.0, 0.0];
    }
    // A faint gradient is the estimate's own noise, not an edge: the coherence
    // counts in proportion to the edge's strength against EDGE_CONTRAST.
    let strength = l1 / (l1 + EDGE_CONTRAST * EDGE_CONTRAST);
    let coherence = ((l1 - l2) / (l1 + l2)).clamp(0.0, 1.0) * strength;
    // The eigenvector of the larger eigenvalue: across the edge.
    let (vx, vy) = if b.abs() > 1e-12 * l1 {
        (l1 - c, b)
    } else if a >= c {
        (1.0, 0.0)
    } else {
        (0.0, 1.0)
    };
    let norm = (vx * vx + vy * vy).sqrt();
    if norm.is_nan() || norm <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    [vx / norm, vy / norm, coherence]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples one per pixel at seeded random positions, coloured 1 above the line
    /// `y = y0 + slope x` and 0.05 below it.
    fn edge_samples(
        n: usize,
        y0: f32,
        slope: f32,
        seed: u64,
    ) -> (Vec<Option<[f32; 2]>>, Vec<[f32; 4]>) {
        let mut state = seed;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 40) as f32) / (1u64 << 24) as f32
        };
        let mut positions = Vec::new();
        let mut colors = Vec::new();
        for y in 0..n {
            for x in 0..n {
                // A lens offset of up to a pixel each way: no longer one sample per pixel.
                let q = [
                    x as f32 + 0.5 + 2.0 * next() - 1.0,
                    y as f32 + 0.5 + 2.0 * next() - 1.0,
                ];
                let v = if q[1] < y0 + slope * q[0] { 1.0 } else { 0.05 };
                positions.push(Some(q));
                colors.push([v, v, v, 1.0]);
            }
        }
        (positions, colors)
    }

    /// The samples put on the grid and normalised: each pixel's value.
    fn splat(
        n: usize,
        positions: &[Option<[f32; 2]>],
        colors: &[[f32; 4]],
        field: Option<&EdgeField>,
    ) -> Vec<f32> {
        let (mut sum, mut weight) = (vec![0.0f32; n * n], vec![0.0f32; n * n]);
        for (q, c) in positions.iter().zip(colors) {
            let [qx, qy] = q.expect("placed");
            let mut add = |x: f32, y: f32, share: f32| {
                if x >= 0.0 && y >= 0.0 && (x as usize) < n && (y as usize) < n {
                    sum[y as usize * n + x as usize] += share * c[0];
                    weight[y as usize * n + x as usize] += share;
                }
            };
            match field {
                Some(f) => f.push_steered(qx, qy, 0.6, &mut add),
                None => push_footprint(qx, qy, 0.6, 0.6, [1.0, 0.0], &mut add),
            }
        }
        sum.iter()
            .zip(&weight)
            .map(|(s, w)| s / w.max(1e-6))
            .collect()
    }

    /// Root mean square of the columns' edge positions (where each column's value crosses
    /// the middle level, found by linear interpolation) off the true line, over the inner
    /// columns.
    fn edge_error(n: usize, image: &[f32], y0: f32, slope: f32) -> f32 {
        let mid = 0.525;
        let mut sq = 0.0f32;
        let mut count = 0;
        for x in 8..n - 8 {
            let col: Vec<f32> = (0..n).map(|y| image[y * n + x]).collect();
            let truth = y0 + slope * (x as f32 + 0.5);
            let from = (truth as usize).saturating_sub(6);
            let Some(k) =
                (from..(from + 12).min(n - 1)).find(|&k| col[k] >= mid && col[k + 1] < mid)
            else {
                continue;
            };
            let crossing = k as f32 + 0.5 + (col[k] - mid) / (col[k] - col[k + 1]);
            sq += (crossing - truth).powi(2);
            count += 1;
        }
        (sq / count.max(1) as f32).sqrt()
    }

    /// A straight edge from scattered samples: stretched along it, the footprints put it back
    /// at least 15 % closer to the true line than round ones (RMS over the columns), for a
    /// level edge and a slanted one.
    #[test]
    fn steered_footprints_straighten_a_torn_edge() {
        let n = 64;
        for (y0, slope) in [(31.3f32, 0.0f32), (20.0, 0.37)] {
            let (positions, colors) = edge_samples(n, y0, slope, 7);
            let field = EdgeField::from_samples(n, n, &positions, &colors, 0.6);
            let round = edge_error(n, &splat(n, &positions, &colors, None), y0, slope);
            let steered = edge_error(n, &splat(n, &positions, &colors, Some(&field)), y0, slope);
            assert!(
                steered < 0.85 * round,
                "edge y = {y0} + {slope} x: {steered:.3} px off steered, {round:.3} px round"
            );
        }
    }

    /// The shares of a steered footprint sum to one and keep its centre, at any coherence.
    #[test]
    fn a_steered_footprint_keeps_weight_and_position() {
        for (sigma_along, across) in [
            (0.6f32, [1.0f32, 0.0f32]),
            (2.4, [0.6, 0.8]),
            (1.5, [0.0, 1.0]),
        ] {
            let (mut total, mut mx, mut my) = (0.0f32, 0.0f32, 0.0f32);
            push_footprint(10.3, 20.7, 0.6, sigma_along, across, |x, y, s| {
                total += s;
                mx += s * (x + 0.5);
                my += s * (y + 0.5);
            });
            assert!((total - 1.0).abs() < 1e-5, "{total}");
            assert!(
                (mx - 10.3).abs() < 0.05 && (my - 20.7).abs() < 0.05,
                "({mx}, {my})"
            );
        }
    }

    /// A flat frame has no edge: the footprint stays round.
    #[test]
    fn a_flat_frame_keeps_round_footprints() {
        let n = 16;
        let positions: Vec<Option<[f32; 2]>> = (0..n * n)
            .map(|i| Some([(i % n) as f32 + 0.5, (i / n) as f32 + 0.5]))
            .collect();
        let colors = vec![[0.4f32, 0.4, 0.4, 1.0]; n * n];
        let field = EdgeField::from_samples(n, n, &positions, &colors, 0.6);
        let (_, coherence) = field.at(8.0, 8.0);
        assert_eq!(coherence, 0.0);
    }
}
