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
        && space.dims().get(1).is_some_and(|d| d.min >= 0.0 && d.max > d.min);
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
