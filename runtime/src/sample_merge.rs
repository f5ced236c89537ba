//! Merging the fragments of stochastic samples that one PSF would draw alike.
//!
//! Reconstruction places every sample on the pixels around its lens-centre, shutter-centre
//! position (four bilinear taps, or up to nine footprint taps), so each pixel receives a dozen
//! or more fragments, most of them of one surface: the same CoC, motion and depth layer within
//! a small fraction of a pixel. Splatting is linear in colour, so fragments of one pixel with
//! the same PSF can be drawn once with their colours summed. Merged before classification, they
//! are looked up, layered and splatted once: comets at 4 spp goes from 4 M fragments to about
//! one per pixel and surface.
//!
//! Two fragments of a pixel merge when, against the first fragment of the group (its seed),
//! - their signed CoC differs by at most [`COC_TOLERANCE_PX`] plus [`RELATIVE_TOLERANCE`] of
//!   the seed's (pixels),
//! - their motion vectors differ by at most [`MOTION_TOLERANCE_PX`] plus
//!   [`MOTION_RELATIVE_TOLERANCE`] of the seed's length (pixels over the shutter), or
//!   [`STRAIGHT_MOTION_RELATIVE_TOLERANCE`] of it where the seed's path is straight,
//! - their parallax differs by at most [`RELATIVE_TOLERANCE`] of the seed's (the depth
//!   layers, and the CoC of a pinhole camera, which has none),
//! - they come from the same source, and the merged fragment is not brighter than
//!   `bright_above` in any channel (a bright fragment is drawn with a dense twin of its own
//!   PSF, and stays alone).
//!
//! The merged fragment carries the summed weight, the weighted mean colour, parallax and
//! motion; its depth is the inverse of its mean parallax. Each member's CoC and parallax are
//! within twice the tolerance of the merged ones, a small part of a database cell; its motion
//! within twice [`MOTION_TOLERANCE_PX`] plus the relative tolerance, by which its own
//! streak's ends would lie apart from the merged one's.

use crate::camera::Camera;
use crate::pipeline::classify::Fragment;
use rayon::prelude::*;

/// Absolute CoC tolerance for merging, pixels.
pub const COC_TOLERANCE_PX: f32 = 0.1;

/// Absolute motion tolerance for merging, pixels over the shutter: the finest step of a smeared
/// PSF's length ([`crate::motion_smear::SmearKey`]), which draws motions this close alike.
pub const MOTION_TOLERANCE_PX: f32 = 0.25;

/// Motion tolerance relative to the seed's motion length on a bent path (straight ones:
/// [`STRAIGHT_MOTION_RELATIVE_TOLERANCE`]). The samples of one surface that land
/// on a pixel carry motions that differ by more than its motion changes over a pixel: each is
/// moved back from its own time, so the motion it is drawn with is an estimate of the shutter
/// centre's. At 2 % (as for the CoC) a moving surface kept two or three fragments a pixel; at
/// 8 % one or two, drawn with the mean of their motions, and every stochastic set scores the
/// same to the fourth digit (docs/BENCHMARKS.md, "Moving samples merged by their smear").
pub const MOTION_RELATIVE_TOLERANCE: f32 = 0.08;

/// Motion tolerance relative to the seed's motion length where the seed's path is straight
/// (no bend). A surface nearing the camera speeds up over the shutter, and its samples' motions,
/// each moved back to the shutter centre from an estimate of that speed-up, still differ by a
/// median 15 % within one pixel (`approaching-car`, 4 spp): at 8 % its moving pixels kept three
/// or four fragments each, a streak drawn three or four times. At 16 % the car's reconstruction
/// at 4 spp draws 29 % fewer streaks in 18 % less time with the same scores; on a bent path (a
/// rolling wheel, whose points' motions differ in direction within a pixel) 16 % cost FLIP, so
/// there the tolerance stays [`MOTION_RELATIVE_TOLERANCE`] (docs/BENCHMARKS.md, "Straight
/// streaks merged at twice the motion tolerance").
pub const STRAIGHT_MOTION_RELATIVE_TOLERANCE: f32 = 0.16;

/// Tolerance relative to the seed's CoC and parallax.
pub const RELATIVE_TOLERANCE: f32 = 0.02;

/// Pixels beyond the frame on every side within which fragments are merged; fragments farther
/// out (a sample with an extreme label) pass through unmerged, so the pixel index stays bounded
/// by the frame.
const MARGIN_PX: i64 = 32;

/// A group of fragments being merged: sums weighted by the fragments' weights.
#[derive(Clone, Copy)]
struct Group {
    seed: Fragment,
    seed_coc: f32,
    /// The largest motion difference accepted, squared (pixels^2).
    motion_tolerance_sq: f32,
    weight: f32,
    color: [f32; 4],
    parallax: f32,
    motion: [f32; 2],
}

