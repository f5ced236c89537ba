//! Denoising stochastic samples where they are cheapest to denoise: at the lens centre and the
//! shutter centre.
//!
//! Moved back there ([`crate::reconstruct::moved_samples`]), the samples of one surface lie
//! densely around its sharp pinhole image, whatever their lens point and time, so the shading
//! noise they carry (light selection, soft shadows, bounces) can be averaged over neighbours of
//! the same surface without blurring lens or motion blur, which the PSFs apply afterwards, and
//! without mixing a foreground with the background seen past its edge.
//!
//! Each sample with guides is a cross-bilateral mean of the samples around it, of its
//! illumination `c / (albedo + eps)` (demodulated, so that texture is kept exactly and only
//! lighting is averaged), multiplied back by its own albedo. The weight of a neighbour `j` for
//! sample `i` is the product of
//! - space: `exp(-d^2 / (2 sigma^2))`, `d` the distance of their moved positions in pixels;
//! - depth: `exp(-(dz / (DEPTH_TOLERANCE z_i))^2)`, the same surface or none, of the depths
//!   at the shutter centre ([`crate::reconstruct::MovedSample::depth`]): a surface nearing the
//!   camera is one depth there, where its samples' own depths, each at its time, lay apart by
//!   more than the tolerance and split it into as many surfaces as times;
//! - normal: `max(0, n_i . n_j)^NORMAL_POWER`;
//! - albedo: `exp(-|a_i - a_j|^2 / ALBEDO_SIGMA^2)`, relative to the brighter albedo, so that an
//!   emitter (whose guide albedo holds its emission) never mixes with a lit surface.
//!
//! The samples of one pixel that lie on one surface (depth within half that tolerance, normal
//! and albedo within a tenth of theirs) share the filtered illumination of their mean position
//! and depth: the filter runs once per pixel and surface, four times less often at 4 spp, and
//! their fragments are merged after it anyway ([`crate::sample_merge`]). Its neighbours see
//! those whose depths agree within a tenth of the tolerance as one entry at their mean
//! position, weighted by their number, or as two where the brightest stands out
//! ([`OUTLIER_FACTOR`]), so that the firefly rules below still see a firefly alone.
//!
//! The first filter reaches 2.5 sigma (4 px at 1 spp, 3 px at 4 spp), too little to take the
//! noise of one or four samples per pixel down to a clean frame. Its result is widened by
//! three passes over the groups ("a trous": a 3 x 3 tent with its taps 2, 4 and 8 px apart;
//! a fourth, 16 px apart, at 1 spp, and only the first two from [`NARROW_WIDENING_SPP`]: the
//! less noise the first filter leaves, the less far it is widened),
//! each weighing a neighbouring group by the same guides and by how far their illumination
//! differs in units of the noise the first filter left (the standard deviation of its
//! weighted mean, the smaller of the two groups'): differences within the noise are averaged,
//! larger ones (a contact shadow, a shadow's edge) are kept, and a noise-free frame is left
//! as the first filter made it.
//!
//! The firefly cap takes light from the surface round a rare bright sample: the light that
//! sample stands for in the converged frame. That light is spread back by wider passes of the
//! guides alone ([`EXCESS_STEPS_PX`]) and added at a share that grows with the sample count
//! ([`excess_weight`]).
//!
//! Samples without a hit, and samples whose neighbours all weigh nothing, keep their colour.

use formats::{SampleGuides, StochasticFrames};
use rayon::prelude::*;

use crate::reconstruct::{MovedSample, SamplesByPixel};

/// Spatial standard deviation of the filter at one sample per pixel, pixels; it narrows as
/// `spp^(-1/4)`, so more samples buy both less noise and less blur.
pub const SIGMA_1SPP_PX: f32 = 1.5;

/// Relative depth difference at which a neighbour's weight falls to `1/e`.
pub const DEPTH_TOLERANCE: f32 = 0.03;

/// Exponent of the normals' cosine in the weight.
pub const NORMAL_POWER: i32 = 16;

/// Relative albedo difference at which a neighbour's weight falls to `1/e`.
pub const ALBEDO_SIGMA: f32 = 0.1;

/// Neighbours farther than this many standard deviations (weight under 0.044) are left out.
const CUTOFF_SIGMAS: f32 = 2.5;

/// A neighbour whose weight's exponent (distance, guides and shading together) exceeds this
/// weighs nothing (`e^-12`, six millionths). The exponent is cut there before it is
/// exponentiated: far beyond it `expf` takes its slow underflow path (cut, a car driving at
/// the camera reconstructs from 4 spp 6 % faster, to the same bytes).
const WEIGHT_EXPONENT_CUT: f32 = 12.0;

/// A neighbour's illumination counts at most this many times the mean round a sample without
/// its brightest neighbour (luminance), in the filter's second pass.
pub const FIREFLY_FACTOR: f32 = 8.0;

/// A neighbour's illumination counts at most this many mean absolute deviations (of the
/// neighbourhood's luminance, without its brightest) above that mean, where this is below
/// [`FIREFLY_FACTOR`] times it: on a bright surface a bounce four times its level passes
/// the factor and became a soft blob. About ten standard deviations of Gaussian noise, so
/// shading (a shadow's edge lies within one deviation or two of the level) is never capped.
pub const FIREFLY_DEVIATIONS: f32 = 12.0;

/// Added to the albedo before demodulating, so that black surfaces keep their colour.
const ALBEDO_EPSILON: f32 = 1e-3;

/// The spatial standard deviation for `spp` samples per pixel, pixels.
pub fn sigma_px(spp: usize) -> f32 {
    SIGMA_1SPP_PX / (spp.max(1) as f32).powf(0.25)
}

