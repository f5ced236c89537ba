//! A sharp surface seen part of the time behind a blurred one: its weights evened out and its
//! holes filled.
//!
//! Where a moving or defocused surface passes in front of a sharp one (a car driving over a
//! road, a near bar in front of a wall in focus), each pixel's samples split between the two:
//! those that hit the blurred surface are moved back to its lens-centre, shutter-centre image
//! and drawn from there with its PSF, which lays a smooth veil over the pixel; those that hit
//! the sharp surface stay on their pixel. The sharp surface's weight on a pixel is then the
//! count of its samples there, `n / spp`, a binomial draw round the share of the shutter (or
//! the lens) it is seen for. Under the smooth veil that count shows as grain: a pixel whose
//! every sample hit the car shows the car's streak alone, a bright speck in the road; its
//! neighbour with all four on the road, a dark one. The converged frame is smooth there.
//!
//! So, near pixels that lost samples to a nearer blurred surface, the sharp surface's weight
//! becomes the tent-weighted mean of its weights over the pixels that hold only it and such
//! nearer blurred samples (a hole, a pixel all of whose samples went to the blur, counts with
//! weight 0):
//!
//! ```text
//! W'(p) = sum over q in R near p of k(p - q) W(q)  /  sum over q in R near p of k(p - q)
//! ```
//!
//! with `R` those pixels and `k` a tent along the blurred samples' motion where they move one
//! way (the veil is smooth along it and may change abruptly across it, at a car's roof and
//! sill), reaching a quarter of their motion, else a square tent reaching half their mean blur
//! radius, both at most a few times [`crate::sample_density::reach_px`]. A hole gets a fragment
//! of the surface of that weight, coloured with its nearest neighbours' mean colour. A pixel
//! that also holds another sharp surface, holds blurred samples farther than the sharp surface,
//! or that the two leave more than a quarter empty (misses) is not in `R`: there the weights
//! say how much of the pixel each surface covers (an edge in focus; a sharp object over a
//! blurred background), and they are kept. Far from any blurred sample nothing changes, so
//! frames without blur keep their bytes.

use crate::grid::dilate;
use crate::pipeline::classify::Fragment;
use crate::sample_density::{MIN_BLUR_PX, SAME_SURFACE_PARALLAX};
use rayon::prelude::*;

/// What the samples of one pixel that are drawn blurred took from it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BlurredSamples {
    /// Their share of the pixel's samples, in `[0, 1]`.
    pub share: f32,
    /// The largest of their depths, scene units (0 without any).
    pub farthest_depth: f32,
    /// The sum of their motions over the shutter, pixels (x right, y down).
    pub motion_sum: [f32; 2],
    /// The sum of their blur radii (the larger of the CoC radius and half the motion over
    /// the shutter), pixels.
    pub blur_sum: f32,
    /// How many they are.
    pub count: u32,
}

/// How the weights round a pixel are averaged: along a unit direction (x right, y down), or
/// over a square, with the tent reaching this many pixels.
#[derive(Clone, Copy)]
enum Smoothing {
    Along([f32; 2], i64),
    Square(i64),
}

/// A fragment with a channel above this (linear) is a light's: its weight is kept, as
/// [`crate::sample_density::even_out`] keeps it.
const BRIGHT: f32 = 1.0;

/// How far short of the whole pixel a sharp surface's weight and the blurred share may add up
/// for the pixel to be in the surface's region: its samples' footprints spread a sharp
/// sample's weight over neighbouring pixels, so a pixel holding nothing else reads a little
/// over or under one.
const WHOLE_PIXEL_TOLERANCE: f32 = 0.25;

/// How far the average along the blur's motion reaches at most, per pixel of the square
/// tent's reach.
const ALONG_MOTION_REACH_PER_TENT_PX: i64 = 5;

