//! Stage 1, classification: every G-buffer pixel becomes one or more [`SplatRecord`](crate::pipeline::SplatRecord)s (PSF
//! index, layer, rotation, weighted colour, drawing path), sorted by layer then pixel order.
//!
//! Per pixel: the signed thin-lens CoC from depth (pixels), the motion over the shutter
//! (pixels), the database PSF nearest to them (O(1) through the nested grid), the rotation of
//! the PSF's reference direction (+x) onto the motion (lens-motion) or onto the radial direction
//! (physical lens), and the path: copied when the PSF lies under a pixel, drawn dense when the
//! database stores that PSF dense (fast track), else splatted sparse.
//!
//! Layers are global and binned uniformly in parallax `1/depth` (the signed CoC is affine in
//! it: constant parallax units), layer 0 the farthest. With soft layering a moving pixel near a
//! layer boundary is split into two records whose weights sum to one; a still one is layered
//! hard, and the surface it belongs to is continued under the nearer layer's part
//! ([`ClassifyOptions::continue_layers`]). A pixel whose blur is beyond the database's range is
//! drawn at a reduced resolution ([`ClassifyOptions::reduced_resolution`]).
//!
//! Anti-aliased edge pixels of a near object carry the depth of the background behind it (the
//! depth pass is not anti-aliased). With `edge_split`, a pixel that has a markedly nearer
//! neighbour is split into a foreground part (the neighbour's depth and motion) and a
//! background part (its own), the foreground fraction estimated by projecting its colour onto
//! the segment between the foreground neighbour's colour and the background colour opposite.
//!
//! Rooms: this file holds the errors, options, effects and entry points (flat, layered);
//! `fragments.rs` turns pixels into fragments, `lookup.rs` finds each fragment's PSF,
//! `layers.rs` layers fragments into sorted records; `deep.rs` (deep input), `edge_split.rs`,
//! `hidden.rs` (background continued behind occluders) and `frame_edges.rs` are the special
//! cases; `turned.rs` (PSFs turned once per frame and shared) and `few_sparse.rs` (a layer's
//! few sparse records drawn from their PSFs' images) give the frame PSF images of its own.

mod bend;
mod deep;
mod edge_split;
mod few_sparse;
mod fragments;
mod frame_edges;
mod hidden;
mod layers;
mod lookup;
mod turned;

use psf_db::PsfModel;

pub(crate) use bend::path_bends;
pub(crate) use deep::classify_deep_with;
pub use deep::{check_deep_size, classify_deep, deep_effects, deep_fragments};
pub use fragments::Fragment;
use fragments::{check_passes, data_window, pixel_fragments, with_edge_depths};
pub use frame_edges::{DataWindow, FrameEdges};
pub use layers::classify_fragments;

pub use super::types::{Classified, LayerInfo, PathCounts};
use crate::camera::Camera;
use crate::dbset::DbSet;
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
    /// The frame's own database (its PSFs' images beside the database's) could not be made.
    #[error("the frame's PSF images: {0}")]
    FrameDatabase(String),
    /// A moving pixel's lens PSF could not be smeared along its motion.
    #[error("motion blur: {0}")]
    MotionSmear(crate::motion_smear::SmearError),
}

