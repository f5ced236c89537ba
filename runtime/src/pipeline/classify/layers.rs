//! From fragments to splat records: each fragment's PSF, its depth layer(s) in constant
//! parallax, occlusion between fragments that share a layer, and the records sorted by layer.

use super::frame_edges::{distance_to, extend_beyond};
use super::lookup::{
    across_first_box_edge, first_box_edges_px, front_turns_the_aperture, lookup_psf, Lookup,
};
use super::*;
use crate::camera::Camera;
use crate::dbset::{DbSet, NO_TWIN};
use crate::motion_smear::{AngleResolution, PsfImage, SmearError, SmearExtent, SmearKey};
use crate::pipeline::packed::{PackedImage, PackedImages};
use crate::pipeline::types::{
    frame_extent_px, frame_psf_reach, psf_reach, CoarseLevel, FrameParams, SplatPath, SplatRecord,
};
use crate::smear_symmetry::{
    canonical_key, is_grid_symmetric, transform_image, BoxImage, GridSymmetry,
};
use crate::subpixel_psf::SubpixelPsf;
use psf_db::{PsfDatabase, PsfModel};
use rayon::prelude::*;

/// Layers fragments and turns them into splat records: the nearest PSF of each (O(1) through
/// the nested grid), its rotation, its drawing path, and its layer(s). `w x h` is the frame
/// (the output); fragments are in frame coordinates and may lie outside it, within `data`
/// (overscan). Beyond `data`, [`ClassifyOptions::frame_edges`] decides. `model` comes from
/// [`resolve_model`]; `counts` carries what the caller already counted (dropped, edge splits).
#[allow(clippy::too_many_arguments)]
pub fn classify_fragments(
    mut fragments: Vec<Fragment>,
    w: usize,
    h: usize,
    data: DataWindow,
    camera: &Camera,
    dbs: &DbSet,
    model: Option<PsfModel>,
    options: &ClassifyOptions,
    mut counts: PathCounts,
) -> Result<Classified, ClassifyError> {
    if options.layers == 0 {
        return Err(ClassifyError::NoLayers);
    }
    let combined = dbs.combined.as_ref();
    let lens = camera.thin_lens();
    let pixels_per_mm = camera.pixels_per_mm() as f32;
    // Nothing to simulate: every pixel is copied, and one layer returns the input unchanged.
    let n_layers = if model.is_some() {
        options.layers as usize
    } else {
        1
    };
    let signed_coc = |d: f32| -> f32 { lens.map_or(0.0, |l| l.signed_coc_px(f64::from(d)) as f32) };
    let (pmin, pmax) = fragments
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), f| {
            (a.min(f.parallax), b.max(f.parallax))
        });
    let span = if pmax > pmin { pmax - pmin } else { 0.0 };

    // One input surface per pixel of each source (render layer), the background continued
    // behind occluders and veils aside. Through a real lens a pixel's PSF changes over the
    // field too: not continued.
    let input_source = |f: &&Fragment| {
        f.source != super::hidden::HIDDEN_SOURCE && f.source != super::hidden::VEIL_SOURCE
    };
    let first_source = fragments.iter().find(input_source).map(|f| f.source);
    let one_source = fragments
        .iter()
        .filter(input_source)
        .all(|f| Some(f.source) == first_source);
    // A fragment's blur, pixels: its CoC radius and half its motion.
    let blur_of = |f: &Fragment| {
        let coc = signed_coc(f.depth).abs();
        let m = f.motion;
        coc + 0.5 * (m[0] * m[0] + m[1] * m[1]).sqrt()
    };
    let edges = LayerEdges::new((pmin, span), n_layers, &fragments, &blur_of);
    // Layer coordinate: 0 at the far edge, n at the near edge.
    let layer_coord = |p: f32| -> f32 { edges.coord(p) };
    let continue_layers = options.continue_layers
        && matches!(model, Some(PsfModel::ThinLens | PsfModel::LensMotion))
        && n_layers > 1;
    if continue_layers {
        let layer_of = |f: &Fragment| (layer_coord(f.parallax).floor() as usize).min(n_layers - 1);
        let continued = if one_source {
            continue_across_layers(
                &fragments,
                (w, h),
                &layer_of,
                &blur_of,
                options.hdr_dense_threshold,
            )
        } else {
            // Render layers: each one's surfaces on their own, what another layer holds in
            // the same pixel being another surface.
            let mut sources: Vec<u32> = fragments
                .iter()
                .filter(input_source)
                .map(|f| f.source)
                .collect();
            sources.sort_unstable();
            sources.dedup();
            let mut continued = Vec::new();
            for source in sources {
                let own: Vec<Fragment> = fragments
                    .iter()
                    .filter(|f| f.source == source)
                    .copied()
                    .collect();
                continued.extend(continue_across_layers(
                    &own,
                    (w, h),
                    &layer_of,
                    &blur_of,
                    options.hdr_dense_threshold,
                ));
            }
            continued
        };
        // Appended in the room the fragments were made with: a copy would touch all of them
        // (13 MB on a 512 px frame) again in fresh memory.
        fragments.extend(continued);
    }
    // A veil matters only where its occluder and the background it lies on can share a depth
    // layer (a soft split spans two neighbouring ones): beside a near, defocused post most of
    // its veils lie on a background layers behind it, and sorting them cost a tenth of the
    // frame's classification.
    if fragments
        .iter()
        .any(|f| f.source == super::hidden::VEIL_SOURCE)
    {
        fragments.retain(|f| {
            f.source != super::hidden::VEIL_SOURCE || f.color[0] <= 0.0 || {
                let occluder = layer_coord(f.parallax).floor();
                let background = layer_coord(1.0 / f.color[0]).floor();
                (occluder - background).abs() <= 1.0
            }
        });
    }
    let fragments = &fragments[..];

    // Layer weights: hard, or blended near the boundary between two layer centres. A sharp
    // fragment is not split: its PSF barely differs between the two layers, and a surface
    // split across two layers lets what lies behind it show through (up to a quarter where
    // the weights are even). Nor is a fragment of several sources (render layers, deep
    // samples): another source's surface lies behind most of it, and showed through as rings
    // along a spinning sphere's iso-depth lines and a darker body on a moving car.
    // A flat input has nothing behind its surfaces but near their silhouettes.
    let own_targets = |frag: &Fragment| {
        let coc = signed_coc(frag.depth).abs();
        let m = frag.motion;
        let motion_len = (m[0] * m[0] + m[1] * m[1]).sqrt();
        let sharp = coc.max(motion_len) < options.soft_layers_min_blur_px;
        // Continued across the layers instead, a still surface is layered hard.
        let continued = continue_layers && motion_len < 1.0;
        let band = options
            .soft_layers
            .filter(|_| !sharp && !continued && one_source);
        layer_targets(layer_coord(frag.parallax), n_layers, band)
    };
    // A surface behind a nearer one in its pixel (another render layer, deep sample, or the
    // background continued behind an occluder) goes into a layer behind the nearer one's
    // farthest, so that compositing lays the nearer surface's blurred or smeared edge over it
    // instead of the two adding up in one layer; and the nearer one is layered hard there, so
    // that its two halves do not let it through (a spinning sphere's rim greyed by the wall
    // continued behind it).
    let ceilings = Ceilings::new(fragments, &own_targets);
    let targets_of = |frag: &Fragment| match ceilings.as_ref() {
        Some(ceilings) if frag.source != super::hidden::VEIL_SOURCE => {
            if ceilings.covers_another(frag) {
                return layer_targets(layer_coord(frag.parallax), n_layers, None);
            }
            ceilings.lower(frag, own_targets(frag))
        }
        _ => own_targets(frag),
    };
    let transmission = occlusion_within_layers(fragments, n_layers, &targets_of);
    let flip_front = front_turns_the_aperture(dbs);

    let centre = [w as f32 * 0.5, h as f32 * 0.5];
    // Through a real lens, the outer edges of its first eccentricity boxes, px.
    let first_box_edges = match (model, dbs.main.as_ref()) {
        (Some(PsfModel::PhysicalLens), Some(db)) if options.continuous_lookup => {
            first_box_edges_px(db, pixels_per_mm)
        }
        _ => Vec::new(),
    };
    // Through a real lens, each moving fragment's lens PSF smeared along its motion: one key
    // per fragment (with whether its parameters were clamped), each key's PSF built once and
    // appended to the frame's own copy of the database. Through the thin lens the same, from
    // the thin-lens PSF of its CoC, where `smear_motion` asks for it.
    let any_moving = fragments
        .iter()
        .any(|f| f.motion[0] != 0.0 || f.motion[1] != 0.0);
    let thin_smear = match (model, dbs.thin_lens.as_ref()) {
        (Some(PsfModel::LensMotion | PsfModel::ThinLens), Some(thin))
            if options.smear_motion && any_moving =>
        {
            Some(thin)
        }
        _ => None,
    };
    let moving_lens = model == Some(PsfModel::PhysicalLens) && any_moving;
    // Each fragment's resolution: frame pixels per drawn pixel, 1 unless its blur is beyond
    // the database's range.
    let range = options
        .reduced_resolution
        .then(|| blur_range(dbs, model, thin_smear.is_some()))
        .flatten();
    // `motion_cap`: the longest motion (px) drawn at the frame's resolution, besides the
    // database's own range; lowered only when the frame's streaks would not fit their budget.
    let scale_of = |frag: &Fragment, motion_cap: f32| -> u32 {
        let Some([coc_max, len_max]) = range else {
            return 1;
        };
        let coc_max = coc_max.min(options.coarse_above_px);
        let len_max = len_max.min(motion_cap);
        let coc = signed_coc(frag.depth).abs();
        let m = frag.motion;
        let len = (m[0] * m[0] + m[1] * m[1]).sqrt();
        let mut scale = 1u32;
        while scale < MAX_SCALE && (coc > coc_max * scale as f32 || len > len_max * scale as f32) {
            scale *= 2;
        }
        scale
    };
    let scales_under = |motion_cap: f32| -> Vec<u8> {
        if range.is_some() {
            fragments
                .par_iter()
                .map(|f| scale_of(f, motion_cap).trailing_zeros() as u8)
                .collect()
        } else {
            Vec::new()
        }
    };
    // A fragment as its level draws it: centred on its coarse pixel, CoC and motion in coarse
    // pixels, colour spread over the coarse pixel's frame pixels.
    let at_level = |frag: &Fragment, level: usize| -> (Fragment, f32) {
        if level == 0 {
            return (*frag, signed_coc(frag.depth));
        }
        let s = (1u32 << level) as f32;
        let coarse = Fragment {
            x: frag.x.div_euclid(1 << level),
            y: frag.y.div_euclid(1 << level),
            color: frag.color.map(|c| c / (s * s)),
            motion: frag.motion.map(|m| m / s),
            bend: frag.bend / s,
            ..*frag
        };
        (coarse, signed_coc(frag.depth) / s)
    };
    let reach: Vec<i32> = match combined {
        Some(all) if moving_lens || thin_smear.is_some() => psf_reach(all),
        _ => Vec::new(),
    };
    // Where the frame's streaks do not fit their budget, the cap on full-resolution motion
    // starts at half the frame's longest motion (px), found then.
    let mut longest_motion: Option<f32> = None;
    let mut motion_cap = f32::INFINITY;
    let (scales, smear_keys, smeared) = loop {
        let scales = scales_under(motion_cap);
        let level_of = |index: usize| scales.get(index).copied().unwrap_or(0) as usize;
        let keys_at_rounded_angles = || -> Vec<Option<(SmearKey, bool)>> {
            if combined.is_none() || !(moving_lens || thin_smear.is_some()) {
                return Vec::new();
            }
            fragments
                .par_iter()
                .enumerate()
                .map(|(index, frag)| {
                    let (frag, signed) = at_level(frag, level_of(index));
                    let frag = &frag;
                    let m = frag.motion;
                    let motion_len = (m[0] * m[0] + m[1] * m[1]).sqrt();
                    if frag.weight <= 0.0 || motion_len < options.copy_threshold_px {
                        return None;
                    }
                    if let Some(thin) = thin_smear {
                        // The thin-lens database comes first in the combined one. In front
                        // of the focus plane the aperture's image is turned half a turn.
                        let (i, clamped) = thin.lookup([signed.abs(), 0.0]);
                        let turned = flip_front && signed < 0.0;
                        let radial = if turned { [-1.0, 0.0] } else { [1.0, 0.0] };
                        let reach = reach.get(i as usize).copied().unwrap_or(0) as f32;
                        let threshold = ordered_dither(frag.x, frag.y);
                        let (key, too_long) =
                            SmearKey::dithered(i, m, frag.bend, radial, reach, threshold);
                        return Some((key, clamped || too_long));
                    }
                    let found = lookup_psf(
                        frag,
                        0.0,
                        motion_len,
                        centre,
                        pixels_per_mm,
                        dbs,
                        model,
                        options,
                        false,
                        &mut psf_db::CellMemo::default(),
                    );
                    if found.path == SplatPath::Copy {
                        return None;
                    }
                    // Near the first eccentricity box's edge, the other box's PSF for its
                    // share of the pixels, dithered: a smear is one PSF, and along the motion
                    // it averages its neighbours' choices.
                    let across = (level_of(index) == 0)
                        .then(|| {
                            let at = (frag.x, frag.y);
                            let edges = &first_box_edges[..];
                            let i = found.psf_index;
                            across_first_box_edge(
                                dbs,
                                i,
                                at,
                                frag.depth,
                                centre,
                                pixels_per_mm,
                                edges,
                            )
                        })
                        .flatten()
                        .filter(|a| ordered_dither(frag.x, frag.y) < a.share);
                    let i = across.map_or(found.psf_index, |a| a.psf_index);
                    let reach = reach.get(i as usize).copied().unwrap_or(0) as f32;
                    let radial = [found.rot_cos, found.rot_sin];
                    Some(SmearKey::new(i, m, frag.bend, radial, reach))
                })
                .collect()
        };
        // Where the frame's streaks turn every which way (a car driving at the camera), its
        // rounded angles are already off a little differently at every pixel, and building a
        // smeared PSF for every few pixels is most of classification: the angles are then
        // dithered between steps twice as far apart, for half the keys.
        let mut smear_keys = keys_at_rounded_angles();
        if thin_smear.is_some() && many_keys(&smear_keys) {
            // Only the angles change: each key's cell, length and turn are kept, in place.
            smear_keys
                .par_iter_mut()
                .enumerate()
                .for_each(|(index, key)| {
                    if let Some((key, _)) = key {
                        let (frag, _) = at_level(&fragments[index], level_of(index));
                        let reach = reach.get(key.cell as usize).copied().unwrap_or(0) as f32;
                        let threshold = ordered_dither(frag.x, frag.y);
                        let angles = AngleResolution::Dithered;
                        *key = key.with_angles(frag.motion, frag.bend, reach, threshold, angles);
                    }
                });
        }
        let built = match combined {
            Some(all) if !smear_keys.is_empty() => SmearedPsfs::build(
                &smear_keys,
                all,
                thin_smear,
                options.pack_images,
                options.smeared_values_budget,
            ),
            _ => Ok(SmearedPsfs::default()),
        };
        match built {
            // Too many streaks, or too long, for the frame's budget: the longest are drawn at
            // half the resolution (a quarter of the pixels, half the angle steps), then a
            // quarter, until they fit or reach the coarsest level.
            Err(e @ ClassifyError::MotionSmear(SmearError::FrameTooLarge { .. }))
                if range.is_some() =>
            {
                let longest = *longest_motion.get_or_insert_with(|| {
                    fragments
                        .par_iter()
                        .map(|f| (f.motion[0] * f.motion[0] + f.motion[1] * f.motion[1]).sqrt())
                        .reduce(|| 0.0, f32::max)
                });
                if motion_cap <= longest / MAX_SCALE as f32 {
                    return Err(e);
                }
                motion_cap = motion_cap.min(longest) / 2.0;
            }
            built => break (scales, smear_keys, built?),
        }
    };
    let level_of = |index: usize| scales.get(index).copied().unwrap_or(0) as usize;
    let combined = smeared.database.as_deref().or(combined);
    // A still pixel's blend of two turned dense PSFs is one record until the shared turns
    // premix it.
    let pack_pairs = options.shared_turns && model == Some(PsfModel::PhysicalLens);
    // One fragment's records into `per_layer`, and what it counts into `counts`.
    let emit = |index: usize,
                frag: &Fragment,
                per_layer: &mut [Vec<SplatRecord>],
                counts: &mut PathCounts,
                memo: &mut psf_db::CellMemo| {
        if frag.weight <= 0.0 {
            return;
        }
        // Layers follow the fragment's own blur; all else its level's.
        let (targets, n_targets) = targets_of(frag);
        let (frag, signed) = at_level(frag, level_of(index));
        let frag = &frag;
        let (x, y) = (frag.x, frag.y);
        let color = frag.color;
        let coc = signed.abs();
        let m = frag.motion;
        let motion_len = (m[0] * m[0] + m[1] * m[1]).sqrt();
        let bright = color[..3]
            .iter()
            .any(|&c| c * frag.weight > options.hdr_dense_threshold);
        // A bright fragment stands alone (a highlight's bokeh is one PSF, not an average over
        // a neighbourhood): it keeps the PSF of its own parameters.
        // Through a real lens, though, a bright fragment blends too: its cell is a box over
        // inverse depth, and the blend of the two nearest cells' PSFs has about the size of
        // its own (a squared RMS radius is linear in the blend).
        let continuous =
            options.continuous_lookup && (!bright || model == Some(PsfModel::PhysicalLens));
        let Lookup {
            path,
            psf_index,
            clamped,
            mut rot_cos,
            mut rot_sin,
            blend,
            round_share,
        } = lookup_psf(
            frag,
            coc,
            motion_len,
            centre,
            pixels_per_mm,
            dbs,
            model,
            options,
            continuous,
            memo,
        );
        // In front of the focus plane the lens images its aperture turned half a turn: the
        // databases hold the PSF behind it (see `front_turns_the_aperture`).
        if flip_front && signed < 0.0 && model != Some(PsfModel::PhysicalLens) {
            rot_cos = -rot_cos;
            rot_sin = -rot_sin;
        }
        let smear = smear_keys.get(index).copied().flatten();
        // A thin-lens smear replaces the lens-motion lookup, and its range with it.
        let lookup_clamped = clamped && !(thin_smear.is_some() && smear.is_some());
        counts.clamped += usize::from(lookup_clamped || smear.is_some_and(|(_, c)| c));
        let smeared_index = smear.and_then(|(k, _)| smeared.index_of(k));
        let round_share = if smeared_index.is_some() {
            0.0
        } else {
            round_share
        };
        // Near the first eccentricity box's edge, a still pixel through a real lens draws
        // part of the next box's PSF ([`super::lookup::first_box_edge`]).
        let across_edge = (continuous && smeared_index.is_none() && level_of(index) == 0)
            .then(|| {
                let at = (frag.x, frag.y);
                let edges = &first_box_edges[..];
                across_first_box_edge(dbs, psf_index, at, frag.depth, centre, pixels_per_mm, edges)
            })
            .flatten();
        let (path, psf_index, blend) = match smeared_index {
            Some(i) => {
                // Built in the image's frame at the fragment's own motion: drawn unrotated,
                // and not blended with a neighbouring cell.
                counts.smeared += 1;
                (rot_cos, rot_sin) = (1.0, 0.0);
                (SplatPath::Dense, i, None)
            }
            None => (path, psf_index, blend),
        };
        // The twin of the sub-cell holding the fragment's own CoC and motion (a thin-lens
        // cell is divided in CoC alone and ignores the motion).
        let twin = dbs.hdr_twin_for(psf_index, [coc, motion_len]);
        let to_twin = path != SplatPath::Copy && bright && twin != NO_TWIN;
        let (path, psf_index) = if to_twin {
            counts.hdr_dense += 1;
            (SplatPath::Dense, twin)
        } else {
            (path, psf_index)
        };

        if n_targets == 2 {
            counts.soft_split += 1;
        }
        // The PSF, and across the first eccentricity box's edge the other box's, each with its
        // share of the fragment.
        let edge_share = across_edge.filter(|_| !to_twin).map_or(0.0, |a| a.share);
        let own_draw = (path, psf_index, blend, round_share, 1.0 - edge_share);
        let draws = [
            Some(own_draw),
            across_edge
                .filter(|_| edge_share > 0.0)
                .map(|a| (a.path, a.psf_index, a.blend, 0.0, a.share)),
        ];
        for (path, psf_index, blend, round_share, draw_share) in draws.into_iter().flatten() {
            // The fragment's PSF, or its cell's and its neighbour's with their shares.
            // A twin is already the PSF of the fragment's own sub-cell.
            // Two dense neighbours are drawn premixed ([`DbSet::dense_blend_for`]), as one record.
            let mut parts = [(path, psf_index, 1.0f32), (path, psf_index, 0.0)];
            if let Some(b) = blend.filter(|b| !to_twin && b.psf_index != psf_index) {
                let both_dense = path == SplatPath::Dense && b.path == SplatPath::Dense;
                let premixed = both_dense
                    .then(|| dbs.dense_blend_for(psf_index, b.psf_index, b.share))
                    .flatten();
                match premixed {
                    Some(mixed) => parts[0].1 = mixed,
                    None => {
                        parts[0].2 = 1.0 - b.share;
                        parts[1] = (b.path, b.psf_index, b.share);
                    }
                }
            }
            let n_parts = if parts[1].2 > 0.0 { 2 } else { 1 };
            for (t, &(layer, lw)) in targets[..n_targets].iter().enumerate() {
                let weight = draw_share
                    * match &transmission {
                        Some(kept) => frag.weight * lw * kept[index][t],
                        None => frag.weight * lw,
                    };
                // Near the optical axis, part of a real lens's PSF is drawn as its rotational
                // average, upright ([`DbSet::axis_round`]); the turned parts first, so that a blend's
                // two stay neighbours.
                let round_of = |psf: u32| {
                    dbs.axis_round
                        .get(psf as usize)
                        .copied()
                        .filter(|&i| round_share > 0.0 && i != NO_TWIN)
                };
                let part_weight = |psf_index: u32, share: f32| {
                    let kept = if round_of(psf_index).is_some() {
                        1.0 - round_share
                    } else {
                        1.0
                    };
                    weight * share * kept
                };
                // Two turned dense PSFs of a frame whose shared turns are drawn upright: one
                // record, premixed there ([`super::turned::pack_pair`]).
                let [(path_a, psf_a, share_a), (path_b, psf_b, share_b)] = parts;
                let pair = (pack_pairs
                    && level_of(index) == 0
                    && n_parts == 2
                    && path_a == SplatPath::Dense
                    && path_b == SplatPath::Dense
                    && !(rot_cos == 1.0 && rot_sin == 0.0))
                    .then(|| {
                        super::turned::pack_pair(
                            (x, y),
                            layer as u32,
                            (rot_cos, rot_sin),
                            color,
                            (psf_a, part_weight(psf_a, share_a)),
                            (psf_b, part_weight(psf_b, share_b)),
                        )
                    })
                    .flatten();
                if let Some(pair) = pair {
                    per_layer[layer].push(pair);
                }
                for &(path, psf_index, share) in &parts[..n_parts] {
                    if pair.is_some() {
                        break;
                    }
                    let weight = part_weight(psf_index, share);
                    // Frame coordinates for now; shifted by the padding once it is known.
                    per_layer[layer].push(SplatRecord {
                        center_x: x,
                        center_y: y,
                        psf_index,
                        layer: layer as u32,
                        rot_cos,
                        rot_sin,
                        weight,
                        path: path as u32,
                        color: color.map(|v| v * weight),
                    });
                }
                // The two PSFs' rotational averages, where both have one: one upright record,
                // premixed as the turned pair is.
                let round_pair = (pack_pairs && level_of(index) == 0 && n_parts == 2)
                    .then(|| {
                        let (a, b) = (round_of(psf_a)?, round_of(psf_b)?);
                        super::turned::pack_pair(
                            (x, y),
                            layer as u32,
                            (1.0, 0.0),
                            color,
                            (a, weight * share_a * round_share),
                            (b, weight * share_b * round_share),
                        )
                    })
                    .flatten();
                if let Some(pair) = round_pair {
                    per_layer[layer].push(pair);
                }
                for &(_, psf_index, share) in &parts[..n_parts] {
                    if round_pair.is_some() {
                        break;
                    }
                    if let Some(round) = round_of(psf_index) {
                        let weight = weight * share * round_share;
                        per_layer[layer].push(SplatRecord {
                            center_x: x,
                            center_y: y,
                            psf_index: round,
                            layer: layer as u32,
                            rot_cos: 1.0,
                            rot_sin: 0.0,
                            weight,
                            path: SplatPath::Dense as u32,
                            color: color.map(|v| v * weight),
                        });
                    }
                }
            }
        }
    };
    // Fragments in chunks on every thread, each chunk's records per layer appended in chunk
    // order: the same records in the same order as one pass over them.
    const CHUNK: usize = 4096;
    // `chunks[c][level][layer]`.
    let n_levels = scales
        .iter()
        .copied()
        .max()
        .map_or(1, |l| usize::from(l) + 1);
    let chunks: Vec<(Vec<Vec<Vec<SplatRecord>>>, PathCounts)> = fragments
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            let mut per_level = vec![vec![Vec::new(); n_layers]; n_levels];
            let mut counted = PathCounts::default();
            let mut memo = psf_db::CellMemo::default();
            for (k, frag) in chunk.iter().enumerate() {
                let index = c * CHUNK + k;
                let level = level_of(index);
                counted.reduced += usize::from(level > 0 && frag.weight > 0.0);
                emit(index, frag, &mut per_level[level], &mut counted, &mut memo);
            }
            // A coarse pixel's frame pixels along a row follow each other here, and most
            // draw the same PSFs: merged now, before the level is assembled (a 3840 x 2160
            // frame's background at a quarter of its resolution emitted 19 M records for 1.2 M
            // merged ones), and again across rows once it is.
            for layers in per_level.iter_mut().skip(1) {
                for records in layers.iter_mut().filter(|r| r.len() > 1) {
                    *records = merged_in_pixel_runs(records);
                }
            }
            (per_level, counted)
        })
        .collect();
    for (_, counted) in &chunks {
        counts.clamped += counted.clamped;
        counts.hdr_dense += counted.hdr_dense;
        counts.soft_split += counted.soft_split;
        counts.smeared += counted.smeared;
        counts.reduced += counted.reduced;
    }
    let mut levels: Vec<Vec<Vec<Vec<SplatRecord>>>> = vec![Vec::new(); n_levels];
    for (per_level, _) in chunks {
        for (level, layers) in per_level.into_iter().enumerate() {
            levels[level].push(layers);
        }
    }
    let mut levels = levels.into_iter().enumerate();
    let fine = levels.next().map(|(_, chunks)| chunks).unwrap_or_default();
    let mut classified = assemble_layers(
        &fine,
        n_layers,
        w,
        h,
        data,
        combined,
        smeared.packed.as_deref(),
        options,
        counts,
        &edges.edges,
    );
    drop(fine);
    for (level, chunks) in levels {
        if chunks.iter().all(|layers| layers.iter().all(Vec::is_empty)) {
            continue;
        }
        let scale = 1u32 << level;
        let coarse_data = DataWindow {
            x0: data.x0.div_euclid(scale as i32),
            y0: data.y0.div_euclid(scale as i32),
            x1: data.x1.div_euclid(scale as i32),
            y1: data.y1.div_euclid(scale as i32),
        };
        let mut coarse = assemble_layers(
            &chunks,
            n_layers,
            w.div_ceil(scale as usize),
            h.div_ceil(scale as usize),
            coarse_data,
            combined,
            smeared.packed.as_deref(),
            options,
            PathCounts::default(),
            &edges.edges,
        );
        merge_coincident(&mut coarse);
        let c = &mut classified.counts;
        c.sparse += coarse.counts.sparse;
        c.dense += coarse.counts.dense;
        c.copied += coarse.counts.copied;
        c.edge_extended += coarse.counts.edge_extended;
        coarse.database = smeared.database.clone();
        coarse.packed = smeared.packed.clone();
        classified.coarse.push(CoarseLevel {
            scale,
            classified: coarse,
        });
    }
    classified.database = smeared.database;
    classified.packed = smeared.packed;
    if options.shared_turns && model == Some(PsfModel::PhysicalLens) {
        let frame_db = classified.database.clone();
        if let Some(base) = frame_db.as_deref().or(dbs.combined.as_ref()) {
            let defocus = if options.scaled_blends {
                super::turned::lens_defocus(dbs, base.psf_count())
            } else {
                vec![f32::NAN; base.psf_count()]
            };
            let turned = super::turned::draw_shared_turns_upright(&mut classified, base, &defocus)?;
            classified.counts.turned += turned;
        }
    }
    if options.few_sparse_images && classified.counts.sparse > 0 {
        let frame_db = classified.database.clone();
        if let Some(base) = frame_db.as_deref().or(dbs.combined.as_ref()) {
            classified.counts.sparse_as_images +=
                super::few_sparse::draw_few_sparse_from_images(&mut classified, base)?;
        }
    }
    Ok(classified)
}

