//! Fragments: what classification splats, one per G-buffer pixel (or two, edge split), per
//! render layer's pixel or per deep sample, with the checks of the passes they come from.

use super::edge_split::edge_split;
use super::hidden::hidden_background;
use super::*;
use crate::camera::Camera;
use crate::gbuffer::GBuffer;
use psf_db::PsfModel;
use rayon::prelude::*;

/// One part of a pixel (or one stochastic sample) before layering: where its PSF is centred,
/// its colour, weight, parallax, depth and motion. Synthesis makes one or two per G-buffer
/// pixel (edge split); reconstruction one per stochastic sample.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Fragment {
    /// Pixel (unpadded, x right) on which the PSF is centred.
    pub x: i32,
    /// Pixel (unpadded, y down) on which the PSF is centred.
    pub y: i32,
    /// Premultiplied linear RGBA, before `weight`.
    pub color: [f32; 4],
    /// Share of `color` this fragment carries (edge split, samples of one pixel).
    pub weight: f32,
    /// Parallax, 1/depth (per scene unit); 0 for infinitely far.
    pub parallax: f32,
    /// Planar depth, scene units.
    pub depth: f32,
    /// Motion over the shutter, pixels (x right, y down).
    pub motion: [f32; 2],
    /// How far its path over the shutter bends away from the straight line, px: the part of
    /// the path's acceleration over the shutter (the pixel's own, `GBuffer::acceleration`, else
    /// `(m . grad) m` from the motion field) along `n`, the motion's direction turned a quarter
    /// turn clockwise on screen (`(-m_y, m_x) / |m|`, y down). The path's ends lie `bend / 8` px off the line; a point turning about a
    /// centre bends towards it. 0 for a straight path.
    pub bend: f32,
    /// Which input surface of its pixel it comes from: the render layer, or the deep sample's
    /// index; 0 for a single input. Where fragments of one pixel from different sources fall
    /// into the same depth layer, the nearer ones occlude the farther ("over" within the
    /// layer), as compositing them would.
    pub source: u32,
}

/// Depth at or beyond which a pixel's depth is the miss value (Blender writes 1e10).
pub(super) const MISS_DEPTH: f32 = 1e9;

/// `gbuffer` with its partly covered pixels that carry the miss depth given the depth and
/// motion of the nearest covered pixel (within 3 pixels, the most covered at equal distance);
/// `None` when there are none.
pub(super) fn with_edge_depths(gbuffer: &GBuffer) -> Option<GBuffer> {
    let depth = gbuffer.depth.as_ref()?;
    let w = gbuffer.width;
    let covered = |j: usize| depth[j] < MISS_DEPTH && gbuffer.color[j][3] > 0.0;
    let repairs: Vec<(usize, usize)> = (0..w * gbuffer.height)
        .filter(|&i| gbuffer.color[i][3] > 0.0 && depth[i] >= MISS_DEPTH)
        .filter_map(|i| nearest_covered(gbuffer, i, &covered).map(|j| (i, j)))
        .collect();
    if repairs.is_empty() {
        return None;
    }
    // A source pixel is covered, so never repaired itself: reading it from `out` is safe.
    let mut out = gbuffer.clone();
    for (i, j) in repairs {
        if let Some(d) = out.depth.as_mut() {
            d[i] = d[j];
        }
        if let Some(m) = out.motion.as_mut() {
            m[i] = m[j];
        }
        if let Some(a) = out.acceleration.as_mut() {
            a[i] = a[j];
        }
    }
    Some(out)
}

