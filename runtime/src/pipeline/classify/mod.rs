//! Stage 1, classification: every G-buffer pixel becomes one or more [`SplatRecord`]s (PSF
//! index, layer, rotation, weighted colour, drawing path), sorted by layer then pixel order.
//!
//! Per pixel: the signed thin-lens CoC from depth (pixels), the motion over the shutter
//! (pixels), the database PSF nearest to them (O(1) through the nested grid), the rotation of
//! the PSF's reference direction (+x) onto the motion (lens-motion) or onto the radial direction
//! (physical lens), and the path: copied when the PSF lies under a pixel, drawn dense when the
//! database stores that PSF dense (fast track), else splatted sparse.
//!
//! Layers are global and binned uniformly in parallax `1/depth` (the signed CoC is affine in
//! it: constant parallax units), layer 0 the farthest. With soft layering a pixel near a layer
//! boundary is split into two records whose weights sum to one.
//!
//! Anti-aliased edge pixels of a near object carry the depth of the background behind it (the
//! depth pass is not anti-aliased). With `edge_split`, a pixel that has a markedly nearer
//! neighbour is split into a foreground part (the neighbour's depth and motion) and a
//! background part (its own), the foreground fraction estimated by projecting its colour onto
//! the segment between the foreground neighbour's colour and the background colour opposite.

mod deep;
mod edge_split;
mod frame_edges;
mod hidden;

use psf_db::{PsfDatabase, PsfModel};

pub use deep::{check_deep_size, classify_deep, deep_effects, deep_fragments};
use edge_split::edge_split;
use frame_edges::{distance_to, extend_beyond};
pub use frame_edges::{DataWindow, FrameEdges};
use hidden::hidden_background;

use super::splat::psf_reach;
use super::types::{FrameParams, SplatPath, SplatRecord};
use crate::camera::Camera;
use crate::dbset::{DbSet, NO_TWIN};
use crate::gbuffer::{GBuffer, ViewLayer};

/// Errors of classification.
#[derive(Debug, thiserror::Error)]
pub enum ClassifyError {
    /// The camera and the G-buffer disagree about the image size.
    #[error("the camera says {cam_w}x{cam_h} pixels but the G-buffer is {img_w}x{img_h}")]
    SizeMismatch {
        /// Camera width.
        cam_w: u32,
        /// Camera height.
        cam_h: u32,
        /// Image width.
        img_w: usize,
        /// Image height.
        img_h: usize,
    },
    /// The camera needs a pass the G-buffer does not have.
    #[error("{effect} needs the {pass} pass, which the input does not have (channels: {present})")]
    MissingPass {
        /// What needs it.
        effect: &'static str,
        /// Which pass.
        pass: &'static str,
        /// Channels in the file.
        present: String,
    },
    /// The effects need a database and none was given.
    #[error("the {0} model is needed but no database of it was given")]
    NoDatabase(&'static str),
    /// The database is of another model than the one the effects need.
    #[error("database model mismatch: the scene needs {needed}, the database is {found}")]
    WrongModel {
        /// What the effects need.
        needed: &'static str,
        /// What was given.
        found: &'static str,
    },
    /// Zero layers requested.
    #[error("--layers must be at least 1")]
    NoLayers,
    /// A layered input with no layer.
    #[error("the layered input has no layers")]
    NoInputLayers,
    /// A render layer does not line up with the others.
    #[error("view layer {layer:?} does not line up with the others: {message}")]
    LayerMismatch {
        /// The layer.
        layer: String,
        /// What differs.
        message: String,
    },
    /// A physical-lens database describes another camera or lacks its prescription.
    #[error("physical-lens database: {0}")]
    PhysicalLens(String),
}

/// Knobs of classification.
#[derive(Clone, Debug, PartialEq)]
pub struct ClassifyOptions {
    /// Number of global depth layers (at least 1).
    pub layers: u32,
    /// Soft layering: width of the blend between neighbouring layers, in layer units (0 = hard
    /// layers, 1 = a tent over the full layer); `None` = hard.
    pub soft_layers: Option<f32>,
    /// Split anti-aliased edge pixels into foreground and background parts.
    pub edge_split: bool,
    /// A PSF whose CoC radius and motion length are both below this (pixels) is copied.
    pub copy_threshold_px: f32,
    /// Extra padding beyond the database's largest PSF extent, pixels.
    pub pad_margin: u32,
    /// A fragment whose weighted colour exceeds this in any of R, G, B (linear, premultiplied)
    /// is drawn with the dense twin of its sub-cell ([`DbSet::hdr_twin_for`]) instead of its
    /// PSF, where one exists: the spreadlets' small relative error would be scaled by the
    /// highlight, and a PSF pre-filtered over its whole cell would draw it as a soft blob.
    /// `f32::INFINITY` never does.
    pub hdr_dense_threshold: f32,
    /// What lies beyond the input's pixels (see [`FrameEdges`]).
    pub frame_edges: FrameEdges,
    /// Fragments whose CoC radius and motion length are both below this (pixels) are not split
    /// by soft layering.
    pub soft_layers_min_blur_px: f32,
    /// Continue the background behind the silhouette of a nearer occluder that is sharper
    /// than it (so that a blurred background does not darken along it: the lens sees past the
    /// occluder's edge) or blurrier (so that a moving or defocused occluder's smear is half
    /// transparent over the background inside its silhouette as well as outside).
    pub fill_hidden: bool,
    /// Look PSFs up continuously, so that a surface whose blur varies smoothly blurs
    /// smoothly instead of showing a line at each cell boundary: a fragment is splatted with
    /// its cell's PSF and with the PSF of the neighbouring cell it is nearer, weighted by the
    /// tent between the two cells' centres ([`psf_db::ParamSpace::neighbour_blend`]), along
    /// the CoC for still pixels (thin lens) and along the motion length for moving ones
    /// (lens-motion). A step in the PSF's size between neighbouring pixels leaves the light
    /// they scatter short of one along the step, a dark line. Bright fragments (drawn with
    /// their HDR twin) and physical-lens lookups take their one cell. Off: every fragment
    /// its one cell, one record.
    pub continuous_lookup: bool,
}

impl Default for ClassifyOptions {
    fn default() -> Self {
        Self {
            layers: 8,
            soft_layers: Some(1.0),
            edge_split: true,
            copy_threshold_px: 0.5,
            pad_margin: 2,
            hdr_dense_threshold: 2.0,
            frame_edges: FrameEdges::Extend,
            fill_hidden: true,
            soft_layers_min_blur_px: 2.0,
            continuous_lookup: true,
        }
    }
}

/// Per-layer summary.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LayerInfo {
    /// Parallax (1/depth, per scene unit) at the far edge of the layer's bin.
    pub parallax_min: f32,
    /// Parallax at the near edge of the layer's bin.
    pub parallax_max: f32,
    /// Index of the layer's first record in [`Classified::records`].
    pub first_record: usize,
    /// Number of records in the layer.
    pub record_count: usize,
    /// Records drawn sparse.
    pub sparse: usize,
    /// Records drawn dense.
    pub dense: usize,
    /// Records copied.
    pub copied: usize,
}

