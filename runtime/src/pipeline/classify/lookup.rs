//! Each fragment's PSF in O(1) through the nested grid: the cell, the neighbouring cell it is
//! blended with across the cell boundary, the rotation onto the motion or the radial direction,
//! and the drawing path.

use super::*;
use crate::dbset::DbSet;
use crate::pipeline::types::SplatPath;
use psf_db::{CellMemo, PsfDatabase, PsfModel};

/// A fragment's PSF: its drawing path, index in the combined database, whether its
/// parameters were clamped to the database's range, and the rotation of the PSF's reference
/// direction (+x) onto the motion (lens-motion) or the radial direction (physical lens).
pub(super) struct Lookup {
    pub(super) path: SplatPath,
    pub(super) psf_index: u32,
    pub(super) clamped: bool,
    pub(super) rot_cos: f32,
    pub(super) rot_sin: f32,
    /// The neighbouring cell the PSF is blended with, if any.
    pub(super) blend: Option<Blend>,
    /// The share of the PSF drawn as its rotational average instead of turned (physical lens,
    /// near the optical axis: [`axis_share`]), 0 elsewhere.
    pub(super) round_share: f32,
}

/// The PSF of the eccentricity box across the first box's outer edge that a pixel near the
/// edge draws part of ([`first_box_edge`]).
#[derive(Clone, Copy)]
pub(super) struct AcrossEdge {
    pub(super) path: SplatPath,
    pub(super) psf_index: u32,
    /// Its cell's neighbour along inverse depth that it is blended with, as the pixel's own.
    pub(super) blend: Option<Blend>,
    /// Its share of the fragment's weight, in `(0, 0.5]`.
    pub(super) share: f32,
}

/// How far either side of the outer edge of a real lens's first eccentricity box a pixel
/// draws part of the PSF of the box across the edge ([`first_box_edge`]), mm on the sensor: 8
/// px of a 512 px frame 36 mm wide. In millimetres because the PSFs' shapes, and the ring
/// their difference leaves, scale with the frame's pixels per millimetre: at 1920 px the ring
/// was 12 px wide, and a band of 8 px left half of it.
pub(super) const FIRST_BOX_EDGE_BAND_MM: f32 = 0.5625;

/// The outer edges of a physical-lens database's first eccentricity boxes (one per depth
/// level of its grid, most often one in all), px from the optical axis at `pixels_per_mm`,
/// sorted, without repeats: a frame finds them once, so that a pixel far from all of them
/// ([`across_first_box_edge`]) does not look its cell's box up.
pub(super) fn first_box_edges_px(db: &PsfDatabase, pixels_per_mm: f32) -> Vec<f32> {
    let space = db.space();
    if space.dim_count() != 2 {
        return Vec::new();
    }
    let mut edges: Vec<f32> = (0..db.psf_count() as u32)
        .filter_map(|i| space.cell_box(i))
        .filter(|b| b.min[1] <= 0.0 && b.max[1] > b.min[1])
        .map(|b| b.max[1] as f32 * pixels_per_mm)
        .collect();
    edges.sort_by(f32::total_cmp);
    edges.dedup();
    edges
}