/// The covered pixel nearest to pixel `i` within 3 pixels (the most covered at equal
/// distance, the first in row order at equal coverage).
pub(super) fn nearest_covered(
    gbuffer: &GBuffer,
    i: usize,
    covered: &dyn Fn(usize) -> bool,
) -> Option<usize> {
    const REACH: i64 = 3;
    let (w, h) = (gbuffer.width as i64, gbuffer.height as i64);
    let (x, y) = (i as i64 % w, i as i64 / w);
    let mut best: Option<(i64, f32, usize)> = None;
    for ny in (y - REACH).max(0)..=(y + REACH).min(h - 1) {
        for nx in (x - REACH).max(0)..=(x + REACH).min(w - 1) {
            let j = (ny * w + nx) as usize;
            if !covered(j) {
                continue;
            }
            let d2 = (nx - x).pow(2) + (ny - y).pow(2);
            let a = gbuffer.color[j][3];
            if best.is_none_or(|(bd, ba, _)| d2 < bd || (d2 == bd && a > ba)) {
                best = Some((d2, a, j));
            }
        }
    }
    best.map(|(_, _, j)| j)
}

/// The data window of `gbuffer` in frame coordinates.
pub(super) fn data_window(gbuffer: &GBuffer) -> DataWindow {
    let (w, h, overscan) = (gbuffer.width, gbuffer.height, gbuffer.overscan);
    DataWindow {
        x0: -(overscan.left as i32),
        y0: -(overscan.top as i32),
        x1: (w - overscan.left) as i32 - 1,
        y1: (h - overscan.top) as i32 - 1,
    }
}

/// The passes the camera needs: depth for depth of field, motion vectors for an open shutter
/// (unless the layer is declared `still`). `layer` names the layer in the message.
pub(super) fn check_passes(
    gbuffer: &GBuffer,
    camera: &Camera,
    layer: Option<&str>,
    still: bool,
) -> Result<(), ClassifyError> {
    let present = || {
        let channels = gbuffer.channels_present.join(", ");
        match layer {
            Some(l) => format!("{channels}; view layer {l:?}"),
            None => channels,
        }
    };
    if camera.has_lens() && gbuffer.depth.is_none() {
        return Err(ClassifyError::MissingPass {
            effect: "depth of field",
            pass: "depth",
            present: present(),
        });
    }
    if camera.has_shutter() && gbuffer.motion.is_none() && !still {
        return Err(ClassifyError::MissingPass {
            effect: "motion blur (shutter_frames > 0)",
            pass: "motion vector",
            present: present(),
        });
    }
    Ok(())
}