impl LayerInfo {
    /// Adds the paths of the layer's `records` to `sparse`, `dense` and `copied`.
    pub fn count_paths(&mut self, records: &[SplatRecord]) {
        for r in records {
            match r.path {
                p if p == SplatPath::Sparse as u32 => self.sparse += 1,
                p if p == SplatPath::Dense as u32 => self.dense += 1,
                _ => self.copied += 1,
            }
        }
    }
}

/// Record counts per path, over all layers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct PathCounts {
    /// Records splatted as sparse spreadlets.
    pub sparse: usize,
    /// Records drawn as dense fast-track PSFs.
    pub dense: usize,
    /// Records whose PSF lies under a pixel, copied.
    pub copied: usize,
    /// Input pixels dropped (non-finite colour, or zero colour and alpha).
    pub dropped: usize,
    /// Records whose PSF coordinates were outside the database and clamped.
    pub clamped: usize,
    /// Pixels split into a foreground and a background part by the edge fix.
    pub edge_split: usize,
    /// Pixels split into two layers by soft layering.
    pub soft_split: usize,
    /// Fragments drawn with a dense twin because they are very bright (also in `dense`).
    pub hdr_dense: usize,
    /// Records added beyond the input's outermost pixels ([`FrameEdges::Extend`]; also in the
    /// path counts).
    pub edge_extended: usize,
    /// Fragments of background continued behind sharper occluders
    /// ([`ClassifyOptions::fill_hidden`]).
    pub hidden_filled: usize,
}

impl PathCounts {
    /// Adds a layer's counts per path.
    pub fn add_layer(&mut self, info: &LayerInfo) {
        self.sparse += info.sparse;
        self.dense += info.dense;
        self.copied += info.copied;
    }
}

/// Output of [`classify`].
#[derive(Clone, Debug, PartialEq)]
pub struct Classified {
    /// Frame constants (size, padding, layers, record count, database channels).
    pub frame: FrameParams,
    /// Records sorted by layer, then by pixel (row-major), then fragment.
    pub records: Vec<SplatRecord>,
    /// One entry per layer (index 0 = farthest).
    pub layers: Vec<LayerInfo>,
    /// Counts per path.
    pub counts: PathCounts,
}

/// The effects a camera and input call for, and the model that covers them most cheaply.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Effects {
    /// Depth of field (finite aperture).
    pub defocus: bool,
    /// Motion blur (open shutter and some non-zero motion).
    pub motion: bool,
}

impl Effects {
    /// What `camera` and `gbuffer` call for.
    pub fn of(camera: &Camera, gbuffer: &GBuffer) -> Self {
        let motion = camera.has_shutter()
            && gbuffer
                .motion
                .as_ref()
                .is_some_and(|m| m.iter().any(|v| v[0] != 0.0 || v[1] != 0.0));
        Self {
            defocus: camera.has_lens(),
            motion,
        }
    }

