//! Anti-aliased edge pixels: a pixel whose depth is its background's but whose colour holds a
//! nearer foreground's light is split into a foreground and a background part.

use crate::gbuffer::GBuffer;

/// How an anti-aliased edge pixel divides between a nearer foreground and its background.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct EdgeSplit {
    /// Foreground coverage of the pixel, in (0, 1].
    pub(super) alpha: f32,
    /// The foreground neighbour whose depth and motion the foreground part takes.
    pub(super) foreground: usize,
    /// The background neighbour whose depth and motion the background part takes.
    pub(super) background: usize,
    /// The foreground part's colour (premultiplied, before `alpha`).
    pub(super) foreground_color: [f32; 4],
    /// The background part's colour (before `1 - alpha`).
    pub(super) background_color: [f32; 4],
}

/// Splits the pixel at `(x, y)` when a neighbour whose CoC differs by more than a pixel lies
/// nearer the viewer and its colour explains part of this pixel's: the pixel's colour `c` is
/// taken as `alpha f + (1 - alpha) b`, with `b` the background seen on the far side of the
/// pixel and `alpha` the projection of `c` onto the segment from `b` to the foreground's
/// colour. The foreground part carries `c - (1 - alpha) b` and the background part `b`, so the
/// two add up to `c` and none of the foreground's light is blurred as background (a bright
/// emitter's anti-aliased rim would otherwise glow with the background's blur). Neighbours two
/// pixels away count too when they are brighter than `hdr_threshold`: a renderer's pixel
/// filter spreads an HDR highlight's light that far. `coc_at(i)` is pixel `i`'s signed CoC
/// (pixels) and `depth_at(i)` its depth.
pub(super) fn edge_split(
    g: &GBuffer,
    x: usize,
    y: usize,
    coc_at: &dyn Fn(usize) -> f32,
    depth_at: &dyn Fn(usize) -> f32,
    hdr_threshold: f32,
) -> Option<EdgeSplit> {
    let (w, h) = (g.width as i32, g.height as i32);
    let (xi, yi) = (x as i32, y as i32);
    let index = |px: i32, py: i32| -> Option<usize> {
        (px >= 0 && py >= 0 && px < w && py < h).then(|| py as usize * w as usize + px as usize)
    };
    let i = index(xi, yi)?;
    let d = depth_at(i);
    let bright = |c: [f32; 4]| c[..3].iter().any(|&v| v > hdr_threshold);
    // The nearest neighbour in the 3x3 window, or a bright one in the 5x5 window.
    let mut best: Option<(usize, i32, i32, f32)> = None;
    for dy in -2i32..=2 {
        for dx in -2i32..=2 {
            if dx == 0 && dy == 0 {
                continue;
            }
            let Some(j) = index(xi + dx, yi + dy) else {
                continue;
            };
            let outer = dx.abs() == 2 || dy.abs() == 2;
            if outer && !bright(g.color[j]) {
                continue;
            }
            let dj = depth_at(j);
            if dj < best.map_or(d, |b| b.3) {
                best = Some((j, dx, dy, dj));
            }
        }
    }
    let (j, dx, dy, dj) = best?;
    let (coc_j, coc_i) = (coc_at(j), coc_at(i));
    let coc_gap = (coc_j - coc_i).abs();
    // Only where the depth step is visible as a difference in blur (or, for a pinhole with
    // motion, a large relative depth step).
    if coc_gap < 1.0 && !(coc_i == 0.0 && dj < 0.8 * d) {
        return None;
    }
    // Background: on the far side of the pixel from the foreground, one or two pixels away,
    // whichever lies farther from the foreground's colour (the nearer one may still carry
    // some of a bright foreground's light); only background-like depths count.
    let (sx, sy) = (dx.signum(), dy.signum());
    let cf = g.color[j];
    let distance_to_foreground =
        |c: [f32; 4]| -> f32 { (0..3).map(|k| (c[k] - cf[k]) * (c[k] - cf[k])).sum() };
    let mut background: Option<usize> = None;
    for step in 1..=2 {
        let Some(o) = index(xi - sx * step, yi - sy * step) else {
            break;
        };
        if (coc_at(o) - coc_i).abs() > 0.5 * coc_gap.max(1.0) {
            break;
        }
        if background
            .is_none_or(|b| distance_to_foreground(g.color[o]) > distance_to_foreground(g.color[b]))
        {
            background = Some(o);
        }
    }
    let o = background?;
    let (cp, cb) = (g.color[i], g.color[o]);
    let mut num = 0.0f32;
    let mut den = 0.0f32;
    for c in 0..3 {
        let a = cf[c] - cb[c];
        num += (cp[c] - cb[c]) * a;
        den += a * a;
    }
    // A colour difference too small to tell the parts apart: leave the pixel whole.
    let scale = cf[..3]
        .iter()
        .chain(&cb[..3])
        .fold(0.0f32, |m, v| m.max(v.abs()));
    if den <= (0.05 * scale).powi(2) || den <= 1e-12 {
        return None;
    }
    let alpha = (num / den).clamp(0.0, 1.0);
    // Too little foreground light to matter: 2 % of the brighter of display white and the
    // background.
    let foreground_peak = cf[..3].iter().fold(0.0f32, |m, &v| m.max(v));
    let background_peak = cb[..3].iter().fold(1.0f32, |m, &v| m.max(v));
    if alpha <= 0.0 || alpha * foreground_peak < 0.02 * background_peak {
        return None;
    }
    let foreground_color =
        std::array::from_fn(|k| ((cp[k] - (1.0 - alpha) * cb[k]) / alpha).max(0.0));
    Some(EdgeSplit {
        alpha,
        foreground: j,
        background: o,
        foreground_color,
        background_color: cb,
    })
}
