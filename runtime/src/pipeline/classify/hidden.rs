//! The background hidden behind the silhouettes of sharper occluders, continued from the
//! visible background beside them (so a blurred background does not darken along them).

use super::bend::same_surface_depth;
use super::Fragment;
use crate::gbuffer::GBuffer;
use rayon::prelude::*;

/// The [`Fragment::source`] of the background continued behind an occluder: where it would
/// fall into the occluder's own depth layer it goes behind it (`layers::Ceilings`), or,
/// behind the farthest layer, the occluder's fragments in its pixel hide it there as
/// compositing would across layers (`layers::occlusion_within_layers`); a source of its own
/// that no input surface has.
pub(super) const HIDDEN_SOURCE: u32 = u32::MAX;

/// How much sharper than the background (CoC radius, px) an occluder must be for the
/// background to be continued behind it. A background blurred by a fraction of a pixel more
/// than a sharp occluder still spreads a share of each pixel beside the silhouette onto the
/// occluder (where compositing hides it) and gets none back from behind it: the row of wall
/// above a car's roof (the wall's CoC 0.8 px, the roof's 0.06 px) came out 13 % dark, a line
/// along the roof, at the earlier threshold of one pixel.
pub(super) const SHARPER_BY_PX: f32 = 0.25;

/// The [`Fragment::source`] of a veil: a fragment that is never drawn (weight 0), laid on a
/// background pixel beside a blurrier occluder, with the occluder's depth, motion and blur and,
/// as its alpha, the share of the pixel the occluder's smear or defocus covers there. Where the
/// background falls into the occluder's own depth layer, `layers::occlusion_within_layers`
/// hides that share of it there, as compositing does across layers: within a layer splats add
/// and compositing divides by coverage, so the smear would otherwise be mixed into the
/// background, fainter than over it, and step at the silhouette. Its red channel holds the
/// depth of the background it lies on (0 where another render layer holds it).
pub(super) const VEIL_SOURCE: u32 = u32::MAX - 1;

/// The share of a pixel whose centre lies `s` px outside a straight edge of an occluder that
/// the occluder covers once blurred: `coc` px of defocus radius and `half_motion` px of motion
/// (half its length over the shutter) across the edge. A box shutter ramps it linearly from
/// one half at the edge to zero `half_motion` px out; a disc of radius `coc` covers the
/// circular segment beyond the edge, `(acos u - u sqrt(1 - u^2)) / pi` at `u = s / coc`.
/// Both together: the larger one's shape over their summed reach.
pub(super) fn edge_coverage(s: f32, coc: f32, half_motion: f32) -> f32 {
    let reach = coc + half_motion;
    if s >= reach || reach <= 0.0 {
        return 0.0;
    }
    let u = (s / reach).max(0.0);
    if half_motion >= coc {
        0.5 * (1.0 - u)
    } else {
        (u.acos() - u * (1.0 - u * u).sqrt()) / std::f32::consts::PI
    }
}

