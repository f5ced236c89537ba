//! Evening out where moved samples happened to land.
//!
//! Moved back to the lens and shutter centre, a surface's samples land at random: two in one
//! pixel, one in its neighbour. Each merged fragment carries the weight of the samples on its
//! pixel, and a blurred pixel is the weighted mean of the fragments its PSF reaches
//! ([`crate::reconstruct::normalize_density`]). So a texture value that a few extra samples
//! happened to land on counts more than its neighbour's, and a blur of a texture comes out
//! with the grain of those counts: streaks along a spinning disc's arcs, blotches on a
//! defocused floor. The converged frame weighs every point of the surface alike.
//!
//! So the weights of a blurred surface's pixels are diffused towards each other: every two
//! pixels `p`, `q` of the surface within the tent's reach exchange a share of the difference
//! of their weights,
//!
//! ```text
//! W'(p) = W(p) + sum over q near p of  k(p - q) (W(q) - W(p)) / K
//! ```
//!
//! with `W` the surface's weight on a pixel, `k` the tent `(r + 1 - |dx|) (r + 1 - |dy|)` of
//! reach `r` ([`reach_px`]: 2 below 8 spp, 1 from it) and `K = (r + 1)^4` its sum. Inside the
//! surface this is the tent's mean of the weights. What one pixel gains its neighbour loses,
//! so the surface's weight (its coverage, which composites it with the layers behind) is kept
//! exactly, and an even surface stays even.
//!
//! Only pixels inside the surface trade: those whose eight neighbours all hold it. At its rim
//! a pixel's weight also says how much of the pixel the surface covers, which evening would
//! blur: a thin defocused bar in front of a sharp background came out a little more opaque
//! (FLIP mean +0.001 on the built-in `occluder`), and a spinning object's outline lost SSIM.
//!
//! Only fragments whose PSF is wider than a pixel are evened out: an in-focus fragment is its
//! own pixel's colour, and its weight against its neighbours' is the pixel filter. A light's
//! fragment (a channel above 1) keeps its weight, as it stays unmerged.

use crate::pipeline::classify::Fragment;
use rayon::prelude::*;

/// A fragment is evened out when its PSF's radius is at least this, pixels: the larger of its
/// CoC radius and half its motion over the shutter.
pub const MIN_BLUR_PX: f32 = 1.0;

/// Fragments of two pixels are of one surface when their parallax differs by at most this
/// fraction.
pub const SAME_SURFACE_PARALLAX: f32 = 0.05;

/// A fragment with a channel above this (linear) is a light's, and keeps its weight.
const BRIGHT: f32 = 1.0;

/// Below this many samples per pixel the tent reaches 2 pixels, from it 1 ([`reach_px`]).
pub const WIDE_TENT_BELOW_SPP: usize = 8;

/// How far the tent reaches at `spp` samples per pixel, pixels: 2 (a 5 x 5 tent) below
/// [`WIDE_TENT_BELOW_SPP`], 1 (3 x 3) from it. Sparser samples clump at a larger scale; at 8
/// spp the wider tent cost FLIP p99 on the built-in `studio` scene (0.1777 -> 0.1791).
pub fn reach_px(spp: usize) -> i64 {
    if spp < WIDE_TENT_BELOW_SPP {
        2
    } else {
        1
    }
}