/// The denoised colour of every sample of `frames` (in its order), given its `guides` and
/// where each sample lands at the lens and shutter centre (`moved`, `None` for samples that
/// carry nothing). Alpha is kept; colour stays premultiplied.
pub fn denoise_samples(
    frames: &StochasticFrames,
    guides: &[SampleGuides],
    moved: &[Option<MovedSample>],
) -> Vec<[f32; 4]> {
    let (w, h) = (frames.width, frames.height);
    let sigma = sigma_px(frames.spp);
    let reach = (CUTOFF_SIGMAS * sigma).ceil() as i64;
    // Samples indexed by the pixel their moved position falls in (counting sort), for those
    // inside the frame.
    let cell_of = |m: &MovedSample| m.pixel(w, h);
    // Members and pixels are numbered in 32 bits (no frame that fits in memory has 4 G
    // samples); such a frame would keep its colours.
    let too_large = frames.samples.len() >= NOT_A_MEMBER as usize || w * h >= NOT_A_MEMBER as usize;
    if guides.len() != frames.samples.len() || too_large {
        return frames.samples.iter().map(|s| s.color).collect();
    }
    let hit = |k: usize| frames.samples[k].color[3] > 0.0;
    // Each sample's pixel (`w * h`, sorting last, for a miss or outside the frame); then the
    // sample indices sorted by it, so that the members are built in parallel, in their final
    // place.
    let cells: Vec<u32> = moved
        .par_iter()
        .enumerate()
        .map(|(k, m)| match m.as_ref().and_then(cell_of) {
            Some(cell) if hit(k) => cell as u32,
            _ => (w * h) as u32,
        })
        .collect();
    let SamplesByPixel {
        starts,
        mut order,
        place,
    } = SamplesByPixel::new(&cells, w * h);
    drop(cells);
    // The members, pixel by pixel; each sample's place among them (NOT_A_MEMBER outside the
    // frame or for a miss).
    let members_count = starts[w * h];
    order.truncate(members_count);
    let member_of: Vec<u32> = place
        .into_iter()
        .map(|p| {
            if (p as usize) < members_count {
                p
            } else {
                NOT_A_MEMBER
            }
        })
        .collect();
    // Every member as the filter reads it, gathered in pixel order: one gather of each
    // sample's colour, guides and moved position, on every thread, after which the grouping
    // reads its members in order. (Built in the samples' order first and then looked up in
    // pixel order, a defocused frame's members were a random read each while grouping, with
    // little else in flight: on comets at 4 spp building and grouping took 77-89 ms, now
    // 56-62.)
    let members: Vec<Member> = order
        .par_iter()
        .map(|&k| {
            let k = k as usize;
            let (s, g) = (&frames.samples[k], &guides[k]);
            // Where and how deep the sample lies at the lens and shutter centre: a surface
            // nearing the camera is one depth there, whatever each sample's time.
            let (q, depth) = moved[k].map_or(([0.0; 2], s.depth), |m| (m.q, m.depth));
            Member {
                q,
                depth,
                normal: g.normal,
                albedo: g.albedo,
                illumination: std::array::from_fn(|c| {
                    s.color[c] / (g.albedo[c].max(0.0) + ALBEDO_EPSILON)
                }),
            }
        })
        .collect();
    // Each pixel's members grouped by surface, row by row on every thread: the groups (as
    // filter targets: mean position, the first member's guides), the neighbour entries they
    // make, each pixel's entry count, and each member's group in its row.
    let rows: Vec<RowGroups> = (0..h)
        .into_par_iter()
        .map(|y| {
            let cells = &starts[y * w..=(y + 1) * w];
            RowGroups::of(&members[cells[0]..cells[w]], cells)
        })
        .collect();
    drop(members);
    let mut entry_starts = Vec::with_capacity(w * h + 1);
    entry_starts.push(0usize);
    for row in &rows {
        for &n in &row.entries_per_cell {
            entry_starts.push(entry_starts[entry_starts.len() - 1] + n as usize);
        }
    }
    let entries: Vec<Entry> = join_rows(
        &rows,
        |r| r.entries.len(),
        |y, part| part.copy_from_slice(&rows[y].entries),
    );
    let inv_two_var = 1.0 / (2.0 * sigma * sigma);
    let max_d2 = (CUTOFF_SIGMAS * sigma).powi(2);
    // The cross-bilateral weights round `target`: every neighbour's (weight, luminance,
    // illumination), in neighbourhood order, into `out`.
    let neighbours = |target: &Member, out: &mut Vec<(f32, f32, [f32; 3])>| {
        out.clear();
        let mi = target;
        let inv_depth = 1.0 / (DEPTH_TOLERANCE * target.depth);
        let (cx, cy) = (mi.q[0].floor() as i64, mi.q[1].floor() as i64);
        for y in (cy - reach).max(0)..=(cy + reach).min(h as i64 - 1) {
            let (x0, x1) = ((cx - reach).max(0), (cx + reach).min(w as i64 - 1));
            if x1 < x0 {
                continue;
            }
            let row = y as usize * w;
            let (first, last) = (row + x0 as usize, row + x1 as usize);
            let row_entries = &entries[entry_starts[first]..entry_starts[last + 1]];
            // Every entry within reach written, and the next one written over it where it
            // weighs nothing: which entries do is data (noise, edges), and a branch for each
            // test mispredicted more than the arithmetic it skipped.
            let mut kept = out.len();
            out.resize(kept + row_entries.len(), (0.0, 0.0, [0.0; 3]));
            for entry in row_entries {
                let mj = &entry.at;
                let (dx, dy) = (mj.q[0] - mi.q[0], mj.q[1] - mi.q[1]);
                let d2 = dx * dx + dy * dy;
                // Beyond the cut-off, or another surface: which entries are is geometry,
                // predictable.
                if d2 > max_d2 || another_surface(mi, mj, inv_depth) {
                    continue;
                }
                let (guides, cosine) = guide_terms(mi, mj, inv_depth);
                let exponent = d2 * inv_two_var + guides;
                let weight = (-exponent.min(WEIGHT_EXPONENT_CUT)).exp()
                    * cosine.powi(NORMAL_POWER)
                    * entry.count;
                let keep = (cosine > 0.0)
                    & (exponent <= WEIGHT_EXPONENT_CUT)
                    & (weight > 0.0)
                    & weight.is_finite();
                out[kept] = (weight, entry.luminance, mj.illumination);
                kept += usize::from(keep);
            }
            out.truncate(kept);
        }
    };
    // The weighted mean illumination of `neighbours`, each neighbour's luminance capped at
    // `ceiling`, or without the brightest neighbour when `ceiling` is infinite (a level that
    // one outlier does not move); and what the cap took from that mean (zero without a cap).
    let capped_mean = |neighbours: &[(f32, f32, [f32; 3])], ceiling: f32| {
        let mut sum = [0.0f32; 3];
        let mut taken = [0.0f32; 3];
        let mut total = 0.0f32;
        // The brightest neighbour: luminance, weight and illumination.
        let mut brightest = (f32::NEG_INFINITY, 0.0f32, [0.0f32; 3]);
        for &(weight, lum, e) in neighbours {
            if lum > brightest.0 {
                brightest = (lum, weight, e);
            }
            if lum > ceiling {
                let cap = ceiling / lum;
                for c in 0..3 {
                    sum[c] += weight * cap * e[c];
                    taken[c] += weight * (1.0 - cap) * e[c];
                }
            } else {
                for (acc, e) in sum.iter_mut().zip(e) {
                    *acc += weight * e;
                }
            }
            total += weight;
        }
        if ceiling.is_infinite() && total - brightest.1 > 0.0 {
            let (_, w, e) = brightest;
            for (acc, e) in sum.iter_mut().zip(e) {
                *acc -= w * e;
            }
            total -= w;
        }
        (total > 0.0 && total.is_finite())
            .then(|| (sum.map(|v| v / total), taken.map(|v| (v / total).max(0.0))))
    };
    let mean_illumination = |neighbours: &[(f32, f32, [f32; 3])], ceiling: f32| {
        capped_mean(neighbours, ceiling).map(|(mean, _)| mean)
    };
    // First the mean without the neighbourhood's brightest sample; then the mean with every
    // neighbour's luminance capped at FIREFLY_FACTOR times that level, or FIREFLY_DEVIATIONS
    // mean absolute deviations above it where that is lower, so that one rare bright sample
    // (a bounce that found a small emitter) is not spread into a blob over its neighbours,
    // nor kept as a speck, on a dark surface or a bright one.
    // The filtered illumination, the light the cap took, and the luminance ceiling under which
    // the noise is measured.
    let filter_capped = |target: &Member, found: &mut Vec<(f32, f32, [f32; 3])>| {
        neighbours(target, found);
        let level = mean_illumination(found, f32::INFINITY)?;
        let level_luminance = luminance(level).max(0.0);
        // The spread round that level: the weighted mean absolute deviation of the
        // neighbours' luminance, the brightest again left out.
        let mut brightest = (f32::NEG_INFINITY, 0.0f32);
        let (mut total, mut deviation) = (0.0f32, 0.0f32);
        for &(weight, lum, _) in found.iter() {
            if lum > brightest.0 {
                brightest = (lum, weight);
            }
            total += weight;
            deviation += weight * (lum - level_luminance).abs();
        }
        let (brightest_luminance, brightest_weight) = brightest;
        let total = total - brightest_weight;
        let deviation =
            deviation - brightest_weight * (brightest_luminance - level_luminance).abs();
        let mut ceiling = FIREFLY_FACTOR * level_luminance;
        if total > 0.0 {
            ceiling =
                ceiling.min(level_luminance + FIREFLY_DEVIATIONS * (deviation / total).max(0.0));
        }
        let (mean, taken) = capped_mean(found, ceiling)?;
        // The widening passes read the noise of the neighbourhood under the factor's cap
        // alone: the deviations' cap, tighter where the surface is quiet, would call a
        // neighbourhood with fireflies in it quieter than it is, and the passes would then
        // leave its bumps in place.
        Some((mean, taken, FIREFLY_FACTOR * level_luminance))
    };
    let filter = |target: &Member, found: &mut Vec<(f32, f32, [f32; 3])>| {
        filter_capped(target, found).map(|(mean, _, _)| mean)
    };
    // The filter's result, the noise it leaves (the standard deviation of the weighted mean of
    // the neighbourhood's luminance under the factor's cap, `sqrt(variance / effective
    // count)`) and the light the cap took from the mean.
    let filter_with_noise = |target: &Member, found: &mut Vec<(f32, f32, [f32; 3])>| {
        let (mean, excess, ceiling) = filter_capped(target, found)?;
        let mean_luminance = luminance(mean);
        let (mut sw, mut sw2, mut swd2) = (0.0f32, 0.0f32, 0.0f32);
        for &(weight, lum, _) in found.iter() {
            let d = lum.min(ceiling) - mean_luminance;
            (sw, sw2, swd2) = (sw + weight, sw2 + weight * weight, swd2 + weight * d * d);
        }
        let noise = if sw > 0.0 && sw2 > 0.0 {
            (swd2 / sw * sw2 / (sw * sw)).sqrt()
        } else {
            0.0
        };
        Some((mean, noise, excess))
    };
    // The members of one pixel that lie on one surface share one filtered illumination, that
    // of their mean position: the filter runs once per pixel and surface, not once per sample.
    let targets: Vec<Member> = join_rows(
        &rows,
        |r| r.targets.len(),
        |y, part| part.copy_from_slice(&rows[y].targets),
    );
    let filtered: Vec<Option<FilteredGroup>> = targets
        .par_iter()
        .map_init(Vec::new, |found, t| filter_with_noise(t, found))
        .collect();
    // Then the wider passes over the groups' filtered illumination.
    let mut target_starts = Vec::with_capacity(w * h + 1);
    target_starts.push(0usize);
    for row in &rows {
        for &n in &row.targets_per_cell {
            target_starts.push(target_starts[target_starts.len() - 1] + n as usize);
        }
    }
    let counts: Vec<f32> = join_rows(
        &rows,
        |r| r.target_counts.len(),
        |y, part| part.copy_from_slice(&rows[y].target_counts),
    );
    // Built on every thread: one cache line a group, and its fresh pages faulted in by both.
    let mut nodes: Vec<WideningNode> = targets
        .par_iter()
        .zip(counts.par_iter())
        .zip(filtered.par_iter())
        .map(|((&at, &count), filtered)| {
            let (light, noise, _) = filtered.unwrap_or(([0.0; 3], 0.0, [0.0; 3]));
            WideningNode {
                at: Member {
                    illumination: light,
                    ..at
                },
                count,
                noise,
                luminance: luminance(light),
                lit: filtered.is_some(),
            }
        })
        .collect();
    // The capped light, spread far by the guides alone: the cap keeps a rare bright sample
    // from standing out as a speck or a blob, and this puts its light back as the smooth
    // lift of the surface round it that it converges to.
    let mut excess: Vec<[f32; 3]> = filtered
        .par_iter()
        // Light beyond f32's range (sums of samples near its limit) is not spread: one
        // infinite group would reach every group within 62 px.
        .map(|f| match f {
            Some((_, _, e)) if e.iter().all(|v| v.is_finite()) => *e,
            _ => [0.0; 3],
        })
        .collect();
    drop(filtered);
    // Most frames' caps take nothing (no rare bright samples): nothing to spread.
    if excess.par_iter().any(|e| e.iter().any(|&v| v > 0.0)) {
        for &step in &EXCESS_STEPS_PX {
            excess = spread_excess(&nodes, &excess, &target_starts, (w, h), step);
        }
    }
    let mut widened = Vec::new();
    for &step in widening_steps_px(frames.spp) {
        widen(&nodes, &target_starts, (w, h), step, &mut widened);
        std::mem::swap(&mut nodes, &mut widened);
    }
    drop(widened);
    let excess_weight = excess_weight(frames.spp);
    let illumination: Vec<Option<[f32; 3]>> = nodes
        .par_iter()
        .zip(&excess)
        .map(|(n, e)| {
            n.lit
                .then(|| std::array::from_fn(|c| n.at.illumination[c] + excess_weight * e[c]))
        })
        .collect();
    // Each member's group among all the frame's (its row's groups are numbered from the row's
    // first, `target_starts` at the row's first pixel).
    let group_of_member: Vec<u32> = join_rows(
        &rows,
        |r| r.group_of.len(),
        |y, part| {
            let first = target_starts[y * w] as u32;
            for (dst, &g) in part.iter_mut().zip(&rows[y].group_of) {
                *dst = first + g;
            }
        },
    );
    (0..frames.samples.len())
        .into_par_iter()
        .map_init(Vec::new, |found, k| {
            let original = frames.samples[k].color;
            let illumination = match (member_of[k], moved[k]) {
                (NOT_A_MEMBER, Some(m)) if hit(k) => {
                    // Outside the frame: on its own, as far as the frame's members reach.
                    let g = &guides[k];
                    let target = Member {
                        q: m.q,
                        depth: m.depth,
                        normal: g.normal,
                        albedo: g.albedo,
                        illumination: [0.0; 3],
                    };
                    filter(&target, found)
                }
                (NOT_A_MEMBER, _) => None,
                (j, _) => illumination[group_of_member[j as usize] as usize],
            };
            let Some(mean) = illumination else {
                return original;
            };
            let a = guides[k].albedo;
            let mut out = original;
            for c in 0..3 {
                out[c] = mean[c] * (a[c].max(0.0) + ALBEDO_EPSILON);
            }
            // Means of samples near f32's limit can overflow: such a sample keeps its colour.
            if out.iter().all(|v| v.is_finite()) {
                out
            } else {
                original
            }
        })
        .collect()
}

