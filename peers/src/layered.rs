//! The layered reconstruction engine shared by Vaidyanathan et al. 2015 and Munkberg et al.
//! 2014: per screen tile, the samples of a window around it are partitioned into depth layers
//! (by signed CoC), each layer is reprojected (splatted to its sheared position, weighted by
//! the lens/shutter Gaussians, with the hole count of the layers behind), filtered by a
//! separable (possibly rotated) screen Gaussian, normalised, and the layers are composited
//! front to back (Vaidyanathan Eq. 35, Algorithm 2; Munkberg Algorithms 1 and 2, Eq. 17).

use crate::inputs::{Image, Sample, SampleView};
use crate::PeerError;
use rayon::prelude::*;

/// Which of the filter shapes a layer got.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FilterCase {
    /// Vaidyanathan's sheared filter (Eq. 15/23); Munkberg's clip against the lens bandlimit.
    Sheared,
    /// Vaidyanathan's small-shear filter (Eq. 28); Munkberg's clip against the pixel bandlimit.
    SmallShear,
    /// Vaidyanathan's axis-aligned fallback (Eq. 11).
    AxisAligned,
    /// Munkberg's clip against the shutter bandlimit (motion dominates).
    TimeSheared,
    /// Munkberg: motion too varied within the layer, motion filter disabled (small filter).
    MotionDisabled,
}

/// A layer's reconstruction filter in the form both papers reduce to:
/// `w(a + eta lu + xi t; sigma_along) w(b + rho lv; sigma_perp) w(lu; sigma_u) w(lv; sigma_v)
/// w(t; sigma_t)`, where `(a, b)` and `(lu, lv)` are screen and lens coordinates in the frame
/// rotated by `angle` (the along axis is `(cos angle, sin angle)` in image coordinates).
/// A sigma of `f32::INFINITY` is a flat weight.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LayerFilter {
    /// Rotation of the filter frame, radians (0 for defocus only).
    pub angle: f32,
    /// Screen shift along the frame's first axis per unit of lens coordinate (px).
    pub eta: f32,
    /// Screen shift along the second axis per unit of lens coordinate (px).
    pub rho: f32,
    /// Screen shift along the first axis per frame of time (px / frame).
    pub xi: f32,
    /// Lens weight widths (unit-disk lens units) along the two axes.
    pub sigma_u: f32,
    /// See `sigma_u`.
    pub sigma_v: f32,
    /// Shutter weight width in frames.
    pub sigma_t: f32,
    /// Screen Gaussian widths (px) along the two axes.
    pub sigma_along: f32,
    /// See `sigma_along`.
    pub sigma_perp: f32,
    /// Which case produced it.
    pub case: FilterCase,
}

/// How many layers used which filter, summed over tiles.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct LayerReport {
    /// Active (tile, layer) pairs.
    pub layers: usize,
    /// Layers with [`FilterCase::Sheared`].
    pub sheared: usize,
    /// Layers with [`FilterCase::SmallShear`].
    pub small_shear: usize,
    /// Layers with [`FilterCase::AxisAligned`].
    pub axis_aligned: usize,
    /// Layers with [`FilterCase::TimeSheared`].
    pub time_sheared: usize,
    /// Layers with [`FilterCase::MotionDisabled`].
    pub motion_disabled: usize,
}

impl LayerReport {
    fn add(&mut self, case: FilterCase) {
        self.layers += 1;
        match case {
            FilterCase::Sheared => self.sheared += 1,
            FilterCase::SmallShear => self.small_shear += 1,
            FilterCase::AxisAligned => self.axis_aligned += 1,
            FilterCase::TimeSheared => self.time_sheared += 1,
            FilterCase::MotionDisabled => self.motion_disabled += 1,
        }
    }

    fn merge(mut self, o: LayerReport) -> LayerReport {
        self.layers += o.layers;
        self.sheared += o.sheared;
        self.small_shear += o.small_shear;
        self.axis_aligned += o.axis_aligned;
        self.time_sheared += o.time_sheared;
        self.motion_disabled += o.motion_disabled;
        self
    }
}

/// Depth partitions as ascending boundaries in signed CoC (pixels): partition `k` holds CoCs in
/// `[b[k-1], b[k])`, with open ends. Front to back is ascending CoC.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Partitions {
    /// Strictly ascending, finite.
    pub boundaries: Vec<f32>,
}

impl Partitions {
    /// Vaidyanathan Sec. 6.2: boundaries with a constant worst-case filter energy
    /// `sigma_x sigma_u`, i.e. (from Eq. 16) equally spaced in `1/c`: on each side
    /// `c_k = c_first (n - 1) / (n - 1 - k)`, `k = 0..n-1`, quantised to multiples of
    /// `quantum` px (duplicates dropped), mirrored to negative CoC. The central partition
    /// `[-c_first, c_first)` straddles the focus plane. The paper uses 15 per side and
    /// 0.5 px bins but gives no `c_first`; we take `c_first = 1` px.
    pub fn constant_energy(per_side: usize, c_first: f32, quantum: f32) -> Partitions {
        let n = per_side.max(2);
        let mut pos: Vec<f32> = (0..n - 1)
            .map(|k| c_first * (n - 1) as f32 / (n - 1 - k) as f32)
            .map(|c| {
                if quantum > 0.0 {
                    (c / quantum).round() * quantum
                } else {
                    c
                }
            })
            .collect();
        pos.dedup();
        let mut b: Vec<f32> = pos.iter().rev().map(|c| -c).collect();
        b.extend(pos);
        Partitions { boundaries: b }
    }

