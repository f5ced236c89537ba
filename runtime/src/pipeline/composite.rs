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
//! of it was hidden. The output is `O + f (1 - O.a) (S - O) / (S.a - O.a)`, with `f` the share
//! below, opaque where `f = 1`. The fill covers all of `1 - O.a`, not only what was hidden: a
//! farther layer's hole (where the nearer one blocked its samples) is blurred by the farther
//! layer's own PSF into a shallower, wider dip than the nearer layer's coverage fills, and what
//! is missing there is the farther surface. Dividing by the joint coverage instead (the ratio estimator) would scale the nearer
//! layer's light up there: round a bright emitter in front of a defocused wall, that put 14 %
//! more light into the frame. Where nothing was hidden (`S.a - O.a` below
//! [`FILL_MIN_HIDDEN`]), the pixel is left for reconstruction's division by coverage.
//!
//! A missing coverage is not always a farther layer's hole, though. A sharp layer's coverage is
//! a handful of samples' footprints, with pixel-sized gaps between them at one sample per
//! pixel, while a blurred layer's is smooth: a sharp sphere in front of a defocused wall has
//! holes of its own, and filling them with the wall's hidden colour speckles the sphere grey.
//! So the gap goes to whichever side is sharper, the layers that hid or the layers they hid:
//! each layer has a sharpness `s = 1 / (1 + r)^2` ([`layer_sharpness`], `r` the mean reach of
//! its PSFs in pixels). A layer `k` hides `A_k O.a` of what lies behind it ("over" turns `O.a`
//! into `A_k + (1 - A_k) O.a`). With `H = S.a - O.a` all that was hidden, the occluders'
//! sharpness is `s_occ = sum_k s_k A_k O.a / H`, and the hidden layers' is `s_hid = sum_l s_l
//! A_l (1 - T_l) / H`, `T_l` the transmittance in front of layer `l`. A share `f = clamp(1/2 +
//! log2(s_hid / s_occ) / 2, 0, 1)` of the gap is filled with the hidden colour: all of it where
//! the hidden layers are at least twice as sharp as what hid them (a blurred emitter over a
//! wall), none where the occluders are (a sharp sphere over a defocused wall). The rest is left
//! for the division by coverage, which fills a layer's own holes with its own colour. Only a
//! sharp layer has holes of its own, though: where the occluders are blurred beyond
//! [`SMOOTH_OCCLUDERS_SHARPNESS`] (a mean reach of about 3.5 px), the gap is the hidden
//! layers' whatever their sharpness, and at least `1 - s_occ / SMOOTH_OCCLUDERS_SHARPNESS` of
//! it is filled. A wall that moves (as in a camera pan, where every pixel does) is smeared as
//! far as a defocused emitter before it, so by sharpness alone the two shared its dip, and the
//! division scaled the emitter up with its half: the lamps of a Blender camera pan came out with
//! 6 % more light than the frame's samples hold. Choosing
//! between the two colours, rather than mixing them by weight, matters: an emitter a thousand
//! times brighter than the wall would dominate any weighted mean of the two.
//!
//! Negative values (approximation ringing) are clamped to zero in the output.

use poisson::Plane;
use rayon::prelude::*;

use super::integrate::IntegratedLayers;
use super::types::{frame_psf_reach, Classified, SplatPath};
use formats::RgbaImage;
use psf_db::PsfDatabase;

/// Hidden coverage below which [`CompositeOptions::restore_occluded`] fills nothing (the same
/// threshold as reconstruction's division by coverage).
pub const FILL_MIN_HIDDEN: f32 = 1e-3;

/// The share of a pixel's missing coverage that [`CompositeOptions::restore_occluded`] fills
/// with the hidden colour, from the sharpness of the layers that hid (`occluders`) and of what
/// they hid (`hidden`): `clamp(1/2 + log2(hidden / occluders) / 2, 0, 1)`, and at least
/// `1 - occluders / SMOOTH_OCCLUDERS_SHARPNESS`; all of it where the occluders have no
/// sharpness.
pub fn hidden_fill_share(occluders: f32, hidden: f32) -> f32 {
    if occluders <= 0.0 {
        return 1.0;
    }
    // Occluders this blurred have no holes of their own.
    let least = (1.0 - occluders / SMOOTH_OCCLUDERS_SHARPNESS).max(0.0);
    if hidden <= 0.0 {
        return least;
    }
    (0.5 + 0.5 * (hidden / occluders).log2())
        .clamp(0.0, 1.0)
        .max(least)
}