/// The dilations of the widening passes after the first filter, pixels: each is a 3 x 3
/// tent kernel with its taps `step` pixels apart ("a trous"), so the filter's reach grows to
/// about 30 px at the cost of 9 pixels a pass. How many of them run depends on the samples
/// per pixel ([`widening_steps_px`]).
pub const WIDENING_STEPS_PX: [i64; 4] = [2, 4, 8, 16];

/// Up to this many samples per pixel all four widening passes run ([`widening_steps_px`]): at
/// 1 spp the 16-px pass takes the blotches the first three leave on a plain wall (comets at 1
/// spp of 1 path: FLIP 0.0324 -> 0.0269; `studio` 0.0799 -> 0.0769), at 2 spp it changed
/// nothing visible and raised `studio`'s FLIP p99 (0.238 -> 0.242), at 4 spp it flattened
/// soft light (the Cycles `approach` car: FLIP 0.0309 -> 0.0336).
pub const WIDEST_WIDENING_MAX_SPP: usize = 1;

/// From this many samples per pixel the widening passes stop at 4 px ([`widening_steps_px`]):
/// the 8-px pass flattened the soft light round emitters (the Cycles `approach` car at 16 spp
/// of 4 paths: FLIP p99 0.218 with it, 0.190 without) and took nothing visible from the noise,
/// while at 8 spp and fewer it still did (`studio` at 8 spp: FLIP 0.0493 with it, 0.0503
/// without).
pub const NARROW_WIDENING_SPP: usize = 16;

/// The dilations of the widening passes for `spp` samples per pixel, pixels: their reach
/// shrinks as the noise the first filter leaves does.
pub fn widening_steps_px(spp: usize) -> &'static [i64] {
    if spp <= WIDEST_WIDENING_MAX_SPP {
        &WIDENING_STEPS_PX
    } else if spp < NARROW_WIDENING_SPP {
        &WIDENING_STEPS_PX[..3]
    } else {
        &WIDENING_STEPS_PX[..2]
    }
}

/// Illumination difference, in units of the noise the first filter leaves on the two groups
/// (combined), at which a widening pass's weight falls to `1/e`: differences within the noise
/// are averaged, larger ones (shading: a contact shadow, a shadow's edge) are kept.
pub const NOISE_TOLERANCE: f32 = 2.0;

/// The tent kernel of the widening passes.
const TENT: [f32; 3] = [0.25, 0.5, 0.25];

/// A group as the widening passes read it, one cache line: its mean position, guides and
/// current illumination (`at`), member count, the noise its first filter left, the
/// illumination's luminance, and whether it has any illumination.
#[derive(Clone, Copy, Debug)]
#[repr(align(64))]
struct WideningNode {
    at: Member,
    count: f32,
    noise: f32,
    luminance: f32,
    lit: bool,
}