/// `classified` with the records of each layer that share their pixel, PSF, rotation and path
/// merged into one (colours and weights summed, in the records' order; the first keeps its
/// place): drawing one is drawing both. At a coarse level up to `scale^2` frame pixels of one
/// surface land on each coarse pixel with the same PSF. Each layer's records must be in row
/// order, as [`assemble_layers`] leaves them.
fn merge_coincident(classified: &mut Classified) {
    let records = &classified.records;
    let merged: Vec<Vec<SplatRecord>> = classified
        .layers
        .par_iter()
        .map(|info| {
            merged_in_pixel_runs(&records[info.first_record..info.first_record + info.record_count])
        })
        .collect();
    let mut first_record = 0;
    let counts = &mut classified.counts;
    (counts.sparse, counts.dense, counts.copied) = (0, 0, 0);
    for (info, layer) in classified.layers.iter_mut().zip(&merged) {
        *info = LayerInfo {
            first_record,
            record_count: layer.len(),
            sparse: 0,
            dense: 0,
            copied: 0,
            ..*info
        };
        info.count_paths(layer);
        counts.add_layer(info);
        first_record += layer.len();
    }
    classified.records = merged.concat();
    classified.frame.record_count = classified.records.len() as u32;
}

/// `records` with those of one run of records at one pixel that share their PSF, rotation and
/// path merged into one (colours and weights summed, in the records' order; the first keeps
/// its place). A pixel's records that do not follow each other are runs of their own.
fn merged_in_pixel_runs(records: &[SplatRecord]) -> Vec<SplatRecord> {
    let same = |a: &SplatRecord, b: &SplatRecord| {
        a.psf_index == b.psf_index
            && a.path == b.path
            && a.rot_cos.to_bits() == b.rot_cos.to_bits()
            && a.rot_sin.to_bits() == b.rot_sin.to_bits()
    };
    let mut out: Vec<SplatRecord> = Vec::with_capacity(records.len() / 2);
    let mut pixel_start = 0;
    for r in records {
        let new_pixel = out
            .get(pixel_start)
            .is_none_or(|first| (first.center_x, first.center_y) != (r.center_x, r.center_y));
        if new_pixel {
            pixel_start = out.len();
        }
        match out[pixel_start..].iter_mut().find(|m| same(m, r)) {
            Some(m) => {
                m.weight += r.weight;
                for (a, b) in m.color.iter_mut().zip(r.color) {
                    *a += b;
                }
            }
            None => out.push(*r),
        }
    }
    out
}