    pub(crate) fn validate(&self) -> Result<(), PeerError> {
        if self.boundaries.len() > 1024 {
            return Err(PeerError::BadParam {
                name: "partitions",
                why: "at most 1024 boundaries",
            });
        }
        if self.boundaries.iter().any(|b| !b.is_finite())
            || self.boundaries.windows(2).any(|w| w[0] >= w[1])
        {
            return Err(PeerError::BadParam {
                name: "partitions",
                why: "boundaries must be finite and strictly ascending",
            });
        }
        Ok(())
    }

    /// Partition index of a signed CoC.
    pub fn index(&self, coc: f32) -> usize {
        self.boundaries.partition_point(|b| *b <= coc)
    }
}

impl Default for Partitions {
    fn default() -> Self {
        Partitions::constant_energy(15, 1.0, 0.5)
    }
}

/// Gaussian weight without normalisation; an infinite sigma is flat.
pub(crate) fn gauss(x: f32, sigma: f32) -> f32 {
    if sigma.is_infinite() {
        1.0
    } else if sigma <= 0.0 {
        if x == 0.0 {
            1.0
        } else {
            0.0
        }
    } else {
        (-0.5 * (x / sigma) * (x / sigma)).exp()
    }
}

/// Tiling of the engine.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Tiling {
    pub tile: usize,
    pub ring: usize,
}

/// Six accumulated quantities per cell: opacity, RGBA irradiance, weight (with holes).
type Cell = [f32; 6];

fn fetch_bilinear(grid: &[Cell], gw: usize, gh: usize, x: f32, y: f32) -> Cell {
    let x0 = x.floor();
    let y0 = y.floor();
    let fx = x - x0;
    let fy = y - y0;
    let mut out = [0.0f32; 6];
    for (dy, wy) in [(0.0, 1.0 - fy), (1.0, fy)] {
        for (dx, wx) in [(0.0, 1.0 - fx), (1.0, fx)] {
            let w = wx * wy;
            if w == 0.0 {
                continue;
            }
            let (cx, cy) = (x0 + dx, y0 + dy);
            if cx < 0.0 || cy < 0.0 || cx >= gw as f32 || cy >= gh as f32 {
                continue;
            }
            let c = &grid[cy as usize * gw + cx as usize];
            for k in 0..6 {
                out[k] += w * c[k];
            }
        }
    }
    out
}

fn kernel(sigma: f32, radius: usize) -> Vec<f32> {
    (0..=2 * radius)
        .map(|k| gauss(k as f32 - radius as f32, sigma))
        .collect()
}

/// Runs the engine; `build` turns the samples of one layer into its filter.
pub(crate) fn reconstruct<F>(
    s: &SampleView,
    tiling: Tiling,
    partitions: &Partitions,
    build: F,
) -> Result<(Image, LayerReport), PeerError>
where
    F: Fn(&[Sample]) -> LayerFilter + Sync,
{
    s.validate()?;
    partitions.validate()?;
    if tiling.tile == 0 || tiling.tile > 1024 || tiling.ring > 1024 {
        return Err(PeerError::BadParam {
            name: "tile",
            why: "tile in 1..=1024, ring <= 1024",
        });
    }
    let (w, h) = (s.width, s.height);
    let (t, ring) = (tiling.tile, tiling.ring);
    let tw = w.div_ceil(t);
    let th = h.div_ceil(t);
    let tiles: Vec<(usize, usize)> = (0..th).flat_map(|y| (0..tw).map(move |x| (x, y))).collect();
    let results: Vec<(Vec<[f32; 4]>, LayerReport)> = tiles
        .par_iter()
        .map(|&(tx, ty)| reconstruct_tile(s, tx * t, ty * t, t, ring, partitions, &build))
        .collect();
    let mut out = vec![[0.0f32; 4]; w * h];
    let mut report = LayerReport::default();
    for (&(tx, ty), (pixels, rep)) in tiles.iter().zip(results) {
        let (x0, y0) = (tx * t, ty * t);
        let iw = (x0 + t).min(w) - x0;
        for (k, p) in pixels.into_iter().enumerate() {
            out[(y0 + k / iw) * w + x0 + k % iw] = p;
        }
        report = report.merge(rep);
    }
    Ok((out, report))
}