/// One widening pass: each group's illumination becomes the mean of the groups' at the 3 x 3
/// taps `step` pixels apart round its pixel (pixel `i`'s groups at
/// `target_starts[i]..target_starts[i + 1]` of `nodes`), weighted by the tent kernel, the
/// groups' member counts, the guides (depth, normal, albedo, as the first filter weighs them)
/// and how far their illuminations' luminances differ in units of the smaller of the two
/// groups' noise ([`NOISE_TOLERANCE`]). A group without noise keeps its illumination; one
/// without illumination stays so and is left out of the others' means. Written into `out`
/// (its memory reused from pass to pass).
fn widen(
    nodes: &[WideningNode],
    target_starts: &[usize],
    (w, h): (usize, usize),
    step: i64,
    out: &mut Vec<WideningNode>,
) {
    nodes
        .par_iter()
        .map(|me| {
            // Without noise round it the group keeps its light: any other weighs nothing.
            if !me.lit || me.noise <= 0.0 {
                return *me;
            }
            let inv_depth = 1.0 / (DEPTH_TOLERANCE * me.at.depth);
            let (cx, cy) = (me.at.q[0].floor() as i64, me.at.q[1].floor() as i64);
            let mut sum = [0.0f32; 3];
            let mut total = 0.0f32;
            for (cell, tent) in tent_taps(cx, cy, step, (w, h)) {
                for other in &nodes[target_starts[cell]..target_starts[cell + 1]] {
                    // Which nodes lie on another surface is geometry, predictable: this
                    // branch costs less than their arithmetic where two surfaces share pixels.
                    if another_surface(&me.at, &other.at, inv_depth) {
                        continue;
                    }
                    let d = other.luminance - me.luminance;
                    // The smaller of the two: a group whose first filter straddled a
                    // shadow's edge reads the edge as noise, its neighbour does not.
                    let sigma = me.noise.min(other.noise);
                    let shading = d * d / (2.0 * (NOISE_TOLERANCE * sigma).powi(2) + 1e-12);
                    let (guides, cosine) = guide_terms(&me.at, &other.at, inv_depth);
                    let exponent = shading + guides;
                    let weight = tent
                        * other.count
                        * (-exponent.min(WEIGHT_EXPONENT_CUT)).exp()
                        * cosine.powi(NORMAL_POWER);
                    // One test of every condition, without a branch for each: which of them
                    // fails is data (noise), and its mispredictions cost more than the
                    // arithmetic they skipped.
                    let keep = other.lit
                        & (cosine > 0.0)
                        & (shading <= 12.0)
                        & (exponent <= WEIGHT_EXPONENT_CUT)
                        & (weight > 0.0)
                        & weight.is_finite();
                    for (acc, e) in sum.iter_mut().zip(other.at.illumination) {
                        *acc += if keep { weight * e } else { 0.0 };
                    }
                    total += if keep { weight } else { 0.0 };
                }
            }
            if !(total > 0.0 && total.is_finite()) {
                return *me;
            }
            let light = sum.map(|v| v / total);
            WideningNode {
                at: Member {
                    illumination: light,
                    ..me.at
                },
                luminance: luminance(light),
                ..*me
            }
        })
        .collect_into_vec(out);
}

/// The taps of the passes' 3 x 3 tent `step` pixels apart round pixel `(cx, cy)` of a
/// `w x h` frame that fall inside it: each tap's pixel index and tent weight.
fn tent_taps(
    cx: i64,
    cy: i64,
    step: i64,
    (w, h): (usize, usize),
) -> impl Iterator<Item = (usize, f32)> {
    let half = (TENT.len() / 2) as i64;
    TENT.iter().enumerate().flat_map(move |(j, &ky)| {
        TENT.iter().enumerate().filter_map(move |(i, &kx)| {
            let (x, y) = (cx + (i as i64 - half) * step, cy + (j as i64 - half) * step);
            (x >= 0 && y >= 0 && x < w as i64 && y < h as i64)
                .then(|| (y as usize * w + x as usize, kx * ky))
        })
    })
}

/// A group's first filter: its illumination, the noise the filter left on it (luminance),
/// and the illumination the firefly cap took from its mean.
type FilteredGroup = ([f32; 3], f32, [f32; 3]);

/// The dilations of the passes that spread the light the firefly cap took away, pixels:
/// 3 x 3 tents as in [`WIDENING_STEPS_PX`], reaching about 60 px: narrower passes (steps 2, 4,
/// 8 or 3, 9, 27) left the spread light in blotches that FLIP and SSIM see.
pub const EXCESS_STEPS_PX: [i64; 5] = [2, 4, 8, 16, 32];

/// The samples per pixel at which the spread excess of the firefly cap is added back at half
/// its weight ([`excess_weight`]).
pub const EXCESS_HALF_WEIGHT_SPP: f32 = 8.0;

/// The share of the firefly cap's spread excess added back at `spp` samples per pixel:
/// `spp / (spp + EXCESS_HALF_WEIGHT_SPP)`. The excess is the light of a few rare samples, so
/// at low counts it is mostly their noise, spread into blotches, and at high counts mostly
/// the light the cap would otherwise take from the frame (a shrinkage towards the capped
/// frame by the excess's noise, which falls as `1 / spp`).
pub fn excess_weight(spp: usize) -> f32 {
    let spp = spp.max(1) as f32;
    spp / (spp + EXCESS_HALF_WEIGHT_SPP)
}

/// The share of a group's own light below which the excess round it is not spread onto it:
/// after a few passes a handful of capped samples' light is spread thin over most of the
/// frame, and weighing every group for a lift far below what can be seen is most of the
/// passes' time. At a hundredth (a thousandth before) the Cycles disc at 4 spp reconstructs
/// 8 % faster and the fence 10 %; no pixel of any stochastic set moves by more than 0.7 % of
/// its luminance (99.9 % of them by under 0.3 %), every score to the fourth digit
/// (docs/BENCHMARKS.md, "The firefly excess spread where it lifts a group by a hundredth").
pub const EXCESS_NEGLIGIBLE: f32 = 1e-2;

/// One pass spreading `excess` (per group of `nodes`, in their order): each group's becomes
/// the mean of the groups' at the 3 x 3 taps `step` pixels apart, weighted by the tent, their
/// member counts and the guides alone (no noise test: the light is to be spread, not kept).
fn spread_excess(
    nodes: &[WideningNode],
    excess: &[[f32; 3]],
    target_starts: &[usize],
    (w, h): (usize, usize),
    step: i64,
) -> Vec<[f32; 3]> {
    // Each pixel's largest excess in any channel of its groups (NaN left out, as the test
    // below leaves it), so that a group reads nine values to learn whether any tap holds
    // excess worth weighing.
    let most: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|cell| {
            excess[target_starts[cell]..target_starts[cell + 1]]
                .iter()
                .flatten()
                .fold(f32::NEG_INFINITY, |m, &v| m.max(v))
        })
        .collect();
    nodes
        .par_iter()
        .zip(excess.par_iter())
        .map(|(me, &mine)| {
            if !me.lit {
                return mine;
            }
            let (cx, cy) = (me.at.q[0].floor() as i64, me.at.q[1].floor() as i64);
            // Most groups have no excess round them worth weighing: none, or so little against
            // their own light that spreading it could not move it by EXCESS_NEGLIGIBLE.
            let cells = || tent_taps(cx, cy, step, (w, h));
            let negligible = EXCESS_NEGLIGIBLE * me.luminance.max(0.0);
            if !cells().any(|(cell, _)| most[cell] > negligible) {
                return mine;
            }
            let inv_depth = 1.0 / (DEPTH_TOLERANCE * me.at.depth);
            let mut sum = [0.0f32; 3];
            let mut total = 0.0f32;
            for (cell, tent) in cells() {
                let first = target_starts[cell];
                for (o, other) in nodes[first..target_starts[cell + 1]].iter().enumerate() {
                    // As in the widening passes.
                    if another_surface(&me.at, &other.at, inv_depth) {
                        continue;
                    }
                    let (guides, cosine) = guide_terms(&me.at, &other.at, inv_depth);
                    let weight = tent
                        * other.count
                        * (-guides.min(WEIGHT_EXPONENT_CUT)).exp()
                        * cosine.powi(NORMAL_POWER);
                    // One test of every condition, as in the widening passes.
                    let keep = other.lit
                        & (cosine > 0.0)
                        & (guides <= WEIGHT_EXPONENT_CUT)
                        & (weight > 0.0)
                        & weight.is_finite();
                    for (acc, e) in sum.iter_mut().zip(excess[first + o]) {
                        *acc += if keep { weight * e } else { 0.0 };
                    }
                    total += if keep { weight } else { 0.0 };
                }
            }
            if total > 0.0 && total.is_finite() {
                sum.map(|v| v / total)
            } else {
                mine
            }
        })
        .collect()
}

/// Whether `b` weighs nothing for `a` by depth alone: the depth term of [`guide_terms`] beyond
/// [`WEIGHT_EXPONENT_CUT`], which every weight's exponent then exceeds too (its other terms are
/// at least zero), so skipping `b` leaves the same result. `inv_depth` as there.
#[inline(always)]
fn another_surface(a: &Member, b: &Member, inv_depth: f32) -> bool {
    let dz = (b.depth - a.depth) * inv_depth;
    dz * dz > WEIGHT_EXPONENT_CUT
}