// Not `#[from]`: that would make the smear error this one's source as well as its text, and a
// chain of errors printed in full would say it twice.
impl From<crate::motion_smear::SmearError> for ClassifyError {
    fn from(e: crate::motion_smear::SmearError) -> Self {
        ClassifyError::MotionSmear(e)
    }
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
    /// the CoC for still pixels (thin lens), along the motion length for moving ones
    /// (lens-motion), and along inverse depth for still pixels through a real lens. A step in
    /// the PSF's size between neighbouring pixels leaves the light they scatter short of one
    /// along the step, a dark line. Bright fragments drawn with their HDR twin take their one
    /// cell. Off: every fragment its one cell, one record.
    pub continuous_lookup: bool,
    /// Draw a moving fragment seen through the thin lens with its thin-lens PSF smeared
    /// along its own motion over the shutter ([`crate::motion_smear`], the factorisation the
    /// physical lens uses too, exact for a point moving at constant depth), built per frame,
    /// instead of the lens-motion database's PSF of its cell. A streak then ends where the
    /// motion says (length quantised in 2 % steps, dithered between neighbouring pixels), not
    /// over a cell several pixels wide, and is drawn unrotated in one record rather than
    /// turned and blended with a neighbouring cell. Needs the thin-lens database, which then
    /// serves moving frames alone; off, or without it, the lens-motion cell's PSF is drawn.
    pub smear_motion: bool,
    /// Draw a fragment whose CoC or motion is beyond the database's range at a resolution
    /// 2, 4 or 8 times lower, where it is in range (`CoarseLevel`): a 4K
    /// frame's background bokeh is then as large as the lens makes it, where the database's
    /// largest PSF would be drawn instead. Thin lens and lens-motion only; off, such a
    /// fragment is drawn with the database's largest PSF (and counted as clamped).
    pub reduced_resolution: bool,
    /// With [`Self::reduced_resolution`], a CoC radius (px) above which a fragment is drawn at a
    /// reduced resolution even inside the database's range (the smallest scale that brings its
    /// CoC to this or below): a large PSF costs its spreadlets at the frame's resolution, a
    /// quarter of them or fewer at half of it, for a rim widened by about a pixel.
    /// `f32::INFINITY`: only beyond the database's range.
    pub coarse_above_px: f32,
    /// Layer still pixels hard and continue a surface that crosses from one depth layer into a
    /// nearer one under the nearer part, as far as its blur reaches
    /// (`layers::continue_across_layers`): "over" then finds the surface's own colour behind
    /// the nearer part's blurred edge, not the layers behind the surface, so there is no seam
    /// along the boundary. Soft layering draws none either, but a surface split between two
    /// layers is seen through by up to a quarter (its two parts composited "over" each
    /// other): a sphere in front of a grey wall greyed. Moving pixels are not continued (a
    /// copy would be smeared from beside them) and keep [`Self::soft_layers`]; nor are
    /// stochastic samples, deep samples and several render layers, which are not one surface
    /// per pixel, nor pixels seen through a real lens (measured: no gain on `rain`).
    pub continue_layers: bool,
    /// Through a real lens, draw the dense records that share a PSF and a quantised turn onto
    /// their radial direction from that PSF turned once per frame, upright (one add per pixel
    /// instead of four bilinear taps, and turned with a sharper cubic), the turn quantised so
    /// that the PSF's rim is at most 1/4 px from the record's own turn (`turned`). Off: every record drawn at its own turn.
    pub shared_turns: bool,
    /// In a layer whose sparse records are few, draw each from its PSF integrated once on its
    /// own small plane, so that the layer has no Laplacian plane to integrate (`few_sparse`).
    /// Off: every sparse record is splatted as spreadlets.
    pub few_sparse_images: bool,
    /// Keep the frame's own grey and RGB PSF images (the lens PSFs smeared along each moving
    /// pixel's motion) packed, as their rows' non-zero spans ([`Classified::packed`]), rather
    /// than in their boxes in the frame's database: a streak's box is mostly zeros, and tens
    /// of thousands of boxes cost more to fault in than to fill. For the CPU splat alone (the
    /// GPU path reads the database's images): [`crate::Renderer`] turns it on when it draws on
    /// the CPU. Off: written into the database.
    pub pack_images: bool,
    /// Through a real lens, scale each of a premixed pair's two PSFs onto the blend's own
    /// defocus before they are mixed, where both cells lie far enough from the focus plane
    /// (`turned`): the bokeh keeps one rim. Off: the two are mixed as they are, and their rims
    /// lie a cell's blur apart.
    pub scaled_blends: bool,
    /// Most values (pixels times channels) of the smeared PSF images one frame builds, summed
    /// ([`crate::motion_smear::MAX_FRAME_SMEARED_VALUES`] by default, 1 GiB of f32). A frame
    /// whose streaks need more (many distinct long motions: a car driving at the camera,
    /// reconstructed from stochastic samples) draws its longest streaks at half the
    /// resolution, then a quarter, an eighth, where [`Self::reduced_resolution`] allows it
    /// (counted in `reduced`); where it still needs more, or cannot be reduced (a real lens),
    /// classification fails with a clear error instead of allocating without bound.
    pub smeared_values_budget: usize,
    /// Reconstruction from frames of at least [`crate::sample_mean::MIN_SPP`] samples per
    /// pixel: lean each pixel towards its samples' plain mean where reconstruction departs
    /// from it by more than the samples' noise explains ([`crate::sample_mean`]), so that
    /// more samples bring the image closer to the scene's and not to reconstruction's own
    /// approximations. Off: reconstruction as drawn. Synthesis ignores it.
    pub lean_to_sample_means: bool,
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
            smear_motion: true,
            reduced_resolution: true,
            coarse_above_px: f32::INFINITY,
            continue_layers: true,
            shared_turns: true,
            few_sparse_images: true,
            pack_images: false,
            scaled_blends: true,
            smeared_values_budget: crate::motion_smear::MAX_FRAME_SMEARED_VALUES,
            lean_to_sample_means: true,
        }
    }
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
    classify_with(gbuffer, camera, Effects::of(camera, gbuffer), dbs, options)
}

