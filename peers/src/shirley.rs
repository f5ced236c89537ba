//! Shirley, Aila, Cohen, Enderton, Laine, Luebke, McGuire 2011, "A local image reconstruction
//! algorithm for stochastic rendering": a per-pixel front-to-back sweep over the depth-sorted
//! samples of a fixed neighbourhood, mixing box filters of a few widths by accumulated
//! coverage.
//!
//! Choices where the text leaves a detail open (see `docs/PEERS.md`):
//! - the denoising diameter is `D = max(2 |coc|, |motion| * shutter_frames)` (Appendix A's
//!   default, "if motion blur is to be smoothed"; `smooth_motion = false` drops the motion);
//! - sample positions are measured from the pixel centre; the neighbourhood is the widest box
//!   (5x5 or 7x7 pixels), clipped at the image border (no renormalisation: the sweep divides
//!   by its own accumulated weight);
//! - the sort is by depth, ties by sample index (deterministic); accumulation in f64;
//! - [`TwoScaleBlend::Step`] is the paper's Algorithm 2 with the 5x5 box as the wide filter
//!   (`D >= threshold` picks it); [`TwoScaleBlend::Linear`] is Appendix A verbatim.

use crate::inputs::{Image, SampleView};
use crate::PeerError;
use rayon::prelude::*;

/// How the two-scale variant turns a diameter into its share of the wide (5x5) filter.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum TwoScaleBlend {
    /// Appendix A: `blend = clamp((D - start) / width, 0, 1)`; the paper's code has
    /// `start = 1`, `width = 5` (pixels).
    Linear {
        /// Diameter (px) where blending starts.
        start: f32,
        /// Diameter range (px) over which the share grows from 0 to 1.
        width: f32,
    },
    /// Algorithm 2: the wide filter iff `D >= threshold` (px).
    Step {
        /// Diameter threshold in pixels.
        threshold: f32,
    },
}

/// Which of the paper's two code samples.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum ShirleyVariant {
    /// Appendix A: 1x1 and 5x5 boxes.
    TwoScale(TwoScaleBlend),
    /// Appendix B: 1x1, 3x3, 5x5 and 7x7 boxes, picked by `D > 7`, `> 5`, `> 3`.
    FourScale,
}

/// Parameters of [`shirley`] and [`shirley_layered_defocus`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShirleyParams {
    /// Default: two scales with Appendix A's linear blend.
    pub variant: ShirleyVariant,
    /// Include the motion length over the shutter in the denoising diameter. Default true.
    pub smooth_motion: bool,
}

impl Default for ShirleyParams {
    fn default() -> Self {
        ShirleyParams {
            variant: ShirleyVariant::TwoScale(TwoScaleBlend::Linear {
                start: 1.0,
                width: 5.0,
            }),
            smooth_motion: true,
        }
    }
}

impl ShirleyParams {
    fn validate(&self) -> Result<(), PeerError> {
        match self.variant {
            ShirleyVariant::TwoScale(TwoScaleBlend::Linear { start, width }) => {
                if !(start.is_finite() && width.is_finite() && width > 0.0) {
                    return Err(PeerError::BadParam {
                        name: "blend",
                        why: "start finite, width finite and > 0",
                    });
                }
            }
            ShirleyVariant::TwoScale(TwoScaleBlend::Step { threshold }) => {
                if !threshold.is_finite() {
                    return Err(PeerError::BadParam {
                        name: "threshold",
                        why: "must be finite",
                    });
                }
            }
            ShirleyVariant::FourScale => {}
        }
        Ok(())
    }

    /// Half-widths (px) of the boxes, narrowest first.
    fn radii(&self) -> &'static [f32] {
        match self.variant {
            ShirleyVariant::TwoScale(_) => &[0.5, 2.5],
            ShirleyVariant::FourScale => &[0.5, 1.5, 2.5, 3.5],
        }
    }

    /// Index of the box a sample of diameter `d` uses, for the one-hot selections.
    fn scale_of(&self, d: f32) -> usize {
        match self.variant {
            ShirleyVariant::TwoScale(TwoScaleBlend::Step { threshold }) => {
                usize::from(d >= threshold)
            }
            ShirleyVariant::TwoScale(TwoScaleBlend::Linear { start, width }) => {
                usize::from((d - start) / width >= 1.0)
            }
            ShirleyVariant::FourScale => {
                if d > 7.0 {
                    3
                } else if d > 5.0 {
                    2
                } else if d > 3.0 {
                    1
                } else {
                    0
                }
            }
        }
    }
}