    /// The cheapest model that covers the effects; `None` when nothing needs simulating.
    pub fn cheapest_model(self) -> Option<PsfModel> {
        match (self.defocus, self.motion) {
            (false, false) => None,
            (true, false) => Some(PsfModel::ThinLens),
            (_, true) => Some(PsfModel::LensMotion),
        }
    }
}

/// One part of a pixel (or one stochastic sample) before layering: where its PSF is centred,
/// its colour, weight, parallax, depth and motion. Synthesis makes one or two per G-buffer
/// pixel (edge split); reconstruction one per stochastic sample.
#[derive(Clone, Copy, Debug, PartialEq)]
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
    /// Which input surface of its pixel it comes from: the render layer, or the deep sample's
    /// index; 0 for a single input. Where fragments of one pixel from different sources fall
    /// into the same depth layer, the nearer ones occlude the farther ("over" within the
    /// layer), as compositing them would.
    pub source: u32,
}

/// Checks that the camera and the G-buffer's frame (without its overscan) agree about the
/// image size.
pub fn classify_sizes(gbuffer: &GBuffer, camera: &Camera) -> Result<(), ClassifyError> {
    check_frame_size(gbuffer.frame_width(), gbuffer.frame_height(), camera)
}

/// Checks that a frame of `fw x fh` pixels is the camera's.
pub(crate) fn check_frame_size(fw: usize, fh: usize, camera: &Camera) -> Result<(), ClassifyError> {
    if camera.width as usize != fw || camera.height as usize != fh {
        return Err(ClassifyError::SizeMismatch {
            cam_w: camera.width,
            cam_h: camera.height,
            img_w: fw,
            img_h: fh,
        });
    }
    Ok(())
}

/// Classifies every pixel. `db` may be `None` only when no effect needs simulating (then every
/// pixel is copied). The physical-lens model is used when `db` is a physical-lens database.
pub fn classify(
    gbuffer: &GBuffer,
    camera: &Camera,
    dbs: &DbSet,
    options: &ClassifyOptions,
) -> Result<Classified, ClassifyError> {
    classify_sizes(gbuffer, camera)?;
    if options.layers == 0 {
        return Err(ClassifyError::NoLayers);
    }
    let effects = Effects::of(camera, gbuffer);
    check_passes(gbuffer, camera, None, false)?;
    let model = resolve_model(effects, dbs)?;
    let mut counts = PathCounts {
        dropped: gbuffer.dropped_pixels,
        ..PathCounts::default()
    };
    let fragments = pixel_fragments(
        gbuffer,
        camera,
        effects,
        model,
        options,
        options.edge_split,
        &mut counts,
    );
    classify_fragments(
        &fragments,
        gbuffer.frame_width(),
        gbuffer.frame_height(),
        data_window(gbuffer),
        camera,
        dbs,
        model,
        options,
        counts,
    )
}

/// Checks that every layer covers the same pixels as the first (size and overscan), naming the
/// one that does not, and that the first fits the camera; returns the first.
pub fn check_layers_line_up<'a>(
    layers: &'a [ViewLayer],
    camera: &Camera,
) -> Result<&'a ViewLayer, ClassifyError> {
    let Some(first) = layers.first() else {
        return Err(ClassifyError::NoInputLayers);
    };
    for layer in layers {
        let g = &layer.gbuffer;
        if (g.width, g.height, g.overscan)
            != (
                first.gbuffer.width,
                first.gbuffer.height,
                first.gbuffer.overscan,
            )
        {
            return Err(ClassifyError::LayerMismatch {
                layer: layer.name.clone(),
                message: format!(
                    "{}x{} pixels with overscan {:?}, but {:?} has {}x{} with {:?}",
                    g.width,
                    g.height,
                    g.overscan,
                    first.name,
                    first.gbuffer.width,
                    first.gbuffer.height,
                    first.gbuffer.overscan
                ),
            });
        }
    }
    classify_sizes(&first.gbuffer, camera)?;
    Ok(first)
}