/// The fragments to append to `fragments` to continue every surface that crosses from a depth
/// layer into a nearer one: where a pixel's fragment (the pixel's heaviest, opaque) lies in layer
/// `l` and its neighbour's along an axis direction in a nearer layer, with blurs within a
/// pixel of each other (one surface, not an occluder's silhouette, which the hidden background
/// handles), the pixel is repeated into the nearer region along that direction, as far as the
/// larger of the two blurs reaches and while the pixels there stay nearer, in its own layer.
/// With hard layers the nearer part's blurred edge would otherwise be composited over the
/// farther part's blurred edge, and the coverage "over" leaves between them (up to a quarter on
/// the boundary) would show the layers behind the surface as a line. A pixel continued from
/// several sides gets the mean. Moving pixels are not continued: a copy put beside a moving
/// pixel is smeared along the motion from there, and the copies of a boundary across the
/// motion draw steps. Nor are pixels brighter than `bright_above` in any of R, G, B: copies of
/// an emitter, half hidden by the nearer part's edge, would add light. `(w, h)` is the frame,
/// `layer_of` a fragment's hard layer, `blur_of` its blur radius (px).
pub(super) fn continue_across_layers(
    fragments: &[Fragment],
    (w, h): (usize, usize),
    layer_of: &(impl Fn(&Fragment) -> usize + Sync),
    blur_of: &(impl Fn(&Fragment) -> f32 + Sync),
    bright_above: f32,
) -> Vec<Fragment> {
    const NONE: u32 = u32::MAX;
    const DIRECTIONS: [(i32, i32); 4] = [(1, 0), (-1, 0), (0, 1), (0, -1)];
    // Each frame pixel's heaviest fragment.
    let mut main = vec![NONE; w * h];
    for (i, f) in fragments.iter().enumerate() {
        if f.x < 0 || f.y < 0 || f.x as usize >= w || f.y as usize >= h {
            continue;
        }
        let p = f.y as usize * w + f.x as usize;
        if main[p] == NONE || fragments[main[p] as usize].weight < f.weight {
            main[p] = i as u32;
        }
    }
    let layers: Vec<usize> = main
        .par_iter()
        .map(|&m| {
            if m == NONE {
                0
            } else {
                layer_of(&fragments[m as usize])
            }
        })
        .collect();
    let (wi, hi) = (w as i32, h as i32);
    let walks: Vec<(u32, (i32, i32), i32)> = (0..hi)
        .into_par_iter()
        .flat_map_iter(|y| {
            let (main, layers) = (&main, &layers);
            (0..wi).flat_map(move |x| {
                let p = (y * wi + x) as usize;
                let m = main[p];
                let mut out = Vec::new();
                if m == NONE {
                    return out;
                }
                let f = &fragments[m as usize];
                // A moving pixel's copies would be smeared along its own motion from where
                // they are put, across the motion: steps along the boundary.
                let bright = f.color[..3].iter().any(|&c| c * f.weight > bright_above);
                if f.color[3] * f.weight < 0.5 || f.motion[0].hypot(f.motion[1]) >= 1.0 || bright {
                    return out;
                }
                let lp = layers[p];
                // Found once a neighbour lies in a nearer layer: most pixels have none.
                let mut own_blur = None;
                for d in DIRECTIONS {
                    let at = |k: i32| -> Option<usize> {
                        let (qx, qy) = (x + d.0 * k, y + d.1 * k);
                        (qx >= 0 && qy >= 0 && qx < wi && qy < hi)
                            .then(|| (qy * wi + qx) as usize)
                            .filter(|&q| main[q] != NONE && layers[q] > lp)
                    };
                    let Some(q) = at(1) else { continue };
                    let blur_p = *own_blur.get_or_insert_with(|| blur_of(f));
                    let blur_q = blur_of(&fragments[main[q] as usize]);
                    if (blur_q - blur_p).abs() > 1.0 {
                        continue;
                    }
                    let reach = blur_p.max(blur_q).ceil() as i32;
                    if reach < 2 {
                        continue;
                    }
                    let steps = (1..=reach).take_while(|&k| at(k).is_some()).count() as i32;
                    out.push((m, d, steps));
                }
                out
            })
        })
        .collect();
    let mut fills = vec![0u16; w * h];
    for &(m, d, steps) in &walks {
        let f = &fragments[m as usize];
        for k in 1..=steps {
            let q = ((f.y + d.1 * k) * wi + f.x + d.0 * k) as usize;
            fills[q] = fills[q].saturating_add(1);
        }
    }
    let extra: usize = walks.iter().map(|&(_, _, steps)| steps as usize).sum();
    let mut out = Vec::with_capacity(extra);
    for (m, d, steps) in walks {
        let f = fragments[m as usize];
        for k in 1..=steps {
            let (x, y) = (f.x + d.0 * k, f.y + d.1 * k);
            let n = fills[(y * wi + x) as usize].max(1);
            out.push(Fragment {
                x,
                y,
                weight: f.weight / f32::from(n),
                ..f
            });
        }
    }
    out
}