/// The fragments of every pixel of `gbuffer` (up to two per pixel with `edge_split`), and
/// the background continued behind sharper occluders ([`ClassifyOptions::fill_hidden`]).
/// With `render_layer` (one render layer of several, with transparency), veils over what the
/// other layers hold beside its surfaces' blurred silhouettes.
#[allow(clippy::too_many_arguments)]
pub(super) fn pixel_fragments(
    gbuffer: &GBuffer,
    camera: &Camera,
    effects: Effects,
    model: Option<PsfModel>,
    options: &ClassifyOptions,
    split_edges: bool,
    render_layer: bool,
    counts: &mut PathCounts,
) -> Vec<Fragment> {
    let (w, h) = (gbuffer.width, gbuffer.height);
    let overscan = gbuffer.overscan;
    let lens = camera.thin_lens();
    let shutter = camera.shutter_frames as f32;
    // Parallax of every pixel and the range over pixels that carry something.
    let depth_at = |i: usize| gbuffer.depth.as_ref().map_or(f32::INFINITY, |d| d[i]);
    let parallax_of = |d: f32| if d.is_finite() { 1.0 / d } else { 0.0 };
    let motion_at = |i: usize| -> [f32; 2] {
        match (&gbuffer.motion, effects.motion) {
            (Some(m), true) => [m[i][0] * shutter, m[i][1] * shutter],
            _ => [0.0, 0.0],
        }
    };
    let signed_coc = |d: f32| -> f32 { lens.map_or(0.0, |l| l.signed_coc_px(f64::from(d)) as f32) };
    // Every pixel's signed CoC, once: the edge split and the hidden background ask for a
    // pixel's and its neighbours' a dozen times per pixel.
    let cocs: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|i| signed_coc(depth_at(i)))
        .collect();
    let coc_at = |i: usize| cocs[i];
    // Every pixel's path bend, where anything moves: found in the frame's units (px per
    // frame); over the shutter it scales with the shutter's square (an acceleration's time
    // unit, squared).
    let bends: Vec<f32> = match (&gbuffer.motion, effects.motion) {
        (Some(m), true) => {
            let mut bends = match &gbuffer.acceleration {
                Some(a) => super::bend::bends_from_acceleration(m, a),
                None => super::bend::path_bends(w, h, m, gbuffer.depth.as_deref(), &gbuffer.color),
            };
            bends.iter_mut().for_each(|b| *b *= shutter * shutter);
            bends
        }
        _ => Vec::new(),
    };
    let bend_at = |i: usize| bends.get(i).copied().unwrap_or(0.0);
    let bright_near = if split_edges && model.is_some() {
        super::edge_split::bright_near(gbuffer, options.hdr_dense_threshold)
    } else {
        Vec::new()
    };

    // Fragments per pixel (up to two: edge split), a row per task, the rows joined in order:
    // the same fragments in the same order as one pass.
    let rows: Vec<(Vec<Fragment>, Vec<SplitPixel>)> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut fragments: Vec<Fragment> = Vec::with_capacity(w);
            let mut split_pixels = Vec::new();
            for x in 0..w {
                let i = y * w + x;
                let c = gbuffer.color[i];
                if c == [0.0; 4] {
                    continue;
                }
                let d = depth_at(i);
                let own = Fragment {
                    x: x as i32 - overscan.left as i32,
                    y: y as i32 - overscan.top as i32,
                    color: c,
                    weight: 1.0,
                    parallax: parallax_of(d),
                    depth: d,
                    motion: motion_at(i),
                    bend: bend_at(i),
                    source: 0,
                };
                let split = if split_edges && model.is_some() {
                    edge_split(
                        gbuffer,
                        x,
                        y,
                        &coc_at,
                        &depth_at,
                        &motion_at,
                        options.hdr_dense_threshold,
                        &bright_near,
                    )
                } else {
                    None
                };
                match split {
                    Some(split) => {
                        split_pixels.push((i, split.alpha));
                        let (j, o) = (split.foreground, split.background);
                        let dj = depth_at(j);
                        fragments.push(Fragment {
                            color: split.foreground_color,
                            weight: split.alpha,
                            parallax: parallax_of(dj),
                            depth: dj,
                            motion: motion_at(j),
                            bend: bend_at(j),
                            ..own
                        });
                        if split.alpha < 1.0 {
                            // The background part keeps this pixel's depth (the depth pass is not
                            // anti-aliased) but not its motion, which the vector pass blends.
                            fragments.push(Fragment {
                                color: split.background_color,
                                weight: 1.0 - split.alpha,
                                motion: motion_at(o),
                                bend: bend_at(o),
                                ..own
                            });
                        }
                    }
                    None => fragments.push(own),
                }
            }
            (fragments, split_pixels)
        })
        .collect();
    let mut was_split = vec![false; w * h];
    // The share of each split pixel its foreground covers: the background hidden there.
    let mut split_hidden = vec![0.0f32; w * h];
    for (_, split_pixels) in &rows {
        counts.edge_split += split_pixels.len();
        for &(i, alpha) in split_pixels {
            was_split[i] = true;
            split_hidden[i] = alpha;
        }
    }

    let filled = if options.fill_hidden && model.is_some() {
        // Along an axis direction: the CoC radius plus half the motion over the shutter
        // projected on it (the streak is centred on the pixel).
        let blur_along = |i: usize, d: (i32, i32)| -> f32 {
            let m = motion_at(i);
            coc_at(i).abs() + 0.5 * (m[0] * d.0 as f32 + m[1] * d.1 as f32).abs()
        };
        let own = |i: usize| Fragment {
            x: (i % w) as i32 - overscan.left as i32,
            y: (i / w) as i32 - overscan.top as i32,
            color: gbuffer.color[i],
            weight: 1.0,
            parallax: parallax_of(depth_at(i)),
            depth: depth_at(i),
            motion: motion_at(i),
            bend: bend_at(i),
            source: super::hidden::HIDDEN_SOURCE,
        };
        let mut filled = hidden_background(
            gbuffer,
            &was_split,
            &split_hidden,
            &coc_at,
            &depth_at,
            &motion_at,
            &blur_along,
            options.hdr_dense_threshold,
            &own,
        );
        // A render layer with transparency: what the other layers hold beside its surface is
        // veiled where the surface's blur covers it.
        if render_layer {
            filled.extend(super::hidden::render_layer_veils(
                gbuffer,
                &coc_at,
                &blur_along,
                &own,
            ));
        }
        // Behind a split pixel the continued background is its hidden share, beside the
        // pixel's own background part rather than behind it: that part must not hide it.
        for f in filled
            .iter_mut()
            .filter(|f| f.source == super::hidden::HIDDEN_SOURCE)
        {
            let (x, y) = (f.x + overscan.left as i32, f.y + overscan.top as i32);
            let split = x >= 0
                && y >= 0
                && (x as usize) < w
                && was_split.get(y as usize * w + x as usize) == Some(&true);
            if split {
                f.source = 0;
            }
        }
        counts.hidden_filled += filled
            .iter()
            .filter(|f| f.source != super::hidden::VEIL_SOURCE)
            .count();
        filled
    } else {
        Vec::new()
    };
    let pieces: Vec<&[Fragment]> = rows
        .iter()
        .map(|(row, _)| row.as_slice())
        .chain(std::iter::once(filled.as_slice()))
        .collect();
    joined_with_room(&pieces)
}