/// Evens out the weights of sharp fragments behind nearer blurred samples and fills the holes
/// those samples left (see the module's text), over a `w` x `h` frame with a tent reaching
/// `reach_px` pixels. `blurred[p]` is what pixel `p`'s blurred samples took from it, `coc_px`
/// a fragment's signed CoC radius, pixels. Fragments outside the frame, lights' and blurred
/// ones keep their weights; new fragments are appended.
pub fn fill_behind_blur(
    fragments: &mut Vec<Fragment>,
    w: usize,
    h: usize,
    reach_px: i64,
    blurred: &[BlurredSamples],
    coc_px: impl Fn(&Fragment) -> f32 + Sync,
) {
    if blurred.len() != w * h || !blurred.iter().any(|b| b.share > 0.0) {
        return;
    }
    let radius = reach_px.max(0);
    let pixel_of = |f: &Fragment| -> Option<usize> {
        (f.x >= 0 && f.y >= 0 && (f.x as usize) < w && (f.y as usize) < h)
            .then(|| f.y as usize * w + f.x as usize)
    };
    let sharp = |f: &Fragment| {
        f.weight > 0.0
            && f.color[..3].iter().all(|&v| v <= BRIGHT)
            && coc_px(f).abs().max(0.5 * f.motion[0].hypot(f.motion[1])) < MIN_BLUR_PX
    };
    // Each pixel's sharp fragments (indices into `fragments`).
    let mut starts = vec![0usize; w * h + 1];
    for f in fragments.iter() {
        if let Some(p) = pixel_of(f).filter(|_| sharp(f)) {
            starts[p + 1] += 1;
        }
    }
    for i in 0..w * h {
        starts[i + 1] += starts[i];
    }
    let mut fill = starts.clone();
    let mut by_pixel = vec![0u32; starts[w * h]];
    for (i, f) in fragments.iter().enumerate() {
        if let Some(p) = pixel_of(f).filter(|_| sharp(f)) {
            by_pixel[fill[p]] = i as u32;
            fill[p] += 1;
        }
    }
    drop(fill);
    if starts[w * h] == 0 {
        return;
    }
    let same = |a: f32, b: f32| (a - b).abs() <= SAME_SURFACE_PARALLAX * b.abs();
    let sharp_at = |p: usize| {
        by_pixel[starts[p]..starts[p + 1]]
            .iter()
            .map(|&i| &fragments[i as usize])
    };
    let has_sharp: Vec<bool> = (0..w * h).map(|p| starts[p] < starts[p + 1]).collect();
    let has_blur: Vec<bool> = blurred.iter().map(|b| b.share > 0.0).collect();
    // Pixels within the tent of a pixel that lost samples to blur (only there do weights
    // move), and within it of a sharp fragment (only there can a hole be filled).
    let near_blur = dilate(&has_blur, w, h, radius as usize);
    let near_sharp = dilate(&has_sharp, w, h, radius as usize);
    // Each pixel's sharp fragments summed: the least and largest parallax, and the weight.
    let surface_at: Vec<Option<PixelSurface>> = (0..w * h)
        .into_par_iter()
        .map(|p| {
            sharp_at(p).fold(None, |found: Option<PixelSurface>, f| {
                Some(match found {
                    None => PixelSurface {
                        parallax: [f.parallax; 2],
                        weight: f.weight,
                    },
                    Some(s) => PixelSurface {
                        parallax: [s.parallax[0].min(f.parallax), s.parallax[1].max(f.parallax)],
                        weight: s.weight + f.weight,
                    },
                })
            })
        })
        .collect();
    // The weight of the surface of `parallax` (at `depth`) on pixel `q` where `q` is in its
    // region: it holds no other sharp surface, its blurred samples are all nearer, and the
    // surface and those samples fill it.
    let region_weight = |q: usize, parallax: f32, depth: f32| -> Option<f32> {
        let own = match surface_at[q] {
            None => 0.0,
            Some(s) if same(s.parallax[0], parallax) && same(s.parallax[1], parallax) => s.weight,
            Some(_) => return None,
        };
        let b = blurred[q];
        if b.share > 0.0 && b.farthest_depth >= depth * (1.0 - SAME_SURFACE_PARALLAX) {
            return None;
        }
        (own + b.share >= 1.0 - WHOLE_PIXEL_TOLERANCE).then_some(own)
    };
    // The holes that may be filled: pixels that lost samples to blur near sharp ones.
    let hole_candidate = |p: usize| has_blur[p] && !has_sharp[p] && near_sharp[p];
    // How the weights round each pixel are averaged, from the blurred samples round it (over
    // the square tent): along their motion where they move one way (the veil they lay is
    // smooth along it and may change abruptly across it, at a car's roof and sill), over a
    // square elsewhere (defocus, a spin); and no farther than a quarter of their motion or
    // half their mean blur radius, over which the veil itself changes (a slowly turning
    // object's outline stays sharp). Worked out where it is asked for (once or twice per pixel
    // whose weights move), not kept for the whole frame.
    let smoothing = |x: i64, y: i64| -> Smoothing {
        let (mut motion, mut blur, mut count) = ([0.0f32; 2], 0.0f32, 0u32);
        for qy in (y - radius).max(0)..=(y + radius).min(h as i64 - 1) {
            for qx in (x - radius).max(0)..=(x + radius).min(w as i64 - 1) {
                let b = &blurred[qy as usize * w + qx as usize];
                motion = [motion[0] + b.motion_sum[0], motion[1] + b.motion_sum[1]];
                blur += b.blur_sum;
                count += b.count;
            }
        }
        if count == 0 {
            return Smoothing::Square(0);
        }
        let length = motion[0].hypot(motion[1]);
        let mean_motion = length / count as f32;
        if mean_motion >= 2.0 * MIN_BLUR_PX {
            let reach = ((0.25 * mean_motion) as i64).min(ALONG_MOTION_REACH_PER_TENT_PX * radius);
            Smoothing::Along([motion[0] / length, motion[1] / length], reach)
        } else {
            Smoothing::Square(((0.5 * blur / count as f32) as i64).min(radius))
        }
    };
    // The pixels round (x, y) the weights are averaged over, with their tent weights.
    let taps = |x: i64, y: i64, out: &mut Vec<(usize, f32)>| {
        out.clear();
        let inside = |qx: i64, qy: i64| qx >= 0 && qy >= 0 && qx < w as i64 && qy < h as i64;
        match smoothing(x, y) {
            Smoothing::Along([dx, dy], reach) => {
                for k in -reach..=reach {
                    let qx = (x as f32 + 0.5 + k as f32 * dx).floor() as i64;
                    let qy = (y as f32 + 0.5 + k as f32 * dy).floor() as i64;
                    if inside(qx, qy) {
                        out.push((qy as usize * w + qx as usize, (reach + 1 - k.abs()) as f32));
                    }
                }
            }
            Smoothing::Square(reach) => {
                for dy in -reach..=reach {
                    for dx in -reach..=reach {
                        if inside(x + dx, y + dy) {
                            let k = (reach + 1 - dx.abs()) * (reach + 1 - dy.abs());
                            out.push(((y + dy) as usize * w + (x + dx) as usize, k as f32));
                        }
                    }
                }
            }
        }
    };
    // The tent's mean of the surface's weight round pixel (x, y) over its region.
    let mean_weight = |x: i64,
                       y: i64,
                       parallax: f32,
                       depth: f32,
                       scratch: &mut Vec<(usize, f32)>|
     -> Option<f32> {
        taps(x, y, scratch);
        let (mut sum, mut norm) = (0.0f32, 0.0f32);
        for &(q, k) in scratch.iter() {
            if let Some(own) = region_weight(q, parallax, depth) {
                sum += k * own;
                norm += k;
            }
        }
        (norm > 0.0).then(|| sum / norm)
    };
    // New weights of the sharp fragments near blur whose pixel is in their surface's region.
    let weights: Vec<Option<f32>> = fragments
        .par_iter()
        .map_init(Vec::new, |scratch, f| {
            let p = pixel_of(f)?;
            if !near_blur[p] || !sharp(f) {
                return None;
            }
            let own = region_weight(p, f.parallax, f.depth)?;
            let mean = mean_weight(i64::from(f.x), i64::from(f.y), f.parallax, f.depth, scratch)?;
            (own > 0.0).then(|| f.weight * mean / own)
        })
        .collect();
    // The holes: pixels that lost samples to blur and hold no sharp fragment, each given the
    // surface round it that weighs most there.
    let holes: Vec<Fragment> = (0..w * h)
        .into_par_iter()
        .filter(|&p| hole_candidate(p))
        .map_init(Vec::new, |scratch, p| {
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            // The surfaces in the nearest square round the hole that holds any (up to the
            // tent's reach), each with its summed weight and weighted sums of colour, parallax
            // and motion, and its heaviest fragment (for its source). The colour comes from the
            // nearest pixels: averaged along the blur's motion it ran across the texture's
            // edges behind.
            let mut surfaces: Vec<NearbySurface> = Vec::new();
            for reach in 1..=radius.max(1) {
                for qy in (y - reach).max(0)..=(y + reach).min(h as i64 - 1) {
                    for qx in (x - reach).max(0)..=(x + reach).min(w as i64 - 1) {
                        if (qx - x).abs().max((qy - y).abs()) != reach {
                            continue;
                        }
                        for f in sharp_at(qy as usize * w + qx as usize) {
                            match surfaces.iter_mut().find(|s| same(f.parallax, s.parallax())) {
                                Some(s) => s.add(f),
                                None => surfaces.push(NearbySurface::of(f)),
                            }
                        }
                    }
                }
                if !surfaces.is_empty() {
                    break;
                }
            }
            let surface = surfaces
                .iter()
                .max_by(|a, b| a.weight.total_cmp(&b.weight))?;
            let parallax = surface.parallax();
            let depth = if parallax > 0.0 {
                1.0 / parallax
            } else {
                surface.heaviest.depth
            };
            // Only a pixel whose blurred samples are all nearer than the surface is its hole
            // (not one where the surface itself is blurred, its samples moved away).
            region_weight(p, parallax, depth)?;
            let weight = mean_weight(x, y, parallax, depth, scratch)?;
            (weight > 0.0).then(|| Fragment {
                x: x as i32,
                y: y as i32,
                color: surface.color_sum.map(|c| c / surface.weight),
                weight,
                parallax,
                depth,
                motion: surface.motion_sum.map(|m| m / surface.weight),
                bend: 0.0,
                source: surface.heaviest.source,
            })
        })
        .flatten()
        .collect();
    for (f, weight) in fragments.iter_mut().zip(weights) {
        if let Some(weight) = weight {
            f.weight = weight;
        }
    }
    fragments.extend(holes);
}