/// Frame pixels per drawn pixel, at most: a fragment whose blur is beyond the database's
/// range even this many times smaller is drawn with the largest PSF (and counted clamped).
const MAX_SCALE: u32 = 8;

/// The largest CoC radius and motion length (px) the lookups of `model` reach without
/// clamping: the thin-lens database's CoC range, and the lens-motion database's motion range
/// (or the longest smear, where moving fragments are smeared); `None` for the physical lens,
/// whose space is over depth and the field, or when nothing is simulated.
fn blur_range(dbs: &DbSet, model: Option<PsfModel>, smear: bool) -> Option<[f32; 2]> {
    let max_of = |db: &PsfDatabase, dim: usize| db.space().dims().get(dim).map(|d| d.max as f32);
    let main = dbs.main.as_ref();
    let thin = dbs.thin_lens.as_ref();
    match model? {
        PsfModel::PhysicalLens => None,
        PsfModel::ThinLens | PsfModel::LensMotion => {
            let motion_db = main.filter(|m| m.model() == PsfModel::LensMotion);
            let coc_max = [thin, motion_db]
                .into_iter()
                .flatten()
                .filter_map(|db| max_of(db, 0))
                .fold(f32::INFINITY, f32::min);
            let len_max = if smear {
                crate::motion_smear::MAX_SMEAR_PX
            } else {
                motion_db
                    .and_then(|db| max_of(db, 1))
                    .unwrap_or(f32::INFINITY)
            };
            coc_max.is_finite().then_some([coc_max, len_max])
        }
    }
}

/// A threshold in `[0, 1)` for pixel `(x, y)`: Roberts' R2 low-discrepancy sequence over the
/// plane, `frac(a x + b y)` with `1/a`, `1/b` the powers of the plastic number. Its thresholds
/// are spread evenly along every row, every column and every small block, so that the pixels
/// along a moving edge, whichever way it runs, round a quantity between two steps in the
/// proportion of its fraction (a 4 x 4 Bayer matrix gives a column only four of its sixteen
/// thresholds, and a column's streaks came out a step too long).
fn ordered_dither(x: i32, y: i32) -> f32 {
    const A: f64 = 0.754_877_666_246_692_8;
    const B: f64 = 0.569_840_290_998_053_3;
    (f64::from(x) * A + f64::from(y) * B).rem_euclid(1.0) as f32
}

/// Distinct smeared PSFs (keys at rounded angles, not counting a narrow PSF's fine ones)
/// beyond which a frame's thin-lens streaks have their angles dithered
/// ([`AngleResolution::Dithered`]). On `approaching-car` (512 px)
/// 10,707 keys became 5,522; a camera pan's 105 to 1,589 stay rounded, where all pixels' angles
/// agree and dithering them spread the streaks' tips (FLIP p99 +0.0055 on a Cycles pan).
const MANY_SMEAR_KEYS: usize = 4096;

/// Whether `keys` holds more than [`MANY_SMEAR_KEYS`] distinct keys whose angles are not in
/// fine steps (a narrow PSF's, which stay rounded). Neighbouring fragments of one surface
/// mostly share a key, so each run of equal keys is looked up once, and the look-ups stop at
/// the first key beyond the bar (a car's 100 k runs were once sorted whole to learn that).
fn many_keys(keys: &[Option<(SmearKey, bool)>]) -> bool {
    let mut distinct = std::collections::HashSet::with_capacity(MANY_SMEAR_KEYS + 1);
    let mut last = None;
    keys.iter()
        .flatten()
        .filter(|(key, _)| key.angle_resolution != AngleResolution::Fine)
        .any(|&(key, _)| {
            let new_run = last.replace(key) != Some(key);
            new_run && distinct.insert(key) && distinct.len() > MANY_SMEAR_KEYS
        })
}

/// The smeared PSFs of one frame ([`crate::motion_smear`]): the database its records index
/// (the set's combined PSFs, then one dense PSF per key) and the keys in order.
#[derive(Default)]
struct SmearedPsfs {
    database: Option<std::sync::Arc<PsfDatabase>>,
    /// The images of `database` kept packed ([`PackedImages`]), each an empty image there.
    packed: Option<std::sync::Arc<PackedImages>>,
    /// Sorted, each with its index in `database` (`None`: its lens PSF is empty).
    keys: Vec<(SmearKey, Option<u32>)>,
}