/// [`classify`] with the effects already found ([`Effects::of`]).
pub(crate) fn classify_with(
    gbuffer: &GBuffer,
    camera: &Camera,
    effects: Effects,
    dbs: &DbSet,
    options: &ClassifyOptions,
) -> Result<Classified, ClassifyError> {
    classify_sizes(gbuffer, camera)?;
    if options.layers == 0 {
        return Err(ClassifyError::NoLayers);
    }
    check_passes(gbuffer, camera, None, false)?;
    let model = resolve_model(effects, dbs, options.smear_motion)?;
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
        false,
        &mut counts,
    );
    classify_fragments(
        fragments,
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
    classify_layers_with(
        layers,
        camera,
        layered_effects(layers, camera),
        dbs,
        options,
    )
}

/// [`classify_layers`] with the effects already found ([`layered_effects`]).
pub(crate) fn classify_layers_with(
    layers: &[ViewLayer],
    camera: &Camera,
    effects: Effects,
    dbs: &DbSet,
    options: &ClassifyOptions,
) -> Result<Classified, ClassifyError> {
    let first = check_layers_line_up(layers, camera)?;
    if options.layers == 0 {
        return Err(ClassifyError::NoLayers);
    }
    let model = resolve_model(effects, dbs, options.smear_motion)?;
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
                !opaque,
                &mut counts,
            )
            .into_iter()
            .map(|f| match f.source {
                hidden::VEIL_SOURCE | hidden::HIDDEN_SOURCE => f,
                _ => Fragment { source, ..f },
            }),
        );
    }
    classify_fragments(
        fragments,
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

/// The model that drives the lookups for `effects`: lens-motion or physical-lens from
/// `dbs.main`, else thin-lens; `None` when nothing needs simulating.
pub fn resolve_model(
    effects: Effects,
    dbs: &DbSet,
    smear_motion: bool,
) -> Result<Option<PsfModel>, ClassifyError> {
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
                // A physical-lens database smears its PSFs along the motion per frame, and a
                // thin-lens one does with `smear_motion`.
                PsfModel::LensMotion => {
                    found == PsfModel::LensMotion
                        || found == PsfModel::PhysicalLens
                        || (smear_motion && found == PsfModel::ThinLens)
                }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::types::SplatPath;

    /// A frame whose smears are too large says so once, however its chain of errors is printed.
    #[test]
    fn a_smear_error_is_told_once() {
        let e = ClassifyError::from(crate::motion_smear::SmearError::FrameTooLarge {
            keys: 3,
            pixels: 1 << 30,
            channels: 1,
            budget_values: 1 << 28,
        });
        assert!(std::error::Error::source(&e).is_none());
        let text = e.to_string();
        assert!(text.starts_with("motion blur: "), "{text}");
        assert_eq!(text.matches("smeared PSFs").count(), 1, "{text}");
    }

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
            // Every fragment here is nearly sharp: split them all, still as they are.
            soft_layers_min_blur_px: 0.0,
            continue_layers: false,
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
