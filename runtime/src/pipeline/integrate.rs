//! Stage 3, integration: each Laplacian plane is turned back into an image (convolution
//! pyramid or the exact lattice inverse, both from `poisson`), then the layer's direct plane
//! (fast-track PSFs and copies) is added.

use poisson::{ExactIntegrator, Plane, PyramidWorkspace};
use rayon::prelude::*;

use super::splat::LayerStack;
use super::types::FrameParams;

/// Which Poisson integrator to use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Integrator {
    /// Convolution pyramid (Farbman et al. 2011), fast, approximate.
    Pyramid,
    /// The lattice Green's function by FFT (f64): exact to rounding. The default: the
    /// pyramid's small relative error becomes visible around HDR highlights.
    #[default]
    Exact,
}

/// Primal layers: per layer four planes (R, G, B, A), padded.
#[derive(Clone, Debug, PartialEq)]
pub struct IntegratedLayers {
    /// Frame constants.
    pub frame: FrameParams,
    /// Index `layer * 4 + channel`, `padded_width x padded_height`, or empty (0x0) for an
    /// empty layer.
    pub planes: Vec<Plane>,
    /// Per layer, the padded rows `[first, end)` outside which its planes are zero, which
    /// compositing skips; empty when every layer may cover every row.
    pub rows: Vec<[usize; 2]>,
}

/// Integrates every non-empty Laplacian plane with `integrator` and adds the direct planes.
pub fn integrate(stack: &LayerStack, integrator: Integrator) -> IntegratedLayers {
    integrate_owned(stack.clone(), integrator)
}

/// [`integrate`], taking the stack: a layer's direct plane becomes its primal plane where the
/// layer has no Laplacian one, moved rather than copied (a frame drawn all dense, as a
/// defocused surface with small CoCs is, copies nothing).
pub fn integrate_owned(stack: LayerStack, integrator: Integrator) -> IntegratedLayers {
    let mut layers = integrate_laplacians(&stack, integrator);
    layers.rows = rows_of(&stack);
    for (primal, direct) in layers.planes.iter_mut().zip(stack.direct) {
        if direct.is_empty() {
            continue;
        }
        if primal.is_empty() {
            *primal = direct;
        } else {
            for (a, b) in primal.data.iter_mut().zip(&direct.data) {
                *a += b;
            }
        }
    }
    layers
}

/// Per layer, the rows its primal planes may be non-zero in: every row where it has a
/// Laplacian plane (integration spreads it over the frame), else its direct planes' rows.
fn rows_of(stack: &LayerStack) -> Vec<[usize; 2]> {
    let height = stack.frame.padded_height as usize;
    (0..stack.frame.layers as usize)
        .map(|l| {
            let has_laplacian = stack.laplacian.get(l * 4).is_some_and(|p| !p.is_empty());
            match stack.direct_rows.get(l) {
                Some(&rows) if !has_laplacian => rows,
                _ => [0, height],
            }
        })
        .collect()
}

/// The primal planes of the stack's Laplacian planes (empty where a layer has none).
fn integrate_laplacians(stack: &LayerStack, integrator: Integrator) -> IntegratedLayers {
    let frame = stack.frame;
    let (pw, ph) = (frame.padded_width as usize, frame.padded_height as usize);
    let exact = (integrator == Integrator::Exact && stack.laplacian.iter().any(|p| !p.is_empty()))
        .then(|| ExactIntegrator::new(pw, ph));
    let planes: Vec<Plane> = stack
        .laplacian
        .par_iter()
        .map_init(
            || None::<PyramidWorkspace>,
            |workspace, lap| {
                if lap.is_empty() {
                    return Plane::default();
                }
                match &exact {
                    Some(e) => e.integrate(lap),
                    None => workspace
                        .get_or_insert_with(|| PyramidWorkspace::new(pw, ph))
                        .integrate(lap),
                }
            },
        )
        .collect();
    IntegratedLayers {
        frame,
        planes,
        rows: Vec::new(),
    }
}

/// Adds the layers of a coarse level ([`super::types::CoarseLevel`], `scale` frame pixels per
/// coarse pixel along each axis) to `fine`'s frame, upsampled bilinearly: frame pixel `x`
/// reads the coarse layer at `(x + 0.5) / scale - 0.5`, the centre of its coarse pixel
/// landing on the centre of the `scale` frame pixels it covers. Values are per pixel, so the
/// light of a coarse pixel lands on its `scale^2` frame pixels (the level's colours are
/// divided by `scale^2`). Only the frame is written: compositing reads nothing else.
pub fn add_upsampled(fine: &mut IntegratedLayers, coarse: &IntegratedLayers, scale: u32) {
    let f = fine.frame;
    let c = coarse.frame;
    let (w, h) = (f.width as usize, f.height as usize);
    let (fpw, fph) = (f.padded_width as usize, f.padded_height as usize);
    let (cpw, cph, cpad) = (
        c.padded_width as usize,
        c.padded_height as usize,
        c.pad as f32,
    );
    let s = scale as f32;
    // Per frame column (and row): the first coarse padded column read and its weight.
    let taps = |n: usize, padded: usize| -> Vec<(usize, f32)> {
        (0..n)
            .map(|x| {
                let u = ((x as f32 + 0.5) / s - 0.5 + cpad).clamp(0.0, (padded - 1) as f32);
                let i = (u.floor() as usize).min(padded.saturating_sub(2));
                (i, u - i as f32)
            })
            .collect()
    };
    let (xs, ys) = (taps(w, cpw), taps(h, cph));
    let pad = f.pad as usize;
    for (k, src) in coarse.planes.iter().enumerate() {
        if src.is_empty() {
            continue;
        }
        let dst = &mut fine.planes[k];
        if dst.is_empty() {
            *dst = Plane::new(fpw, fph);
        }
        dst.data
            .par_chunks_mut(fpw)
            .skip(pad)
            .take(h)
            .zip(&ys)
            .for_each(|(row, &(j, ty))| {
                let (r0, r1) = (&src.data[j * cpw..], &src.data[(j + 1) * cpw..]);
                for (dst, &(i, tx)) in row[pad..pad + w].iter_mut().zip(&xs) {
                    let top = r0[i] + tx * (r0[i + 1] - r0[i]);
                    let bottom = r1[i] + tx * (r1[i + 1] - r1[i]);
                    *dst += top + ty * (bottom - top);
                }
            });
        // Plane `k` is channel `k % 4` of layer `k / 4`.
        if let Some(rows) = fine.rows.get_mut(k / 4) {
            *rows = [0, fph];
        }
    }
}