/// A sample relative to the pixel being reconstructed.
#[derive(Clone, Copy)]
struct Local {
    dx: f32,
    dy: f32,
    depth: f32,
    diameter: f32,
    coc: f32,
    color: [f32; 4],
    index: usize,
}

fn box_weight(d: f32, radius: f32) -> f64 {
    if d.abs() < radius {
        0.5 / radius as f64
    } else {
        0.0
    }
}

fn gather(s: &SampleView, p: &ShirleyParams, x: usize, y: usize, reach: usize) -> Vec<Local> {
    let mut out = Vec::with_capacity((2 * reach + 1).pow(2) * s.spp);
    let x0 = x.saturating_sub(reach);
    let y0 = y.saturating_sub(reach);
    let x1 = (x + reach).min(s.width - 1);
    let y1 = (y + reach).min(s.height - 1);
    for py in y0..=y1 {
        for px in x0..=x1 {
            let base = (py * s.width + px) * s.spp;
            for (k, smp) in s.samples[base..base + s.spp].iter().enumerate() {
                let motion_len = if p.smooth_motion {
                    (smp.motion[0].hypot(smp.motion[1])) * s.shutter_frames
                } else {
                    0.0
                };
                out.push(Local {
                    dx: px as f32 - x as f32 + smp.jitter[0],
                    dy: py as f32 - y as f32 + smp.jitter[1],
                    depth: smp.depth,
                    diameter: (2.0 * smp.coc.abs()).max(motion_len),
                    coc: smp.coc,
                    color: smp.color,
                    index: base + k,
                });
            }
        }
    }
    out
}

/// The per-pixel sorted sweep (Appendix A or B verbatim).
fn sweep_pixel(mut samples: Vec<Local>, p: &ShirleyParams, spp: usize) -> [f32; 4] {
    samples.sort_by(|a, b| a.depth.total_cmp(&b.depth).then(a.index.cmp(&b.index)));
    let radii = p.radii();
    let ns = spp as f64;
    let mut cov = [0.0f64; 4];
    let mut total = 0.0f64;
    let mut sum = [0.0f64; 4];
    for s in &samples {
        let mut wm = [0.0f64; 4];
        for (m, r) in radii.iter().enumerate() {
            wm[m] = box_weight(s.dx, *r) * box_weight(s.dy, *r) / ns;
        }
        let w = match p.variant {
            ShirleyVariant::TwoScale(TwoScaleBlend::Linear { start, width }) => {
                // Appendix A, in its order: the wide update first, the narrow one sees it.
                let blend = ((s.diameter - start) / width).clamp(0.0, 1.0) as f64;
                let mut w = blend * (wm[1] * (1.0 - cov[0]) + wm[0] * cov[0]);
                cov[1] += blend * (wm[1] * (1.0 - cov[0]));
                w += (1.0 - blend) * (wm[0] * (1.0 - cov[1]) + wm[1] * cov[1]);
                cov[0] += (1.0 - blend) * (wm[0] * (1.0 - cov[1]));
                w
            }
            _ => {
                // Algorithm 2 / Appendix B: one scale k per sample.
                let k = p.scale_of(s.diameter);
                let others: f64 = (0..radii.len()).filter(|&m| m != k).map(|m| cov[m]).sum();
                let mixed: f64 = (0..radii.len())
                    .filter(|&m| m != k)
                    .map(|m| wm[m] * cov[m])
                    .sum();
                cov[k] += wm[k] * (1.0 - others);
                wm[k] * (1.0 - others) + mixed
            }
        };
        total += w;
        for (acc, c) in sum.iter_mut().zip(s.color) {
            *acc += w * c as f64;
        }
    }
    if total <= 0.0 {
        return [0.0; 4];
    }
    sum.map(|v| (v / total) as f32)
}