/// The background hidden behind the silhouette of a nearer occluder that is sharper or
/// blurrier than it, continued from the visible background next to it.
///
/// A pinhole image holds no pixels of what an occluder hides, but a lens sees past the
/// occluder's edge, and a moving or defocused occluder is itself partly transparent within its
/// blur of its silhouette. Where the background is blurred more than the occluder, its layer
/// would otherwise lose the light of its hidden pixels and darken in a band along the
/// silhouette. Where the occluder is blurred more than the background (a car crossing a street,
/// a defocused post in front of a sharp wall), its smear is half transparent on both sides of
/// its silhouette, but only outside it is there a background to show: inside, compositing
/// fills the missing coverage with the occluder's own colour, so the smear stays opaque up to
/// the silhouette and ends in a hard edge there. As at the frame's edges, the background is
/// taken to continue as it is: each background pixel next to such an occluder is repeated into
/// the occluder along that direction (left, right, up, down), as far as the larger of the two
/// blurs reaches along it, under the occluder (which hides the copies wherever it is opaque).
/// A hidden pixel filled from several sides gets their mean weighted inversely by each walk's
/// distance from the pixel it repeats ([`walk_weight`]), so that walks from opposite sides of
/// an occluder blend linearly across it; then every hidden pixel takes the mean of the filled
/// pixels of its 3 x 3 window: each walk repeats one pixel, so neighbouring walks that start
/// on differently lit or textured pixels (along a curved silhouette, across the rows of a
/// texture) would leave stripes and steps one pixel apart, seen through the smear; what lies
/// behind is not known, and a smooth continuation of it shows less than an invented pattern.
/// A background brighter than `hdr_threshold` is not continued behind a blurrier occluder: a
/// small emitter does not go on behind what passes in front of it, and its copies, half hidden
/// by the smear, would add light (29 % more on the comets example); nor behind an occluder of
/// less than half coverage, which hides little. `coc_at(i)` is pixel `i`'s signed CoC (pixels),
/// `depth_at(i)` its depth, `blur_along(i, d)` its blur reach along axis direction `d`
/// (pixels: its CoC radius plus half its motion over the shutter projected on `d`) and
/// `own(i)` its own fragment. A pixel of `was_split` (an edge split's, or one the caller draws
/// otherwise) is not continued, and a walk may start past one; `split_hidden[i]` is the share
/// of such a pixel its foreground covers (empty: none), which a walk stepping over it fills
/// too, so that the background's layer has no gap of that share along the silhouette.
#[allow(clippy::too_many_arguments)]
pub(super) fn hidden_background(
    g: &GBuffer,
    was_split: &[bool],
    split_hidden: &[f32],
    coc_at: &(impl Fn(usize) -> f32 + Sync),
    depth_at: &(impl Fn(usize) -> f32 + Sync),
    motion_at: &(impl Fn(usize) -> [f32; 2] + Sync),
    blur_along: &(impl Fn(usize, (i32, i32)) -> f32 + Sync),
    hdr_threshold: f32,
    own: &(impl Fn(usize) -> Fragment + Sync),
) -> Vec<Fragment> {
    let (w, h) = (g.width as i32, g.height as i32);
    const DIRECTIONS: [(i32, i32); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];
    // A walk that starts past a split pixel fills that pixel's hidden share too.
    let hidden_share = |q: usize| split_hidden.get(q).copied().unwrap_or(0.0);
    // The walks ([`Walk`]), found row by row on every thread and joined in row order.
    let walks: Vec<Walk> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut walks = Vec::new();
            for x in 0..w {
                let b = (y * w + x) as usize;
                if was_split[b] || g.color[b] == [0.0; 4] {
                    continue;
                }
                let (db, coc_b) = (depth_at(b), coc_at(b));
                let bright = g.color[b][..3].iter().any(|&c| c > hdr_threshold);
                for d in DIRECTIONS {
                    // Nearer than the background one step along `d`, or two past a split
                    // pixel: what `first` below needs, without the blurs, which most pixels
                    // (none of them nearer) never need.
                    let nearer = |k: i32| {
                        let (qx, qy) = (x + d.0 * k, y + d.1 * k);
                        qx >= 0
                            && qy >= 0
                            && qx < w
                            && qy < h
                            && depth_at((qy * w + qx) as usize) < db
                    };
                    let split_next = was_split
                        [((y + d.1).clamp(0, h - 1) * w + (x + d.0).clamp(0, w - 1)) as usize];
                    if !(nearer(1) || (split_next && nearer(2))) {
                        continue;
                    }
                    let (blur_b, motion_b) = (blur_along(b, d), motion_at(b));
                    // Hidden: nearer than the background, and sharper by more than
                    // SHARPER_BY_PX or blurred by more than a pixel along `d` than it. The
                    // first step may be the silhouette's anti-aliased pixel, which carries the
                    // background's depth.
                    let occluder = |k: i32| -> Option<usize> {
                        let (qx, qy) = (x + d.0 * k, y + d.1 * k);
                        if qx < 0 || qy < 0 || qx >= w || qy >= h {
                            return None;
                        }
                        let q = (qy * w + qx) as usize;
                        let dq = depth_at(q);
                        // A blurrier occluder hides the background only where it is opaque
                        // (an emitter of no coverage hides nothing, and copies under it would
                        // add light).
                        let opaque = g.color[q][3] >= 0.5;
                        (dq < db
                            && !one_surface((db, motion_b), (dq, motion_at(q)))
                            && (coc_at(q).abs() + SHARPER_BY_PX < coc_b.abs()
                                || (!bright && opaque && blur_along(q, d) > blur_b + 1.0)))
                            .then_some(q)
                    };
                    let hidden = |k: i32| occluder(k).is_some();
                    let first = if hidden(1) {
                        1
                    } else if split_next && hidden(2) {
                        2
                    } else {
                        continue;
                    };
                    let silhouette_blur = occluder(first).map_or(0.0, |q| blur_along(q, d));
                    let reach = coc_b.abs().max(silhouette_blur).ceil() as i32;
                    if reach < 1 {
                        continue;
                    }
                    let steps = (first..=reach).take_while(|&k| hidden(k)).last();
                    if let Some(steps) = steps {
                        let stepped_over = ((y + d.1) * w + x + d.0) as usize;
                        let start = if first == 2 && hidden_share(stepped_over) > 0.0 {
                            1
                        } else {
                            first
                        };
                        walks.push((b, d, start, first, steps));
                    }
                }
            }
            walks
        })
        .flatten_iter()
        .collect();
    if walks.is_empty() {
        return Vec::new();
    }
    // Veils: outward from each walk's start, over the background a blurrier occluder's smear
    // or defocus reaches, one per pixel (the most covered where several reach it).
    let veils: Vec<Veil> = walks
        .par_iter()
        .flat_map_iter(|&(b, d, _, first, _)| {
            let mut out = Vec::new();
            let (bx, by) = ((b as i32) % w, (b as i32) / w);
            let q = ((by + d.1 * first) * w + bx + d.0 * first) as usize;
            let (coc_q, reach_q) = (coc_at(q).abs(), blur_along(q, d));
            if reach_q > blur_along(b, d) + 1.0 {
                let occluder_depth = depth_at(q);
                let ends = |p: usize| {
                    was_split[p] || g.color[p] == [0.0; 4] || depth_at(p) <= occluder_depth
                };
                let edge = EdgeBlur {
                    coc: coc_q,
                    half_motion: (reach_q - coc_q).max(0.0),
                };
                walk_veils((bx, by), d, first, q, edge, (w, h), &ends, &mut out);
            }
            out
        })
        .collect();
    // Each hidden pixel's total walk weight (zero where no walk reaches) and its walks' colours
    // summed with those weights, in one pass.
    let mut fills = vec![0.0f32; (w * h) as usize];
    let mut walked = vec![[0.0f32; 4]; (w * h) as usize];
    for &(b, d, start, _, steps) in &walks {
        let (bx, by) = ((b as i32) % w, (b as i32) / w);
        let c = g.color[b];
        for k in start..=steps {
            let q = ((by + d.1 * k) * w + bx + d.0 * k) as usize;
            let weight = walk_weight(k);
            fills[q] += weight;
            for (acc, v) in walked[q].iter_mut().zip(c) {
                *acc += weight * v;
            }
        }
    }
    // Only the filled pixels' colours are read, each once per walk through it: found where
    // they are read rather than over the whole frame (a frame's worth of fresh memory).
    let color = |q: usize| smoothed_fill_color(&walked, &fills, (w, h), q);
    // On every thread, in the walks' order.
    let (fills, color, hidden_share) = (&fills, &color, &hidden_share);
    let mut out: Vec<Fragment> = walks
        .par_iter()
        .flat_map_iter(|&(b, d, start, first, steps)| {
            let base = own(b);
            let (bx, by) = ((b as i32) % w, (b as i32) / w);
            (start..=steps).map(move |k| {
                let q = ((by + d.1 * k) * w + bx + d.0 * k) as usize;
                let share = if k < first { hidden_share(q) } else { 1.0 };
                Fragment {
                    x: base.x + d.0 * k,
                    y: base.y + d.1 * k,
                    weight: share * walk_weight(k) / fills[q],
                    color: color(q),
                    ..base
                }
            })
        })
        .collect();
    out.extend(veil_fragments(veils, depth_at, own));
    out
}