impl SmearedPsfs {
    /// The smeared PSFs of the fragments' keys (`None`: not smeared), from the lens PSFs of
    /// `all`; the frame's smeared images hold at most
    /// `budget_values` values (pixels times channels), or this fails with
    /// [`SmearError::FrameTooLarge`] before building any. With `pack`, grey and RGB images
    /// are kept packed.
    fn build(
        fragment_keys: &[Option<(SmearKey, bool)>],
        all: &PsfDatabase,
        thin_lens: Option<&PsfDatabase>,
        pack: bool,
        budget_values: usize,
    ) -> Result<Self, ClassifyError> {
        let mut keys: Vec<SmearKey> = fragment_keys.iter().flatten().map(|&(k, _)| k).collect();
        if keys.is_empty() {
            return Ok(Self::default());
        }
        keys.par_sort_unstable();
        keys.dedup();
        // Each lens PSF turned once (a sparse one is integrated from its spreadlets first),
        // then smeared for every key that uses it: many keys share a cell and a turn.
        let mut turned: Vec<(u32, u32, u32)> = keys
            .iter()
            .map(|k| (k.cell, k.turn_step, k.turn_steps))
            .collect();
        turned.par_sort_unstable();
        turned.dedup();
        let bases: Vec<Option<PsfImage>> = turned
            .par_iter()
            .map(|&(cell, turn_step, turn_steps)| {
                let angle = crate::motion_smear::turn_rad(turn_step, turn_steps);
                crate::motion_smear::psf_image(all, cell as usize)
                    .map(|psf| crate::motion_smear::turn(&psf, angle))
            })
            .collect();
        // Turned lens PSFs that are the same image smear alike: the cells of a sharp pixel
        // all trim to a single pixel, and an in-focus spinning disc's keys differed in their
        // cell alone. Each key is drawn from the first turn of its image, and keys that then
        // agree share one smeared PSF.
        let mut first_of_image = std::collections::HashMap::new();
        let canonical: Vec<usize> = bases
            .iter()
            .enumerate()
            .map(|(i, base)| match base {
                Some(b) => {
                    let bits: Vec<u32> = b.data.iter().map(|v| v.to_bits()).collect();
                    *first_of_image
                        .entry((b.origin, b.width, b.height, b.channels, bits))
                        .or_insert(i)
                }
                None => i,
            })
            .collect();
        // A narrow thin-lens disc's images at sub-pixel shifts, for the first turn of each
        // image: its taps then land where its path puts them.
        let subpixel: Vec<Option<SubpixelPsf>> = bases
            .par_iter()
            .enumerate()
            .map(|(t, base)| match (thin_lens, base) {
                (Some(thin), Some(base)) if canonical[t] == t => {
                    let (cell, turn_step, turn_steps) = turned[t];
                    // A thin-lens key is upright or turned half a turn (in front of the focus),
                    // to the nearest of its turn's steps.
                    let angle = crate::motion_smear::turn_rad(turn_step, turn_steps);
                    let step = std::f32::consts::TAU / turn_steps.max(1) as f32;
                    let half_turn = (angle - std::f32::consts::PI).abs() < step;
                    (turn_step == 0 || half_turn)
                        .then(|| SubpixelPsf::of_cell(thin, cell, base, half_turn))
                        .flatten()
                }
                _ => None,
            })
            .collect();
        let turn_of = |k: &SmearKey| {
            turned
                .binary_search(&(k.cell, k.turn_step, k.turn_steps))
                .expect("every key's turn is listed")
        };
        let drawn_as = |k: &SmearKey| {
            let (cell, turn_step, turn_steps) = turned[canonical[turn_of(k)]];
            SmearKey {
                cell,
                turn_step,
                turn_steps,
                ..*k
            }
        };
        // Each key as drawn, with its own index: sorted, the distinct ones and which of them
        // each key is, in one pass.
        let mut mapped: Vec<(SmearKey, u32)> = keys
            .par_iter()
            .enumerate()
            .map(|(i, k)| (drawn_as(k), i as u32))
            .collect();
        mapped.par_sort_unstable();
        let mut unique: Vec<SmearKey> = Vec::with_capacity(mapped.len());
        let mut unique_of_key = vec![0u32; keys.len()];
        for &(k, i) in &mapped {
            if unique.last() != Some(&k) {
                unique.push(k);
            }
            unique_of_key[i as usize] = unique.len() as u32 - 1;
        }
        drop(mapped);
        // A lens PSF the pixel grid's symmetries keep (a sharp point's) smears along a key
        // into a symmetry's image of its smear along the least key of the key's orbit: that
        // one is smeared, the others moved from it.
        let symmetric: Vec<bool> = bases
            .par_iter()
            .map(|b| b.as_ref().is_some_and(is_grid_symmetric))
            .collect();
        // Each image's box (and the turned lens PSF it smears, and the orbit it is drawn from)
        // first, then all written in place into the frame's database.
        let extent_of = |base: &PsfImage, k: SmearKey| {
            crate::motion_smear::smear_extent(base, k.length_px(), k.angle_rad(), k.bend_px())
        };
        let extents = unique
            .par_iter()
            .map(|k| {
                let t = turn_of(k);
                bases[t]
                    .as_ref()
                    .map(
                        |base| match symmetric[t].then(|| canonical_key(*k)).flatten() {
                            Some((canonical, g)) => extent_of(base, canonical).map(|e| {
                                let orbit = SmearOrbit {
                                    canonical,
                                    symmetry: g,
                                    extent: e,
                                };
                                (base, e.moved(g), Some(orbit))
                            }),
                            None => extent_of(base, *k).map(|e| (base, e, None)),
                        },
                    )
                    .transpose()
            })
            .collect::<Result<Vec<_>, _>>()?;
        // The bound is on memory, the boxes the images are built in (known before any is
        // built): a grey lens PSF's smeared images hold one value per pixel where an RGB one
        // holds three.
        let pixels: usize = extents
            .iter()
            .flatten()
            .map(|(_, e, _)| e.width.saturating_mul(e.height))
            .fold(0, usize::saturating_add);
        let channels = all.channels().max(1);
        if pixels.saturating_mul(channels) > budget_values {
            return Err(SmearError::FrameTooLarge {
                keys: unique.len(),
                pixels,
                channels,
                budget_values,
            }
            .into());
        }
        let first = all.psf_count() as u32;
        let mut drawn = Vec::new();
        let mut unique_index = Vec::with_capacity(unique.len());
        for (&key, found) in unique.iter().zip(extents) {
            let index = found.map(|(base, extent, orbit)| {
                drawn.push((key, base, extent, orbit, subpixel[turn_of(&key)].as_ref()));
                first + drawn.len() as u32 - 1
            });
            unique_index.push(index);
        }
        let indexed: Vec<(SmearKey, Option<u32>)> = keys
            .iter()
            .zip(&unique_of_key)
            .map(|(k, &u)| (*k, unique_index[u as usize]))
            .collect();
        let not_built = |e: psf_db::DbError| ClassifyError::PhysicalLens(e.to_string());
        // Packed images first, each smeared into a box of its thread's that is reused; in the
        // database each is an empty image, its box kept with its values.
        let packable = |base: &PsfImage| pack && (base.channels == 1 || base.channels == 3);
        let boxes: Vec<_> = drawn
            .iter()
            .map(|&(_, base, e, _, _)| {
                if packable(base) {
                    ([0, 0], 0, 0)
                } else {
                    (e.origin, e.width, e.height)
                }
            })
            .collect();
        // Each orbit's members in turn, so its smear is built once; an image of its own
        // (`None`) is an orbit of one.
        let mut by_orbit: Vec<(Option<SmearKey>, usize)> = drawn
            .iter()
            .enumerate()
            .map(|(i, d)| (d.3.map(|o| o.canonical), i))
            .collect();
        by_orbit.par_sort_unstable();
        let order: Vec<usize> = by_orbit.iter().map(|&(_, i)| i).collect();
        let orbit_of = |i: usize| drawn[i].3.map(|o| o.canonical);
        let orbits: Vec<&[usize]> = order
            .chunk_by(|&a, &b| orbit_of(a).is_some() && orbit_of(a) == orbit_of(b))
            .collect();
        // Per orbit, its smear packed and, where a member needs it, its transpose; each member
        // is one of them mirrored.
        type OrbitImages = (Vec<PackedImage>, Vec<(usize, u32, [bool; 2])>);
        let packed_orbits: Vec<OrbitImages> = orbits
            .par_iter()
            .map_init(SmearScratch::default, |scratch, members| {
                let (key, base, extent, orbit, sub) = drawn[members[0]];
                if !packable(base) {
                    return Ok((Vec::new(), Vec::new()));
                }
                let ch = base.channels;
                let not_finite = || {
                    not_built(psf_db::DbError::OutOfBounds {
                        what: "a smeared PSF value is not finite".into(),
                    })
                };
                let Some(orbit) = orbit else {
                    let smeared = scratch.smear(base, sub, key, extent);
                    let image = PackedImage::pack(
                        extent.origin,
                        extent.width,
                        ch,
                        smeared.values,
                        smeared.rows,
                    );
                    return Ok((
                        vec![image.ok_or_else(not_finite)?],
                        vec![(members[0], 0, [false, false])],
                    ));
                };
                scratch.smear(base, sub, orbit.canonical, orbit.extent);
                let mut images = Vec::with_capacity(2);
                let mut which = [None, None];
                let mut slots = Vec::with_capacity(members.len());
                for &i in members.iter() {
                    // An orbit's members all name it and their symmetry.
                    let g = drawn[i].3.map_or(GridSymmetry::IDENTITY, |o| o.symmetry);
                    let (transposed, mirrors) = g.as_transpose_and_mirrors();
                    let index = match which[usize::from(transposed)] {
                        Some(index) => index,
                        None => {
                            let g = if transposed {
                                GridSymmetry::TRANSPOSE
                            } else {
                                GridSymmetry::IDENTITY
                            };
                            let source = scratch.moved(g);
                            let e = orbit.extent.moved(g);
                            let image = PackedImage::pack(
                                e.origin,
                                e.width,
                                ch,
                                source.values,
                                source.rows,
                            );
                            images.push(image.ok_or_else(not_finite)?);
                            let index = images.len() as u32 - 1;
                            which[usize::from(transposed)] = Some(index);
                            index
                        }
                    };
                    slots.push((i, index, mirrors));
                }
                Ok((images, slots))
            })
            .collect::<Result<_, ClassifyError>>()?;
        let mut pool = Vec::new();
        let mut slots: Vec<Option<(u32, [bool; 2])>> = vec![None; drawn.len()];
        for (images, members) in packed_orbits {
            let first_of_orbit = pool.len() as u32;
            pool.extend(images);
            for (i, index, mirrors) in members {
                slots[i] = Some((first_of_orbit + index, mirrors));
            }
        }
        let extension = crate::dbset::extend_with_dense(all, &boxes).map_err(not_built)?;
        let database = extension
            .fill_within(|i, out, written| {
                let (k, base, extent, orbit, sub) = drawn[i];
                if packable(base) {
                    written.fill([0, 0]);
                    return;
                }
                let Some(orbit) = orbit else {
                    crate::motion_smear::smear_key_within(base, sub, k, extent, out, written);
                    return;
                };
                let mut scratch = SmearScratch::default();
                scratch.smear(base, sub, orbit.canonical, orbit.extent);
                let moved = scratch.moved(orbit.symmetry);
                let ch = base.channels;
                for (v, (&span, w)) in moved.rows.iter().zip(written.iter_mut()).enumerate() {
                    let [a, b] = span.map(usize::from);
                    let row = (v * extent.width + a) * ch..(v * extent.width + b) * ch;
                    out[row.clone()].copy_from_slice(&moved.values[row]);
                    *w = span;
                }
            })
            .map_err(not_built)?;
        let packed = slots
            .iter()
            .any(Option::is_some)
            .then(|| std::sync::Arc::new(PackedImages { first, pool, slots }));
        Ok(Self {
            database: Some(std::sync::Arc::new(database)),
            packed,
            keys: indexed,
        })
    }