fn reach(p: &ShirleyParams) -> usize {
    match p.variant {
        ShirleyVariant::TwoScale(_) => 2,
        ShirleyVariant::FourScale => 3,
    }
}

/// Shirley 2011 reconstruction: depth-sorted front-to-back sweep per pixel.
/// Returns premultiplied RGBA, width x height.
pub fn shirley(s: &SampleView, p: &ShirleyParams) -> Result<Image, PeerError> {
    s.validate()?;
    p.validate()?;
    let w = s.width;
    let reach = reach(p);
    let mut out = vec![[0.0f32; 4]; w * s.height];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            *o = sweep_pixel(gather(s, p, x, y, reach), p, s.spp);
        }
    });
    Ok(out)
}

/// The paper's layered shortcut for defocus only (Sec. 3.1, last paragraph): no sort; the
/// samples are binned into depth layers in which every sample uses the same box (the near
/// out-of-focus layers, the in-focus layer, the far ones, ordered by signed CoC), the box sums
/// are accumulated per layer and the layers combined front to back. Equal to [`shirley`] up to
/// rounding when the CoC grows monotonically away from the focus plane with depth (thin lens).
///
/// Needs a one-hot scale choice (`TwoScaleBlend::Step` or `FourScale`) and no motion blur
/// to smooth (`smooth_motion = false` or still samples): otherwise `PeerError::Unsupported`.
pub fn shirley_layered_defocus(s: &SampleView, p: &ShirleyParams) -> Result<Image, PeerError> {
    s.validate()?;
    p.validate()?;
    if matches!(
        p.variant,
        ShirleyVariant::TwoScale(TwoScaleBlend::Linear { .. })
    ) {
        return Err(PeerError::Unsupported(
            "the layered shortcut needs a one-hot scale (Step or FourScale)",
        ));
    }
    if p.smooth_motion
        && s.shutter_frames > 0.0
        && s.samples
            .iter()
            .any(|x| x.motion[0] != 0.0 || x.motion[1] != 0.0)
    {
        return Err(PeerError::Unsupported(
            "the layered shortcut is for defocus only (samples move)",
        ));
    }
    let w = s.width;
    let reach = reach(p);
    let n_scales = p.radii().len();
    let n_layers = 2 * n_scales - 1;
    let mut out = vec![[0.0f32; 4]; w * s.height];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            // Per layer: sum of each box's weight, and of weight times colour.
            let mut wsum = vec![[0.0f64; 4]; n_layers];
            let mut csum = vec![[[0.0f64; 4]; 4]; n_layers];
            let mut layer_scale = vec![0usize; n_layers];
            for smp in gather(s, p, x, y, reach) {
                let k = p.scale_of(smp.diameter);
                let layer = if k == 0 {
                    n_scales - 1
                } else if smp.coc < 0.0 {
                    n_scales - 1 - k
                } else {
                    n_scales - 1 + k
                };
                layer_scale[layer] = k;
                for (m, r) in p.radii().iter().enumerate() {
                    let wm = box_weight(smp.dx, *r) * box_weight(smp.dy, *r) / s.spp as f64;
                    wsum[layer][m] += wm;
                    for (acc, c) in csum[layer][m].iter_mut().zip(smp.color) {
                        *acc += wm * c as f64;
                    }
                }
            }
            let mut cov = [0.0f64; 4];
            let mut total = 0.0f64;
            let mut sum = [0.0f64; 4];
            for layer in 0..n_layers {
                let k = layer_scale[layer];
                let others: f64 = (0..n_scales).filter(|&m| m != k).map(|m| cov[m]).sum();
                total += wsum[layer][k] * (1.0 - others);
                for ch in 0..4 {
                    sum[ch] += csum[layer][k][ch] * (1.0 - others);
                }
                for m in (0..n_scales).filter(|&m| m != k) {
                    total += wsum[layer][m] * cov[m];
                    for ch in 0..4 {
                        sum[ch] += csum[layer][m][ch] * cov[m];
                    }
                }
                cov[k] += wsum[layer][k] * (1.0 - others);
            }
            *o = if total > 0.0 {
                sum.map(|v| (v / total) as f32)
            } else {
                [0.0; 4]
            };
        }
    });
    Ok(out)
}