/// Whether two neighbouring pixels, each a planar depth and a motion (px), can be one surface,
/// with nothing hidden between them: depths within [`same_surface_depth`], and motions both
/// shorter than [`SAME_DIRECTION_MIN_PX`] or both longer and pointing within
/// [`SAME_DIRECTION_MIN_COS`] of each other. A surface tilted a little away from the camera is
/// nearer a pixel on, and where it also spins, it moves differently there: continued behind
/// itself, its copies carried the motion of pixels several apart, along arcs off its own, and
/// drew a halo outside a spinning disc's rim. Its anti-aliased rim pixels move as it does, only
/// less (their vectors are blended with the background's), so the directions are compared, not
/// the lengths. An occluder moving over a still background a little behind it is not one
/// surface with it.
fn one_surface((da, ma): (f32, [f32; 2]), (db, mb): (f32, [f32; 2])) -> bool {
    if !same_surface_depth(da, db) {
        return false;
    }
    let la = (ma[0] * ma[0] + ma[1] * ma[1]).sqrt();
    let lb = (mb[0] * mb[0] + mb[1] * mb[1]).sqrt();
    match (la < SAME_DIRECTION_MIN_PX, lb < SAME_DIRECTION_MIN_PX) {
        (true, true) => true,
        (false, false) => ma[0] * mb[0] + ma[1] * mb[1] >= SAME_DIRECTION_MIN_COS * la * lb,
        _ => false,
    }
}

