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
//! Each blurred fragment's weight is therefore spread over the pixels around it that hold
//! fragments of the same surface, by a tent (5 x 5 below 8 spp, 3 x 3 from it, [`reach_px`])
//! normalised over those pixels only:
//!
//! ```text
//! W'(p) = sum over q near p of  W(q) k(p - q) / sum over r near q, r of the surface, of k(r - q)
//! ```
//!
//! where `W(q)` is the surface's weight on pixel `q` and `k` the tent
//! `(r + 1 - |dx|) (r + 1 - |dy|)` of reach `r`.
//! A surface's weight never moves onto a pixel it does not reach, so its sum is kept exactly
//! (its coverage, which composites it with the layers behind, stays where it was) and a thin
//! bar keeps its weight; inside the surface the counts' grain averages out.
//!
//! Only fragments whose PSF is wider than a pixel are evened out: an in-focus fragment is its
//! own pixel's colour, and its weight against its neighbours' is the pixel filter. A light's
//! fragment (a channel above 1) keeps its weight, as it stays unmerged. From
//! [`EVEN_BELOW_SPP`] samples per pixel the counts are even enough: there the step made
//! sharp edges slightly softer and is left out.

use crate::pipeline::classify::Fragment;
use rayon::prelude::*;

/// Frames with fewer samples per pixel than this have their blurred fragments' weights evened
/// out. At 16 spp it cost FLIP p99 on the built-in `studio` scene and a Cycles disc.
pub const EVEN_BELOW_SPP: usize = 16;

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
/// [`WIDE_TENT_BELOW_SPP`], 1 (3 x 3) from it. At 1 to 4 spp the wider tent did better on
/// every Cycles and built-in frame but `fence` at 4 spp (FLIP mean +0.0002); at 8 spp it cost
/// FLIP p99 on `studio` (0.1777 -> 0.1791).
pub fn reach_px(spp: usize) -> i64 {
    if spp < WIDE_TENT_BELOW_SPP {
        2
    } else {
        1
    }
}

/// Evens out the weights of the blurred fragments of a `w` x `h` frame in place (see the
/// module's text), with a tent reaching `reach_px` pixels ([`reach_px`]). `coc_px(f)` is a fragment's signed CoC radius, pixels. Fragments outside
/// the frame, lights' fragments and those of blur under [`MIN_BLUR_PX`] keep their weights.
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
    // The weight of the surface of parallax `parallax` on pixel (x, y); 0 outside the frame.
    let surface_weight = |x: i64, y: i64, parallax: f32| -> f32 {
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            return 0.0;
        }
        let p = y as usize * w + x as usize;
        by_pixel[starts[p]..starts[p + 1]]
            .iter()
            .filter(|&&(_, other)| (other - parallax).abs() <= SAME_SURFACE_PARALLAX * parallax.abs())
            .map(|&(weight, _)| weight)
            .sum()
    };
    let tent = |dx: i64, dy: i64| ((radius + 1 - dx.abs()) * (radius + 1 - dy.abs())) as f32;
    // First each fragment's weight per unit of the tent over its surface's pixels around it
    // (0 for one that keeps its weight), in the order of `by_pixel`.
    let mut per_tent = vec![0.0f32; by_pixel.len()];
    per_tent
        .par_chunks_mut(w.max(1))
        .zip(by_pixel.par_chunks(w.max(1)))
        .enumerate()
        .for_each(|(chunk, (out, entries))| {
            // Entries of one chunk lie on consecutive pixels; find each one's pixel by walking
            // `starts` along with it.
            let first = chunk * w.max(1);
            let mut pixel = starts.partition_point(|&s| s <= first) - 1;
            for (i, (o, &(weight, parallax))) in out.iter_mut().zip(entries).enumerate() {
                while starts[pixel + 1] <= first + i {
                    pixel += 1;
                }
                if weight <= 0.0 {
                    continue;
                }
                let (x, y) = ((pixel % w) as i64, (pixel / w) as i64);
                let mut spread = 0.0f32;
                for dy in -radius..=radius {
                    for dx in -radius..=radius {
                        if surface_weight(x + dx, y + dy, parallax) > 0.0 {
                            spread += tent(dx, dy);
                        }
                    }
                }
                *o = weight / spread;
            }
        });
    // What the pixels of fragment `f`'s surface around it give its pixel.
    let received = |f: &Fragment| -> f32 {
        let mut sum = 0.0f32;
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let (x, y) = (i64::from(f.x) + dx, i64::from(f.y) + dy);
                if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                    continue;
                }
                let p = y as usize * w + x as usize;
                let given: f32 = (starts[p]..starts[p + 1])
                    .filter(|&j| {
                        let other = by_pixel[j].1;
                        (other - f.parallax).abs() <= SAME_SURFACE_PARALLAX * f.parallax.abs()
                    })
                    .map(|j| per_tent[j])
                    .sum();
                sum += tent(dx, dy) * given;
            }
        }
        sum
    };
    let weights: Vec<f32> = fragments
        .par_iter()
        .map(|f| {
            if pixel_of(f).is_none() || !evened(f) {
                return f.weight;
            }
            let own = surface_weight(i64::from(f.x), i64::from(f.y), f.parallax);
            if own <= 0.0 {
                return f.weight;
            }
            // The pixel's fragments of this surface share what it receives as they shared
            // its weight.
            f.weight * received(f) / own
        })
        .collect();
    for (f, weight) in fragments.iter_mut().zip(weights) {
        f.weight = weight;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fragment(x: i32, y: i32, depth: f32, color: f32, weight: f32) -> Fragment {
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
    /// comes out even inside, keeps its whole weight, and moves none onto pixels it does not
    /// reach; an in-focus surface, a light and a surface at another depth keep theirs.
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
        assert!((sum(&frags) - sum(&before)).abs() < 1e-4, "the surface's weight is kept");
        for f in &frags[..blurred] {
            // Pixels two or more from the edge see only the surface's checker around them.
            let inner = (4..8).contains(&f.x) && (4..8).contains(&f.y);
            if inner {
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

    /// A thin bar (one pixel wide) keeps its weight: none of it leaks to the pixels beside it.
    #[test]
    fn a_thin_bar_keeps_its_weight() {
        let mut frags: Vec<Fragment> = (0..8)
            .map(|y| fragment(4, y, 2.0, 0.5, if y % 2 == 0 { 0.25 } else { 1.0 }))
            .collect();
        let before: f32 = frags.iter().map(|f| f.weight).sum();
        even_out(&mut frags, 8, 8, 2, |_| 3.0);
        let after: f32 = frags.iter().map(|f| f.weight).sum();
        assert!((after - before).abs() < 1e-5);
        assert!(frags.iter().all(|f| f.x == 4 && f.weight > 0.25));
    }
}
