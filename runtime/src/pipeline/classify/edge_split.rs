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

/// Splits the pixel at `(x, y)` when a neighbour sharing an edge with it whose CoC differs by
/// more than a pixel lies nearer the viewer and its colour explains part of this pixel's: the
/// pixel's colour `c` is taken as `alpha f + (1 - alpha) b`, with `b` the background seen on
/// the far side of the pixel and `alpha` the projection of `c` onto the segment from `b` to the
/// foreground's colour. The foreground part carries `c - (1 - alpha) b` and the background part
/// `b`, so the two add up to `c` and none of the foreground's light is blurred as background (a
/// bright emitter's anti-aliased rim would otherwise glow with the background's blur). Diagonal
/// neighbours, and those two pixels away, count only when they are brighter than
/// `hdr_threshold`: a renderer's pixel filter spreads an HDR highlight's light that far, but an
/// ordinary edge's anti-aliasing reaches only the pixels it cuts, and a pixel touching a
/// foreground only at a corner is most often background whose texture (a checker's other
/// colour) the projection would take for the foreground's. A moving HDR foreground's rim is
/// split also where the blurs are alike, when its path over the shutter crosses the pixel
/// ([`crossing_motion`]): drawn whole with the background's motion, that share of its light
/// would stay where the light starts, a still glow at one end of its streak. `coc_at(i)` is
/// pixel `i`'s signed CoC (pixels), `depth_at(i)` its depth and `motion_at(i)` its motion over
/// the shutter (pixels); `bright_near` is [`bright_near`] of the frame.
#[allow(clippy::too_many_arguments)]
pub(super) fn edge_split(
    g: &GBuffer,
    x: usize,
    y: usize,
    coc_at: &impl Fn(usize) -> f32,
    depth_at: &impl Fn(usize) -> f32,
    motion_at: &impl Fn(usize) -> [f32; 2],
    hdr_threshold: f32,
    bright_near: &[bool],
) -> Option<EdgeSplit> {
    let (w, h) = (g.width as i32, g.height as i32);
    let (xi, yi) = (x as i32, y as i32);
    let index = |px: i32, py: i32| -> Option<usize> {
        (px >= 0 && py >= 0 && px < w && py < h).then(|| py as usize * w as usize + px as usize)
    };
    let i = index(xi, yi)?;
    let d = depth_at(i);
    let bright = |c: [f32; 4]| c[..3].iter().any(|&v| v > hdr_threshold);
    // The nearest neighbour of the four sharing an edge, or a bright one in the 5x5 window.
    let mut best: Option<(usize, i32, i32, f32)> = None;
    let mut consider = |dx: i32, dy: i32| {
        if let Some(j) = index(xi + dx, yi + dy) {
            let dj = depth_at(j);
            if dj < best.map_or(d, |b| b.3) {
                best = Some((j, dx, dy, dj));
            }
        }
    };
    if bright_near.get(i).copied().unwrap_or(true) {
        // Diagonal neighbours and the outer ring count only where bright.
        for dy in -2i32..=2 {
            for dx in -2i32..=2 {
                if dx == 0 && dy == 0 {
                    continue;
                }
                let sharing_an_edge = dx == 0 || dy == 0;
                let outer = dx.abs() == 2 || dy.abs() == 2;
                let dim = || index(xi + dx, yi + dy).is_none_or(|j| !bright(g.color[j]));
                if (outer || !sharing_an_edge) && dim() {
                    continue;
                }
                consider(dx, dy);
            }
        }
    } else {
        // Without a bright pixel in the 5x5 window only the four pixels sharing an edge are
        // candidates: those alone are looked at, in the window's order.
        for (dx, dy) in [(0, -1), (-1, 0), (1, 0), (0, 1)] {
            consider(dx, dy);
        }
    }
    let (j, dx, dy, dj) = best?;
    let (coc_j, coc_i) = (coc_at(j), coc_at(i));
    // The two parts' difference in blur: their CoCs', and for a moving light half its motion
    // relative to the pixel where its path crosses the pixel.
    let mut coc_gap = (coc_j - coc_i).abs();
    if bright(g.color[j]) {
        coc_gap += 0.5
            * crossing_motion(
                (xi, yi),
                (d, dj),
                motion_at(j),
                motion_at(i),
                &index,
                depth_at,
            );
    }
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
    let projection = num / den;
    // The depth pass is sampled at the pixel's centre, and this pixel's is the background's:
    // the foreground rarely covers more than three quarters of it. A colour that projects
    // beyond that, up to twice as far as the foreground's own, is the background's texture (a
    // light checker square with a dark one beyond it), not a mix; one far beyond both is a
    // lone bright pixel (a noisy render's), whose light is drawn with the foreground as before.
    if !bright(cf) && projection > MOST_COVERED_RIM && projection <= TEXTURE_PROJECTION {
        return None;
    }
    let alpha = projection.clamp(0.0, 1.0);
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

/// The largest share of a pixel whose depth is the background's that a non-HDR foreground's
/// anti-aliased edge is taken to cover: with the depth sampled at the pixel's centre, an edge
/// covering more would have given the pixel the foreground's depth.
const MOST_COVERED_RIM: f32 = 0.75;

/// How far beyond the foreground's colour (as a multiple of the distance from the background's
/// to it) a pixel's colour may project and still be read as the background's texture rather
/// than a lone bright pixel ([`edge_split`]).
const TEXTURE_PROJECTION: f32 = 2.0;

/// The length of a foreground's motion relative to the pixel at `(x, y)` (pixels over the
/// shutter) where its path crosses the pixel, else 0: the foreground's depth is looked for at
/// eight points along the relative motion, an eighth to a half of it either side, a point
/// counting where it is nearer than halfway between the pixel's depth and the foreground's
/// (`depth`, `foreground_depth`). A leading or trailing
/// edge's path crosses the pixels beside it; a rim moving along itself (a spinning disc's, a
/// streak's top and bottom) does not, since a convex silhouette's tangent stays outside it, and
/// such a rim drawn still stays where the reference has it.
fn crossing_motion(
    (x, y): (i32, i32),
    (depth, foreground_depth): (f32, f32),
    foreground_motion: [f32; 2],
    motion: [f32; 2],
    index: &impl Fn(i32, i32) -> Option<usize>,
    depth_at: &impl Fn(usize) -> f32,
) -> f32 {
    let relative = [
        foreground_motion[0] - motion[0],
        foreground_motion[1] - motion[1],
    ];
    let length = relative[0].hypot(relative[1]);
    if !(length > 0.0 && length.is_finite()) {
        return 0.0;
    }
    let halfway = 0.5 * (depth + foreground_depth);
    let crosses = [-0.5f32, -0.375, -0.25, -0.125, 0.125, 0.25, 0.375, 0.5]
        .iter()
        .any(|&t| {
            let px = (x as f32 + t * relative[0]).round() as i32;
            let py = (y as f32 + t * relative[1]).round() as i32;
            index(px, py).is_some_and(|q| depth_at(q) < halfway)
        });
    if crosses {
        length
    } else {
        0.0
    }
}

/// Per pixel of `g`, whether its 5x5 window holds a pixel brighter than `hdr_threshold` in
/// some channel: the edge split looks two pixels away only for such a neighbour.
pub(super) fn bright_near(g: &GBuffer, hdr_threshold: f32) -> Vec<bool> {
    use rayon::prelude::*;
    let (w, h) = (g.width, g.height);
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let bright: Vec<bool> = g
        .color
        .par_iter()
        .map(|c| c[..3].iter().any(|&v| v > hdr_threshold))
        .collect();
    // Widened by two pixels along rows, then along columns, a row per task.
    let mut across = vec![false; w * h];
    across
        .par_chunks_mut(w)
        .zip(bright.par_chunks(w))
        .for_each(|(out, row)| {
            for (x, o) in out.iter_mut().enumerate() {
                *o = row[x.saturating_sub(2)..(x + 3).min(w)].iter().any(|&b| b);
            }
        });
    let mut near = vec![false; w * h];
    near.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        for (x, o) in out.iter_mut().enumerate() {
            *o = (y.saturating_sub(2)..(y + 3).min(h)).any(|yy| across[yy * w + x]);
        }
    });
    near
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame of nested depth steps, textured colour and a few HDR pixels (one at the border).
    fn frame() -> GBuffer {
        let (w, h) = (23, 17);
        let mut color = Vec::with_capacity(w * h);
        let mut depth = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let near = (6..15).contains(&x) && (4..12).contains(&y);
                let v = 0.2 + 0.05 * ((x * 7 + y * 3) % 5) as f32;
                let lit = [(10, 8), (6, 8), (0, 0), (22, 3), (3, 16)].contains(&(x, y));
                // Anti-aliased: half the near square's colour, the far depth.
                let rim = !near && (5..16).contains(&x) && (3..13).contains(&y);
                let c = if lit {
                    40.0
                } else if near {
                    0.9
                } else if rim {
                    0.5 * (0.9 + v)
                } else {
                    v
                };
                color.push([c, 0.5 * c, v, 1.0]);
                depth.push(if near { 1.0 } else { 4.0 + 0.01 * x as f32 });
            }
        }
        GBuffer::from_planes(w, h, color, Some(depth), None).expect("frame")
    }

    /// The 5x5 windows holding a bright pixel are flagged, and no other.
    #[test]
    fn bright_windows_are_found() {
        let g = frame();
        let near = bright_near(&g, 8.0);
        let lit = |x: usize, y: usize| g.color[y * g.width + x][0] > 8.0;
        for y in 0..g.height {
            for x in 0..g.width {
                let expected = (y.saturating_sub(2)..(y + 3).min(g.height))
                    .any(|yy| (x.saturating_sub(2)..(x + 3).min(g.width)).any(|xx| lit(xx, yy)));
                assert_eq!(near[y * g.width + x], expected, "pixel ({x}, {y})");
            }
        }
    }

    /// A light square of a checker touching a nearer, sharper foreground only at a corner is
    /// not split, although its colour lies between the dark square beyond it and the
    /// foreground's; beside the foreground's edge, an anti-aliased pixel still is.
    #[test]
    fn a_pixel_touching_the_foreground_at_a_corner_is_not_split() {
        let (w, h) = (9, 9);
        let foreground = |x: usize, y: usize| x >= 5 && y >= 5;
        let mut color = Vec::new();
        let mut depth = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let c = if foreground(x, y) {
                    [0.3, 0.6, 0.3, 1.0]
                } else if (x, y) == (4, 6) {
                    // Half the foreground over the light wall.
                    [0.45, 0.6, 0.45, 1.0]
                } else if x <= 3 && y <= 3 {
                    [0.1, 0.1, 0.1, 1.0]
                } else {
                    [0.6, 0.6, 0.6, 1.0]
                };
                color.push(c);
                depth.push(if foreground(x, y) { 1.0 } else { 4.0 });
            }
        }
        let g = GBuffer::from_planes(w, h, color, Some(depth.clone()), None).expect("frame");
        let coc_at = |i: usize| 6.0 * (depth[i] - 2.0) / depth[i];
        let depth_at = |i: usize| depth[i];
        let still = |_: usize| [0.0f32; 2];
        let near = bright_near(&g, 8.0);
        // (4, 4): light, its only nearer neighbour the diagonal (5, 5), dark squares beyond.
        assert_eq!(
            edge_split(&g, 4, 4, &coc_at, &depth_at, &still, 8.0, &near),
            None
        );
        let rim = edge_split(&g, 4, 6, &coc_at, &depth_at, &still, 8.0, &near).expect("rim split");
        assert!((rim.alpha - 0.5).abs() < 0.05, "rim coverage {}", rim.alpha);
    }

    /// A light checker square beside a green foreground, with a dark square beyond it: its
    /// colour projects past the foreground's from the dark square's, which no pixel whose centre
    /// lies on the wall shows as a mix, so it is left whole; a lone bright pixel there, far
    /// beyond both, is still split off with the foreground.
    #[test]
    fn a_background_texture_beside_a_foreground_is_not_split() {
        let (w, h) = (9, 5);
        let foreground = |x: usize| x <= 3;
        let colour_of = |x: usize, lone: bool| -> [f32; 4] {
            if foreground(x) {
                [0.3, 0.6, 0.3, 1.0]
            } else if x == 4 {
                if lone {
                    [3.0, 3.0, 3.0, 1.0]
                } else {
                    [0.6, 0.6, 0.6, 1.0]
                }
            } else {
                [0.1, 0.1, 0.1, 1.0]
            }
        };
        let frame = |lone: bool| {
            let color: Vec<[f32; 4]> = (0..w * h).map(|i| colour_of(i % w, lone)).collect();
            let depth: Vec<f32> = (0..w * h)
                .map(|i| if foreground(i % w) { 1.0 } else { 4.0 })
                .collect();
            GBuffer::from_planes(w, h, color, Some(depth), None).expect("frame")
        };
        for (lone, split) in [(false, false), (true, true)] {
            let g = frame(lone);
            let depth = g.depth.clone().expect("depth");
            let coc_at = |i: usize| 6.0 * (depth[i] - 2.0) / depth[i];
            let depth_at = |i: usize| depth[i];
            let still = |_: usize| [0.0f32; 2];
            let near = bright_near(&g, 8.0);
            let got = edge_split(&g, 4, 2, &coc_at, &depth_at, &still, 8.0, &near);
            assert_eq!(got.is_some(), split, "lone bright pixel {lone}: {got:?}");
        }
    }

    /// A light (40 times white) moving 8 px along x over a wall, both nearly in focus (CoCs
    /// 0.2 px apart): its anti-aliased leading edge, which the light's path crosses, is split
    /// off with the light's motion; its top rim, which the light moves along, and the same
    /// frame standing still are left whole.
    #[test]
    fn a_moving_lights_leading_rim_moves_with_it() {
        let (w, h) = (20, 9);
        let light = |x: usize, y: usize| (6..10).contains(&x) && (3..6).contains(&y);
        let mut color = Vec::new();
        let mut depth = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let wall = [0.2, 0.2, 0.2, 1.0];
                let c = if light(x, y) {
                    [40.0, 40.0, 40.0, 1.0]
                } else if (x == 10 && (3..6).contains(&y)) || (y == 2 && (6..10).contains(&x)) {
                    // Half covered by the light.
                    [20.1, 20.1, 20.1, 1.0]
                } else {
                    wall
                };
                color.push(c);
                depth.push(if light(x, y) { 1.0 } else { 1.2 });
            }
        }
        let g = GBuffer::from_planes(w, h, color, Some(depth.clone()), None).expect("frame");
        let coc_at = |i: usize| if depth[i] < 1.1 { 0.3 } else { 0.5 };
        let depth_at = |i: usize| depth[i];
        let moving = |i: usize| {
            if depth[i] < 1.1 {
                [8.0f32, 0.0]
            } else {
                [0.0; 2]
            }
        };
        let still = |_: usize| [0.0f32; 2];
        let near = bright_near(&g, 8.0);
        let split = |x, y, motion: &dyn Fn(usize) -> [f32; 2]| {
            edge_split(&g, x, y, &coc_at, &depth_at, &motion, 8.0, &near)
        };
        let leading = split(10, 4, &moving).expect("the leading rim is split");
        assert!(
            (leading.alpha - 0.5).abs() < 0.05,
            "coverage {}",
            leading.alpha
        );
        assert_eq!(split(8, 2, &moving), None, "the top rim moves along itself");
        assert_eq!(
            split(10, 4, &still),
            None,
            "a still light's rim at the wall's blur"
        );
    }

    /// Walking the 3x3 window where no bright pixel is near splits every pixel as the full
    /// 5x5 walk does.
    #[test]
    fn the_short_walk_splits_as_the_full_one() {
        let g = frame();
        let depth = g.depth.clone().expect("depth");
        // A CoC growing with the distance from a focus at depth 2.
        let coc_at = |i: usize| 6.0 * (depth[i] - 2.0) / depth[i];
        let depth_at = |i: usize| depth[i];
        let still = |_: usize| [0.0f32; 2];
        let near = bright_near(&g, 8.0);
        let everywhere = vec![true; near.len()];
        let mut splits = 0;
        for y in 0..g.height {
            for x in 0..g.width {
                let full = edge_split(&g, x, y, &coc_at, &depth_at, &still, 8.0, &everywhere);
                let short = edge_split(&g, x, y, &coc_at, &depth_at, &still, 8.0, &near);
                assert_eq!(full, short, "pixel ({x}, {y})");
                splits += usize::from(full.is_some());
            }
        }
        assert!(
            splits > 10,
            "{splits} pixels split: the frame should have edges"
        );
    }
}