fn reconstruct_tile<F>(
    s: &SampleView,
    x0: usize,
    y0: usize,
    t: usize,
    ring: usize,
    partitions: &Partitions,
    build: &F,
) -> (Vec<[f32; 4]>, LayerReport)
where
    F: Fn(&[Sample]) -> LayerFilter,
{
    let (w, h) = (s.width, s.height);
    let ix1 = (x0 + t).min(w);
    let iy1 = (y0 + t).min(h);
    let wx0 = x0.saturating_sub(ring);
    let wy0 = y0.saturating_sub(ring);
    let wx1 = (ix1 + ring).min(w);
    let wy1 = (iy1 + ring).min(h);
    let (gw, gh) = (wx1 - wx0, wy1 - wy0);
    let (iw, ih) = (ix1 - x0, iy1 - y0);

    // The window's samples with their partitions.
    let mut window: Vec<(Sample, [f32; 2], usize)> = Vec::with_capacity(gw * gh * s.spp);
    for py in wy0..wy1 {
        for px in wx0..wx1 {
            let base = (py * w + px) * s.spp;
            for smp in &s.samples[base..base + s.spp] {
                let pos = [
                    px as f32 + 0.5 + smp.jitter[0],
                    py as f32 + 0.5 + smp.jitter[1],
                ];
                window.push((*smp, pos, partitions.index(smp.coc)));
            }
        }
    }
    let mut active: Vec<usize> = window.iter().map(|e| e.2).collect();
    active.sort_unstable();
    active.dedup();

    let mut report = LayerReport::default();
    let mut color = vec![[0.0f32; 4]; iw * ih];
    let mut visibility = vec![1.0f32; iw * ih];
    let mut grid = vec![[0.0f32; 6]; gw * gh];
    let mut pass1 = vec![[0.0f32; 6]; gw * gh];
    for &layer in &active {
        let members: Vec<Sample> = window
            .iter()
            .filter(|e| e.2 == layer)
            .map(|e| e.0)
            .collect();
        let f = build(&members);
        report.add(f.case);
        let (ca, sa) = (f.angle.cos(), f.angle.sin());

        // Reprojection (splat) with the hole count.
        grid.iter_mut().for_each(|c| *c = [0.0; 6]);
        for (smp, pos, k) in &window {
            if *k < layer {
                continue;
            }
            // The papers write the pinhole position as `x + c u`; our samples (the scene
            // crate's convention) land at pinhole + c lens, so their `u` is `-lens`.
            let (u, v) = (-smp.lens[0], -smp.lens[1]);
            let lu = ca * u + sa * v;
            let lv = -sa * u + ca * v;
            let along = f.eta * lu + f.xi * smp.time;
            let perp = f.rho * lv;
            let qx = pos[0] + along * ca - perp * sa;
            let qy = pos[1] + along * sa + perp * ca;
            let (bx, by) = (qx.floor() - wx0 as f32, qy.floor() - wy0 as f32);
            if bx < 0.0 || by < 0.0 || bx >= gw as f32 || by >= gh as f32 {
                continue;
            }
            let wgt = gauss(lu, f.sigma_u) * gauss(lv, f.sigma_v) * gauss(smp.time, f.sigma_t);
            let cell = &mut grid[by as usize * gw + bx as usize];
            if *k == layer {
                cell[0] += wgt;
                for ch in 0..4 {
                    cell[1 + ch] += wgt * smp.color[ch];
                }
            }
            cell[5] += wgt;
        }

        // Separable screen Gaussian: along the frame's first axis over the whole window, then
        // along the second for the inner tile. Radius: 3 sigma, at most the ring.
        let r1 = ((3.0 * f.sigma_along).ceil() as usize).min(ring);
        let r2 = ((3.0 * f.sigma_perp).ceil() as usize).min(ring);
        let k1 = kernel(f.sigma_along, r1);
        let k2 = kernel(f.sigma_perp, r2);
        for gy in 0..gh {
            for gx in 0..gw {
                let mut acc = [0.0f32; 6];
                for (i, kw) in k1.iter().enumerate() {
                    let d = i as f32 - r1 as f32;
                    let c = fetch_bilinear(&grid, gw, gh, gx as f32 + d * ca, gy as f32 + d * sa);
                    for q in 0..6 {
                        acc[q] += kw * c[q];
                    }
                }
                pass1[gy * gw + gx] = acc;
            }
        }
        for py in 0..ih {
            for px in 0..iw {
                let (gx, gy) = ((x0 + px - wx0) as f32, (y0 + py - wy0) as f32);
                let mut acc = [0.0f32; 6];
                for (i, kw) in k2.iter().enumerate() {
                    let d = i as f32 - r2 as f32;
                    let c = fetch_bilinear(&pass1, gw, gh, gx - d * sa, gy + d * ca);
                    for q in 0..6 {
                        acc[q] += kw * c[q];
                    }
                }
                if acc[5] <= 0.0 {
                    continue;
                }
                let o = py * iw + px;
                let alpha = (acc[0] / acc[5]).clamp(0.0, 1.0);
                for ch in 0..4 {
                    color[o][ch] += visibility[o] * acc[1 + ch] / acc[5];
                }
                visibility[o] *= 1.0 - alpha;
            }
        }
    }
    (color, report)
}