/// Motions shorter than this (px over the shutter) count as still in [`one_surface`].
const SAME_DIRECTION_MIN_PX: f32 = 2.0;
/// The least cosine between two motions of one surface's neighbouring pixels in
/// [`one_surface`] (about 25 degrees).
const SAME_DIRECTION_MIN_COS: f32 = 0.9;

/// A veil before it is a fragment: the pixel it lies on, the share of it covered, and the
/// occluder's pixel.
type Veil = (usize, f32, usize);

/// An occluder's blur across its edge, px: its CoC radius and half its motion over the
/// shutter along the walk's axis.
#[derive(Clone, Copy)]
struct EdgeBlur {
    coc: f32,
    half_motion: f32,
}

/// The veils of one walk outward from `start` (pixel `(x, y)`, the first background pixel
/// beside the occluder at `q`) against direction `d`: the edge lies `first - 1/2` px beyond
/// `start` along `d`. It goes on while the occluder's blurred edge covers a thousandth of a
/// pixel or more, and stops at the frame's edge or at a pixel where `ends` says so.
#[allow(clippy::too_many_arguments)]
fn walk_veils(
    (x, y): (i32, i32),
    d: (i32, i32),
    first: i32,
    q: usize,
    edge: EdgeBlur,
    (w, h): (i32, i32),
    ends: &dyn Fn(usize) -> bool,
    out: &mut Vec<Veil>,
) {
    for j in 0.. {
        let (px, py) = (x - d.0 * j, y - d.1 * j);
        if px < 0 || py < 0 || px >= w || py >= h {
            break;
        }
        let p = (py * w + px) as usize;
        if ends(p) {
            break;
        }
        let coverage = edge_coverage((j + first) as f32 - 0.5, edge.coc, edge.half_motion);
        if coverage < 1e-3 {
            break;
        }
        out.push((p, coverage, q));
    }
}

/// `veils` as fragments ([`VEIL_SOURCE`]), one per pixel (the most covered where several lie
/// on it), with their occluder's depth, motion and blur (`own`) and the depth of the
/// background they lie on (`background_depth`) in red.
fn veil_fragments(
    mut veils: Vec<Veil>,
    background_depth: &(impl Fn(usize) -> f32 + Sync),
    own: &(impl Fn(usize) -> Fragment + Sync),
) -> Vec<Fragment> {
    // A total order (pixel, the most covered first, occluder), so the unstable sort's result
    // is the one order.
    veils.par_sort_unstable_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)).then(a.2.cmp(&b.2)));
    veils.dedup_by_key(|v| v.0);
    veils
        .into_par_iter()
        .map(|(p, coverage, q)| {
            let at = own(p);
            Fragment {
                x: at.x,
                y: at.y,
                color: [background_depth(p), 0.0, 0.0, coverage],
                weight: 0.0,
                source: VEIL_SOURCE,
                ..own(q)
            }
        })
        .collect()
}