/// The filter's weight of `b` for `a` without the distance (both passes weigh the guides
/// alike): the exponent of the depth and albedo terms and the normals' cosine (raised to
/// [`NORMAL_POWER`] by the caller; a neighbour whose cosine is not positive weighs nothing, which
/// the caller tests with its other conditions).
/// `inv_depth` is `1 / (DEPTH_TOLERANCE a.depth)`, computed once per `a`.
#[inline(always)]
fn guide_terms(a: &Member, b: &Member, inv_depth: f32) -> (f32, f32) {
    let cosine = a.normal[0] * b.normal[0] + a.normal[1] * b.normal[1] + a.normal[2] * b.normal[2];
    let dz = (b.depth - a.depth) * inv_depth;
    let mut scale = ALBEDO_EPSILON;
    let mut da2 = 0.0;
    for c in 0..3 {
        scale = scale.max(a.albedo[c].abs().max(b.albedo[c].abs()));
        da2 += (a.albedo[c] - b.albedo[c]).powi(2);
    }
    let inv_albedo_var = 1.0 / (ALBEDO_SIGMA * ALBEDO_SIGMA);
    (dz * dz + da2 / (scale * scale) * inv_albedo_var, cosine)
}

/// One list of every row's part, each row's part (`len` items) written by `write(row index,
/// part)` on a thread of its own into memory that is zeroed lazily: one thread joining the
/// rows (and faulting their fresh pages in) was a serial stretch of the denoiser.
fn join_rows<T: bytemuck::Zeroable + Send>(
    rows: &[RowGroups],
    len: impl Fn(&RowGroups) -> usize,
    write: impl Fn(usize, &mut [T]) + Sync,
) -> Vec<T> {
    let mut out: Vec<T> = bytemuck::zeroed_vec(rows.iter().map(&len).sum());
    let mut rest = out.as_mut_slice();
    let mut parts = Vec::with_capacity(rows.len());
    for row in rows {
        let (part, tail) = std::mem::take(&mut rest).split_at_mut(len(row));
        parts.push(part);
        rest = tail;
    }
    parts
        .into_par_iter()
        .enumerate()
        .for_each(|(y, part)| write(y, part));
    out
}

/// [`denoise_samples`]' mark for a sample that is not among the frame's members.
const NOT_A_MEMBER: u32 = u32::MAX;

/// Of two members of one pixel filtered as one surface, the albedos differ by at most this
/// fraction of [`ALBEDO_SIGMA`] (and the normals by at most [`SAME_SURFACE_COSINE`], the
/// depths by at most [`SAME_SURFACE_DEPTH_FRACTION`] or [`NEIGHBOUR_DEPTH_FRACTION`]).
const SAME_SURFACE_ALBEDO_FRACTION: f32 = 0.1;

/// Of two members of one pixel that share one filtered illumination (one target of the first
/// filter and one node of the widening passes), the depths differ by at most this fraction of
/// [`DEPTH_TOLERANCE`] (1.5 %). A floor receding towards the horizon changes its depth by more
/// than a tenth of the tolerance across one pixel, and at a tenth its samples each made a
/// target: the targets, and with them the work of the filter and of the passes (targets times
/// neighbours), grew with the sample count (a car driving at the camera at 16 spp: 1.39 M
/// targets of 4.17 M samples, 7.7 s; at half the tolerance 0.93 M, 5.3 s). A target's depth
/// is its members' mean, the depth at their mean position on a plane.
const SAME_SURFACE_DEPTH_FRACTION: f32 = 0.5;

/// Of two members of one pixel that a neighbour sees as one entry, the depths differ by at
/// most this fraction of [`DEPTH_TOLERANCE`] (0.3 %). Merged as loosely as the targets, a
/// receding floor's entries stood at their mean position and the first filter lost the spread
/// its spatial weights read (`studio` at 8 spp: FLIP mean 0.0451 -> 0.0453, p99 0.1634 ->
/// 0.1667); kept apart, every score is as before or better.
const NEIGHBOUR_DEPTH_FRACTION: f32 = 0.1;

/// The least cosine between the normals of two members filtered as one surface (about 2.6
/// degrees).
const SAME_SURFACE_COSINE: f32 = 0.999;

/// Rec. 709 luminance of linear RGB.
fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// One sample as the filter reads it, stored in the order of the pixels its moved position
/// falls in.
#[derive(Clone, Copy, Debug, Default, bytemuck::Zeroable)]
struct Member {
    q: [f32; 2],
    depth: f32,
    normal: [f32; 3],
    albedo: [f32; 3],
    illumination: [f32; 3],
}

/// The members of one pixel on one surface as a neighbour sees them (their depths within
/// [`NEIGHBOUR_DEPTH_FRACTION`]): at their mean position and depth, with the first member's
/// normal and albedo, `count` members of the given mean illumination. A group
/// whose brightest member stands out ([`OUTLIER_FACTOR`]) makes two entries, that member alone
/// and the rest, so that the filter can still set a firefly aside and cap its luminance.
#[derive(Clone, Copy, Debug, bytemuck::Zeroable)]
struct Entry {
    at: Member,
    count: f32,
    luminance: f32,
}

/// A group's brightest member stands alone among the neighbour entries when its luminance is
/// more than this many times the mean of the rest's (a firefly); otherwise the group is one
/// entry.
const OUTLIER_FACTOR: f32 = 2.0;

/// A pixel's members on one surface, while they are gathered.
#[derive(Clone, Copy)]
struct Group {
    /// The first member: its normal and albedo stand for the group's.
    first: Member,
    position_sum: [f32; 2],
    depth_sum: f32,
    count: usize,
    /// The member of the largest illumination luminance (the first of equals).
    brightest: Member,
    illumination_sum: [f32; 3],
}

/// One row of pixels' members grouped by surface.
#[derive(Default)]
struct RowGroups {
    /// One per group, in pixel order: the mean position and depth, and the first member's
    /// normal and albedo.
    targets: Vec<Member>,
    /// The entries of the row's groups, in pixel order.
    entries: Vec<Entry>,
    /// How many entries each pixel of the row has.
    entries_per_cell: Vec<u32>,
    /// How many groups (targets) each pixel of the row has.
    targets_per_cell: Vec<u32>,
    /// How many members each group has.
    target_counts: Vec<f32>,
    /// Each member's group (an index into `targets`), in member order.
    group_of: Vec<u32>,
}

impl RowGroups {
    /// The groups of a row whose members are `members`, pixel `i`'s at `cell_starts[i] -
    /// cell_starts[0]..cell_starts[i + 1] - cell_starts[0]`.
    fn of(members: &[Member], cell_starts: &[usize]) -> Self {
        let mut row = RowGroups::default();
        let base = cell_starts[0];
        let mut groups: Vec<Group> = Vec::new();
        let mut entry_groups: Vec<Group> = Vec::new();
        for bounds in cell_starts.windows(2) {
            groups.clear();
            entry_groups.clear();
            for m in &members[bounds[0] - base..bounds[1] - base] {
                let g = Group::join(&mut groups, m, SAME_SURFACE_DEPTH_FRACTION);
                Group::join(&mut entry_groups, m, NEIGHBOUR_DEPTH_FRACTION);
                row.group_of.push((row.targets.len() + g) as u32);
            }
            let before = row.entries.len();
            for group in &groups {
                row.targets.push(group.at());
                row.target_counts.push(group.count as f32);
            }
            for group in &entry_groups {
                let Group {
                    count,
                    brightest,
                    illumination_sum: sum,
                    ..
                } = *group;
                let at = group.at();
                let rest = count.saturating_sub(1) as f32;
                let rest_illumination: [f32; 3] =
                    std::array::from_fn(|c| (sum[c] - brightest.illumination[c]) / rest.max(1.0));
                let brightest_luminance = luminance(brightest.illumination);
                let outlier =
                    brightest_luminance > OUTLIER_FACTOR * luminance(rest_illumination).max(0.0);
                if count > 1 && !outlier {
                    // Nothing stands out: one entry of all the members.
                    let illumination = sum.map(|v| v / count as f32);
                    row.entries.push(Entry {
                        at: Member { illumination, ..at },
                        count: count as f32,
                        luminance: luminance(illumination),
                    });
                } else {
                    row.entries.push(Entry {
                        at: Member {
                            illumination: brightest.illumination,
                            ..at
                        },
                        count: 1.0,
                        luminance: brightest_luminance,
                    });
                    if count > 1 {
                        row.entries.push(Entry {
                            at: Member {
                                illumination: rest_illumination,
                                ..at
                            },
                            count: rest,
                            luminance: luminance(rest_illumination),
                        });
                    }
                }
            }
            row.entries_per_cell
                .push((row.entries.len() - before) as u32);
            row.targets_per_cell.push(groups.len() as u32);
        }
        row
    }
}