    /// Index in [`SmearedPsfs::database`] of the PSF smeared as `key` says.
    fn index_of(&self, key: SmearKey) -> Option<u32> {
        let i = self.keys.binary_search_by(|(k, _)| k.cmp(&key)).ok()?;
        self.keys[i].1
    }
}

/// The orbit a smeared image is moved from ([`crate::smear_symmetry`]): the least key of its
/// key's orbit, its box, and the symmetry that moves its smear onto the image.
#[derive(Clone, Copy)]
struct SmearOrbit {
    canonical: SmearKey,
    symmetry: GridSymmetry,
    extent: SmearExtent,
}

/// One thread's boxes for smearing: the smear last built, and an image moved from it.
#[derive(Default)]
struct SmearScratch {
    values: Vec<f32>,
    rows: Vec<[u16; 2]>,
    extent: Option<SmearExtent>,
    channels: usize,
    moved_values: Vec<f32>,
    moved_rows: Vec<[u16; 2]>,
}

/// A box image in [`SmearScratch`]: its values and per row the columns outside which it is
/// zero.
struct ScratchImage<'a> {
    values: &'a [f32],
    rows: &'a [[u16; 2]],
}

impl SmearScratch {
    /// `base` smeared as `key` says into the box `extent`.
    fn smear(
        &mut self,
        base: &PsfImage,
        sub: Option<&SubpixelPsf>,
        key: SmearKey,
        extent: SmearExtent,
    ) -> ScratchImage<'_> {
        let len = extent.width * extent.height * base.channels;
        if self.values.len() < len {
            self.values.resize(len, 0.0);
        }
        self.rows.clear();
        self.rows.resize(extent.height, [0, 0]);
        let out = &mut self.values[..len];
        crate::motion_smear::smear_key_within(base, sub, key, extent, out, &mut self.rows);
        self.extent = Some(extent);
        self.channels = base.channels;
        ScratchImage {
            values: &self.values[..len],
            rows: &self.rows,
        }
    }

    /// The last smear moved by `g`.
    fn moved(&mut self, g: GridSymmetry) -> ScratchImage<'_> {
        let extent = self.extent.expect("a smear is built before it is moved");
        let ch = self.channels;
        if g == GridSymmetry::IDENTITY {
            return ScratchImage {
                values: &self.values[..extent.width * extent.height * ch],
                rows: &self.rows,
            };
        }
        let src = BoxImage {
            origin: extent.origin,
            width: extent.width,
            channels: ch,
            values: &self.values,
            rows: &self.rows,
        };
        let (_, width) = transform_image(&src, g, &mut self.moved_values, &mut self.moved_rows);
        ScratchImage {
            values: &self.moved_values[..width * self.moved_rows.len() * ch],
            rows: &self.moved_rows,
        }
    }
}

/// The frame's records from its chunks' (`chunks[c][layer]`, frame coordinates, each layer's
/// in fragment order): overscan records that cannot reach the frame dropped, the data's border
/// extended outwards as [`ClassifyOptions::frame_edges`] says, row order within each layer
/// (stable: what a stable sort of the layer's records by row, then column, gives), the padding
/// every PSF needs, and the layers' summaries. `edges` are the layers' parallax edges, far to
/// near ([`LayerEdges`]); `packed`, the images of `combined` kept packed, whose boxes count
/// for the reach and the padding.
///
/// Each layer is written once, into its place in the frame's list: copied where its records
/// are in row order already (a flat frame's pixels, row by row), else counted into its rows
/// and each row put in column order (stochastic samples, placed on four pixels each), with no
/// list of the layer's own in between: a stochastic frame's records run to hundreds of MB.
#[allow(clippy::too_many_arguments)]
pub(super) fn assemble_layers(
    chunks: &[Vec<Vec<SplatRecord>>],
    n_layers: usize,
    w: usize,
    h: usize,
    data: DataWindow,
    combined: Option<&PsfDatabase>,
    packed: Option<&PackedImages>,
    options: &ClassifyOptions,
    mut counts: PathCounts,
    edges: &[f32],
) -> Classified {
    // Beyond the data: records of the outermost pixels, repeated outwards (or nothing).
    let reach: Vec<i32> = combined.map_or_else(Vec::new, |db| frame_psf_reach(db, packed));
    let reach_of = |r: &SplatRecord| -> i32 {
        let of = |psf: u32| reach.get(psf as usize).copied().unwrap_or(0);
        if r.path == SplatPath::Copy as u32 {
            0
        } else if let Some((lo, hi, _, _)) = super::turned::pair_parts(r) {
            of(lo).max(of(hi))
        } else {
            of(r.psf_index)
        }
    };
    let frame = DataWindow::frame(w, h);
    // Overscan pixels whose PSF cannot reach the frame add nothing to the output.
    let kept = |r: &&SplatRecord| distance_to(frame, r.center_x, r.center_y) <= reach_of(r) as f32;
    let layer_pieces = |l: usize| chunks.iter().map(move |layers| layers[l].as_slice());
    let row_order = |r: &SplatRecord| (r.center_y, r.center_x);

    // Per layer, on every thread: its extension, and what placing it needs.
    #[derive(Default)]
    struct LayerPlan {
        extension: Vec<SplatRecord>,
        info: LayerInfo,
        /// Whether the kept records, then the extension, come in row order.
        in_row_order: bool,
        last: (i32, i32),
        rows: (i32, i32),
        beyond: i32,
    }
    let tally = |plan: &mut LayerPlan, r: &SplatRecord| {
        plan.info.record_count += 1;
        plan.info.count_paths(std::slice::from_ref(r));
        let key = row_order(r);
        plan.in_row_order &= key >= plan.last;
        plan.last = key;
        plan.rows = (plan.rows.0.min(r.center_y), plan.rows.1.max(r.center_y));
        let ox = (-r.center_x).max(r.center_x - (w as i32 - 1)).max(0);
        let oy = (-r.center_y).max(r.center_y - (h as i32 - 1)).max(0);
        plan.beyond = plan.beyond.max(ox.max(oy) + reach_of(r));
    };
    let on_border = |r: &SplatRecord| {
        r.center_x == data.x0
            || r.center_x == data.x1
            || r.center_y == data.y0
            || r.center_y == data.y1
    };
    let plans: Vec<LayerPlan> = (0..n_layers)
        .into_par_iter()
        .map(|l| {
            let mut plan = LayerPlan {
                in_row_order: true,
                last: (i32::MIN, i32::MIN),
                rows: (i32::MAX, i32::MIN),
                ..LayerPlan::default()
            };
            // One pass over the kept records; the border's are what the extension repeats.
            let mut border = Vec::new();
            for r in layer_pieces(l).flatten().filter(kept) {
                tally(&mut plan, r);
                if on_border(r) {
                    border.push(*r);
                }
            }
            let extension = if options.frame_edges == FrameEdges::Extend {
                extend_beyond(&border, data, frame, &reach_of)
            } else {
                Vec::new()
            };
            for r in &extension {
                tally(&mut plan, r);
            }
            LayerPlan { extension, ..plan }
        })
        .collect();
    counts.edge_extended += plans.iter().map(|p| p.extension.len()).sum::<usize>();
    // Padding: every PSF, wherever its centre lies, must fit inside the padded layer.
    let beyond = plans.iter().map(|p| p.beyond).max().unwrap_or(0);
    let pad = combined
        .map_or(0, |d| frame_extent_px(d, packed))
        .max(beyond.max(0) as u32)
        + options.pad_margin;
    let padded_width = w as u32 + 2 * pad;
    let padded_height = h as u32 + 2 * pad;
    let mut layers = Vec::with_capacity(n_layers);
    let mut first_record = 0;
    for (l, plan) in plans.iter().enumerate() {
        let info = LayerInfo {
            parallax_min: edges[l],
            parallax_max: edges[l + 1],
            first_record,
            ..plan.info
        };
        counts.add_layer(&info);
        layers.push(info);
        first_record += info.record_count;
    }
    // The layers' records one after another, shifted by the padding, each layer written on
    // its own thread into its own part of the frame's list.
    let mut records: Vec<SplatRecord> = bytemuck::zeroed_vec(first_record);
    let mut parts = Vec::with_capacity(n_layers);
    let mut rest = records.as_mut_slice();
    for (l, plan) in plans.iter().enumerate() {
        let (part, tail) = rest.split_at_mut(plan.info.record_count);
        parts.push((l, part, plan));
        rest = tail;
    }
    let shifted = |r: &SplatRecord| SplatRecord {
        center_x: r.center_x + pad as i32,
        center_y: r.center_y + pad as i32,
        ..*r
    };
    parts.into_par_iter().for_each(|(l, part, plan)| {
        let layer = || {
            let extension = plan.extension.iter().copied();
            layer_pieces(l)
                .flatten()
                .filter(kept)
                .copied()
                .chain(extension)
        };
        if plan.in_row_order {
            for (dst, r) in part.iter_mut().zip(layer()) {
                *dst = shifted(&r);
            }
            return;
        }
        // Counted into rows, in the layer's order (stable), then each row by column.
        let (y0, y1) = plan.rows;
        let mut starts = vec![0usize; (y1 - y0) as usize + 2];
        for r in layer() {
            starts[(r.center_y - y0) as usize + 1] += 1;
        }
        for i in 1..starts.len() {
            starts[i] += starts[i - 1];
        }
        let mut next = starts.clone();
        for r in layer() {
            let slot = &mut next[(r.center_y - y0) as usize];
            part[*slot] = shifted(&r);
            *slot += 1;
        }
        for row in starts.windows(2) {
            let row = &mut part[row[0]..row[1]];
            if !row.is_sorted_by_key(|r| r.center_x) {
                row.sort_by_key(|r| r.center_x);
            }
        }
    });
    let frame = FrameParams {
        width: w as u32,
        height: h as u32,
        pad,
        layers: n_layers as u32,
        padded_width,
        padded_height,
        record_count: records.len() as u32,
        db_channels: combined.map_or(1, |d| d.channels() as u32),
    };
    Classified {
        frame,
        records,
        layers,
        counts,
        database: None,
        packed: None,
        coarse: Vec::new(),
    }
}