/// The sharpness ([`layer_sharpness`]) below which occluders are too blurred to have holes of
/// their own: `1 / (1 + r)^2` for a mean PSF reach `r` of about 3.5 px, where neighbouring
/// samples' footprints overlap at any sample count. The share [`hidden_fill_share`] gives the
/// hidden colour is at least `1 - s_occ / SMOOTH_OCCLUDERS_SHARPNESS`.
pub const SMOOTH_OCCLUDERS_SHARPNESS: f32 = 0.05;

/// The sharpness of each layer (index 0 = farthest) for [`CompositeOptions::restore_occluded`]:
/// `1 / (1 + r)^2`, with `r` the mean reach of its records' PSFs (px, [`psf_reach`]; weighted
/// by each record's coverage; 0 for a copied pixel), the inverse of one sample's footprint.
/// Layers without records get 1.
pub fn layer_sharpness(classified: &Classified, db: Option<&PsfDatabase>) -> Vec<f32> {
    let reach = db.map_or_else(Vec::new, |db| {
        frame_psf_reach(db, classified.packed.as_deref())
    });
    let layers = classified.frame.layers as usize;
    let mut reach_sum = vec![0.0f64; layers];
    let mut coverage_sum = vec![0.0f64; layers];
    for r in &classified.records {
        let layer = r.layer as usize;
        if layer >= layers {
            continue;
        }
        let px = if r.path == SplatPath::Copy as u32 {
            0.0
        } else {
            f64::from(reach.get(r.psf_index as usize).copied().unwrap_or(0))
        };
        let coverage = f64::from(r.color[3].abs());
        reach_sum[layer] += coverage * px;
        coverage_sum[layer] += coverage;
    }
    reach_sum
        .iter()
        .zip(&coverage_sum)
        .map(|(&r, &c)| {
            let mean = if c > 0.0 { r / c } else { 0.0 };
            (1.0 / (1.0 + mean).powi(2)) as f32
        })
        .collect()
}

/// Knobs of compositing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CompositeOptions {
    /// Scale the result up to the layers' joint coverage (see the module documentation).
    pub renormalize_coverage: bool,
    /// Make up the missing coverage with the colour "over" hid of the farther layers, where
    /// they are sharper than what hid them (`O + f (1 - O.a) (S - O) / (S.a - O.a)`, see the
    /// module documentation), instead of scaling the whole pixel up to the layers' joint
    /// coverage: for reconstruction from stochastic samples, whose visibility is already in
    /// the samples. Takes effect only with `renormalize_coverage`.
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

/// Composites the layers back to front (layer 0 = farthest) into a `width x height` image,
/// every layer equally sharp for [`CompositeOptions::restore_occluded`].
pub fn composite(layers: &IntegratedLayers, options: &CompositeOptions) -> RgbaImage {
    composite_with_sharpness(layers, options, &[])
}

