//! Stage 4, compositing: the layers, cropped to the image, back to front with "over".
//!
//! Each layer is first renormalised as Lee et al. 2008 do: where its accumulated coverage
//! (alpha) exceeds one, colour and alpha are divided by it. Then, optionally, coverage
//! renormalisation: where "over" leaves less coverage than the layers hold together (capped at
//! one), as at the seam between two layers that split one continuous surface, whose halves
//! wrongly occlude each other, the colour is scaled up to that coverage. Where a layer truly
//! occludes another, the total coverage is already one and nothing changes.
//! Negative values (approximation ringing) are clamped to zero in the output.

use super::integrate::IntegratedLayers;
use formats::RgbaImage;

/// Knobs of compositing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CompositeOptions {
    /// Scale the result up to the layers' joint coverage (see the module documentation).
    pub renormalize_coverage: bool,
}

impl Default for CompositeOptions {
    fn default() -> Self {
        Self {
            renormalize_coverage: true,
        }
    }
}

/// Composites the layers back to front (layer 0 = farthest) into a `width x height` image.
pub fn composite(layers: &IntegratedLayers, options: &CompositeOptions) -> RgbaImage {
    let f = layers.frame;
    let (w, h) = (f.width as usize, f.height as usize);
    let (pw, pad) = (f.padded_width as usize, f.pad as usize);
    let mut out = RgbaImage::new(w, h);
    let mut total = vec![0.0f32; w * h];
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
                total[i] += c[3];
                let acc = &mut out.pixels[i];
                let t = 1.0 - c[3];
                for ch in 0..4 {
                    acc[ch] = c[ch] + t * acc[ch];
                }
            }
        }
    }
    for (px, &tot) in out.pixels.iter_mut().zip(&total) {
        if options.renormalize_coverage {
            let target = tot.min(1.0);
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