/// Classifies the pixels of several render layers of one frame (view layers, one file per
/// layer): every layer's pixels are fragments with their own colour, alpha, depth and
/// motion, layered together into the global depth layers, so what a foreground hides is
/// real data behind it. Every layer must cover the camera's frame with the same overscan.
/// Partly covered edge pixels whose depth is the miss value (Blender writes the depth of the
/// first sample that hit the layer) take the depth and motion of their nearest covered
/// neighbour in the same layer; a layer with transparency is not edge split (its edge pixels
/// hold its own surface only), an opaque one is.
pub fn classify_layers(
    layers: &[ViewLayer],
    camera: &Camera,
    dbs: &DbSet,
    options: &ClassifyOptions,
) -> Result<Classified, ClassifyError> {
    let first = check_layers_line_up(layers, camera)?;
    if options.layers == 0 {
        return Err(ClassifyError::NoLayers);
    }
    let effects = layered_effects(layers, camera);
    let model = resolve_model(effects, dbs)?;
    let mut counts = PathCounts::default();
    let mut fragments = Vec::new();
    for (source, layer) in (0u32..).zip(layers) {
        check_passes(&layer.gbuffer, camera, Some(&layer.name), layer.still)?;
        counts.dropped += layer.gbuffer.dropped_pixels;
        let repaired = with_edge_depths(&layer.gbuffer);
        let gbuffer = repaired.as_ref().unwrap_or(&layer.gbuffer);
        let opaque = gbuffer.color.iter().all(|c| c[3] >= 0.999);
        let layer_effects = Effects {
            motion: effects.motion && gbuffer.motion.is_some(),
            ..effects
        };
        fragments.extend(
            pixel_fragments(
                gbuffer,
                camera,
                layer_effects,
                model,
                options,
                options.edge_split && opaque,
                &mut counts,
            )
            .into_iter()
            .map(|f| Fragment { source, ..f }),
        );
    }
    classify_fragments(
        &fragments,
        first.gbuffer.frame_width(),
        first.gbuffer.frame_height(),
        data_window(&first.gbuffer),
        camera,
        dbs,
        model,
        options,
        counts,
    )
}

/// The effects of a layered frame: depth of field from the camera, motion blur when the
/// shutter is open and some layer moves.
pub fn layered_effects(layers: &[ViewLayer], camera: &Camera) -> Effects {
    Effects {
        defocus: camera.has_lens(),
        motion: layers
            .iter()
            .any(|l| Effects::of(camera, &l.gbuffer).motion),
    }
}

/// Depth at or beyond which a pixel's depth is the miss value (Blender writes 1e10).
const MISS_DEPTH: f32 = 1e9;

/// `gbuffer` with its partly covered pixels that carry the miss depth given the depth and
/// motion of the nearest covered pixel (within 3 pixels, the most covered at equal distance);
/// `None` when there are none.
fn with_edge_depths(gbuffer: &GBuffer) -> Option<GBuffer> {
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
    }
    Some(out)
}