/// An edge-split pixel: its index and the share of it its foreground covers.
type SplitPixel = (usize, f32);

/// `pieces` joined in order, copied on every thread, in a list with room for a quarter more
/// (the continuations across depth layers) that is not touched until it is used: the fragments
/// of a 512 px frame are 13 MB, and memory touched first by one thread is faulted in by one.
fn joined_with_room(pieces: &[&[Fragment]]) -> Vec<Fragment> {
    let total: usize = pieces.iter().map(|p| p.len()).sum();
    // Zeroed by the allocator: fresh pages stay unmapped until written.
    let mut joined: Vec<Fragment> = bytemuck::zeroed_vec(total + total / 4);
    joined.truncate(total);
    let mut rest = joined.as_mut_slice();
    let mut places = Vec::with_capacity(pieces.len());
    for piece in pieces {
        let (place, tail) = std::mem::take(&mut rest).split_at_mut(piece.len());
        places.push(place);
        rest = tail;
    }
    places
        .into_par_iter()
        .zip(pieces.par_iter())
        .for_each(|(place, piece)| place.copy_from_slice(piece));
    joined
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pieces come out in order, each fragment as it was, with room for a quarter more.
    #[test]
    fn pieces_are_joined_in_order_with_room() {
        let at = |x: i32| Fragment {
            x,
            y: -x,
            color: [x as f32, 0.5, 0.25, 1.0],
            weight: 0.5,
            parallax: 0.1,
            depth: 10.0,
            motion: [1.0, -2.0],
            bend: 0.5,
            source: x as u32,
        };
        let pieces: Vec<Vec<Fragment>> = vec![
            (0..5).map(at).collect(),
            Vec::new(),
            (5..6).map(at).collect(),
            (6..40).map(at).collect(),
        ];
        let slices: Vec<&[Fragment]> = pieces.iter().map(Vec::as_slice).collect();
        let joined = joined_with_room(&slices);
        assert_eq!(joined, (0..40).map(at).collect::<Vec<_>>());
        assert!(joined.capacity() >= 50, "{}", joined.capacity());
    }
}