/// A pixel's sharp fragments: the least and the largest of their parallaxes, and their summed
/// weight (in fragment order).
#[derive(Clone, Copy)]
struct PixelSurface {
    parallax: [f32; 2],
    weight: f32,
}

/// A surface's sharp fragments round a hole: their summed weight, weighted sums of colour,
/// parallax and motion, and the heaviest of them (whose source a hole's fragment takes).
struct NearbySurface<'a> {
    weight: f32,
    color_sum: [f32; 4],
    parallax_sum: f32,
    motion_sum: [f32; 2],
    heaviest: &'a Fragment,
}

impl<'a> NearbySurface<'a> {
    fn of(f: &'a Fragment) -> Self {
        Self {
            weight: f.weight,
            color_sum: f.color.map(|c| f.weight * c),
            parallax_sum: f.weight * f.parallax,
            motion_sum: f.motion.map(|m| f.weight * m),
            heaviest: f,
        }
    }

    fn add(&mut self, f: &'a Fragment) {
        self.weight += f.weight;
        for (sum, c) in self.color_sum.iter_mut().zip(f.color) {
            *sum += f.weight * c;
        }
        self.parallax_sum += f.weight * f.parallax;
        for (sum, m) in self.motion_sum.iter_mut().zip(f.motion) {
            *sum += f.weight * m;
        }
        if f.weight > self.heaviest.weight {
            self.heaviest = f;
        }
    }