impl Group {
    fn new(f: &Fragment, coc: f32) -> Self {
        let relative = if f.bend == 0.0 {
            STRAIGHT_MOTION_RELATIVE_TOLERANCE
        } else {
            MOTION_RELATIVE_TOLERANCE
        };
        let tolerance = MOTION_TOLERANCE_PX + relative * f.motion[0].hypot(f.motion[1]);
        Group {
            seed: *f,
            seed_coc: coc,
            motion_tolerance_sq: tolerance * tolerance,
            weight: f.weight,
            color: f.color.map(|c| c * f.weight),
            parallax: f.parallax * f.weight,
            motion: f.motion.map(|m| m * f.weight),
        }
    }

    /// Whether `f` (of signed CoC `coc`) is drawn alike by the seed's PSF.
    fn accepts(&self, f: &Fragment, coc: f32) -> bool {
        let s = &self.seed;
        let dm = [f.motion[0] - s.motion[0], f.motion[1] - s.motion[1]];
        f.source == s.source
            && (coc - self.seed_coc).abs()
                <= COC_TOLERANCE_PX + RELATIVE_TOLERANCE * self.seed_coc.abs()
            && dm[0] * dm[0] + dm[1] * dm[1] <= self.motion_tolerance_sq
            && (f.parallax - s.parallax).abs() <= RELATIVE_TOLERANCE * s.parallax.abs()
    }

    fn add(&mut self, f: &Fragment) {
        self.weight += f.weight;
        for (a, c) in self.color.iter_mut().zip(f.color) {
            *a += c * f.weight;
        }
        self.parallax += f.parallax * f.weight;
        for (a, m) in self.motion.iter_mut().zip(f.motion) {
            *a += m * f.weight;
        }
    }

    /// The largest colour channel the merged fragment would draw with `f` added (weighted).
    fn brightest_with(&self, f: &Fragment) -> f32 {
        (0..3)
            .map(|c| self.color[c] + f.color[c] * f.weight)
            .fold(f32::NEG_INFINITY, f32::max)
    }

    fn fragment(&self) -> Fragment {
        let w = self.weight;
        if w <= 0.0 || !w.is_finite() {
            return self.seed;
        }
        let parallax = self.parallax / w;
        Fragment {
            color: self.color.map(|c| c / w),
            weight: w,
            parallax,
            depth: if parallax > 0.0 {
                1.0 / parallax
            } else {
                self.seed.depth
            },
            motion: self.motion.map(|m| m / w),
            ..self.seed
        }
    }
}

/// `fragments` (a `w x h` frame's, from stochastic samples) with those of each pixel that one
/// PSF draws alike merged (module documentation), in row order of their pixels, then the
/// fragments outside the frame's margin as they were. Deterministic: each pixel's fragments
/// are grouped in their input order. `bright_above` is the brightness (a weighted colour
/// channel) above which a fragment is drawn alone.
pub fn merge_alike(
    fragments: &[Fragment],
    w: usize,
    h: usize,
    camera: &Camera,
    bright_above: f32,
) -> Vec<Fragment> {
    merge_placed(
        w,
        h,
        camera,
        bright_above,
        fragments.len(),
        |items, emit| {
            for i in items {
                emit(fragments[i].x, fragments[i].y, i as u32, 1.0);
            }
        },
        |_, _, i, _| fragments[i as usize],
    )
}

/// A fragment's signed CoC radius through `camera`'s thin lens, pixels (0 without a lens),
/// from its parallax: the CoC is affine in it, `coc_scale (1 - focus parallax)`.
pub(crate) fn signed_coc_of(camera: &Camera) -> impl Fn(&Fragment) -> f32 + Copy + Sync {
    let (coc_scale, focus) = camera.thin_lens().map_or((0.0, 0.0), |l| {
        (l.coc_scale_px as f32, l.focus_distance as f32)
    });
    move |f: &Fragment| coc_scale * (1.0 - focus * f.parallax)
}