/// Evens out the weights of the blurred fragments of a `w` x `h` frame in place (see the
/// module's text), with a tent reaching `reach_px` pixels ([`reach_px`]). `coc_px(f)` is a
/// fragment's signed CoC radius, pixels. Fragments outside the frame, lights' fragments,
/// those of blur under [`MIN_BLUR_PX`] and those on their surface's rim keep their weights.
pub fn even_out(
    fragments: &mut [Fragment],
    w: usize,
    h: usize,
    reach_px: i64,
    coc_px: impl Fn(&Fragment) -> f32 + Sync,
) {
    let radius = reach_px.max(0);
    let pixel_of = |f: &Fragment| -> Option<usize> {
        (f.x >= 0 && f.y >= 0 && (f.x as usize) < w && (f.y as usize) < h)
            .then(|| f.y as usize * w + f.x as usize)
    };
    let bright = |f: &Fragment| f.color[..3].iter().any(|&v| v > BRIGHT);
    let evened = |f: &Fragment| {
        !bright(f) && coc_px(f).abs().max(0.5 * f.motion[0].hypot(f.motion[1])) >= MIN_BLUR_PX
    };
    // Fragments by pixel (a counting sort); those that are not evened out count for nothing.
    let mut starts = vec![0usize; w * h + 1];
    for f in fragments.iter() {
        if let Some(p) = pixel_of(f) {
            starts[p + 1] += 1;
        }
    }
    for i in 0..w * h {
        starts[i + 1] += starts[i];
    }
    let mut fill = starts.clone();
    let mut by_pixel = vec![(0.0f32, 0.0f32); starts[w * h]];
    for f in fragments.iter() {
        if let Some(p) = pixel_of(f) {
            by_pixel[fill[p]] = (if evened(f) { f.weight } else { 0.0 }, f.parallax);
            fill[p] += 1;
        }
    }
    drop(fill);
    let same = |a: f32, b: f32| (a - b).abs() <= SAME_SURFACE_PARALLAX * b.abs();
    // The weight of the surface of parallax `parallax` on pixel (x, y); 0 outside the frame.
    let surface_weight = |x: i64, y: i64, parallax: f32| -> f32 {
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            return 0.0;
        }
        let p = y as usize * w + x as usize;
        by_pixel[starts[p]..starts[p + 1]]
            .iter()
            .filter(|&&(_, other)| same(other, parallax))
            .map(|&(weight, _)| weight)
            .sum()
    };
    // Whether each entry's surface holds all eight pixels round it: only such pixels trade
    // weight, so a surface's rim, where its weight also says how much of a pixel it covers,
    // and a bar two pixels wide keep their samples' weights.
    let interior: Vec<bool> = (0..w * h)
        .into_par_iter()
        .flat_map_iter(|p| {
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            by_pixel[starts[p]..starts[p + 1]]
                .iter()
                .map(move |&(weight, parallax)| {
                    weight > 0.0
                        && (-1..=1).all(|dy| {
                            (-1..=1).all(|dx| surface_weight(x + dx, y + dy, parallax) > 0.0)
                        })
                })
        })
        .collect();
    // The weight of the surface of parallax `parallax` on pixel (x, y) where that pixel is
    // inside it, else 0.
    let inner_weight = |x: i64, y: i64, parallax: f32| -> f32 {
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            return 0.0;
        }
        let p = y as usize * w + x as usize;
        let mut sum = 0.0f32;
        for j in starts[p]..starts[p + 1] {
            let (weight, other) = by_pixel[j];
            if same(other, parallax) {
                if !interior[j] && weight > 0.0 {
                    return 0.0;
                }
                sum += weight;
            }
        }
        sum
    };
    let tent = |dx: i64, dy: i64| ((radius + 1 - dx.abs()) * (radius + 1 - dy.abs())) as f32;
    // The whole tent's sum, `(r + 1)^4`: every pair of pixels exchanges `k / K` of the
    // difference of their weights, so that an even surface stays even at its edges.
    let tent_sum = ((radius + 1) * (radius + 1)).pow(2) as f32;
    let weights: Vec<f32> = fragments
        .par_iter()
        .map(|f| {
            if pixel_of(f).is_none() || !evened(f) {
                return f.weight;
            }
            let (x, y) = (i64::from(f.x), i64::from(f.y));
            let own = inner_weight(x, y, f.parallax);
            if own <= 0.0 {
                return f.weight;
            }
            let mut exchanged = 0.0f32;
            for dy in -radius..=radius {
                for dx in -radius..=radius {
                    if (dx, dy) == (0, 0) {
                        continue;
                    }
                    let other = inner_weight(x + dx, y + dy, f.parallax);
                    if other > 0.0 {
                        exchanged += tent(dx, dy) * (other - own);
                    }
                }
            }
            // The pixel's fragments of this surface share the new weight as they shared the
            // old.
            f.weight * (own + exchanged / tent_sum) / own
        })
        .collect();
    for (f, weight) in fragments.iter_mut().zip(weights) {
        f.weight = weight;
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A still fragment of grey `color` on pixel (x, y) at `depth`, CoC left to the caller.
    pub(crate) fn fragment(x: i32, y: i32, depth: f32, color: f32, weight: f32) -> Fragment {
        Fragment {
            x,
            y,
            color: [color, color, color, 1.0],
            weight,
            parallax: 1.0 / depth,
            depth,
            motion: [0.0; 2],
            bend: 0.0,
            source: 0,
        }
    }

    /// A defocused surface whose samples landed unevenly (weights 0.5 and 1.5 in a checker)
    /// comes out even inside and keeps its whole weight; its rim keeps its samples' weights,
    /// and an in-focus surface, a light, another surface and a fragment outside the frame keep
    /// theirs.
    #[test]
    fn a_surfaces_uneven_counts_even_out_and_its_weight_is_kept() {
        let (w, h) = (12usize, 12usize);
        let coc_of_depth = |d: f32| if d > 1.5 { 4.0 } else { 0.2 };
        let mut frags = Vec::new();
        for y in 2..10 {
            for x in 2..10 {
                let weight = if (x + y) % 2 == 0 { 0.5 } else { 1.5 };
                frags.push(fragment(x, y, 2.0, 0.5, weight));
            }
        }
        let blurred = frags.len();
        frags.push(fragment(0, 0, 1.0, 0.5, 0.3)); // in focus
        frags.push(fragment(5, 5, 2.0, 3.0, 0.25)); // a light on the surface
        frags.push(fragment(6, 6, 8.0, 0.5, 0.7)); // another surface
        frags.push(fragment(-3, 4, 2.0, 0.5, 0.9)); // outside the frame
        let before = frags.clone();
        even_out(&mut frags, w, h, 1, |f| coc_of_depth(f.depth));
        let sum = |fs: &[Fragment]| fs[..blurred].iter().map(|f| f.weight).sum::<f32>();
        assert!(
            (sum(&frags) - sum(&before)).abs() < 1e-4,
            "the surface's weight is kept"
        );
        for (f, b) in frags[..blurred].iter().zip(&before) {
            let rim = f.x == 2 || f.x == 9 || f.y == 2 || f.y == 9;
            // Pixels two or more from the rim trade only with pixels inside the surface.
            let inner = (4..8).contains(&f.x) && (4..8).contains(&f.y);
            if rim {
                assert_eq!(
                    f.weight, b.weight,
                    "the rim ({}, {}) keeps its weight",
                    f.x, f.y
                );
            } else if inner {
                assert!(
                    (f.weight - 1.0).abs() < 1e-5,
                    "inside the surface ({}, {}) evens out: {}",
                    f.x,
                    f.y,
                    f.weight
                );
            }
        }
        for (a, b) in frags[blurred..].iter().zip(&before[blurred..]) {
            assert_eq!(a.weight, b.weight, "{a:?} keeps its weight");
        }
    }

    /// A defocused bar two pixels wide, whose weights across it say how much of each pixel it
    /// covers, keeps them: no pixel of it is inside it.
    #[test]
    fn a_thin_bar_keeps_its_weights() {
        let mut frags: Vec<Fragment> = (0..8)
            .flat_map(|y| [fragment(4, y, 2.0, 0.5, 1.0), fragment(5, y, 2.0, 0.5, 0.3)])
            .collect();
        let before = frags.clone();
        even_out(&mut frags, 8, 8, 2, |_| 3.0);
        for (a, b) in frags.iter().zip(&before) {
            assert_eq!(a.weight, b.weight);
        }
    }

    /// An evenly sampled surface that fills the frame stays even, at the frame's edges too.
    #[test]
    fn an_even_surface_stays_even() {
        let (w, h) = (10usize, 7usize);
        let mut frags: Vec<Fragment> = (0..h as i32)
            .flat_map(|y| (0..w as i32).map(move |x| fragment(x, y, 2.0, 0.5, 0.75)))
            .collect();
        even_out(&mut frags, w, h, 2, |_| 3.0);
        for f in &frags {
            assert!(
                (f.weight - 0.75).abs() < 1e-6,
                "({}, {}): {}",
                f.x,
                f.y,
                f.weight
            );
        }
    }
}