/// The PSF across the first eccentricity box's outer edge that a still pixel at `(x, y)`
/// (frame pixels; `centre` the frame's centre) through a real lens draws part of, at planar
/// `depth` in its cell `psf_index` of the combined database (`dbs.main`'s offset by
/// `dbs.main_offset`), and its share ([`first_box_edge`]); `None` beyond
/// [`FIRST_BOX_EDGE_BAND_MM`] of every edge in `edges_px` ([`first_box_edges_px`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn across_first_box_edge(
    dbs: &DbSet,
    psf_index: u32,
    (x, y): (i32, i32),
    depth: f32,
    centre: [f32; 2],
    pixels_per_mm: f32,
    edges_px: &[f32],
) -> Option<AcrossEdge> {
    let dx = x as f32 + 0.5 - centre[0];
    let dy = y as f32 + 0.5 - centre[1];
    let r = (dx * dx + dy * dy).sqrt();
    let band = FIRST_BOX_EDGE_BAND_MM * pixels_per_mm;
    let near = edges_px.iter().any(|&e| (e - r).abs() < band);
    if !near {
        return None;
    }
    let (db, all) = (dbs.main.as_ref()?, dbs.combined.as_ref()?);
    let offset = dbs.main_offset;
    let idx = psf_index.checked_sub(offset)?;
    let s = [1.0 / depth, r / pixels_per_mm];
    let (at, share) = first_box_edge(db, idx, s, r, pixels_per_mm)?;
    let (j, _, neighbour) = db.lookup_and_blend(at, 0);
    Some(AcrossEdge {
        path: path_of(all, j + offset),
        psf_index: j + offset,
        blend: neighbour.map(|(i, share)| Blend {
            path: path_of(all, i + offset),
            psf_index: i + offset,
            share,
        }),
        share,
    })
}

/// For a pixel `r_px` from the optical axis whose physical-lens cell is `idx` (parameters `s`:
/// inverse depth, eccentricity in mm; `pixels_per_mm` on the sensor), within
/// [`FIRST_BOX_EDGE_BAND_MM`] of the first eccentricity box's outer edge: the parameters to
/// look the box across the edge up at, and its share, `(1 - d / band) / 2` at `d` px from the
/// edge. A box's PSF is traced at the middle of its eccentricities, and the first box is the
/// widest (the boxes narrow outwards), its PSF the farthest from the lens's at its outer edge:
/// where it met the second box's, a flat wall through the double Gauss showed a ring up to 5 %
/// dark. Blended so, the PSF changes linearly across the band. The other boxes' edges differ
/// by a fraction of that and are left as they are: a band at every edge draws a quarter more
/// records.
pub(super) fn first_box_edge(
    db: &PsfDatabase,
    idx: u32,
    s: [f32; 2],
    r_px: f32,
    pixels_per_mm: f32,
) -> Option<([f32; 2], f32)> {
    let space = db.space();
    if space.dim_count() != 2 || !s[0].is_finite() {
        return None;
    }
    let b = space.cell_box(idx)?;
    let (lo, hi) = (b.min[1] as f32, b.max[1] as f32);
    let band = FIRST_BOX_EDGE_BAND_MM * pixels_per_mm;
    let (across, d_px) = if lo <= 0.0 {
        (hi * (1.0 + 1e-4), hi * pixels_per_mm - r_px)
    } else {
        let d_px = r_px - lo * pixels_per_mm;
        if !(0.0..band).contains(&d_px) {
            return None;
        }
        let below = lo * (1.0 - 1e-4);
        let (inner, _) = space.lookup([s[0], below]);
        if space.cell_box(inner)?.min[1] > 0.0 {
            return None;
        }
        (below, d_px)
    };
    if !(0.0..band).contains(&d_px) || hi <= lo {
        return None;
    }
    Some(([s[0], across], 0.5 * (1.0 - d_px / band)))
}

/// The second PSF of a blended lookup ([`ClassifyOptions::continuous_lookup`]).
#[derive(Clone, Copy)]
pub(super) struct Blend {
    pub(super) path: SplatPath,
    pub(super) psf_index: u32,
    /// Its share of the fragment's weight, in `(0, 0.5]`.
    pub(super) share: f32,
}