/// [`merge_alike`] over fragments made on demand from `items` producers (samples):
/// `produce(range, emit)` calls `emit(x, y, index, share)` once per fragment of the items in
/// `range`, in the same order each time it is called, and `fragment_of(x, y, index, share)`
/// makes that fragment. A frame's unmerged fragments are never held at once, only 8 bytes for
/// each. The items are sorted in a fixed number of consecutive runs on every thread, and each
/// pixel reads its fragments run by run: the order of one pass, whatever the thread count.
pub fn merge_placed(
    w: usize,
    h: usize,
    camera: &Camera,
    bright_above: f32,
    items: usize,
    produce: impl Fn(std::ops::Range<usize>, &mut dyn FnMut(i32, i32, u32, f32)) + Sync,
    fragment_of: impl Fn(i32, i32, u32, f32) -> Fragment + Sync,
) -> Vec<Fragment> {
    let coc_of = signed_coc_of(camera);
    let (bw, bh) = (w as i64 + 2 * MARGIN_PX, h as i64 + 2 * MARGIN_PX);
    let cell_of = |x: i32, y: i32| -> Option<usize> {
        let (x, y) = (i64::from(x) + MARGIN_PX, i64::from(y) + MARGIN_PX);
        (x >= 0 && y >= 0 && x < bw && y < bh).then(|| (y * bw + x) as usize)
    };
    let cells = (bw * bh) as usize;
    // Each run's fragments by pixel (a counting sort, stable), and those outside the margin.
    let run_len = items.div_ceil(SORT_RUNS).max(1);
    let runs: Vec<SortedRun> = (0..SORT_RUNS)
        .into_par_iter()
        .map(|r| {
            let range = (r * run_len).min(items)..((r + 1) * run_len).min(items);
            let mut starts = vec![0usize; cells + 1];
            let mut outside = Vec::new();
            produce(
                range.clone(),
                &mut |x, y, index, share| match cell_of(x, y) {
                    Some(c) => starts[c + 1] += 1,
                    None => outside.push(fragment_of(x, y, index, share)),
                },
            );
            for i in 0..cells {
                starts[i + 1] += starts[i];
            }
            let mut fill = starts.clone();
            let mut sorted = vec![(0u32, 0.0f32); starts[cells]];
            produce(range, &mut |x, y, index, share| {
                if let Some(c) = cell_of(x, y) {
                    sorted[fill[c]] = (index, share);
                    fill[c] += 1;
                }
            });
            SortedRun {
                starts,
                sorted,
                outside,
            }
        })
        .collect();
    // Rows of pixels on every thread, each row's groups in pixel order: the same fragments in
    // the same order as one pass.
    let bw = bw as usize;
    let rows: Vec<Vec<Fragment>> = (0..bh as usize)
        .into_par_iter()
        .map_init(Vec::new, |groups: &mut Vec<(Group, bool)>, row| {
            let mut merged = Vec::new();
            for c in row * bw..(row + 1) * bw {
                let mut members = runs
                    .iter()
                    .flat_map(|run| &run.sorted[run.starts[c]..run.starts[c + 1]])
                    .peekable();
                if members.peek().is_none() {
                    continue;
                }
                let (x, y) = ((c % bw) as i64 - MARGIN_PX, row as i64 - MARGIN_PX);
                let (x, y) = (x as i32, y as i32);
                groups.clear();
                for &(index, share) in members {
                    let f = &fragment_of(x, y, index, share);
                    let coc = coc_of(f);
                    let alone = f.color[..3].iter().any(|&v| v * f.weight > bright_above);
                    let into = (!alone)
                        .then(|| {
                            groups.iter_mut().find(|(g, open)| {
                                *open && g.accepts(f, coc) && g.brightest_with(f) <= bright_above
                            })
                        })
                        .flatten();
                    match into {
                        Some((g, _)) => g.add(f),
                        None => groups.push((Group::new(f, coc), !alone)),
                    }
                }
                merged.extend(groups.iter().map(|(g, _)| g.fragment()));
            }
            merged
        })
        .collect();
    let outside: usize = runs.iter().map(|run| run.outside.len()).sum();
    let mut merged = Vec::with_capacity(rows.iter().map(Vec::len).sum::<usize>() + outside);
    for row in rows {
        merged.extend(row);
    }
    for run in runs {
        merged.extend(run.outside);
    }
    merged
}

/// How many consecutive runs of items [`merge_placed`] sorts apart (in parallel): fixed, so
/// that the merge's order does not depend on the number of threads.
const SORT_RUNS: usize = 4;