impl Group {
    /// Adds `m` to the first of `groups` on its surface (depths within `depth_fraction` of
    /// [`DEPTH_TOLERANCE`]), or to a new group; returns the group's index.
    fn join(groups: &mut Vec<Group>, m: &Member, depth_fraction: f32) -> usize {
        let g = match groups
            .iter()
            .position(|g| g.first.same_surface(m, depth_fraction))
        {
            Some(g) => g,
            None => {
                groups.push(Group {
                    first: *m,
                    position_sum: [0.0; 2],
                    depth_sum: 0.0,
                    count: 0,
                    brightest: *m,
                    illumination_sum: [0.0; 3],
                });
                groups.len() - 1
            }
        };
        groups[g].add(m);
        g
    }

    fn add(&mut self, m: &Member) {
        let q = &mut self.position_sum;
        (q[0], q[1]) = (q[0] + m.q[0], q[1] + m.q[1]);
        self.depth_sum += m.depth;
        self.count += 1;
        if luminance(m.illumination) > luminance(self.brightest.illumination) {
            self.brightest = *m;
        }
        for (sum, e) in self.illumination_sum.iter_mut().zip(m.illumination) {
            *sum += e;
        }
    }

    /// The group as one member: its mean position and depth, its first member's normal and
    /// albedo (and illumination, which callers replace).
    fn at(&self) -> Member {
        let (q, n) = (self.position_sum, self.count as f32);
        Member {
            q: [q[0] / n, q[1] / n],
            depth: self.depth_sum / n,
            ..self.first
        }
    }
}

