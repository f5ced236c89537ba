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
    /// Coarse levels whose layers add to these, upsampled bilinearly where a frame pixel is
    /// read ([`add_upsampled`], [`IntegratedLayers::layer_row`]); empty for most frames.
    pub coarse: Vec<UpsampledLevel>,
}

/// A coarse level's integrated layers ([`super::types::CoarseLevel`]) as the frame reads them:
/// frame pixel `x` reads the coarse layer at `(x + 0.5) / scale - 0.5`, bilinearly.
#[derive(Clone, Debug, PartialEq)]
pub struct UpsampledLevel {
    /// The level's layers, in its own padded frame.
    pub layers: IntegratedLayers,
    /// Frame pixels per coarse pixel along each axis.
    pub scale: u32,
    /// Per frame column, the first coarse padded column read and the second one's weight.
    columns: Vec<(usize, f32)>,
    /// Per frame row, the first coarse padded row read and the second one's weight.
    rows: Vec<(usize, f32)>,
}

impl UpsampledLevel {
    /// Adds frame row `y` (0 = the image's top row) of plane `k` (channel `k % 4` of layer
    /// `k / 4`), upsampled, to channel `k % 4` of `out` (one entry per image column). Nothing
    /// where the level has no such plane.
    fn add_row(&self, k: usize, y: usize, out: &mut [[f32; 4]]) {
        let Some(src) = self.layers.planes.get(k).filter(|p| !p.is_empty()) else {
            return;
        };
        let Some(&(j, ty)) = self.rows.get(y) else {
            return;
        };
        let cpw = self.layers.frame.padded_width as usize;
        let (r0, r1) = (&src.data[j * cpw..], &src.data[(j + 1) * cpw..]);
        let ch = k % 4;
        for (px, &(i, tx)) in out.iter_mut().zip(&self.columns) {
            let top = r0[i] + tx * (r0[i + 1] - r0[i]);
            let bottom = r1[i] + tx * (r1[i + 1] - r1[i]);
            px[ch] += top + ty * (bottom - top);
        }
    }
}

impl IntegratedLayers {
    /// Whether plane `k` (channel `k % 4` of layer `k / 4`) holds anything, here or in a
    /// coarse level.
    pub fn has_plane(&self, k: usize) -> bool {
        let drawn = |layers: &IntegratedLayers| layers.planes.get(k).is_some_and(|p| !p.is_empty());
        drawn(self) || self.coarse.iter().any(|level| drawn(&level.layers))
    }

    /// Whether layer `layer` has coarse levels' light to add to its own planes.
    pub fn has_coarse(&self, layer: usize) -> bool {
        self.coarse.iter().any(|level| {
            (0..4).any(|c| {
                level
                    .layers
                    .planes
                    .get(layer * 4 + c)
                    .is_some_and(|p| !p.is_empty())
            })
        })
    }

    /// Image row `y` (0 = top, unpadded) of layer `layer` as premultiplied RGBA, one entry per
    /// image column: its own planes (zero where it has none) plus every coarse level's,
    /// upsampled, added in the levels' order.
    pub fn layer_row(&self, layer: usize, y: usize, out: &mut [[f32; 4]]) {
        let f = self.frame;
        let (pw, pad) = (f.padded_width as usize, f.pad as usize);
        let start = (y + pad) * pw + pad;
        for c in 0..4 {
            match self.planes.get(layer * 4 + c).filter(|p| !p.is_empty()) {
                Some(plane) => {
                    for (px, &v) in out.iter_mut().zip(&plane.data[start..]) {
                        px[c] = v;
                    }
                }
                None => out.iter_mut().for_each(|px| px[c] = 0.0),
            }
        }
        for level in &self.coarse {
            for c in 0..4 {
                level.add_row(layer * 4 + c, y, out);
            }
        }
    }
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
        coarse: Vec::new(),
    }
}