/// The fragments of one run of items sorted by pixel: pixel `c`'s are
/// `sorted[starts[c]..starts[c + 1]]` as (index, share); those outside the frame's margin
/// are made at once.
struct SortedRun {
    starts: Vec<usize>,
    sorted: Vec<(u32, f32)>,
    outside: Vec<Fragment>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera::from_json_str(
            r#"{"width":8,"height":8,"focal_length_mm":50,"sensor_width_mm":36,
            "f_stop":2.0,"focus_distance":1.0,"aperture_blades":0,"shutter_frames":1.0}"#,
        )
        .expect("camera")
    }

    fn fragment(x: i32, y: i32, depth: f32, motion: [f32; 2], color: f32, weight: f32) -> Fragment {
        Fragment {
            x,
            y,
            color: [color, color, color, 1.0],
            weight,
            parallax: 1.0 / depth,
            depth,
            motion,
            bend: 0.0,
            source: 0,
        }
    }

    /// Fragments of one surface in a pixel become one, with the weighted colour and the light
    /// (colour times weight) kept; another depth, another motion or another pixel stays apart.
    #[test]
    fn merges_one_surface_and_keeps_the_light() {
        let frags = [
            fragment(3, 3, 2.0, [4.0, 0.0], 0.2, 0.25),
            fragment(3, 3, 2.001, [4.01, 0.0], 0.6, 0.5),
            fragment(3, 3, 5.0, [4.0, 0.0], 0.9, 0.25), // another depth: its own CoC
            fragment(3, 3, 2.0, [0.0, 4.0], 0.9, 0.25), // another motion
            fragment(4, 3, 2.0, [4.0, 0.0], 0.9, 0.25), // another pixel
        ];
        let merged = merge_alike(&frags, 8, 8, &camera(), 2.0);
        assert_eq!(merged.len(), 4);
        let first = merged[0];
        assert_eq!((first.x, first.y), (3, 3));
        assert!((first.weight - 0.75).abs() < 1e-6);
        let light = first.color[0] * first.weight;
        assert!((light - (0.2 * 0.25 + 0.6 * 0.5)).abs() < 1e-6, "{light}");
        let total = |fs: &[Fragment]| -> f32 { fs.iter().map(|f| f.color[0] * f.weight).sum() };
        assert!((total(&merged) - total(&frags)).abs() < 1e-5);
    }

    /// Motions within the tolerance of the seed's (0.25 px plus 8 % of its length on a bent
    /// path, 16 % on a straight one) merge to their weighted mean; a motion farther off starts
    /// a fragment of its own.
    #[test]
    fn moving_fragments_merge_within_the_motion_tolerance() {
        let bent = |motion: [f32; 2]| Fragment {
            bend: 2.0,
            ..fragment(2, 2, 2.0, motion, 0.5, 0.25)
        };
        let frags = [
            bent([40.0, 0.0]),
            bent([42.0, 1.0]), // 2.2 px off, within 3.45
            bent([44.0, 0.0]), // 4 px off: apart
            fragment(2, 2, 2.0, [0.2, 0.1], 0.5, 0.25),
            fragment(2, 2, 2.0, [0.0, 0.0], 0.5, 0.25), // 0.22 px off a slow seed
        ];
        let merged = merge_alike(&frags, 8, 8, &camera(), 2.0);
        assert_eq!(merged.len(), 3, "{merged:?}");
        assert_eq!(merged[0].motion, [41.0, 0.5]);
        assert!((merged[0].weight - 0.5).abs() < 1e-6);
        assert_eq!(merged[1].motion, [44.0, 0.0]);
        assert!((merged[2].motion[0] - 0.1).abs() < 1e-6);
        // Straight paths: 4 px off a 40 px motion is within 6.65 px, 7 px is not.
        let frags = [
            fragment(2, 2, 2.0, [40.0, 0.0], 0.5, 0.25),
            fragment(2, 2, 2.0, [44.0, 0.0], 0.5, 0.25),
            fragment(2, 2, 2.0, [40.0, -7.0], 0.5, 0.25),
        ];
        let merged = merge_alike(&frags, 8, 8, &camera(), 2.0);
        assert_eq!(merged.len(), 2, "{merged:?}");
        assert_eq!(merged[0].motion, [42.0, 0.0]);
        assert_eq!(merged[1].motion, [40.0, -7.0]);
    }

    /// A bright fragment is never merged, nor does merging make a group bright.
    #[test]
    fn bright_fragments_stay_alone() {
        let frags = [
            fragment(1, 1, 2.0, [0.0; 2], 12.0, 0.25), // 3.0 weighted: bright
            fragment(1, 1, 2.0, [0.0; 2], 1.2, 0.25),
            fragment(1, 1, 2.0, [0.0; 2], 1.2, 0.25),
            fragment(1, 1, 2.0, [0.0; 2], 6.0, 0.25), // 1.5 alone, 2.1 with the pair: apart
        ];
        let merged = merge_alike(&frags, 8, 8, &camera(), 2.0);
        assert_eq!(merged.len(), 3);
        assert_eq!(merged[0].color[0], 12.0);
        assert!((merged[1].weight - 0.5).abs() < 1e-6);
    }

    /// Fragments far outside the frame are kept as they are, after the others.
    #[test]
    fn fragments_beyond_the_margin_pass_through() {
        let far = fragment(-1_000_000, 5, 2.0, [0.0; 2], 0.5, 1.0);
        let merged = merge_alike(&[far, far], 8, 8, &camera(), 2.0);
        assert_eq!(merged, vec![far, far]);
    }
}