/// The covered pixel nearest to pixel `i` within 3 pixels (the most covered at equal
/// distance, the first in row order at equal coverage).
fn nearest_covered(gbuffer: &GBuffer, i: usize, covered: &dyn Fn(usize) -> bool) -> Option<usize> {
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
fn data_window(gbuffer: &GBuffer) -> DataWindow {
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
fn check_passes(
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
fn pixel_fragments(
    gbuffer: &GBuffer,
    camera: &Camera,
    effects: Effects,
    model: Option<PsfModel>,
    options: &ClassifyOptions,
    split_edges: bool,
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

    // Fragments per pixel (up to two: edge split).
    let mut fragments: Vec<Fragment> = Vec::with_capacity(w * h);
    let mut was_split = vec![false; w * h];
    for y in 0..h {
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
                source: 0,
            };
            let split = if split_edges && model.is_some() {
                edge_split(
                    gbuffer,
                    x,
                    y,
                    &signed_coc,
                    &depth_at,
                    options.hdr_dense_threshold,
                )
            } else {
                None
            };
            match split {
                Some(split) => {
                    counts.edge_split += 1;
                    was_split[i] = true;
                    let (j, o) = (split.foreground, split.background);
                    let dj = depth_at(j);
                    fragments.push(Fragment {
                        color: split.foreground_color,
                        weight: split.alpha,
                        parallax: parallax_of(dj),
                        depth: dj,
                        motion: motion_at(j),
                        ..own
                    });
                    if split.alpha < 1.0 {
                        // The background part keeps this pixel's depth (the depth pass is not
                        // anti-aliased) but not its motion, which the vector pass blends.
                        fragments.push(Fragment {
                            color: split.background_color,
                            weight: 1.0 - split.alpha,
                            motion: motion_at(o),
                            ..own
                        });
                    }
                }
                None => fragments.push(own),
            }
        }
    }

    if options.fill_hidden && model.is_some() {
        // Along an axis direction: the CoC radius plus half the motion over the shutter
        // projected on it (the streak is centred on the pixel).
        let blur_along = |i: usize, d: (i32, i32)| -> f32 {
            let m = motion_at(i);
            signed_coc(depth_at(i)).abs() + 0.5 * (m[0] * d.0 as f32 + m[1] * d.1 as f32).abs()
        };
        let filled = hidden_background(
            gbuffer,
            &was_split,
            &signed_coc,
            &depth_at,
            &blur_along,
            options.hdr_dense_threshold,
            &|i| Fragment {
                x: (i % w) as i32 - overscan.left as i32,
                y: (i / w) as i32 - overscan.top as i32,
                color: gbuffer.color[i],
                weight: 1.0,
                parallax: parallax_of(depth_at(i)),
                depth: depth_at(i),
                motion: motion_at(i),
                source: 0,
            },
        );
        counts.hidden_filled += filled.len();
        fragments.extend(filled);
    }

    fragments
}

/// The model that drives the lookups for `effects`: lens-motion or physical-lens from
/// `dbs.main`, else thin-lens; `None` when nothing needs simulating.
pub fn resolve_model(effects: Effects, dbs: &DbSet) -> Result<Option<PsfModel>, ClassifyError> {
    // The model that drives the lookups: lens-motion or physical-lens from `main`, else
    // thin-lens. Still pixels use the thin-lens database whenever the set has one.
    let thin = dbs.thin_lens.as_ref();
    let main = dbs.main.as_ref();
    Ok(match effects.cheapest_model() {
        None => None,
        Some(needed) => {
            let found = main.map(|m| m.model()).or(thin.map(|t| t.model()));
            let Some(found) = found else {
                return Err(ClassifyError::NoDatabase(needed.name()));
            };
            let ok = match needed {
                PsfModel::ThinLens => true,
                PsfModel::LensMotion => found == PsfModel::LensMotion,
                PsfModel::PhysicalLens => found == PsfModel::PhysicalLens,
            };
            if !ok {
                return Err(ClassifyError::WrongModel {
                    needed: needed.name(),
                    found: found.name(),
                });
            }
            Some(found)
        }
    })
}

/// Layers fragments and turns them into splat records: the nearest PSF of each (O(1) through
/// the nested grid), its rotation, its drawing path, and its layer(s). `w x h` is the frame
/// (the output); fragments are in frame coordinates and may lie outside it, within `data`
/// (overscan). Beyond `data`, [`ClassifyOptions::frame_edges`] decides. `model` comes from
/// [`resolve_model`]; `counts` carries what the caller already counted (dropped, edge splits).
#[allow(clippy::too_many_arguments)]
pub fn classify_fragments(
    fragments: &[Fragment],
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
    // Layer coordinate: 0 at the far edge, n at the near edge.
    let layer_coord = |p: f32| -> f32 {
        if span > 0.0 {
            ((p - pmin) / span * n_layers as f32).clamp(0.0, n_layers as f32)
        } else {
            0.0
        }
    };

    // Layer weights: hard, or blended near the boundary between two layer centres. A sharp
    // fragment is not split: its PSF barely differs between the two layers, and a surface
    // split across two layers lets what lies behind it show through (up to a quarter where
    // the weights are even).
    let targets_of = |frag: &Fragment| {
        let coc = signed_coc(frag.depth).abs();
        let m = frag.motion;
        let motion_len = (m[0] * m[0] + m[1] * m[1]).sqrt();
        let sharp = coc.max(motion_len) < options.soft_layers_min_blur_px;
        let band = options.soft_layers.filter(|_| !sharp);
        layer_targets(layer_coord(frag.parallax), n_layers, band)
    };
    let transmission = occlusion_within_layers(fragments, n_layers, &targets_of);
    let flip_front = front_turns_the_aperture(dbs);

    // Records per layer, then concatenated (deterministic order).
    let mut per_layer: Vec<Vec<SplatRecord>> = vec![Vec::new(); n_layers];
    let centre = [w as f32 * 0.5, h as f32 * 0.5];
    for (index, frag) in fragments.iter().enumerate() {
        if frag.weight <= 0.0 {
            continue;
        }
        let (x, y) = (frag.x, frag.y);
        let color = frag.color;
        let signed = signed_coc(frag.depth);
        let coc = signed.abs();
        let m = frag.motion;
        let motion_len = (m[0] * m[0] + m[1] * m[1]).sqrt();
        let bright = color[..3]
            .iter()
            .any(|&c| c * frag.weight > options.hdr_dense_threshold);
        // A bright fragment stands alone (a highlight's bokeh is one PSF, not an average over
        // a neighbourhood): it keeps the PSF of its own parameters.
        let continuous = options.continuous_lookup && !bright;
        let Lookup {
            path,
            psf_index,
            clamped,
            mut rot_cos,
            mut rot_sin,
            blend,
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
        );
        // In front of the focus plane the lens images its aperture turned half a turn: the
        // databases hold the PSF behind it (see `front_turns_the_aperture`).
        if flip_front && signed < 0.0 && model != Some(PsfModel::PhysicalLens) {
            rot_cos = -rot_cos;
            rot_sin = -rot_sin;
        }
        counts.clamped += usize::from(clamped);
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

        let (targets, n_targets) = targets_of(frag);
        if n_targets == 2 {
            counts.soft_split += 1;
        }
        // The fragment's PSF, or its cell's and its neighbour's with their shares.
        // A twin is already the PSF of the fragment's own sub-cell.
        let mut parts = [(path, psf_index, 1.0f32), (path, psf_index, 0.0)];
        if let Some(b) = blend.filter(|b| !to_twin && b.psf_index != psf_index) {
            parts[0].2 = 1.0 - b.share;
            parts[1] = (b.path, b.psf_index, b.share);
        }
        let n_parts = if parts[1].2 > 0.0 { 2 } else { 1 };
        for (t, &(layer, lw)) in targets[..n_targets].iter().enumerate() {
            let weight = match &transmission {
                Some(kept) => frag.weight * lw * kept[index][t],
                None => frag.weight * lw,
            };
            for &(path, psf_index, share) in &parts[..n_parts] {
                let weight = weight * share;
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
        }
    }

    Ok(assemble_layers(
        per_layer,
        w,
        h,
        data,
        combined,
        options,
        counts,
        (pmin, span),
    ))
}

/// The frame's records from its layers' (frame coordinates): overscan records that cannot
/// reach the frame dropped, the data's border extended outwards as
/// [`ClassifyOptions::frame_edges`] says, row order within each layer, the padding every PSF
/// needs, and the layers' summaries. `parallax` is the far edge and the span of the layers.
#[allow(clippy::too_many_arguments)]
fn assemble_layers(
    mut per_layer: Vec<Vec<SplatRecord>>,
    w: usize,
    h: usize,
    data: DataWindow,
    combined: Option<&PsfDatabase>,
    options: &ClassifyOptions,
    mut counts: PathCounts,
    parallax: (f32, f32),
) -> Classified {
    let (pmin, span) = parallax;
    let n_layers = per_layer.len();
    // Beyond the data: records of the outermost pixels, repeated outwards (or nothing).
    let reach: Vec<i32> = combined.map_or_else(Vec::new, psf_reach);
    let reach_of = |r: &SplatRecord| -> i32 {
        if r.path == SplatPath::Copy as u32 {
            0
        } else {
            reach.get(r.psf_index as usize).copied().unwrap_or(0)
        }
    };
    let frame = DataWindow::frame(w, h);
    for recs in &mut per_layer {
        // Overscan pixels whose PSF cannot reach the frame add nothing to the output.
        recs.retain(|r| distance_to(frame, r.center_x, r.center_y) <= reach_of(r) as f32);
        if options.frame_edges == FrameEdges::Extend {
            let extended = extend_beyond(recs, data, frame, &reach_of);
            counts.edge_extended += extended.len();
            recs.extend(extended);
        }
        // Row order within the layer (the splat visits bands of rows; the extension and the
        // hidden background come after the pixels); stable, so the pixels' records keep their
        // order.
        if !recs.is_sorted_by_key(|r| (r.center_y, r.center_x)) {
            recs.sort_by_key(|r| (r.center_y, r.center_x));
        }
    }
    // Padding: every PSF, wherever its centre lies, must fit inside the padded layer.
    let beyond = per_layer
        .iter()
        .flatten()
        .map(|r| {
            let ox = (-r.center_x).max(r.center_x - (w as i32 - 1)).max(0);
            let oy = (-r.center_y).max(r.center_y - (h as i32 - 1)).max(0);
            ox.max(oy) + reach_of(r)
        })
        .max()
        .unwrap_or(0);
    let pad = combined
        .map_or(0, |d| d.max_extent_px())
        .max(beyond.max(0) as u32)
        + options.pad_margin;
    let padded_width = w as u32 + 2 * pad;
    let padded_height = h as u32 + 2 * pad;
    for r in per_layer.iter_mut().flatten() {
        r.center_x += pad as i32;
        r.center_y += pad as i32;
    }

    let mut records = Vec::with_capacity(per_layer.iter().map(Vec::len).sum());
    let mut layers = Vec::with_capacity(n_layers);
    for (l, recs) in per_layer.into_iter().enumerate() {
        let mut info = LayerInfo {
            parallax_min: pmin + span * l as f32 / n_layers as f32,
            parallax_max: pmin + span * (l + 1) as f32 / n_layers as f32,
            first_record: records.len(),
            record_count: recs.len(),
            ..LayerInfo::default()
        };
        info.count_paths(&recs);
        counts.add_layer(&info);
        layers.push(info);
        records.extend(recs);
    }
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
    }
}

/// A fragment's PSF: its drawing path, index in the combined database, whether its
/// parameters were clamped to the database's range, and the rotation of the PSF's reference
/// direction (+x) onto the motion (lens-motion) or the radial direction (physical lens).
struct Lookup {
    path: SplatPath,
    psf_index: u32,
    clamped: bool,
    rot_cos: f32,
    rot_sin: f32,
    /// The neighbouring cell the PSF is blended with, if any.
    blend: Option<Blend>,
}

/// The second PSF of a blended lookup ([`ClassifyOptions::continuous_lookup`]).
#[derive(Clone, Copy)]
struct Blend {
    path: SplatPath,
    psf_index: u32,
    /// Its share of the fragment's weight, in `(0, 0.5]`.
    share: f32,
}

/// The PSF of `frag` (CoC `coc` and motion `motion_len`, pixels), O(1) through the nested
/// grid: still pixels from the thin-lens database, moving ones from the lens-motion one,
/// everything from a physical-lens one; copied when both are under
/// [`ClassifyOptions::copy_threshold_px`]. `centre` is the frame's centre, pixels.
#[allow(clippy::too_many_arguments)]
fn lookup_psf(
    frag: &Fragment,
    coc: f32,
    motion_len: f32,
    centre: [f32; 2],
    pixels_per_mm: f32,
    dbs: &DbSet,
    model: Option<PsfModel>,
    options: &ClassifyOptions,
    continuous: bool,
) -> Lookup {
    let (thin, main, combined) = (
        dbs.thin_lens.as_ref(),
        dbs.main.as_ref(),
        dbs.combined.as_ref(),
    );
    let (x, y) = (frag.x, frag.y);
    let m = frag.motion;
    let (mut rot_cos, mut rot_sin) = (1.0f32, 0.0f32);
    let offset = dbs.main_offset;
    let mut blend = None;
    // The neighbour along `dim` that a continuous lookup blends the PSF of `s` with.
    let neighbour = |db: &PsfDatabase, s: [f32; 2], dim: usize, offset: u32| {
        if !continuous {
            return None;
        }
        let (i, share) = db.neighbour_blend(s, dim)?;
        let j = i + offset;
        Some(Blend {
            path: combined.map_or(SplatPath::Copy, |all| path_of(all, j)),
            psf_index: j,
            share,
        })
    };
    let (path, psf_index, clamped) = match (model, main, combined) {
        (Some(PsfModel::PhysicalLens), Some(db), Some(all)) => {
            let dx = x as f32 + 0.5 - centre[0];
            let dy = y as f32 + 0.5 - centre[1];
            let r = (dx * dx + dy * dy).sqrt();
            if r > 0.0 {
                rot_cos = dx / r;
                rot_sin = dy / r;
            }
            // The physical-lens space is over inverse depth (1 / scene units).
            let (idx, cl) = db.lookup([1.0 / frag.depth, r / pixels_per_mm]);
            (path_of(all, idx + offset), idx + offset, cl)
        }
        (Some(_), _, Some(all))
            if coc >= options.copy_threshold_px || motion_len >= options.copy_threshold_px =>
        {
            let still = motion_len < options.copy_threshold_px;
            let mut thin_lookup = |t: &PsfDatabase| {
                blend = neighbour(t, [coc, 0.0], 0, 0);
                t.lookup([coc, 0.0])
            };
            let (idx, cl) = match (thin, main) {
                (Some(t), _) if still => thin_lookup(t),
                (_, Some(db_m)) => {
                    if db_m.model() == PsfModel::LensMotion && motion_len > 0.0 {
                        rot_cos = m[0] / motion_len;
                        rot_sin = m[1] / motion_len;
                    }
                    let (i, cl) = db_m.lookup([coc, motion_len]);
                    if db_m.model() == PsfModel::LensMotion {
                        blend = neighbour(db_m, [coc, motion_len], 1, offset);
                    }
                    (i + offset, cl)
                }
                (Some(t), None) => thin_lookup(t),
                (None, None) => (0, false),
            };
            (path_of(all, idx), idx, cl)
        }
        _ => (SplatPath::Copy, 0, false),
    };
    Lookup {
        path,
        psf_index,
        clamped,
        rot_cos,
        rot_sin,
        blend,
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
fn occlusion_within_layers(
    fragments: &[Fragment],
    n_layers: usize,
    targets_of: &dyn Fn(&Fragment) -> LayerTargets,
) -> Option<Vec<[f32; 2]>> {
    let first_source = fragments.first()?.source;
    if fragments.iter().all(|f| f.source == first_source) {
        return None;
    }
    let mut kept = vec![[1.0f32; 2]; fragments.len()];
    // Fragments by pixel, each pixel's in input order (a stable sort).
    let mut order: Vec<u32> = (0..fragments.len() as u32).collect();
    order.sort_by_key(|&i| {
        let f = &fragments[i as usize];
        (f.y, f.x)
    });
    let mut through = vec![1.0f32; n_layers];
    let mut coverage = vec![0.0f32; n_layers];
    let mut touched: Vec<usize> = Vec::new();
    // (nearest depth of the fragment's source in this pixel, source, fragment)
    let mut entries: Vec<(f32, u32, u32)> = Vec::new();
    let key = |i: u32| (fragments[i as usize].y, fragments[i as usize].x);
    for pixel in order.chunk_by(|&a, &b| key(a) == key(b)) {
        let source_of = |i: u32| fragments[i as usize].source;
        if pixel.iter().all(|&i| source_of(i) == source_of(pixel[0])) {
            continue;
        }
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
                let alpha = frag.color[3].clamp(0.0, 1.0) * frag.weight.max(0.0);
                for (t, &(layer, lw)) in targets[..n].iter().enumerate() {
                    kept[i as usize][t] = through[layer];
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
    Some(kept)
}

/// Whether the databases' aperture looks different turned half a turn (an odd number of
/// blades, or a drawn image): then a fragment in front of the focus plane, whose PSF is the
/// aperture's image point-reflected, draws its PSF turned by pi. Disks, even polygons and
/// their anamorphic squeezes are symmetric under that turn and are drawn as they are (the
/// turn would only cost the exact pixel placement).
fn front_turns_the_aperture(dbs: &DbSet) -> bool {
    let db = dbs.thin_lens.as_ref().or(dbs.main.as_ref());
    db.is_some_and(|db| {
        let a = &db.header().aperture;
        (a.blades >= 3 && a.blades % 2 == 1) || a.image_hash != 0
    })
}

/// A fragment's depth layers and its weight in each: one or two (soft layers) of the pair.
type LayerTargets = ([(usize, f32); 2], usize);

fn layer_targets(u: f32, n_layers: usize, band: Option<f32>) -> LayerTargets {
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

fn path_of(db: &PsfDatabase, idx: u32) -> SplatPath {
    if db.dense(idx as usize).is_some() {
        SplatPath::Dense
    } else {
        SplatPath::Sparse
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(w: u32, h: u32, lens: bool, shutter: f64) -> Camera {
        Camera {
            width: w,
            height: h,
            focal_length_mm: 50.0,
            sensor_width_mm: 36.0,
            f_stop: lens.then_some(2.0),
            focus_distance: lens.then_some(1.0),
            aperture_blades: 0,
            aperture_rotation_deg: 0.0,
            aperture_ratio: 1.0,
            aperture_image: None,
            lens: None,
            shutter_frames: shutter,
            scene_unit_mm: 1000.0,
        }
    }

    #[test]
    fn pinhole_still_is_all_copies_in_one_layer_without_a_database() {
        let g = GBuffer::from_planes(
            3,
            2,
            vec![[0.5, 0.25, 1.0, 1.0]; 6],
            Some(vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
            None,
        )
        .expect("g");
        let c = classify(
            &g,
            &camera(3, 2, false, 0.0),
            &DbSet::none(),
            &ClassifyOptions::default(),
        )
        .expect("classify");
        assert_eq!(c.counts.copied, 6);
        assert_eq!(c.records.len(), 6);
        assert_eq!(c.frame.pad, ClassifyOptions::default().pad_margin);
        assert!(c.records.iter().all(|r| r.path == SplatPath::Copy as u32));
    }

    #[test]
    fn defocus_needs_a_thin_lens_database_and_rejects_motion() {
        let g =
            GBuffer::from_planes(2, 1, vec![[1.0; 4]; 2], Some(vec![0.5, 3.0]), None).expect("g");
        let err = classify(
            &g,
            &camera(2, 1, true, 0.0),
            &DbSet::none(),
            &ClassifyOptions::default(),
        )
        .expect_err("no db");
        assert!(err.to_string().contains("thin-lens"));
        assert_eq!(
            Effects::of(&camera(2, 1, true, 0.0), &g).cheapest_model(),
            Some(PsfModel::ThinLens)
        );
        let err = classify(
            &g,
            &camera(3, 1, true, 0.0),
            &DbSet::none(),
            &ClassifyOptions::default(),
        )
        .expect_err("size");
        assert!(err.to_string().contains("3x1"));
    }

    #[test]
    fn soft_layer_weights_sum_to_one_per_pixel() {
        let n = 64;
        let depth: Vec<f32> = (0..n).map(|i| 0.5 + i as f32 * 0.05).collect();
        let g = GBuffer::from_planes(n, 1, vec![[1.0; 4]; n], Some(depth), None).expect("g");
        let space =
            psf_db::ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 64.0]], 8).expect("space");
        let mut b = psf_db::DatabaseBuilder::new(psf_db::DbHeader::new(
            PsfModel::ThinLens,
            space.clone(),
            16,
        ));
        for _ in 0..space.psf_count() {
            b.push_sparse(&[[0, 0]], &[-1.0]).expect("push");
        }
        let db = b.finish().expect("db");
        let opts = ClassifyOptions {
            layers: 4,
            soft_layers: Some(1.0),
            edge_split: false,
            // Every fragment here is nearly sharp: split them all.
            soft_layers_min_blur_px: 0.0,
            ..ClassifyOptions::default()
        };
        let dbs = DbSet::single(db).expect("set");
        let c = classify(&g, &camera(n as u32, 1, true, 0.0), &dbs, &opts).expect("c");
        let mut sums = vec![0.0f32; n];
        for r in &c.records {
            // Records beyond the frame repeat its outermost pixels (frame edges extended).
            let x = r.center_x - c.frame.pad as i32;
            let y = r.center_y - c.frame.pad as i32;
            if (0..n as i32).contains(&x) && y == 0 {
                sums[x as usize] += r.weight;
            }
        }
        for s in sums {
            assert!((s - 1.0).abs() < 1e-6, "{s}");
        }
        assert!(c.counts.soft_split > 0);
        // Sorted by layer, nearest pixel (smallest depth) in the last layer.
        assert!(c.records.windows(2).all(|p| p[0].layer <= p[1].layer));
        let last = c.records.last().expect("records");
        assert_eq!(last.layer, 3);
    }
}