/// The layers a fragment at layer coordinate `u` (0 at the far edge, `n_layers` at the near
/// edge) goes to, with their weights, and how many (1 or 2). With a soft band (layer units),
/// a fragment near the boundary between two layer centres is split between them.
/// For fragments from several sources (render layers, deep samples), the share of each
/// fragment's weight in each of its target layers that the nearer sources of its pixel let
/// through in that same layer: `prod (1 - coverage)` over the nearer sources, a source's
/// coverage in a layer being the sum of its fragments' alpha x weight x layer weight there
/// (capped at one). Fragments of one source (an edge split's two parts) do not occlude each
/// other: their weights already share the pixel. Across layers compositing does the
/// occluding. `None` when every fragment comes from one source (nothing to do).
pub(super) fn occlusion_within_layers(
    fragments: &[Fragment],
    n_layers: usize,
    targets_of: &(dyn Fn(&Fragment) -> LayerTargets + Sync),
) -> Option<Vec<[f32; 2]>> {
    let first_source = fragments.first()?.source;
    if fragments.par_iter().all(|f| f.source == first_source) {
        return None;
    }
    // Only pixels holding a fragment of another source than the first can have one occlude
    // another: on a flat frame those are the few along its silhouettes that the background
    // is continued behind, and sorting every fragment by pixel cost more than the rest of
    // the frame's classification. Each pass over every fragment runs on every thread: one
    // thread walking a 512 px frame's 13 MB of fragments three times was a serial tenth of
    // a moving frame's classification.
    let (x0, y0, x1, y1) = fragments.par_iter().map(|f| (f.x, f.y, f.x, f.y)).reduce(
        || (i32::MAX, i32::MAX, i32::MIN, i32::MIN),
        |a, b| (a.0.min(b.0), a.1.min(b.1), a.2.max(b.2), a.3.max(b.3)),
    );
    let width = (i64::from(x1) - i64::from(x0) + 1) as usize;
    let height = (i64::from(y1) - i64::from(y0) + 1) as usize;
    let cells = width.saturating_mul(height);
    let mut order: Vec<u32> = if cells <= 4 * fragments.len() + (1 << 20) {
        let cell = |f: &Fragment| (f.y - y0) as usize * width + (f.x - x0) as usize;
        let others: Vec<usize> = fragments
            .par_iter()
            .filter(|f| f.source != first_source)
            .map(cell)
            .collect();
        let mut mixed = vec![false; cells];
        for c in others {
            mixed[c] = true;
        }
        (0..fragments.len() as u32)
            .into_par_iter()
            .filter(|&i| mixed[cell(&fragments[i as usize])])
            .collect()
    } else {
        // Fragments scattered far beyond any frame: every one, rather than a map that large.
        (0..fragments.len() as u32).collect()
    };
    // Those pixels' fragments by pixel, each pixel's in input order (a stable sort).
    let key = |i: u32| (fragments[i as usize].y, fragments[i as usize].x);
    order.par_sort_by_key(|&i| key(i));
    // Each pixel on its own: pixels in parallel, each thread's shares listed, then written.
    let shares: Vec<(u32, usize, f32)> = order
        .par_chunk_by(|&a, &b| key(a) == key(b))
        .fold(
            || (Vec::new(), PixelScratch::new(n_layers)),
            |(mut out, mut scratch), pixel| {
                occlusion_in_pixel(fragments, pixel, targets_of, &mut scratch, &mut out);
                (out, scratch)
            },
        )
        .map(|(out, _)| out)
        .reduce(Vec::new, |mut a, b| {
            a.extend(b);
            a
        });
    let mut kept = vec![[1.0f32; 2]; fragments.len()];
    for (i, t, share) in shares {
        kept[i as usize][t] = share;
    }
    Some(kept)
}

/// One thread's scratch for [`occlusion_in_pixel`].
struct PixelScratch {
    through: Vec<f32>,
    coverage: Vec<f32>,
    touched: Vec<usize>,
    /// (nearest depth of the fragment's source in this pixel, source, fragment)
    entries: Vec<(f32, u32, u32)>,
}

impl PixelScratch {
    fn new(n_layers: usize) -> Self {
        Self {
            through: vec![1.0; n_layers],
            coverage: vec![0.0; n_layers],
            touched: Vec::new(),
            entries: Vec::new(),
        }
    }
}

/// The shares of one pixel's fragments (`pixel`, indices into `fragments`, in input order)
/// that the nearer sources there let through in each of their target layers, appended to
/// `out` as (fragment, target, share); nothing where the pixel holds one source.
fn occlusion_in_pixel(
    fragments: &[Fragment],
    pixel: &[u32],
    targets_of: &(dyn Fn(&Fragment) -> LayerTargets + Sync),
    scratch: &mut PixelScratch,
    out: &mut Vec<(u32, usize, f32)>,
) {
    let source_of = |i: u32| fragments[i as usize].source;
    if pixel.iter().all(|&i| source_of(i) == source_of(pixel[0])) {
        return;
    }
    let PixelScratch {
        through,
        coverage,
        touched,
        entries,
    } = scratch;
    entries.clear();
    entries.extend(
        pixel
            .iter()
            .map(|&i| (fragments[i as usize].depth, source_of(i), i)),
    );
    entries.sort_by_key(|e| (e.1, e.2));
    for run in entries.chunk_by_mut(|a, b| a.1 == b.1) {
        let nearest = run.iter().map(|e| e.0).fold(f32::INFINITY, f32::min);
        run.iter_mut().for_each(|e| e.0 = nearest);
    }
    entries.sort_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))));
    through.iter_mut().for_each(|t| *t = 1.0);
    for run in entries.chunk_by(|a, b| a.1 == b.1) {
        for &(_, _, i) in run {
            let frag = &fragments[i as usize];
            let (targets, n) = targets_of(frag);
            // A veil is never drawn: its alpha is what it hides.
            let alpha = if frag.source == super::hidden::VEIL_SOURCE {
                frag.color[3].clamp(0.0, 1.0)
            } else {
                frag.color[3].clamp(0.0, 1.0) * frag.weight.max(0.0)
            };
            for (t, &(layer, lw)) in targets[..n].iter().enumerate() {
                out.push((i, t, through[layer]));
                coverage[layer] += alpha * lw;
                touched.push(layer);
            }
        }
        for layer in touched.drain(..) {
            through[layer] *= 1.0 - coverage[layer].min(1.0);
            coverage[layer] = 0.0;
        }
    }
}

/// The parallax edges of the depth layers, far to near: `n + 1` of them, the first and last
/// the frame's parallax range.
///
/// Where several sources share pixels (render layers; a flat frame's surfaces over the
/// background continued behind them), each inner edge moves, within half a layer of its even
/// place, to where the fewest blurred fragments that cover another source lie: the edge crosses
/// such a surface at the cost of a seam. Its two parts are each smeared or defocused with a
/// soft edge where the layer edge cut them, and "over" of the two lets what lies behind show
/// through along the cut (a ball passing in a camera pan, hard-layered in its own view layer
/// and split across its middle, showed the road through its lower half). Where the range
/// allows, the edge passes the surface by. Without such fragments the edges are evenly spaced.
pub(super) struct LayerEdges {
    /// The parallax of each edge, far to near.
    pub(super) edges: Vec<f32>,
    /// Whether the edges are evenly spaced (the layer coordinate is then one expression).
    even: bool,
    pmin: f32,
    span: f32,
}

/// Cells of the parallax histogram per layer, where [`LayerEdges`] looks for a place to cut.
const EDGE_CELLS_PER_LAYER: usize = 32;

/// The least blur (CoC radius plus half the motion, pixels) of a fragment that an edge of the
/// layers avoids crossing: a sharper surface's two parts barely spread over each other.
const EDGE_AVOIDS_BLUR_PX: f32 = 1.0;

impl LayerEdges {
    /// The edges of `n` layers over `(pmin, span)` for `fragments`; `blur_of` gives a
    /// fragment's blur in pixels.
    pub(super) fn new(
        (pmin, span): (f32, f32),
        n: usize,
        fragments: &[Fragment],
        blur_of: &dyn Fn(&Fragment) -> f32,
    ) -> Self {
        let even_edges: Vec<f32> = (0..=n).map(|l| pmin + span * l as f32 / n as f32).collect();
        let mut edges = LayerEdges {
            edges: even_edges,
            even: true,
            pmin,
            span,
        };
        if n < 2 || span <= 0.0 {
            return edges;
        }
        let Some(sources) = Ceilings::nearest_sources(fragments) else {
            return edges;
        };
        let cells = n * EDGE_CELLS_PER_LAYER;
        let mut mass = vec![0.0f64; cells];
        for f in fragments {
            if f.weight > 0.0 && sources.covers_another(f) && blur_of(f) >= EDGE_AVOIDS_BLUR_PX {
                let u = (f.parallax - pmin) / span * cells as f32;
                if u.is_finite() {
                    mass[(u.max(0.0) as usize).min(cells - 1)] += f64::from(f.weight);
                }
            }
        }
        // Edge `i` may sit on any cell boundary `c` within half a layer of its even place
        // (`i * EDGE_CELLS_PER_LAYER`); crossing there costs the mass of the two cells beside
        // it. The cheapest wins, the nearest to the even place among equals.
        let half = EDGE_CELLS_PER_LAYER / 2;
        for i in 1..n {
            let even = i * EDGE_CELLS_PER_LAYER;
            let cost = |c: usize| mass[c - 1] + mass[c];
            let mut best = (cost(even), 0usize, even);
            for c in (even + 1 - half)..(even + half) {
                let candidate = (cost(c), c.abs_diff(even), c);
                if (candidate.0, candidate.1) < (best.0, best.1) {
                    best = candidate;
                }
            }
            if best.2 != even {
                edges.edges[i] = pmin + span * best.2 as f32 / cells as f32;
                edges.even = false;
            }
        }
        edges
    }

    /// The layer coordinate of parallax `p`: 0 at the far edge, `n` at the near edge, linear
    /// within each layer.
    pub(super) fn coord(&self, p: f32) -> f32 {
        let n = self.edges.len() - 1;
        if self.span <= 0.0 {
            return 0.0;
        }
        if self.even {
            return ((p - self.pmin) / self.span * n as f32).clamp(0.0, n as f32);
        }
        // NaN as the far edge.
        if p.is_nan() || p <= self.edges[0] {
            return 0.0;
        }
        if p >= self.edges[n] {
            return n as f32;
        }
        // The layer whose edges enclose `p`: the last edge at or below it.
        let l = self
            .edges
            .partition_point(|&e| e <= p)
            .saturating_sub(1)
            .min(n - 1);
        let (a, b) = (self.edges[l], self.edges[l + 1]);
        l as f32 + if b > a { (p - a) / (b - a) } else { 0.0 }
    }
}

