//! What classification hands to the drawing stages of either device: the buffer records, the
//! frame's constants, the per-layer summary, and each PSF's reach.
//!
//! [`SplatRecord`] and [`FrameParams`] are `#[repr(C)]` and `bytemuck::Pod`; their WGSL twins
//! live in `shaders/common.wgsl` with the same field order. Change both or neither.

use bytemuck::{Pod, Zeroable};
use psf_db::PsfDatabase;

use super::packed::PackedImages;

/// One pixel (or one stochastic sample) after classification: where its PSF is centred, which
/// database PSF it uses, which layer it goes to and with what colour.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct SplatRecord {
    /// PSF centre in padded-layer pixel coordinates (x right), integer pixel.
    pub center_x: i32,
    /// PSF centre in padded-layer pixel coordinates (y down), integer pixel.
    pub center_y: i32,
    /// Index of the nearest database PSF (nested-grid cell).
    pub psf_index: u32,
    /// Destination layer, 0 = farthest.
    pub layer: u32,
    /// Cosine of the rotation from the database's reference direction (+x) to the motion.
    pub rot_cos: f32,
    /// Sine of that rotation (y down, so positive turns +x towards +y).
    pub rot_sin: f32,
    /// Weight of this record (soft layering splits a pixel into two records; stochastic
    /// samples of one pixel share its weight). Already folded into `color`; kept for stats.
    pub weight: f32,
    /// Which path draws it: see [`SplatPath`].
    pub path: u32,
    /// Premultiplied linear RGBA times `weight`.
    pub color: [f32; 4],
}

/// How a record is drawn.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SplatPath {
    /// Sparse spreadlets into the layer's Laplacian image.
    Sparse = 0,
    /// Dense fast-track PSF into the layer's direct image.
    Dense = 1,
    /// PSF under a pixel: the colour is copied into the layer's direct image.
    Copy = 2,
}

/// Per-frame constants.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct FrameParams {
    /// Output image width in pixels.
    pub width: u32,
    /// Output image height in pixels.
    pub height: u32,
    /// Padding added on every side of each layer, pixels (the largest PSF extent).
    pub pad: u32,
    /// Number of depth layers.
    pub layers: u32,
    /// `width + 2 * pad`.
    pub padded_width: u32,
    /// `height + 2 * pad`.
    pub padded_height: u32,
    /// Number of [`SplatRecord`]s.
    pub record_count: u32,
    /// Colour channels per spreadlet value in the database (1 or 3).
    pub db_channels: u32,
}