/// Veils ([`VEIL_SOURCE`]) beside the silhouette of a render layer's own surface, over the
/// pixels the layer leaves uncovered (alpha under one half) that its blur reaches: what the
/// other render layers hold there is what the surface's smear or defocus half covers, and
/// where it shares the surface's depth layer it must be covered there, not added to.
/// `coc_at`, `blur_along` and `own` as for [`hidden_background`].
pub(super) fn render_layer_veils(
    g: &GBuffer,
    coc_at: &(impl Fn(usize) -> f32 + Sync),
    blur_along: &(impl Fn(usize, (i32, i32)) -> f32 + Sync),
    own: &(impl Fn(usize) -> Fragment + Sync),
) -> Vec<Fragment> {
    let (w, h) = (g.width as i32, g.height as i32);
    const DIRECTIONS: [(i32, i32); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];
    let covered = |i: usize| g.color[i][3] >= 0.5;
    let veils: Vec<Veil> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut veils = Vec::new();
            for x in 0..w {
                let b = (y * w + x) as usize;
                if covered(b) {
                    continue;
                }
                for d in DIRECTIONS {
                    let (qx, qy) = (x + d.0, y + d.1);
                    if qx < 0 || qy < 0 || qx >= w || qy >= h {
                        continue;
                    }
                    let q = (qy * w + qx) as usize;
                    if !covered(q) {
                        continue;
                    }
                    let (coc_q, reach_q) = (coc_at(q).abs(), blur_along(q, d));
                    let edge = EdgeBlur {
                        coc: coc_q,
                        half_motion: (reach_q - coc_q).max(0.0),
                    };
                    walk_veils((x, y), d, 1, q, edge, (w, h), &covered, &mut veils);
                }
            }
            veils
        })
        .flatten_iter()
        .collect();
    // What lies beside the layer's surface is another layer's: its depth is not known here.
    veil_fragments(veils, &|_| 0.0, own)
}

/// A walk of the continuation: the background pixel it repeats, its direction (an axis), the
/// first step it fills (a split pixel it steps over included), its first hidden step and its
/// last step.
type Walk = (usize, (i32, i32), i32, i32, i32);

/// The weight of a walk's copy `k` pixels from the background pixel it repeats, where walks
/// meet: `1 / k`. Two walks from opposite sides of an occluder, `a` and `b` pixels from their
/// sources, then give `(b A + a B) / (a + b)`, the linear blend of the two sides across it; with
/// equal weights every hidden pixel took the mean of the two, a flat band of one colour down
/// the middle of a blurred bar.
fn walk_weight(k: i32) -> f32 {
    1.0 / k.max(1) as f32
}