/// [`composite`] with each layer's sharpness for [`CompositeOptions::restore_occluded`]
/// (index 0 = farthest, [`layer_sharpness`]); missing entries count as 1.
pub fn composite_with_sharpness(
    layers: &IntegratedLayers,
    options: &CompositeOptions,
    sharpness: &[f32],
) -> RgbaImage {
    let f = layers.frame;
    let (w, h) = (f.width as usize, f.height as usize);
    let (pw, pad) = (f.padded_width as usize, f.pad as usize);
    let mut out = RgbaImage::new(w, h);
    // Each drawn layer: its index, its planes (`None` where coarse levels add to them, read a
    // row at a time through `layer_row`), sharpness and the padded rows it may be non-zero
    // in. A zero pixel leaves every sum as it was, so the rows outside are skipped, unread.
    type Drawn<'a> = (usize, Option<&'a [Plane]>, f32, [usize; 2]);
    let drawn: Vec<Drawn> = (0..f.layers as usize)
        .filter_map(|l| {
            let rows = layers.rows.get(l).copied().unwrap_or([0, usize::MAX]);
            let sharpness = sharpness.get(l).copied().unwrap_or(1.0);
            if layers.has_coarse(l) {
                return (0..4)
                    .all(|c| layers.has_plane(l * 4 + c))
                    .then_some((l, None, sharpness, rows));
            }
            let planes = layers.planes.get(l * 4..l * 4 + 4)?;
            (!planes.iter().any(|p| p.is_empty())).then_some((l, Some(planes), sharpness, rows))
        })
        .collect();
    // Row by row on every thread, the sums in the row's own buffers (the image is written
    // once, not read first): a pixel sees the layers in the same order whatever the thread
    // count, so the bytes do not depend on it.
    out.pixels
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, out_row)| {
            // "Over" so far.
            let mut over = vec![[0.0f32; 4]; w];
            // The layers' plain sum, colour and coverage (`S`).
            let mut total = vec![[0.0f32; 4]; w];
            // Coverage-weighted sharpness: of what "over" shows, summed over the layers, and
            // of what hid something.
            let mut sharp = vec![[0.0f32; 3]; w];
            // A layer's row with its coarse levels' light added.
            let mut layer_row = Vec::new();
            let row = (y + pad) * pw + pad;
            for &(l, planes, s, [first, end]) in &drawn {
                if y + pad < first || y + pad >= end {
                    continue;
                }
                match planes {
                    Some(planes) => {
                        for x in 0..w {
                            let k = row + x;
                            let c = [
                                planes[0].data[k],
                                planes[1].data[k],
                                planes[2].data[k],
                                planes[3].data[k],
                            ];
                            fold_layer_pixel(c, s, &mut over[x], &mut total[x], &mut sharp[x]);
                        }
                    }
                    None => {
                        layer_row.resize(w, [0.0f32; 4]);
                        layers.layer_row(l, y, &mut layer_row);
                        for (x, &c) in layer_row.iter().enumerate() {
                            fold_layer_pixel(c, s, &mut over[x], &mut total[x], &mut sharp[x]);
                        }
                    }
                }
            }
            for (((dst, mut px), sum), sharp) in
                out_row.iter_mut().zip(over).zip(&total).zip(&sharp)
            {
                finish_pixel(&mut px, sum, sharp, options);
                *dst = px;
            }
        });
    out
}

/// One layer's pixel `c` (premultiplied RGBA, as drawn) of sharpness `s` put under a pixel's
/// sums so far, which go from the farthest layer to the nearest: its "over" `acc`, the plain
/// sum `total`, and the coverage-weighted sharpness sums `sharp`. The layer is first
/// renormalised where its coverage exceeds one, its negative coverage taken as zero.
#[inline]
pub(super) fn fold_layer_pixel(
    mut c: [f32; 4],
    s: f32,
    acc: &mut [f32; 4],
    total: &mut [f32; 4],
    sharp: &mut [f32; 3],
) {
    c[3] = c[3].max(0.0);
    if c[3] > 1.0 {
        let inv = 1.0 / c[3];
        c = c.map(|v| v * inv);
    }
    for ch in 0..4 {
        total[ch] += c[ch];
    }
    let t = 1.0 - c[3];
    let [shown, summed, hiding] = *sharp;
    *sharp = [
        s * c[3] + t * shown,
        summed + s * c[3],
        hiding + s * c[3] * acc[3],
    ];
    for ch in 0..4 {
        acc[ch] = c[ch] + t * acc[ch];
    }
}

/// A pixel's "over" `px` made up to the layers' joint coverage (`sum`, the plain sum of the
/// layers; `sharp`, the coverage-weighted sharpness sums) as `options` ask, then clamped at 0.
#[inline]
pub(super) fn finish_pixel(
    px: &mut [f32; 4],
    sum: &[f32; 4],
    sharp: &[f32; 3],
    options: &CompositeOptions,
) {
    if options.renormalize_coverage && options.restore_occluded {
        let hidden = sum[3] - px[3];
        if hidden > FILL_MIN_HIDDEN && px[3] < 1.0 {
            let share = hidden_fill_share(sharp[2] / hidden, (sharp[1] - sharp[0]) / hidden);
            let f = share * (1.0 - px[3]) / hidden;
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