impl FrameParams {
    /// A `width x height` frame (pixels) of `layers` depth layers padded by `pad` pixels on
    /// every side; no records yet, one colour channel per spreadlet value.
    pub fn padded(width: u32, height: u32, pad: u32, layers: u32) -> Self {
        Self {
            width,
            height,
            pad,
            layers,
            padded_width: width + 2 * pad,
            padded_height: height + 2 * pad,
            record_count: 0,
            db_channels: 1,
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
    /// Records added beyond the input's outermost pixels ([`super::FrameEdges::Extend`]; also in
    /// the path counts).
    pub edge_extended: usize,
    /// Moving fragments drawn with their lens PSF smeared along their own motion (through a
    /// real lens, or the thin lens with [`super::ClassifyOptions::smear_motion`]; also in
    /// `dense`).
    pub smeared: usize,
    /// Fragments of background continued behind sharper occluders
    /// ([`super::ClassifyOptions::fill_hidden`]).
    pub hidden_filled: usize,
    /// Fragments drawn at a reduced resolution (`Classified::coarse`): their blur is beyond the
    /// database's range, or above `ClassifyOptions::coarse_above_px` (also in the path counts).
    pub reduced: usize,
    /// Dense records drawn upright from their PSF turned once per frame onto a quantised
    /// radial direction that other records share ([`super::ClassifyOptions::shared_turns`];
    /// also in `dense`).
    pub turned: usize,
    /// Sparse records drawn from their PSF's image, in layers whose few sparse records cost
    /// less drawn so than the layer's integration
    /// ([`super::ClassifyOptions::few_sparse_images`]; also in `dense`).
    pub sparse_as_images: usize,
}

impl PathCounts {
    /// Adds a layer's counts per path.
    pub fn add_layer(&mut self, info: &LayerInfo) {
        self.sparse += info.sparse;
        self.dense += info.dense;
        self.copied += info.copied;
    }
}

/// Output of classification ([`super::classify::classify`]): the records every device
/// draws.
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
    /// The database the records index when it is not the set's combined one: the combined
    /// PSFs followed by this frame's own (the physical-lens PSFs of its moving pixels smeared
    /// along their motion, [`crate::motion_smear`]). `None`: the set's combined database.
    pub database: Option<std::sync::Arc<PsfDatabase>>,
    /// Images of `database` kept packed ([`super::packed::PackedImages`]; each an empty image
    /// there, its box read with [`frame_psf_reach`]), drawn by the CPU splat. `None`: every
    /// image is in the database.
    pub packed: Option<std::sync::Arc<super::packed::PackedImages>>,
    /// The fragments whose CoC or motion is beyond the database's range, at reduced
    /// resolutions ([`super::ClassifyOptions::reduced_resolution`]), each level a frame of
    /// its own in the same depth layers; empty when every fragment is in range.
    pub coarse: Vec<CoarseLevel>,
}

/// The records of the fragments drawn `scale` times smaller than the frame: a fragment of
/// frame pixel `(x, y)` is centred on the coarse pixel `(x div scale, y div scale)`, with its
/// CoC and motion divided by `scale` and its colour by `scale^2` (a coarse pixel covers
/// `scale^2` frame pixels), so that the coarse layers, integrated and upsampled bilinearly
/// ([`super::integrate::add_upsampled`]), add the same light as the frame's own would.
#[derive(Clone, Debug, PartialEq)]
pub struct CoarseLevel {
    /// Frame pixels per coarse pixel along each axis: 2, 4 or 8.
    pub scale: u32,
    /// The level's records, `ceil(width / scale) x ceil(height / scale)` pixels, padded as
    /// its own PSFs need, with the frame's layers.
    pub classified: Classified,
}

impl Classified {
    /// The database the records index: the frame's own, else `combined` (the set's).
    pub fn database_or<'a>(&'a self, combined: Option<&'a PsfDatabase>) -> Option<&'a PsfDatabase> {
        self.database.as_deref().or(combined)
    }
}

/// For every PSF of `db`, the largest distance (px, rounded up, plus one) of any of its
/// spreadlets or dense pixels from its centre.
pub fn psf_reach(db: &PsfDatabase) -> Vec<i32> {
    (0..db.psf_count())
        .map(|i| {
            let r2 = match db.dense(i) {
                Some(d) => box_corner_distance_sq(d.origin, d.width, d.height),
                None => db
                    .spreadlets(i)
                    .0
                    .iter()
                    .map(|p| i32::from(p[0]).pow(2) + i32::from(p[1]).pow(2))
                    .max()
                    .unwrap_or(0),
            };
            (f64::from(r2).sqrt().ceil() as i32) + 1
        })
        .collect()
}

/// Squared distance (px^2) from a PSF's centre to the farthest corner pixel of its image's
/// box: `origin` its top-left pixel, `width x height` px.
fn box_corner_distance_sq(origin: [i32; 2], width: usize, height: usize) -> i32 {
    let xs = [origin[0], origin[0] + width as i32 - 1];
    let ys = [origin[1], origin[1] + height as i32 - 1];
    let mx = xs.iter().map(|x| x.abs()).max().unwrap_or(0);
    let my = ys.iter().map(|y| y.abs()).max().unwrap_or(0);
    mx * mx + my * my
}

/// [`psf_reach`] of a frame's database whose images kept packed (`packed`) are empty boxes
/// there: a packed image's reach is its own box's.
pub fn frame_psf_reach(db: &PsfDatabase, packed: Option<&PackedImages>) -> Vec<i32> {
    let mut reach = psf_reach(db);
    for (psf, image) in packed.into_iter().flat_map(PackedImages::images) {
        if let Some(r) = reach.get_mut(psf as usize) {
            let r2 = box_corner_distance_sq(image.origin(), image.image.width, image.height());
            *r = (f64::from(r2).sqrt().ceil() as i32) + 1;
        }
    }
    reach
}

/// [`PsfDatabase::max_extent_px`] of a frame's database whose images kept packed (`packed`)
/// are empty boxes there: the farthest any of its PSFs reaches from its centre, px, the
/// packed images' boxes included.
pub fn frame_extent_px(db: &PsfDatabase, packed: Option<&PackedImages>) -> u32 {
    let packed_extent = packed
        .into_iter()
        .flat_map(PackedImages::images)
        .filter(|(_, image)| image.image.width > 0 && image.height() > 0)
        .map(|(_, image)| {
            let r2 = box_corner_distance_sq(image.origin(), image.image.width, image.height());
            f64::from(r2).sqrt().ceil() as u32
        })
        .max()
        .unwrap_or(0);
    db.max_extent_px().max(packed_extent)
}