/// Filled pixel `q`'s colour (premultiplied RGBA): over the filled pixels of its 3 x 3
/// window, the mean of each one's walks' colours, weighted by their [`walk_weight`]s
/// (`walked`: the weighted sums; `fills`: the weights' sums, zero where no walk fills).
fn smoothed_fill_color(
    walked: &[[f32; 4]],
    fills: &[f32],
    (w, h): (i32, i32),
    q: usize,
) -> [f32; 4] {
    let (x, y) = (q as i32 % w, q as i32 / w);
    let mut sum = [0.0f32; 4];
    let mut n = 0.0f32;
    for yy in (y - 1).max(0)..=(y + 1).min(h - 1) {
        for xx in (x - 1).max(0)..=(x + 1).min(w - 1) {
            let p = (yy * w + xx) as usize;
            let f = fills[p];
            if f > 0.0 {
                for (acc, v) in sum.iter_mut().zip(walked[p]) {
                    *acc += v / f;
                }
                n += 1.0;
            }
        }
    }
    sum.map(|v| v / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blurred edge's coverage against its closed forms: a box shutter's linear ramp, a
    /// disc's circular segment (one half at the edge, 0.1955 of the disc beyond a chord half
    /// the radius out), nothing beyond the reach.
    #[test]
    fn edge_coverage_is_the_ramp_of_a_box_shutter_and_the_segment_of_a_disc() {
        assert!((edge_coverage(0.0, 0.0, 10.0) - 0.5).abs() < 1e-6);
        assert!((edge_coverage(5.0, 0.0, 10.0) - 0.25).abs() < 1e-6);
        assert!((edge_coverage(0.0, 8.0, 0.0) - 0.5).abs() < 1e-6);
        let segment = (0.5f32.acos() - 0.5 * 0.75f32.sqrt()) / std::f32::consts::PI;
        assert!((segment - 0.1955).abs() < 1e-4, "{segment}");
        assert!((edge_coverage(4.0, 8.0, 0.0) - segment).abs() < 1e-6);
        assert_eq!(edge_coverage(10.0, 0.0, 10.0), 0.0);
        assert_eq!(edge_coverage(12.0, 8.0, 3.0), 0.0);
        assert_eq!(edge_coverage(1.0, 0.0, 0.0), 0.0);
    }

    /// A `w x h` frame of greys, `pixel(x, y)` giving each pixel's grey and depth; and the
    /// depths.
    fn grey_frame(
        w: usize,
        h: usize,
        pixel: impl Fn(usize, usize) -> (f32, f32),
    ) -> (GBuffer, Vec<f32>) {
        let (mut color, mut depth) = (Vec::new(), Vec::new());
        for y in 0..h {
            for x in 0..w {
                let (v, d) = pixel(x, y);
                color.push([v, v, v, 1.0]);
                depth.push(d);
            }
        }
        let g = GBuffer::from_planes(w, h, color, Some(depth.clone()), None).expect("frame");
        (g, depth)
    }

    /// Pixel `i`'s own still fragment in `g` (of depths `depth`).
    fn own_fragment(g: &GBuffer, depth: &[f32], i: usize) -> Fragment {
        Fragment {
            x: (i % g.width) as i32,
            y: (i / g.width) as i32,
            color: g.color[i],
            weight: 1.0,
            parallax: 1.0 / depth[i],
            depth: depth[i],
            motion: [0.0; 2],
            bend: 0.0,
            source: 0,
        }
    }

    /// A defocused bar over a wall that is dark on its left and light on its right: the wall
    /// continued behind the bar blends linearly from one side to the other, where the mean of
    /// the two sides would leave a flat band of one grey down the bar.
    #[test]
    fn the_continuation_blends_the_two_sides_of_a_bar() {
        let (w, h) = (24usize, 12usize);
        let bar = |x: usize| (8..16).contains(&x);
        let (dark, light) = (0.2f32, 0.8f32);
        let (g, depth) = grey_frame(w, h, |x, _| match x {
            x if bar(x) => (0.5, 0.5),
            x if x < 8 => (dark, 3.0),
            _ => (light, 3.0),
        });
        let own = |i: usize| own_fragment(&g, &depth, i);
        // The bar is blurred (CoC 12 px), the wall sharp: both sides walk across the bar.
        let coc = |i: usize| if depth[i] < 1.0 { 12.0 } else { 0.0 };
        let filled = hidden_background(
            &g,
            &vec![false; w * h],
            &[],
            &coc,
            &|i| depth[i],
            &|_| [0.0; 2],
            &|i, _| coc(i),
            8.0,
            &own,
        );
        let y = h / 2;
        let mut level = vec![[0.0f32; 2]; w];
        for f in filled.iter().filter(|f| f.y as usize == y) {
            level[f.x as usize][0] += f.weight * f.color[0];
            level[f.x as usize][1] += f.weight;
        }
        for (x, &[sum, weight]) in level.iter().enumerate().take(15).skip(9) {
            assert!((weight - 1.0).abs() < 1e-5, "column {x}: weight {weight}");
            // Pixel x lies x - 7 px from the dark side's last pixel and 16 - x from the light's.
            let (a, b) = ((x - 7) as f32, (16 - x) as f32);
            let linear = (b * dark + a * light) / (a + b);
            assert!(
                (sum - linear).abs() < 0.03,
                "column {x}: {sum} against {linear}"
            );
        }
    }

    /// The continued background of a sharp frame `g` (depths `depth`, no pixel split) whose
    /// pixel `i` moves `motion(i)` px over the shutter.
    fn continued_sharp(
        g: &GBuffer,
        depth: &[f32],
        motion: &(impl Fn(usize) -> [f32; 2] + Sync),
        blur_along: &(impl Fn(usize, (i32, i32)) -> f32 + Sync),
        own: &(impl Fn(usize) -> Fragment + Sync),
    ) -> Vec<Fragment> {
        let split = vec![false; g.width * g.height];
        let depth_at = |i: usize| depth[i];
        hidden_background(
            g,
            &split,
            &[],
            &|_| 0.0,
            &depth_at,
            motion,
            blur_along,
            8.0,
            own,
        )
    }

    /// A disc tilted a little away from the camera (each pixel 0.01 % farther than the one
    /// above it) spinning in place, its outermost pixels anti-aliased (their motion half the
    /// disc's, blended with the still wall's): each rim pixel at the bottom is farther than
    /// the one above it and moves by pixels less along the column, yet nothing of the disc is
    /// continued behind itself. A bar moving over a still wall only 2 % behind it is an
    /// occluder: the wall is continued behind it.
    #[test]
    fn a_tilted_spinning_disc_is_not_continued_behind_itself() {
        let (w, h) = (48usize, 48usize);
        let (cx, cy, radius, turn) = (24.0f32, 24.0f32, 20.0f32, 0.6f32);
        let inside = |x: usize, y: usize| {
            let (dx, dy) = (x as f32 + 0.5 - cx, y as f32 + 0.5 - cy);
            dx * dx + dy * dy <= radius * radius
        };
        let (g, depth) = grey_frame(w, h, |x, y| {
            if inside(x, y) {
                (0.6, 1.0 + 1e-4 * y as f32)
            } else {
                (0.3, 1.6)
            }
        });
        // A turn about the centre: the motion is `turn` times the offset turned a quarter.
        let motion = |i: usize| -> [f32; 2] {
            let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            if inside(i % w, i / w) {
                let (dx, dy) = (x - cx, y - cy);
                let rim = dx * dx + dy * dy > (radius - 1.0) * (radius - 1.0);
                let share = if rim { 0.5 } else { 1.0 };
                [-share * turn * dy, share * turn * dx]
            } else {
                [0.0; 2]
            }
        };
        let blur_along = |i: usize, d: (i32, i32)| {
            let m = motion(i);
            0.5 * (m[0] * d.0 as f32 + m[1] * d.1 as f32).abs()
        };
        let own = |i: usize| Fragment {
            motion: motion(i),
            ..own_fragment(&g, &depth, i)
        };
        let filled = continued_sharp(&g, &depth, &motion, &blur_along, &own);
        let behind_itself = filled
            .iter()
            .filter(|f| f.source != VEIL_SOURCE && f.depth < 1.5)
            .count();
        assert_eq!(
            behind_itself,
            0,
            "{} of {} continued",
            behind_itself,
            filled.len()
        );
        // The disc covers the wall: the wall is continued behind it, as before.
        assert!(filled
            .iter()
            .any(|f| f.source != VEIL_SOURCE && f.depth > 1.5));

        // A bar moving 12 px to the right over a still wall 2 % behind it.
        let (w, h) = (32usize, 6usize);
        let bar = |x: usize| (12..20).contains(&x);
        let (g, depth) = grey_frame(w, h, |x, _| if bar(x) { (0.9, 1.0) } else { (0.3, 1.02) });
        let motion = |i: usize| if bar(i % w) { [12.0, 0.0] } else { [0.0; 2] };
        let blur_along = |i: usize, d: (i32, i32)| 0.5 * (motion(i)[0] * d.0 as f32).abs();
        let own = |i: usize| own_fragment(&g, &depth, i);
        let filled = continued_sharp(&g, &depth, &motion, &blur_along, &own);
        let wall_behind_bar = filled
            .iter()
            .filter(|f| f.source != VEIL_SOURCE && bar(f.x as usize))
            .count();
        assert!(wall_behind_bar >= 2 * 6 * 6, "{wall_behind_bar}");
    }

    /// The anti-aliased pixel beside a blurred bar, split into the bar's share (0.4) and the
    /// wall's, gets the wall continued over the share the bar hides: the wall's layer then has
    /// no gap along the bar's silhouette (a thin line of the bar's colour through its blur).
    #[test]
    fn a_split_pixel_beside_an_occluder_is_filled_over_its_hidden_share() {
        let (w, h) = (16usize, 5usize);
        let bar = |x: usize| (6..10).contains(&x);
        let rim = 5usize;
        let (g, depth) = grey_frame(w, h, |x, _| if bar(x) { (0.9, 0.5) } else { (0.3, 3.0) });
        let own = |i: usize| own_fragment(&g, &depth, i);
        let coc = |i: usize| if depth[i] < 1.0 { 12.0 } else { 0.0 };
        let was_split: Vec<bool> = (0..w * h).map(|i| i % w == rim).collect();
        let split_hidden: Vec<f32> = was_split
            .iter()
            .map(|&s| if s { 0.4 } else { 0.0 })
            .collect();
        let filled = hidden_background(
            &g,
            &was_split,
            &split_hidden,
            &coc,
            &|i| depth[i],
            &|_| [0.0; 2],
            &|i, _| coc(i),
            8.0,
            &own,
        );
        let weight_at = |x: i32| -> f32 {
            filled
                .iter()
                .filter(|f| f.y == 2 && f.x == x)
                .map(|f| f.weight)
                .sum()
        };
        assert!(
            (weight_at(rim as i32) - 0.4).abs() < 1e-5,
            "rim {}",
            weight_at(rim as i32)
        );
        assert!(
            (weight_at(7) - 1.0).abs() < 1e-5,
            "behind the bar {}",
            weight_at(7)
        );
    }

    /// A wall whose rows alternate between two greys, beside a nearer, blurrier occluder (a
    /// moving box): the wall continued behind the box is smooth across the rows, where each
    /// walk repeating its own row's pixel would leave stripes a pixel apart.
    #[test]
    fn the_continuation_behind_an_occluder_has_no_stripes() {
        let (w, h) = (24usize, 16usize);
        let occluder = |x: usize, y: usize| x >= 12 && (4..12).contains(&y);
        let grey = |y: usize| if y.is_multiple_of(2) { 0.3 } else { 0.7 };
        let (g, depth) = grey_frame(w, h, |x, y| {
            if occluder(x, y) {
                (0.9, 1.0)
            } else {
                (grey(y), 4.0)
            }
        });
        let own = |i: usize| own_fragment(&g, &depth, i);
        // The box is sharp and moves 16 px along x; the wall is sharp and still.
        let blur_along = |i: usize, d: (i32, i32)| {
            if depth[i] < 2.0 {
                8.0 * d.0.abs() as f32
            } else {
                0.0
            }
        };
        let filled = hidden_background(
            &g,
            &vec![false; w * h],
            &[],
            &|_| 0.0,
            &|i| depth[i],
            &|_| [0.0; 2],
            &blur_along,
            8.0,
            &own,
        );
        // The hidden pixels' colours, weighted as the fragments are.
        let mut hidden = vec![[0.0f32; 2]; w * h];
        for f in &filled {
            let q = f.y as usize * w + f.x as usize;
            hidden[q][0] += f.weight * f.color[0];
            hidden[q][1] += f.weight;
        }
        let level = |x: usize, y: usize| {
            let [sum, weight] = hidden[y * w + x];
            (weight > 0.0).then(|| sum / weight)
        };
        let mut rows_compared = 0;
        for y in 5..11 {
            for x in 12..20 {
                if let (Some(a), Some(b)) = (level(x, y), level(x, y + 1)) {
                    rows_compared += 1;
                    assert!((a - b).abs() < 0.2, "({x}, {y}): {a} against {b} below it");
                }
            }
        }
        assert!(rows_compared > 20, "{rows_compared} pixel pairs filled");
    }
}