    /// The weighted mean parallax.
    fn parallax(&self) -> f32 {
        self.parallax_sum / self.weight
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    // Still and given CoC 0 below: sharp.
    use crate::sample_density::tests::fragment as sharp;

    /// Every pixel of a `w` x `h` frame lost `share` of its samples to blurred ones at
    /// `depth` moving `motion` px over the shutter.
    fn veil(w: usize, h: usize, share: f32, depth: f32, motion: [f32; 2]) -> Vec<BlurredSamples> {
        vec![
            BlurredSamples {
                share,
                farthest_depth: depth,
                motion_sum: motion,
                blur_sum: 0.5 * motion[0].hypot(motion[1]),
                count: 1,
            };
            w * h
        ]
    }

    /// A wall at 4 behind a car at 2 moving 24 px along x, seen a quarter of the time: its
    /// pixels hold 0 to 2 of 4 samples (weights 0, 0.25, 0.5). The weights even out to
    /// their mean along the motion, and the holes get the wall's colour at that weight.
    #[test]
    fn a_wall_behind_a_moving_car_evens_out_and_its_holes_are_filled() {
        let (w, h) = (24usize, 3usize);
        let counts = [0u32, 1, 2, 1, 0, 1, 2, 1];
        let mut frags = Vec::new();
        for y in 0..h as i32 {
            for x in 0..w as i32 {
                let n = counts[x as usize % counts.len()];
                if n > 0 {
                    frags.push(sharp(x, y, 4.0, 0.3, 0.25 * n as f32));
                }
            }
        }
        let mut blurred = veil(w, h, 0.0, 2.0, [24.0, 0.0]);
        for y in 0..h {
            for x in 0..w {
                blurred[y * w + x].share = 1.0 - 0.25 * counts[x % counts.len()] as f32;
            }
        }
        fill_behind_blur(&mut frags, w, h, 2, &blurred, |_| 0.0);
        let mut weight = vec![0.0f32; w * h];
        for f in &frags {
            let off = f
                .color
                .iter()
                .zip([0.3, 0.3, 0.3, 1.0])
                .map(|(a, b)| (a - b).abs());
            assert!(
                off.fold(0.0, f32::max) < 1e-6,
                "a hole takes its neighbours' colour"
            );
            weight[f.y as usize * w + f.x as usize] += f.weight;
        }
        // Away from the frame's ends the tent (reach 6 along x) covers whole periods.
        for y in 0..h {
            for x in 8..16 {
                let got = weight[y * w + x];
                assert!((got - 0.25).abs() < 0.03, "({x}, {y}): {got}");
            }
        }
    }

    /// Where the blurred samples lie behind the sharp surface (a sharp object's edge over a
    /// defocused background), where another sharp surface shares the pixel (an edge in
    /// focus), and where nothing was blurred, the weights are kept and no hole is filled.
    #[test]
    fn edges_in_focus_and_sharp_objects_over_blur_keep_their_weights() {
        let (w, h) = (8usize, 8usize);
        // A sharp object at 2 over the left half, covering column 4 by half; a background
        // at 6 behind it blurred.
        let mut frags: Vec<Fragment> = (0..h as i32)
            .flat_map(|y| {
                (0..5).map(move |x| sharp(x, y, 2.0, 0.8, if x == 4 { 0.5 } else { 1.0 }))
            })
            .collect();
        let mut blurred = veil(w, h, 0.0, 0.0, [0.0; 2]);
        for y in 0..h {
            for x in 4..w {
                blurred[y * w + x] = BlurredSamples {
                    share: if x == 4 { 0.5 } else { 1.0 },
                    farthest_depth: 6.0,
                    motion_sum: [0.0; 2],
                    blur_sum: 5.0,
                    count: 1,
                };
            }
        }
        let before = frags.clone();
        fill_behind_blur(&mut frags, w, h, 2, &blurred, |_| 0.0);
        assert_eq!(frags, before, "a sharp object over a blurred background");

        // Two sharp surfaces meeting at column 4, a nearer blurred veil over both.
        let mut frags: Vec<Fragment> = (0..h as i32)
            .flat_map(|y| {
                (0..w as i32).flat_map(move |x| match x {
                    4 => vec![sharp(x, y, 3.0, 0.2, 0.3), sharp(x, y, 5.0, 0.7, 0.3)],
                    x if x < 4 => vec![sharp(x, y, 3.0, 0.2, 0.6)],
                    _ => vec![sharp(x, y, 5.0, 0.7, 0.6)],
                })
            })
            .collect();
        let blurred = veil(w, h, 0.4, 1.0, [0.0, 0.0]);
        let before = frags.clone();
        fill_behind_blur(&mut frags, w, h, 2, &blurred, |_| 0.0);
        let column = |fs: &[Fragment]| -> Vec<f32> {
            fs.iter().filter(|f| f.x == 4).map(|f| f.weight).collect()
        };
        assert_eq!(
            column(&frags),
            column(&before),
            "the edge's pixels keep their cover"
        );

        let mut frags = before.clone();
        fill_behind_blur(&mut frags, w, h, 2, &veil(w, h, 0.0, 1.0, [0.0; 2]), |_| {
            0.0
        });
        assert_eq!(frags, before, "nothing blurred, nothing changes");
    }
}