/// Per pixel holding fragments of several sources (a render layer over another, a deep
/// image's samples, the background continued behind an occluder), its nearest source and
/// that source's farthest depth layer there: the farther sources' fragments of the pixel go
/// into the layers behind it ([`Ceilings::lower`]).
///
/// Within a layer splats add and compositing divides by coverage, so a farther surface sharing
/// the nearer one's layer is mixed into it; hiding it there instead (the nearer surface's
/// coverage at the pixel is 1) lost what a moving or defocused surface's edge reveals: a car's
/// forward smear stopped in a hard edge where the road beside its wheels shares the car's
/// layer. In a farther layer, compositing lays the nearer surface's ramp over it as it does
/// for any background.
pub(super) struct Ceilings {
    origin: (i32, i32),
    width: usize,
    /// Per cell: the depth and source of its nearest fragment (infinite depth: none).
    nearest: Vec<(f32, u32)>,
    /// Per cell: the farthest layer of its nearest source (`u8::MAX`: none).
    ceiling: Vec<u8>,
    /// Per cell: whether a fragment of another source than the nearest lies there.
    mixed: Vec<bool>,
}

impl Ceilings {
    /// `None` when every fragment comes from one source, or the fragments of the other
    /// sources spread over a box too large to map. Veils ([`super::hidden::VEIL_SOURCE`]) and
    /// fragments of no weight neither set nor take a ceiling.
    pub(super) fn new(
        fragments: &[Fragment],
        targets_of: &dyn Fn(&Fragment) -> LayerTargets,
    ) -> Option<Self> {
        let mut ceilings = Self::nearest_sources(fragments)?;
        ceilings.lay(fragments, targets_of);
        Some(ceilings)
    }

    /// Each pixel's nearest source and whether another lies behind it, without the ceilings
    /// ([`Ceilings::covers_another`] answers, [`Ceilings::lower`] keeps every target).
    pub(super) fn nearest_sources(fragments: &[Fragment]) -> Option<Self> {
        let counts = |f: &Fragment| f.weight > 0.0 && f.source != super::hidden::VEIL_SOURCE;
        let first_source = fragments.iter().find(|f| counts(f))?.source;
        // Only a pixel holding a fragment of another source than the first has two.
        let (x0, y0, x1, y1) = fragments
            .iter()
            .filter(|f| counts(f) && f.source != first_source)
            .fold(
                (i32::MAX, i32::MAX, i32::MIN, i32::MIN),
                |(x0, y0, x1, y1), f| (x0.min(f.x), y0.min(f.y), x1.max(f.x), y1.max(f.y)),
            );
        if x1 < x0 {
            return None;
        }
        let width = (i64::from(x1) - i64::from(x0) + 1) as usize;
        let height = (i64::from(y1) - i64::from(y0) + 1) as usize;
        let cells = width.checked_mul(height)?;
        if cells > 4 * fragments.len() + (1 << 20) {
            return None;
        }
        let mut ceilings = Ceilings {
            origin: (x0, y0),
            width,
            nearest: vec![(f32::INFINITY, 0); cells],
            ceiling: vec![u8::MAX; cells],
            mixed: vec![false; cells],
        };
        for f in fragments.iter().filter(|f| counts(f)) {
            if let Some(cell) = ceilings.cell(f) {
                let nearest = &mut ceilings.nearest[cell];
                if f.depth < nearest.0 {
                    *nearest = (f.depth, f.source);
                }
            }
        }
        for f in fragments.iter().filter(|f| counts(f)) {
            if let Some(cell) = ceilings.cell(f) {
                if f.source != ceilings.nearest[cell].1 {
                    ceilings.mixed[cell] = true;
                }
            }
        }
        Some(ceilings)
    }

    /// Sets each mixed pixel's ceiling: the farthest of `targets_of` its nearest source's
    /// fragments there.
    fn lay(&mut self, fragments: &[Fragment], targets_of: &dyn Fn(&Fragment) -> LayerTargets) {
        let counts = |f: &Fragment| f.weight > 0.0 && f.source != super::hidden::VEIL_SOURCE;
        let ceilings = self;
        // Only the pixels holding two sources need their nearest source's layers: on a flat
        // frame the few along its silhouettes.
        for f in fragments.iter().filter(|f| counts(f)) {
            let Some(cell) = ceilings.cell(f) else {
                continue;
            };
            if ceilings.mixed[cell] && f.source == ceilings.nearest[cell].1 {
                let (targets, n) = targets_of(f);
                let farthest = targets[..n].iter().map(|t| t.0).min().unwrap_or(0);
                let farthest = farthest.min(usize::from(u8::MAX - 1)) as u8;
                ceilings.ceiling[cell] = ceilings.ceiling[cell].min(farthest);
            }
        }
    }

    /// Whether `f` belongs to its pixel's nearest source and another source lies behind it
    /// there.
    pub(super) fn covers_another(&self, f: &Fragment) -> bool {
        self.cell(f)
            .is_some_and(|cell| self.mixed[cell] && self.nearest[cell].1 == f.source)
    }

    fn cell(&self, f: &Fragment) -> Option<usize> {
        let x = usize::try_from(i64::from(f.x) - i64::from(self.origin.0)).ok()?;
        let y = usize::try_from(i64::from(f.y) - i64::from(self.origin.1)).ok()?;
        (x < self.width && y * self.width + x < self.ceiling.len()).then_some(y * self.width + x)
    }

    /// `targets` of `f`, moved behind the farthest layer of its pixel's nearest source when
    /// `f` comes from another source and lies behind it. Where that is the farthest layer,
    /// they stay (and `occlusion_within_layers` hides `f` under the nearer coverage there).
    pub(super) fn lower(&self, f: &Fragment, targets: LayerTargets) -> LayerTargets {
        let Some(cell) = self.cell(f) else {
            return targets;
        };
        let (depth, source) = self.nearest[cell];
        let ceiling = self.ceiling[cell];
        if f.source == source || f.depth <= depth || ceiling == u8::MAX || ceiling == 0 {
            return targets;
        }
        let below = usize::from(ceiling) - 1;
        let (mut layers, n) = targets;
        if layers[..n].iter().all(|t| t.0 <= below) {
            return targets;
        }
        for t in &mut layers[..n] {
            t.0 = t.0.min(below);
        }
        if n == 2 && layers[0].0 == layers[1].0 {
            layers[0].1 += layers[1].1;
            layers[1] = (0, 0.0);
            return (layers, 1);
        }
        (layers, n)
    }
}

/// A fragment's depth layers and its weight in each: one or two (soft layers) of the pair.
pub(super) type LayerTargets = ([(usize, f32); 2], usize);

pub(super) fn layer_targets(u: f32, n_layers: usize, band: Option<f32>) -> LayerTargets {
    let mut targets = [(0usize, 0.0f32); 2];
    match band {
        Some(band) if band > 0.0 && n_layers > 1 => {
            let t = (u - 0.5).clamp(0.0, (n_layers - 1) as f32);
            let a = (t.floor() as usize).min(n_layers - 2);
            let f = t - a as f32;
            let near = ((f - 0.5) / band + 0.5).clamp(0.0, 1.0);
            if near <= 0.0 {
                targets[0] = (a, 1.0);
                (targets, 1)
            } else if near >= 1.0 {
                targets[0] = (a + 1, 1.0);
                (targets, 1)
            } else {
                ([(a, 1.0 - near), (a + 1, near)], 2)
            }
        }
        _ => {
            targets[0] = ((u.floor() as usize).min(n_layers - 1), 1.0);
            (targets, 1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distinct keys are counted across runs, however they repeat: the bar's own count is not
    /// many, one more is, and fine-angled keys never count.
    #[test]
    fn many_keys_counts_distinct_keys_beyond_the_bar() {
        let key = |i: usize, angle_resolution| SmearKey {
            cell: 0,
            length_step: (i % 97) as u32,
            angle_step: (i / 97) as u32,
            turn_step: 0,
            turn_steps: 8,
            angle_resolution,
            bend_step: 0,
        };
        // Every distinct key in runs of two, the whole set twice over.
        let keys_of = |n: usize, resolution| -> Vec<Option<(SmearKey, bool)>> {
            (0..2 * n)
                .flat_map(|i| [Some((key(i % n, resolution), false)); 2])
                .chain([None])
                .collect()
        };
        let rounded = AngleResolution::Rounded;
        assert!(!many_keys(&keys_of(MANY_SMEAR_KEYS, rounded)));
        assert!(many_keys(&keys_of(MANY_SMEAR_KEYS + 1, rounded)));
        assert!(!many_keys(&keys_of(
            MANY_SMEAR_KEYS + 1,
            AngleResolution::Fine
        )));
        assert!(!many_keys(&vec![
            Some((key(3, rounded), true));
            3 * MANY_SMEAR_KEYS
        ]));
    }

    fn record(x: i32, psf: u32, rot: f32, color: f32) -> SplatRecord {
        SplatRecord {
            center_x: x,
            center_y: 3,
            psf_index: psf,
            rot_cos: rot.cos(),
            rot_sin: rot.sin(),
            weight: color,
            path: SplatPath::Dense as u32,
            color: [color, 2.0 * color, 0.5, 1.0],
            ..SplatRecord::default()
        }
    }

    /// Records of one pixel that follow each other and draw alike are summed in order into the
    /// first; another PSF, turn or path, another pixel, or the same pixel after another one,
    /// stays a record of its own, in the order the records came.
    #[test]
    fn a_pixels_run_of_alike_records_is_merged_into_its_first() {
        let mut sparse = record(0, 7, 0.0, 0.25);
        sparse.path = SplatPath::Sparse as u32;
        let records = [
            record(0, 7, 0.0, 0.5),
            record(0, 8, 0.0, 0.25),
            record(0, 7, 0.0, 0.125),
            sparse,
            record(0, 7, 0.5, 1.0),
            record(1, 7, 0.0, 2.0),
            record(1, 8, 0.0, 4.0),
            record(1, 7, 0.0, 8.0),
            record(0, 7, 0.0, 16.0),
        ];
        let merged = merged_in_pixel_runs(&records);
        let expected = [
            SplatRecord {
                weight: 0.625,
                color: [0.625, 1.25, 1.0, 2.0],
                ..records[0]
            },
            records[1],
            records[3],
            records[4],
            SplatRecord {
                weight: 10.0,
                color: [10.0, 20.0, 1.0, 2.0],
                ..records[5]
            },
            records[6],
            records[8],
        ];
        assert_eq!(merged, expected);
        assert!(merged_in_pixel_runs(&[]).is_empty());
    }
}
