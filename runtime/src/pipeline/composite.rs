//! Stage 4, compositing: the layers, cropped to the image, back to front with "over".
//!
//! Each layer is first renormalised as Lee et al. 2008 do: where its accumulated coverage
//! (alpha) exceeds one, colour and alpha are divided by it. Then, optionally, coverage
//! renormalisation: where "over" leaves less coverage than the layers hold together (capped at
//! one), as at the seam between two layers that split one continuous surface, whose halves
//! wrongly occlude each other, the colour is scaled up to that coverage. Where a layer truly
//! occludes another, the total coverage is already one and nothing changes.
//!
//! How that coverage is made up is a choice ([`CompositeOptions::restore_occluded`]).
//! Synthesis scales the whole pixel up. Reconstruction from stochastic samples must not: its
//! samples already carry their visibility (a wall sample exists only where the lens saw past
//! the foreground), so "over" occludes the farther layers a second time, and scaling the pixel
//! up to make up for it brightens the foreground too: a bright emitter in front of a wall
//! gained 7-10 % of the frame's light on the comets frames. There the missing coverage is
//! filled with the colour that "over" hid instead. With `S` the layers' plain sum and `O` the
//! "over" result, both premultiplied, `S - O` is that hidden colour: the nearest layer loses
//! nothing to "over", so it is the farther layers' own colour, each in proportion to how much
//! of it was hidden. The output is `O + (1 - O.a) (S - O) / (S.a - O.a)`, opaque. The fill
//! covers all of `1 - O.a`, not only the hidden `S.a - O.a`: a farther layer's hole (where the
//! nearer one blocked its samples) is blurred by the farther layer's own PSF into a shallower,
//! wider dip than the nearer layer's coverage fills, and what is missing there is the farther
//! surface. Dividing by the joint coverage instead (the ratio estimator) would scale the nearer
//! layer's light up there: round a bright emitter in front of a defocused wall, that put 14 %
//! more light into the frame. Where nothing was hidden (`S.a - O.a` below
//! [`FILL_MIN_HIDDEN`]), the pixel is left for reconstruction's division by coverage.
//! Negative values (approximation ringing) are clamped to zero in the output.

use super::integrate::IntegratedLayers;
use formats::RgbaImage;

/// Hidden coverage below which [`CompositeOptions::restore_occluded`] fills nothing (the same
/// threshold as reconstruction's division by coverage).
pub const FILL_MIN_HIDDEN: f32 = 1e-3;

/// Knobs of compositing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CompositeOptions {
    /// Scale the result up to the layers' joint coverage (see the module documentation).
    pub renormalize_coverage: bool,
    /// Make up the missing coverage with the colour "over" hid of the farther layers (`O + (1 -
    /// O.a) (S - O) / (S.a - O.a)`, see the module documentation) instead of scaling the whole
    /// pixel up to the layers' joint coverage: for
    /// reconstruction from stochastic samples, whose visibility is already in the samples.
    /// Takes effect only with `renormalize_coverage`.
    pub restore_occluded: bool,
}

impl Default for CompositeOptions {
    fn default() -> Self {
        Self {
            renormalize_coverage: true,
            restore_occluded: false,
        }
    }
}

/// Composites the layers back to front (layer 0 = farthest) into a `width x height` image.
pub fn composite(layers: &IntegratedLayers, options: &CompositeOptions) -> RgbaImage {
    let f = layers.frame;
    let (w, h) = (f.width as usize, f.height as usize);
    let (pw, pad) = (f.padded_width as usize, f.pad as usize);
    let mut out = RgbaImage::new(w, h);
    // The layers' plain sum, colour and coverage (`S`).
    let mut total = vec![[0.0f32; 4]; w * h];
    for l in 0..f.layers as usize {
        let planes = &layers.planes[l * 4..l * 4 + 4];
        if planes.iter().any(|p| p.is_empty()) {
            continue;
        }
        for y in 0..h {
            let row = (y + pad) * pw + pad;
            for x in 0..w {
                let k = row + x;
                let mut c = [
                    planes[0].data[k],
                    planes[1].data[k],
                    planes[2].data[k],
                    planes[3].data[k].max(0.0),
                ];
                if c[3] > 1.0 {
                    let inv = 1.0 / c[3];
                    c = c.map(|v| v * inv);
                }
                let i = y * w + x;
                for ch in 0..4 {
                    total[i][ch] += c[ch];
                }
                let acc = &mut out.pixels[i];
                let t = 1.0 - c[3];
                for ch in 0..4 {
                    acc[ch] = c[ch] + t * acc[ch];
                }
            }
        }
    }
    for (px, sum) in out.pixels.iter_mut().zip(&total) {
        if options.renormalize_coverage && options.restore_occluded {
            let hidden = sum[3] - px[3];
            if hidden > FILL_MIN_HIDDEN && px[3] < 1.0 {
                let f = (1.0 - px[3]) / hidden;
                let over = *px;
                for ch in 0..4 {
                    px[ch] += f * (sum[ch] - over[ch]);
                }
            }
        } else if options.renormalize_coverage {
            let target = sum[3].min(1.0);
            if px[3] > 1e-6 && target > px[3] {
                let s = target / px[3];
                *px = px.map(|v| v * s);
                px[3] = target;
            }
        }
        *px = px.map(|v| v.max(0.0));
    }
    out
}