/// The PSF of `frag` (CoC `coc` and motion `motion_len`, pixels), O(1) through the nested
/// grid: still pixels from the thin-lens database, moving ones from the lens-motion one,
/// everything from a physical-lens one (whose moving fragments the caller then smears along
/// their motion, [`crate::motion_smear`]); copied when both are under
/// [`ClassifyOptions::copy_threshold_px`]. `centre` is the frame's centre, pixels. `memo`
/// remembers the thin-lens or physical-lens cell last found, for the next fragment's lookup.
#[allow(clippy::too_many_arguments)]
pub(super) fn lookup_psf(
    frag: &Fragment,
    coc: f32,
    motion_len: f32,
    centre: [f32; 2],
    pixels_per_mm: f32,
    dbs: &DbSet,
    model: Option<PsfModel>,
    options: &ClassifyOptions,
    continuous: bool,
    memo: &mut CellMemo,
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
    let mut round_share = 0.0;
    // The blend with PSF `j` of the combined database at `share`.
    let blend_with = |(j, share): (u32, f32)| Blend {
        path: combined.map_or(SplatPath::Copy, |all| path_of(all, j)),
        psf_index: j,
        share,
    };
    // The neighbour along `dim` that a continuous lookup blends the PSF of `s` with.
    let neighbour = |db: &PsfDatabase, s: [f32; 2], dim: usize, offset: u32| {
        if !continuous {
            return None;
        }
        let (i, share) = db.neighbour_blend(s, dim)?;
        Some(blend_with((i + offset, share)))
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
            let s = [1.0 / frag.depth, r / pixels_per_mm];
            let (idx, cl, neighbour) = db.lookup_and_blend_memo(s, memo);
            blend = neighbour
                .filter(|_| continuous)
                .map(|(i, share)| blend_with((i + offset, share)));
            round_share = axis_share(db, idx, r, pixels_per_mm);
            (path_of(all, idx + offset), idx + offset, cl)
        }
        (Some(_), _, Some(all))
            if coc >= options.copy_threshold_px || motion_len >= options.copy_threshold_px =>
        {
            let still = motion_len < options.copy_threshold_px;
            let mut thin_lookup = |t: &PsfDatabase| {
                let (i, clamped, neighbour) = t.lookup_blended_1d(coc, continuous, memo);
                blend = neighbour.map(blend_with);
                (i, clamped)
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
        round_share,
    }
}

/// The share of a physical-lens PSF to draw as its rotational average
/// ([`DbSet::axis_round`]) for a pixel `r_px` from the optical axis whose PSF is cell `idx` of
/// `db`: `1 - r / r_c` within the centre `r_c` of the first eccentricity box, 0 beyond. The
/// lens's PSF is round on the axis and turns lopsided with the eccentricity; the first box's
/// PSF stands for all of it.
pub(super) fn axis_share(db: &PsfDatabase, idx: u32, r_px: f32, pixels_per_mm: f32) -> f32 {
    let space = db.space();
    // A cell above the grid's first eccentricity box starts above the range's start, which
    // is not below zero: decided without turning grid units into millimetres.
    let above_first_box = space.grid().cell_box(idx).is_some_and(|g| g.min[1] > 0.0)
        && space
            .dims()
            .get(1)
            .is_some_and(|d| d.min >= 0.0 && d.max > d.min);
    if above_first_box {
        return 0.0;
    }
    let first_box = space.cell_box(idx).is_some_and(|b| b.min[1] <= 0.0);
    let Some(centre) = space.cell_center(idx).filter(|_| first_box) else {
        return 0.0;
    };
    let r_c = centre[1] as f32 * pixels_per_mm;
    if r_c <= 0.0 {
        return 0.0;
    }
    (1.0 - r_px / r_c).max(0.0)
}

/// Whether the databases' aperture looks different turned half a turn (an odd number of
/// blades, or a drawn image): then a fragment in front of the focus plane, whose PSF is the
/// aperture's image point-reflected, draws its PSF turned by pi. Disks, even polygons and
/// their anamorphic squeezes are symmetric under that turn and are drawn as they are (the
/// turn would only cost the exact pixel placement).
pub(super) fn front_turns_the_aperture(dbs: &DbSet) -> bool {
    let db = dbs.thin_lens.as_ref().or(dbs.main.as_ref());
    db.is_some_and(|db| {
        let a = &db.header().aperture;
        (a.blades >= 3 && a.blades % 2 == 1) || a.image_hash != 0
    })
}

pub(super) fn path_of(db: &PsfDatabase, idx: u32) -> SplatPath {
    if db.dense(idx as usize).is_some() {
        SplatPath::Dense
    } else {
        SplatPath::Sparse
    }
}