impl Member {
    /// Whether `other` lies on this member's surface, their depths within `depth_fraction` of
    /// [`DEPTH_TOLERANCE`] (normals and albedos within [`SAME_SURFACE_COSINE`] and
    /// [`SAME_SURFACE_ALBEDO_FRACTION`]): the filter weighs both alike against any neighbour.
    fn same_surface(&self, other: &Member, depth_fraction: f32) -> bool {
        let depth =
            (other.depth - self.depth).abs() <= depth_fraction * DEPTH_TOLERANCE * self.depth.abs();
        let cosine: f32 = (0..3).map(|c| self.normal[c] * other.normal[c]).sum();
        let scale = (0..3).fold(ALBEDO_EPSILON, |s, c| {
            s.max(self.albedo[c].abs()).max(other.albedo[c].abs())
        });
        let albedo = (0..3).all(|c| {
            (self.albedo[c] - other.albedo[c]).abs()
                <= SAME_SURFACE_ALBEDO_FRACTION * ALBEDO_SIGMA * scale
        });
        depth && cosine >= SAME_SURFACE_COSINE && albedo
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use formats::Sample;

    /// A `w x h` frame at 1 spp, every sample a hit at its pixel centre, depth 2 (or `depth`
    /// per pixel), facing the camera, with colour `albedo * light`.
    fn frame(
        w: usize,
        h: usize,
        albedo: impl Fn(usize, usize) -> f32,
        light: impl Fn(usize, usize) -> f32,
        depth: impl Fn(usize, usize) -> f32,
    ) -> (StochasticFrames, Vec<Option<MovedSample>>) {
        let mut samples = Vec::new();
        let mut guides = Vec::new();
        let mut moved = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let (a, l, z) = (albedo(x, y), light(x, y), depth(x, y));
                samples.push(Sample {
                    color: [a * l, a * l, a * l, 1.0],
                    depth: z,
                    ..Sample::default()
                });
                guides.push(SampleGuides {
                    albedo: [a; 3],
                    normal: [0.0, 0.0, -1.0],
                });
                moved.push(Some(MovedSample {
                    q: [x as f32 + 0.5, y as f32 + 0.5],
                    depth: z,
                    ..MovedSample::default()
                }));
            }
        }
        let frames = StochasticFrames::new(w, h, 1, samples)
            .with_guides(guides)
            .expect("guides");
        (frames, moved)
    }

    /// A deterministic noise in [-0.5, 0.5) per pixel.
    fn noise(x: usize, y: usize) -> f32 {
        let h = (x as u64)
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add((y as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9));
        ((h >> 40) as f32 / (1u64 << 24) as f32) - 0.5
    }

    fn mean_var(values: impl Iterator<Item = f32>) -> (f64, f64) {
        let v: Vec<f64> = values.map(f64::from).collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64;
        (mean, var)
    }

    /// Noisy lighting on one surface: the noise's variance falls at least fivefold and the
    /// mean stays within 1 %.
    #[test]
    fn lighting_noise_is_averaged_over_the_surface() {
        let (frames, moved) = frame(40, 40, |_, _| 0.5, |x, y| 1.0 + noise(x, y), |_, _| 2.0);
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        let inner = |k: &usize| {
            let (x, y) = (k % 40, k / 40);
            (4..36).contains(&x) && (4..36).contains(&y)
        };
        let (m0, v0) = mean_var((0..1600).filter(inner).map(|k| frames.samples[k].color[0]));
        let (m1, v1) = mean_var((0..1600).filter(inner).map(|k| out[k][0]));
        assert!(v1 * 5.0 < v0, "variance {v0} -> {v1}");
        assert!((m1 / m0 - 1.0).abs() < 0.01, "mean {m0} -> {m1}");
        assert!(out.iter().all(|c| c[3] == 1.0));
    }

    /// The widening passes take the first filter's leftover noise further down on a flat,
    /// evenly lit surface: at 1 spp its variance falls at least 500-fold (the first filter
    /// alone: about 115-fold; with the widening about 2,000-fold).
    #[test]
    fn widening_averages_the_leftover_noise() {
        let (frames, moved) = frame(64, 64, |_, _| 0.5, |x, y| 1.0 + noise(x, y), |_, _| 2.0);
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        let inner = |k: &usize| {
            let (x, y) = (k % 64, k / 64);
            (12..52).contains(&x) && (12..52).contains(&y)
        };
        let (m0, v0) = mean_var((0..4096).filter(inner).map(|k| frames.samples[k].color[0]));
        let (m1, v1) = mean_var((0..4096).filter(inner).map(|k| out[k][0]));
        assert!(v1 * 500.0 < v0, "variance {v0} -> {v1}");
        assert!((m1 / m0 - 1.0).abs() < 0.01, "mean {m0} -> {m1}");
    }

    /// A noise-free hard shadow's edge on one surface is not widened: beyond the first
    /// filter's reach (4 px at 1 spp) every sample keeps its light, because the widening
    /// passes weigh a neighbour by how far its light lies outside the noise, and there is none.
    #[test]
    fn a_hard_shadow_edge_is_not_widened() {
        let light = |x: usize, _: usize| if x < 20 { 1.0 } else { 0.3 };
        let (frames, moved) = frame(40, 24, |_, _| 0.5, light, |_, _| 2.0);
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        for (k, c) in out.iter().enumerate() {
            if (15..25).contains(&(k % 40)) {
                continue;
            }
            let want = frames.samples[k].color[0];
            assert!((c[0] / want - 1.0).abs() < 0.02, "{k}: {c:?} vs {want}");
        }
    }

    /// Under even light a checkered texture comes back exactly: only lighting is averaged.
    #[test]
    fn texture_is_kept() {
        let checker = |x: usize, y: usize| {
            if (x / 3 + y / 3).is_multiple_of(2) {
                0.8
            } else {
                0.1
            }
        };
        let (frames, moved) = frame(24, 24, checker, |_, _| 0.7, |_, _| 2.0);
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        for (k, c) in out.iter().enumerate() {
            let want = frames.samples[k].color[0];
            assert!(
                (c[0] - want).abs() < 1e-5 * want.max(1.0),
                "{k}: {c:?} vs {want}"
            );
        }
    }

    /// One sample two hundred times brighter than its surface (a bounce that found a small
    /// emitter) is not spread into a blob: every sample round it stays within twice the
    /// surface's level (without the cap its neighbours would reach about twelve times it).
    #[test]
    fn a_firefly_is_not_spread_over_its_neighbours() {
        let light = |x: usize, y: usize| if (x, y) == (10, 10) { 200.0 } else { 1.0 };
        let (frames, moved) = frame(21, 21, |_, _| 0.5, light, |_, _| 2.0);
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        let worst = out.iter().map(|c| c[0]).fold(0.0f32, f32::max);
        assert!(worst < 2.0 * 0.5, "brightest sample {worst}");
    }

    /// On a noisy surface (light 1 +- 10 %), one sample five times its level, under the
    /// factor's cap: it is not spread into a soft blob either (the factor alone let its
    /// neighbours reach 1.31 times the level).
    #[test]
    fn a_moderate_firefly_on_a_quiet_surface_is_not_spread() {
        let light = |x: usize, y: usize| {
            if (x, y) == (12, 12) {
                5.0
            } else {
                1.0 + 0.2 * noise(x, y)
            }
        };
        let (frames, moved) = frame(25, 25, |_, _| 0.5, light, |_, _| 2.0);
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        let worst = out.iter().map(|c| c[0] / 0.5).fold(0.0f32, f32::max);
        assert!(worst < 1.15, "brightest light {worst}");
    }

    /// Samples near the largest finite float (a broken shader, a light of absurd power) among
    /// ordinary ones: every denoised sample stays finite, however much light the cap takes.
    #[test]
    fn samples_near_the_float_limit_leave_every_colour_finite() {
        let light = |x: usize, y: usize| {
            if (x + y).is_multiple_of(3) {
                3.0e38
            } else {
                1.0
            }
        };
        let (frames, moved) = frame(12, 12, |_, _| 1.0, light, |_, _| 2.0);
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        assert!(
            out.iter().flatten().all(|v| v.is_finite()),
            "a colour is not finite"
        );
    }

    /// Four samples per pixel, `surface(x, y, k)` giving each one's (albedo, light, depth), at
    /// jittered positions inside its pixel, facing the camera.
    fn frame_4spp(
        w: usize,
        h: usize,
        surface: impl Fn(usize, usize, usize) -> (f32, f32, f32),
    ) -> (StochasticFrames, Vec<Option<MovedSample>>) {
        let (mut samples, mut guides, mut moved) = (Vec::new(), Vec::new(), Vec::new());
        for y in 0..h {
            for x in 0..w {
                for k in 0..4 {
                    let (a, l, z) = surface(x, y, k);
                    samples.push(Sample {
                        color: [a * l, a * l, a * l, 1.0],
                        depth: z,
                        ..Sample::default()
                    });
                    guides.push(SampleGuides {
                        albedo: [a; 3],
                        normal: [0.0, 0.0, -1.0],
                    });
                    let jitter = [0.2 + 0.5 * (k % 2) as f32, 0.3 + 0.4 * (k / 2) as f32];
                    moved.push(Some(MovedSample {
                        q: [x as f32 + jitter[0], y as f32 + jitter[1]],
                        depth: z,
                        ..MovedSample::default()
                    }));
                }
            }
        }
        let frames = StochasticFrames::new(w, h, 4, samples)
            .with_guides(guides)
            .expect("guides");
        (frames, moved)
    }

    /// At 4 spp, two surfaces sharing every pixel (a fine pattern at two depths, or of two
    /// albedos) are filtered apart: each keeps its own light, although their samples share
    /// pixels; and one surface's noise is still averaged.
    #[test]
    fn surfaces_sharing_a_pixel_are_filtered_apart() {
        let near = |k: usize| k.is_multiple_of(2);
        let (frames, moved) = frame_4spp(16, 16, |x, y, k| {
            let light = 1.0 + 0.5 * noise(x * 4 + k, y);
            if near(k) {
                (0.5, 4.0 * light, 0.5)
            } else {
                (0.5, light, 3.0)
            }
        });
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        for (i, c) in out.iter().enumerate() {
            let want = if near(i % 4) { 2.0 } else { 0.5 };
            assert!((c[0] / want - 1.0).abs() < 0.15, "{i}: {c:?} vs {want}");
        }
        let (frames, moved) = frame_4spp(16, 16, |x, y, k| {
            let light = 1.0 + 0.5 * noise(x * 4 + k, y);
            (if near(k) { 0.8 } else { 0.1 }, light, 2.0)
        });
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        for (i, c) in out.iter().enumerate() {
            let want = if near(i % 4) { 0.8 } else { 0.1 };
            assert!((c[0] / want - 1.0).abs() < 0.15, "{i}: {c:?} vs {want}");
        }
    }

    /// At 4 spp a firefly shares its pixel with three samples of its surface: it is neither
    /// kept nor spread (every sample within twice the surface's level).
    #[test]
    fn a_firefly_among_its_pixels_samples_is_removed() {
        let (frames, moved) = frame_4spp(15, 15, |x, y, k| {
            let light = if (x, y, k) == (7, 7, 1) { 200.0 } else { 1.0 };
            (0.5, light, 2.0)
        });
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        let worst = out.iter().map(|c| c[0]).fold(0.0f32, f32::max);
        assert!(worst < 2.0 * 0.5, "brightest sample {worst}");
    }

    /// At 16 spp, rare bright samples (one in 128, 40 times the surface's light: bounces that
    /// found the light) are part of the surface's converged level, 1.30 times the rest's. The
    /// cap keeps each from standing out; the light it takes is spread back over the surface
    /// (two thirds of it at 16 spp, [`excess_weight`]), so the frame's mean comes back
    /// towards the converged level, and no pixel is a speck.
    #[test]
    fn the_light_of_capped_fireflies_is_spread_back() {
        let (w, h, spp) = (48usize, 48usize, 16usize);
        let firefly = |x: usize, y: usize, k: usize| {
            let mut z = ((y * w + x) * spp + k) as u64;
            z = (z ^ (z >> 30))
                .wrapping_mul(0xBF58_476D_1CE4_E5B9)
                .wrapping_add(0x9E37_79B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            (z ^ (z >> 31)).is_multiple_of(128)
        };
        let (mut samples, mut guides, mut moved) = (Vec::new(), Vec::new(), Vec::new());
        for y in 0..h {
            for x in 0..w {
                for k in 0..spp {
                    let light = if firefly(x, y, k) { 40.0 } else { 1.0 };
                    samples.push(Sample {
                        color: [0.5 * light, 0.5 * light, 0.5 * light, 1.0],
                        depth: 2.0,
                        ..Sample::default()
                    });
                    guides.push(SampleGuides {
                        albedo: [0.5; 3],
                        normal: [0.0, 0.0, -1.0],
                    });
                    let jitter = [(k % 4) as f32 * 0.25 + 0.125, (k / 4) as f32 * 0.25 + 0.125];
                    moved.push(Some(MovedSample {
                        q: [x as f32 + jitter[0], y as f32 + jitter[1]],
                        depth: 2.0,
                        ..MovedSample::default()
                    }));
                }
            }
        }
        let frames = StochasticFrames::new(w, h, spp, samples)
            .with_guides(guides)
            .expect("guides");
        let converged: f64 = frames
            .samples
            .iter()
            .map(|s| f64::from(s.color[0]))
            .sum::<f64>()
            / frames.samples.len() as f64;
        let out = denoise_samples(&frames, &frames.guides.clone().expect("guides"), &moved);
        let mean: f64 = out.iter().map(|c| f64::from(c[0])).sum::<f64>() / out.len() as f64;
        let brightest = out.iter().map(|c| c[0]).fold(0.0f32, f32::max);
        // The cap alone keeps a quarter of the fireflies' light (0.538 here).
        assert!(
            mean > 0.5 + 0.6 * (converged - 0.5),
            "denoised mean {mean} against the converged {converged}"
        );
        assert!(
            f64::from(brightest) < 1.5 * converged,
            "brightest {brightest}"
        );
    }

    /// A spreading pass weighs a group only where the excess round it could lift its light by
    /// [`EXCESS_NEGLIGIBLE`] or more: a thinner excess stays where it is, a visible one is
    /// spread onto the groups the tent reaches.
    #[test]
    fn an_excess_far_below_the_surfaces_light_is_not_spread() {
        let w = 9;
        let nodes: Vec<WideningNode> = (0..w)
            .map(|x| WideningNode {
                at: Member {
                    q: [x as f32 + 0.5, 0.5],
                    depth: 2.0,
                    normal: [0.0, 0.0, -1.0],
                    albedo: [0.5; 3],
                    illumination: [1.0; 3],
                },
                count: 1.0,
                noise: 0.1,
                luminance: 1.0,
                lit: true,
            })
            .collect();
        let target_starts: Vec<usize> = (0..=w).collect();
        let spread = |amount: f32| {
            let mut excess = vec![[0.0f32; 3]; w];
            excess[4] = [amount; 3];
            spread_excess(&nodes, &excess, &target_starts, (w, 1), 2)
        };
        let thin = spread(0.5 * EXCESS_NEGLIGIBLE);
        assert_eq!(thin[4], [0.5 * EXCESS_NEGLIGIBLE; 3]);
        assert!(
            thin.iter()
                .enumerate()
                .all(|(x, e)| x == 4 || *e == [0.0; 3]),
            "{thin:?}"
        );
        let visible = spread(0.5);
        for x in [2, 6] {
            assert!(visible[x][0] > 0.1, "group {x}: {:?}", visible[x]);
        }
        assert!(visible[4][0] < 0.5, "the centre kept {:?}", visible[4]);
    }

    /// Samples moved far outside the frame (a huge motion label) keep their colour and do not
    /// disturb the others.
    #[test]
    fn samples_outside_the_frame_are_left_alone() {
        let (frames, mut moved) = frame(8, 8, |_, _| 0.5, |x, y| 1.0 + noise(x, y), |_, _| 2.0);
        for (k, q) in [
            (0, [-1e6, -1e6]),
            (9, [1e6, 4.0]),
            (20, [4.0, -30.0]),
            (30, [-40.0, 3.0]),
        ] {
            moved[k] = Some(MovedSample {
                q,
                depth: 2.0,
                ..MovedSample::default()
            });
        }
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        for k in [0, 9, 20, 30] {
            assert_eq!(out[k], frames.samples[k].color);
        }
        assert!(out.iter().flatten().all(|v| v.is_finite()));
    }

    /// A near surface and a far one side by side, lit differently: neither takes the other's
    /// light across their edge.
    #[test]
    fn surfaces_at_other_depths_do_not_mix() {
        let near = |x: usize, _: usize| x < 12;
        let (frames, moved) = frame(
            24,
            12,
            |_, _| 0.5,
            |x, y| if near(x, y) { 4.0 } else { 1.0 },
            |x, y| if near(x, y) { 0.5 } else { 3.0 },
        );
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        for (k, c) in out.iter().enumerate() {
            let want = frames.samples[k].color[0];
            assert!((c[0] / want - 1.0).abs() < 1e-4, "{k}: {c:?} vs {want}");
        }
    }

    /// A surface nearing the camera: each pixel's samples, taken at four times over the
    /// shutter, lie 6 % apart in depth from first to last (twice the depth tolerance), but
    /// at one depth at the shutter centre, where they are compared. They are filtered as one
    /// surface: every sample of a pixel gets the same light, and the noise between the
    /// times is averaged as well as the noise between pixels.
    #[test]
    fn a_nearing_surface_is_one_surface_at_the_shutter_centre() {
        let times = [-0.375f32, -0.125, 0.125, 0.375];
        // Depth at the shutter centre, and its change over a frame (scene units).
        let (centre_depth, speed) = (2.0f32, -0.16f32);
        let (frames, mut moved) = frame_4spp(24, 24, |x, y, k| {
            let light = 1.0 + 0.5 * noise(x * 4 + k, y);
            (0.5, light, centre_depth + speed * times[k])
        });
        for (m, s) in moved.iter_mut().zip(&frames.samples) {
            if let Some(m) = m {
                m.depth = centre_depth;
            }
            // Each sample's own depth is its time's.
            assert!(s.depth != centre_depth);
        }
        let guides = frames.guides.clone().expect("guides");
        let out = denoise_samples(&frames, &guides, &moved);
        let inner = |k: &usize| {
            let (x, y) = ((k / 4) % 24, k / 96);
            (4..20).contains(&x) && (4..20).contains(&y)
        };
        // The four times' light, each averaged over the inner pixels: apart in the input by
        // the noise between times, together after it.
        let per_time = |colours: &dyn Fn(usize) -> f32| -> Vec<f64> {
            (0..4)
                .map(|t| {
                    let ks = (0..frames.samples.len())
                        .filter(inner)
                        .filter(|k| k % 4 == t);
                    mean_var(ks.map(colours)).0
                })
                .collect()
        };
        let spread = |v: &[f64]| {
            v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
        };
        let before = per_time(&|k| frames.samples[k].color[0]);
        let after = per_time(&|k| out[k][0]);
        let (m0, v0) = mean_var(
            (0..frames.samples.len())
                .filter(inner)
                .map(|k| frames.samples[k].color[0]),
        );
        let (m1, v1) = mean_var((0..frames.samples.len()).filter(inner).map(|k| out[k][0]));
        assert!(v1 * 20.0 < v0, "variance {v0} -> {v1}");
        assert!((m1 / m0 - 1.0).abs() < 0.01, "mean {m0} -> {m1}");
        assert!(
            spread(&after) * 4.0 < spread(&before),
            "the times' means {before:?} -> {after:?}"
        );
        // A pixel's four samples share one light.
        for pixel in out.chunks(4) {
            assert!(pixel.iter().all(|c| c[0] == pixel[0][0]), "{pixel:?}");
        }
    }

    fn member_at(depth: f32, normal: [f32; 3]) -> Member {
        Member {
            q: [0.5, 0.5],
            depth,
            normal,
            albedo: [0.5; 3],
            illumination: [1.0; 3],
        }
    }

    /// A floor receding from the camera changes its depth by about a percent across one pixel
    /// near the horizon: its samples there share one filtered illumination. A surface 5 %
    /// farther, or turned, is another.
    #[test]
    fn a_pixels_samples_on_a_receding_floor_are_one_surface() {
        let up = [0.0, 1.0, 0.0];
        let floor = member_at(2.0, up);
        assert!(floor.same_surface(&member_at(2.02, up), SAME_SURFACE_DEPTH_FRACTION));
        assert!(floor.same_surface(&member_at(1.98, up), SAME_SURFACE_DEPTH_FRACTION));
        assert!(!floor.same_surface(&member_at(2.1, up), SAME_SURFACE_DEPTH_FRACTION));
        assert!(!floor.same_surface(
            &member_at(2.0, [0.0, 0.0, -1.0]),
            SAME_SURFACE_DEPTH_FRACTION
        ));
        // The group stands at its members' mean position and depth, and counts them all.
        let members: Vec<Member> = [2.0, 2.01, 2.02, 2.015, 2.4]
            .iter()
            .enumerate()
            .map(|(i, &z)| Member {
                q: [0.1 + 0.2 * i as f32, 0.5],
                ..member_at(z, up)
            })
            .collect();
        let row = RowGroups::of(&members, &[0, members.len()]);
        assert_eq!(row.targets.len(), 2);
        assert_eq!(row.target_counts, vec![4.0, 1.0]);
        let (near, far) = (&row.targets[0], &row.targets[1]);
        assert!((near.depth - 2.01125).abs() < 1e-5, "{}", near.depth);
        assert!((near.q[0] - 0.4).abs() < 1e-5, "{:?}", near.q);
        assert_eq!(far.depth, 2.4);
        assert_eq!(row.group_of, vec![0, 0, 0, 0, 1]);
        // Its neighbours see the near members as entries of depths within a tenth of the
        // tolerance, each at its own mean: 2.0; 2.01 and 2.015; 2.02; and the far one.
        let counts: Vec<f32> = row.entries.iter().map(|e| e.count).collect();
        assert_eq!(counts, vec![1.0, 2.0, 1.0, 1.0]);
        assert!((row.entries[1].at.depth - 2.0125).abs() < 1e-5);
        assert!(
            (row.entries[1].at.q[0] - 0.5).abs() < 1e-5,
            "{:?}",
            row.entries[1].at.q
        );
        assert_eq!(row.entries_per_cell, vec![4]);
    }
}