/// Adds the layers of a coarse level ([`super::types::CoarseLevel`], `scale` frame pixels per
/// coarse pixel along each axis) to `fine`'s frame, upsampled bilinearly: frame pixel `x`
/// reads the coarse layer at `(x + 0.5) / scale - 0.5`, the centre of its coarse pixel
/// landing on the centre of the `scale` frame pixels it covers. Values are per pixel, so the
/// light of a coarse pixel lands on its `scale^2` frame pixels (the level's colours are
/// divided by `scale^2`). The level is kept and read upsampled where compositing reads a row
/// ([`IntegratedLayers::layer_row`]), not written into full-resolution planes: at 3840 x 2160
/// each such plane was 38 MB of fresh memory, and filling a dozen of them took most of a
/// second, nearly all of it first touches of new pages.
pub fn add_upsampled(fine: &mut IntegratedLayers, coarse: IntegratedLayers, scale: u32) {
    let f = fine.frame;
    let c = coarse.frame;
    let (w, h) = (f.width as usize, f.height as usize);
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
    let fph = f.padded_height as usize;
    for (k, plane) in coarse.planes.iter().enumerate() {
        // Plane `k` is channel `k % 4` of layer `k / 4`.
        if let (false, Some(rows)) = (plane.is_empty(), fine.rows.get_mut(k / 4)) {
            *rows = [0, fph];
        }
    }
    fine.coarse.push(UpsampledLevel {
        columns: taps(w, cpw),
        rows: taps(h, cph),
        layers: coarse,
        scale,
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::{composite, CompositeOptions};

    /// Layers whose planes hold `value(layer, channel, padded x, padded y)`, or none where
    /// `drawn(layer)` is false.
    fn layers_from(
        frame: FrameParams,
        drawn: impl Fn(usize) -> bool,
        value: impl Fn(usize, usize, usize, usize) -> f32,
    ) -> IntegratedLayers {
        let (pw, ph) = (frame.padded_width as usize, frame.padded_height as usize);
        let planes = (0..frame.layers as usize * 4)
            .map(|k| {
                if drawn(k / 4) {
                    Plane::from_fn(pw, ph, |x, y| value(k / 4, k % 4, x, y))
                } else {
                    Plane::default()
                }
            })
            .collect();
        IntegratedLayers {
            frame,
            planes,
            rows: vec![[0, 0]; frame.layers as usize],
            coarse: Vec::new(),
        }
    }

    /// Coarse levels at two scales, read upsampled row by row, add what a bilinear
    /// reading of each gives, computed here in f64: a plane that varies linearly is read back
    /// exactly at every frame pixel. A layer drawn only at a coarse level is composited, one
    /// drawn nowhere is not.
    #[test]
    fn coarse_levels_are_read_bilinearly_where_the_frame_reads_a_row() {
        let (w, h) = (12usize, 8usize);
        // Layer 0: its own planes and both levels; layer 1: only the scale-4 level; layer 2:
        // nothing anywhere.
        let fine_value =
            |l: usize, c: usize, x: usize, y: usize| (l + c) as f32 * 0.01 + (x * y) as f32 * 1e-3;
        let mut fine = layers_from(
            FrameParams::padded(w as u32, h as u32, 2, 3),
            |l| l == 0,
            fine_value,
        );
        let linear = |s: f32| {
            move |l: usize, c: usize, x: usize, y: usize| {
                0.1 * s + 0.02 * (l + c) as f32 + 0.03 * x as f32 - 0.01 * y as f32
            }
        };
        let half = layers_from(FrameParams::padded(6, 4, 3, 3), |l| l == 0, linear(1.0));
        let quarter = layers_from(FrameParams::padded(3, 2, 2, 3), |l| l <= 1, linear(2.0));
        add_upsampled(&mut fine, half, 2);
        add_upsampled(&mut fine, quarter, 4);
        assert_eq!(fine.rows[0], [0, h + 4]);
        assert_eq!(fine.rows[1], [0, h + 4]);
        assert_eq!(
            fine.rows[2],
            [0, 0],
            "a layer no level draws keeps its rows"
        );
        assert!(fine.has_coarse(0) && fine.has_coarse(1) && !fine.has_coarse(2));
        assert!((0..8).all(|k| fine.has_plane(k)) && !(8..12).any(|k| fine.has_plane(k)));

        // The coarse position of frame pixel `x` at `scale` with `pad`, in padded pixels.
        let at = |x: usize, scale: f64, pad: f64| (x as f64 + 0.5) / scale - 0.5 + pad;
        let mut row = vec![[0.0f32; 4]; w];
        for l in 0..2 {
            for y in 0..h {
                fine.layer_row(l, y, &mut row);
                for (x, px) in row.iter().enumerate() {
                    for (c, &got) in px.iter().enumerate() {
                        let own = if l == 0 {
                            f64::from(fine_value(l, c, x + 2, y + 2))
                        } else {
                            0.0
                        };
                        let level = |s: f64, pad: f64, offset: f64| {
                            offset + 0.02 * (l + c) as f64 + 0.03 * at(x, s, pad)
                                - 0.01 * at(y, s, pad)
                        };
                        let half = if l == 0 { level(2.0, 3.0, 0.1) } else { 0.0 };
                        let expected = own + half + level(4.0, 2.0, 0.2);
                        assert!(
                            (f64::from(got) - expected).abs() < 1e-5,
                            "layer {l} channel {c} at ({x}, {y}): {} against {expected}",
                            got
                        );
                    }
                }
            }
        }

        // Compositing sees layer 1 (drawn only coarse) over layer 0, as from full planes.
        let options = CompositeOptions::default();
        let image = composite(&fine, &options);
        let mut eager = layers_from(fine.frame, |l| l <= 1, |_, _, _, _| 0.0);
        for l in 0..2 {
            for y in 0..h {
                fine.layer_row(l, y, &mut row);
                for (x, px) in row.iter().enumerate() {
                    for (c, &v) in px.iter().enumerate() {
                        eager.planes[l * 4 + c].data[(y + 2) * (w + 4) + x + 2] = v;
                    }
                }
            }
        }
        eager.rows = Vec::new();
        assert_eq!(image, composite(&eager, &options));
    }
}
