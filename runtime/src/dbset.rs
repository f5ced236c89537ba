//! The databases one synthesis uses, and their concatenation that the splat stage reads.
//!
//! "Simulate only what the scene calls for" holds per pixel: in a frame with motion blur, the
//! pixels that do not move are looked up in the thin-lens database (fine steps in CoC) and only
//! the moving ones in the lens-motion database (whose first cells in motion length are many
//! pixels wide). The splat stage, CPU or GPU, sees one database: the thin-lens PSFs first, then
//! the other database's, so a [`crate::pipeline::SplatRecord::psf_index`] addresses either.

use psf_db::{DatabaseBuilder, DbError, DbHeader, DenseShape, ParamSpace, PsfDatabase, PsfModel};

/// The databases of one synthesis.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DbSet {
    /// Thin-lens database: defocus alone, and the still pixels of a frame with motion.
    pub thin_lens: Option<PsfDatabase>,
    /// Lens-motion database (moving pixels) or physical-lens database (every pixel).
    pub main: Option<PsfDatabase>,
    /// What the splat stage reads: `thin_lens` then `main`, concatenated.
    pub combined: Option<PsfDatabase>,
    /// Index of `main`'s first PSF in `combined`.
    pub main_offset: u32,
    /// For each PSF of `combined`: the index (in `combined`) of its first dense twin, or
    /// `NO_TWIN`. Twins are the analytic PSF pre-filtered over the same cell
    /// (`condition::analytic_cell_psf`), or for small PSFs over each of its sub-cells
    /// ([`DbSet::hdr_twin_cells`]), made for the thin-lens and lens-motion models with a
    /// circular aperture; for a sparse physical-lens PSF, the image its spreadlets integrate
    /// to with their negative residue clamped. Very bright (HDR) pixels are drawn with them:
    /// a sparse PSF's small relative error, multiplied by a highlight of 100, shows as dark
    /// holes and haze beside it (the comets example: SSIM 0.9710 without, see
    /// docs/BENCHMARKS.md), and a PSF pre-filtered over a whole cell as a soft blob larger
    /// than the highlight's own bokeh.
    pub hdr_twins: Vec<u32>,
    /// For each PSF of `combined` with twins: its cell in the source database's parameters
    /// (CoC radius px, motion length px) and how many sub-cells per axis its twins cover. The
    /// twin of the sub-cell holding a fragment's own parameters is
    /// [`DbSet::hdr_twin_for`]; a twin pre-filtered over the whole cell would draw a small
    /// highlight's bokeh as a soft blob up to the cell's largest PSF.
    pub hdr_twin_cells: Vec<Option<TwinCell>>,
    /// For each PSF `i` of `combined`: the index (in `combined`) of the first of its
    /// [`BLEND_STEPS`] premixed blends with PSF `i - 1` (`[0]`) and with PSF `i + 1` (`[1]`),
    /// or `NO_TWIN`. Made for neighbouring dense thin-lens PSFs: blend `k` (from 1) is
    /// `(1 - s) P_i + s P_j` with `s = k / (2 BLEND_STEPS)`, so that a blended fragment
    /// ([`crate::ClassifyOptions::continuous_lookup`]) is one record instead of two.
    pub dense_blends: Vec<[u32; 2]>,
    /// For each PSF of `combined`: the index (in `combined`) of its rotational average where
    /// it is a physical-lens PSF of the first eccentricity box (the optical axis), else
    /// `NO_TWIN`. Drawn turned onto each pixel's radial direction, a PSF that is not round
    /// leaves the pixels round the axis short of light: each receives only its neighbours'
    /// PSFs along their radial direction (a flat wall through the double Gauss came out 2.5 %
    /// dark over 4 px round the axis). The lens's own PSF on the axis is round, so pixels near
    /// it draw this average (`pipeline::classify`, "axis").
    pub axis_round: Vec<u32>,
}

/// Premixed shares per neighbouring pair of dense PSFs ([`DbSet::dense_blends`]): a blend's
/// share in `(0, 1/2]` is drawn as the nearest step `k / (2 BLEND_STEPS)`. Rounded, not
/// dithered: a per-pixel dither of the share summed neighbours' PSFs of different steps at
/// each pixel, which left noise and a level 0.09 % low on a flat wall (FLIP mean 0.0087 ->
/// 0.0119 on the fast box); rounded, the image is within 95 dB of the two records' blend.
pub const BLEND_STEPS: u32 = 32;

/// The cell a PSF's HDR twins divide (see [`DbSet::hdr_twin_cells`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TwinCell {
    /// Lower corner: CoC radius px, motion length px.
    pub min: [f64; 2],
    /// Upper corner.
    pub max: [f64; 2],
    /// Sub-cells per axis (1 where the axis is unused or the PSF is large).
    pub splits: [u32; 2],
}

impl TwinCell {
    /// The sub-cell holding `params` (CoC radius px, motion length px), row-major; clamped.
    pub fn sub_index(&self, params: [f32; 2]) -> u32 {
        let along = |k: usize| -> u32 {
            let n = self.splits[k];
            let span = self.max[k] - self.min[k];
            if n <= 1 || span <= 0.0 {
                return 0;
            }
            let t = (f64::from(params[k]) - self.min[k]) / span;
            ((t * f64::from(n)).floor().max(0.0) as u32).min(n - 1)
        };
        along(1) * self.splits[0] + along(0)
    }
}

/// [`DbSet::hdr_twins`] entry of a PSF without a twin.
pub const NO_TWIN: u32 = u32::MAX;

impl DbSet {
    /// No database (nothing to simulate).
    pub fn none() -> Self {
        Self::default()
    }

    /// A set of one or two databases. `thin_lens` must be a thin-lens database (or `None`).
    pub fn new(thin_lens: Option<PsfDatabase>, main: Option<PsfDatabase>) -> Result<Self, DbError> {
        Self::with_axis(thin_lens, main, None)
    }

    /// A physical-lens database `main` and `axis`, its lens's PSFs on the optical axis, one
    /// per inverse-depth box of `main` (`dbcache::axis_config`): the pixels near the axis draw
    /// the rotational average of those ([`DbSet::axis_round`]) instead of that of their first
    /// eccentricity box's PSF, traced off the axis at the box's middle.
    pub fn physical(main: PsfDatabase, axis: Option<PsfDatabase>) -> Result<Self, DbError> {
        if let Some(axis) = &axis {
            let depths = |db: &PsfDatabase| db.space().dims().first().map(|d| (d.min, d.max));
            let matches = main.model() == PsfModel::PhysicalLens
                && axis.model() == PsfModel::PhysicalLens
                && depths(&main) == depths(axis)
                && on_axis_cells(&main) == axis.psf_count();
            if !matches {
                return Err(DbError::Invalid(
                    "the PSFs on the axis are not of the physical-lens database's depths".into(),
                ));
            }
        }
        Self::with_axis(None, Some(main), axis.as_ref())
    }

    fn with_axis(
        thin_lens: Option<PsfDatabase>,
        main: Option<PsfDatabase>,
        axis: Option<&PsfDatabase>,
    ) -> Result<Self, DbError> {
        if let Some(t) = &thin_lens {
            if t.model() != PsfModel::ThinLens {
                return Err(DbError::Invalid(format!(
                    "the still-pixel database must be thin-lens, not {}",
                    t.model().name()
                )));
            }
        }
        let sources: Vec<&PsfDatabase> = thin_lens.iter().chain(main.iter()).collect();
        let main_offset = match (&thin_lens, &main) {
            (Some(t), Some(_)) => t.psf_count() as u32,
            _ => 0,
        };
        let base: usize = sources.iter().map(|d| d.psf_count()).sum();
        let mut hdr_twins = vec![NO_TWIN; base];
        let mut hdr_twin_cells = vec![None; base];
        let mut twins = Vec::new();
        let mut first = 0usize;
        // The combined database keeps the last one's header, so its PSF bound.
        let bound = sources
            .last()
            .map_or(0, |d| d.header().psf_resolution as i32);
        for db in &sources {
            for (i, twin) in dense_twins(db, bound).into_iter().enumerate() {
                if let Some((cell, images)) = twin {
                    hdr_twins[first + i] = (base + twins.len()) as u32;
                    hdr_twin_cells[first + i] = Some(cell);
                    twins.extend(images);
                }
            }
            first += db.psf_count();
        }
        // The still pixels' blends of neighbouring dense PSFs, premixed: the thin-lens PSFs
        // come first in `combined`.
        let mut dense_blends = vec![[NO_TWIN; 2]; base];
        if let Some(thin) = &thin_lens {
            for (i, sides) in premixed_blends(thin).into_iter().enumerate() {
                for (side, images) in sides.into_iter().enumerate() {
                    if let Some(images) = images {
                        dense_blends[i][side] = (base + twins.len()) as u32;
                        twins.extend(images);
                    }
                }
            }
        }
        // The rotational averages of the physical-lens PSFs on the axis.
        let mut axis_round = vec![NO_TWIN; base];
        if let Some(m) = main
            .as_ref()
            .filter(|m| m.model() == PsfModel::PhysicalLens)
        {
            for (i, image) in round_on_axis(m, axis).into_iter().enumerate() {
                if let Some(image) = image {
                    axis_round[main_offset as usize + i] = (base + twins.len()) as u32;
                    twins.push(image);
                }
            }
        }
        let combined = match sources.as_slice() {
            [] => None,
            [one] if twins.is_empty() => Some((*one).clone()),
            _ => Some(concatenate(&sources, &twins)?),
        };
        // Row order lets the CPU splat visit only the spreadlets of each band of rows.
        let combined = combined.map(PsfDatabase::into_spreadlets_in_row_order);
        Ok(Self {
            thin_lens,
            main,
            combined,
            main_offset,
            hdr_twins,
            hdr_twin_cells,
            dense_blends,
            axis_round,
        })
    }

    /// The premixed blend (index in `combined`) that draws `(1 - share)` of PSF `psf_index`
    /// and `share` of its neighbour `neighbour`, the share rounded to the nearest step of
    /// `1 / (2 BLEND_STEPS)`; `psf_index` itself where it rounds to 0; `None` where the pair
    /// has no premixed blends.
    pub fn dense_blend_for(&self, psf_index: u32, neighbour: u32, share: f32) -> Option<u32> {
        let side = if neighbour == psf_index.checked_add(1)? {
            1
        } else if neighbour.checked_add(1)? == psf_index {
            0
        } else {
            return None;
        };
        let first = self.dense_blends.get(psf_index as usize)?[side];
        if first == NO_TWIN {
            return None;
        }
        let steps = 2 * BLEND_STEPS;
        let k = ((share * steps as f32).round().max(0.0) as u32).min(BLEND_STEPS);
        Some(if k == 0 { psf_index } else { first + k - 1 })
    }

    /// The HDR twin (index in `combined`) of PSF `psf_index` for a fragment of parameters
    /// `params` (CoC radius px, motion length px), or `NO_TWIN`.
    pub fn hdr_twin_for(&self, psf_index: u32, params: [f32; 2]) -> u32 {
        let i = psf_index as usize;
        match (self.hdr_twins.get(i), self.hdr_twin_cells.get(i)) {
            (Some(&first), Some(Some(cell))) if first != NO_TWIN => first + cell.sub_index(params),
            (Some(&first), _) => first,
            _ => NO_TWIN,
        }
    }

    /// A set of one database, of any model.
    pub fn single(db: PsfDatabase) -> Result<Self, DbError> {
        if db.model() == PsfModel::ThinLens {
            Self::new(Some(db), None)
        } else {
            Self::new(None, Some(db))
        }
    }

    /// The model names in the set.
    pub fn models(&self) -> Vec<&'static str> {
        self.thin_lens
            .iter()
            .chain(self.main.iter())
            .map(|d| d.model().name())
            .collect()
    }
}

/// A dense PSF image: offset of its top-left pixel from the centre (px), width, height, and
/// one value per pixel (broadcast to the database's channels) or per pixel and channel
/// (channel-interleaved).
type DenseImage = ([i16; 2], u16, u16, Vec<f32>);

/// `db` followed by one dense image of zeros per `(origin, width, height)` of `boxes` (origin:
/// top-left pixel from the centre, px; `db`'s channel count), whose values the caller writes
/// in place ([`psf_db::DenseExtension::fill`]); the images' indices follow `db`'s PSFs in
/// order, and `db`'s PSFs are kept as stored.
pub fn extend_with_dense(
    db: &PsfDatabase,
    boxes: &[([i32; 2], usize, usize)],
) -> Result<psf_db::DenseExtension, DbError> {
    let mut shapes = Vec::with_capacity(boxes.len());
    for &(origin, width, height) in boxes {
        let shape = || {
            Some(DenseShape {
                origin: [
                    i16::try_from(origin[0]).ok()?,
                    i16::try_from(origin[1]).ok()?,
                ],
                width: u16::try_from(width).ok()?,
                height: u16::try_from(height).ok()?,
            })
        };
        let Some(shape) = shape() else {
            return Err(DbError::Invalid(format!(
                "a {width} x {height} PSF image at {origin:?} does not fit the format's sizes"
            )));
        };
        shapes.push(shape);
    }
    let header = combined_header(&[db], &shapes)?;
    let empty = header.stored_psf_count() - db.psf_count() - shapes.len();
    psf_db::DenseExtension::new(db, header, &shapes, empty)
}

/// `img` in the database's dense form, or `None` where its size or origin does not fit the
/// format's fields (u16 sizes, i16 origin).
fn into_dense_image(img: crate::motion_smear::PsfImage) -> Option<DenseImage> {
    Some((
        [
            i16::try_from(img.origin[0]).ok()?,
            i16::try_from(img.origin[1]).ok()?,
        ],
        u16::try_from(img.width).ok()?,
        u16::try_from(img.height).ok()?,
        img.data,
    ))
}

/// Largest twin image (pixels) whose cell is divided into sub-cells: the blob a whole-cell
/// twin draws shows most on small highlights, and large twins would multiply memory and load
/// time.
const SUBDIVIDED_TWIN_MAX_PIXELS: usize = 64 * 64;

/// Sub-cells per axis of a divided twin cell.
const TWIN_SPLITS: u32 = 3;

/// The dense twins of `db`'s sparse PSFs (see [`DbSet::hdr_twins`]): per PSF its cell and the
/// twins of its sub-cells in row-major order; `None` where a PSF is empty, of a model or
/// aperture the analytic PSF does not describe (bladed, anamorphic or drawn), or where a twin would reach beyond
/// `bound` px from the centre (the database's PSF resolution).
fn dense_twins(db: &PsfDatabase, bound: i32) -> Vec<Option<(TwinCell, Vec<DenseImage>)>> {
    use rayon::prelude::*;
    let analytic = matches!(db.model(), PsfModel::ThinLens | PsfModel::LensMotion)
        && db.header().aperture.blades == 0
        && db.header().aperture.ratio == 1.0
        && db.header().aperture.image_hash == 0;
    let motion = db.model() == PsfModel::LensMotion;
    if db.model() == PsfModel::PhysicalLens {
        return physical_twins(db);
    }
    (0..db.psf_count())
        .into_par_iter()
        .map(|i| {
            if !analytic || (db.dense(i).is_none() && db.spreadlets(i).0.is_empty()) {
                return None;
            }
            let cell = db.space().cell_box(i as u32)?;
            let len = if motion {
                (cell.min[1], cell.max[1])
            } else {
                (0.0, 0.0)
            };
            let coc = (cell.min[0], cell.max[0]);
            let fits = |twin: &DenseImage| {
                let (origin, w, h) = (twin.0, i32::from(twin.1), i32::from(twin.2));
                i32::from(origin[0]) >= -bound
                    && i32::from(origin[1]) >= -bound
                    && i32::from(origin[0]) + w - 1 <= bound
                    && i32::from(origin[1]) + h - 1 <= bound
            };
            let whole = crate::condition::analytic_cell_psf(coc, len);
            if !fits(&whole) {
                return None;
            }
            let small = usize::from(whole.1) * usize::from(whole.2) <= SUBDIVIDED_TWIN_MAX_PIXELS;
            let splits = match (small, motion) {
                (false, _) => [1, 1],
                (true, true) => [TWIN_SPLITS, TWIN_SPLITS],
                (true, false) => [TWIN_SPLITS, 1],
            };
            let twin_cell = TwinCell {
                min: [coc.0, len.0],
                max: [coc.1, len.1],
                splits,
            };
            if splits == [1, 1] {
                return Some((twin_cell, vec![whole]));
            }
            let part = |lo: f64, hi: f64, k: u32, n: u32| {
                let step = (hi - lo) / f64::from(n);
                (lo + step * f64::from(k), lo + step * f64::from(k + 1))
            };
            let mut images = Vec::with_capacity((splits[0] * splits[1]) as usize);
            for j in 0..splits[1] {
                for k in 0..splits[0] {
                    let sub_coc = part(coc.0, coc.1, k, splits[0]);
                    let sub_len = part(len.0, len.1, j, splits[1]);
                    let twin = crate::condition::analytic_cell_psf(sub_coc, sub_len);
                    if !fits(&twin) {
                        return None;
                    }
                    images.push(twin);
                }
            }
            Some((twin_cell, images))
        })
        .collect()
}

/// For each PSF `i` of a thin-lens `db`, its premixed blends with PSF `i - 1` and with PSF
/// `i + 1` ([`DbSet::dense_blends`]) where both are dense and of one channel count: the
/// [`BLEND_STEPS`] images `(1 - s) P_i + s P_j` over the union of their boxes.
fn premixed_blends(db: &PsfDatabase) -> Vec<[Option<Vec<DenseImage>>; 2]> {
    let count = db.psf_count();
    let blends = |i: usize, j: usize| -> Option<Vec<DenseImage>> {
        let (a, b) = (db.dense(i)?, db.dense(j)?);
        if a.channels != b.channels {
            return None;
        }
        let c = a.channels;
        let x0 = a.origin[0].min(b.origin[0]);
        let y0 = a.origin[1].min(b.origin[1]);
        let x1 = (a.origin[0] + a.width as i32).max(b.origin[0] + b.width as i32);
        let y1 = (a.origin[1] + a.height as i32).max(b.origin[1] + b.height as i32);
        let (w, h) = ((x1 - x0) as usize, (y1 - y0) as usize);
        // Each image placed in the union box.
        let placed = |v: &psf_db::DenseView| {
            let mut out = vec![0.0f32; w * h * c];
            for y in 0..v.height {
                let row = (y as i32 + v.origin[1] - y0) as usize;
                for x in 0..v.width {
                    let col = (x as i32 + v.origin[0] - x0) as usize;
                    let (from, to) = ((y * v.width + x) * c, (row * w + col) * c);
                    out[to..to + c].copy_from_slice(&v.data[from..from + c]);
                }
            }
            out
        };
        let (pa, pb) = (placed(&a), placed(&b));
        let origin = [i16::try_from(x0).ok()?, i16::try_from(y0).ok()?];
        let size = (u16::try_from(w).ok()?, u16::try_from(h).ok()?);
        Some(
            (1..=BLEND_STEPS)
                .map(|k| {
                    let s = k as f32 / (2 * BLEND_STEPS) as f32;
                    let data = pa
                        .iter()
                        .zip(&pb)
                        .map(|(&p, &q)| (1.0 - s) * p + s * q)
                        .collect();
                    (origin, size.0, size.1, data)
                })
                .collect(),
        )
    };
    (0..count)
        .map(|i| {
            let lower = i.checked_sub(1).and_then(|j| blends(i, j));
            let upper = (i + 1 < count).then(|| blends(i, i + 1)).flatten();
            [lower, upper]
        })
        .collect()
}

/// The dense twins of a physical-lens database's sparse PSFs: each the image its spreadlets
/// integrate to, with the sparse fit's negative residue clamped
/// ([`crate::motion_smear::psf_image`]): no analytic PSF describes a real lens, and a bright
/// drop times a negative residue draws dark specks around its bokeh. One twin per cell (the
/// cell is not divided).
fn physical_twins(db: &PsfDatabase) -> Vec<Option<(TwinCell, Vec<DenseImage>)>> {
    use rayon::prelude::*;
    (0..db.psf_count())
        .into_par_iter()
        .map(|i| {
            if db.dense(i).is_some() {
                return None;
            }
            let image = into_dense_image(crate::motion_smear::psf_image(db, i)?)?;
            let cell = TwinCell {
                min: [0.0; 2],
                max: [0.0; 2],
                splits: [1, 1],
            };
            Some((cell, vec![image]))
        })
        .collect()
}

/// Turns over which a PSF on the optical axis is averaged ([`DbSet::axis_round`]). The first
/// eccentricity box's PSFs are nearly round, so eight turns leave a flat wall through the
/// double Gauss as even on the axis as 32 did (within 2 px of it 0.9953 against 0.9952 of the
/// wall's level at 3 m, 0.9943 against 0.9942 at 0.6 m), at a quarter of the cost a process
/// pays when it loads the database (14 ms -> 4 ms on 2 cores).
const AXIS_TURNS: u32 = 8;

/// Whether cell `i` of a physical-lens `db` starts at eccentricity 0 (its first eccentricity
/// box, whose PSFs are drawn as rotational averages near the axis).
pub fn starts_on_axis(db: &PsfDatabase, i: u32) -> bool {
    db.space().cell_box(i).is_some_and(|b| b.min[1] <= 0.0)
}

/// How many cells of a physical-lens `db` start at eccentricity 0: one per inverse-depth box.
pub fn on_axis_cells(db: &PsfDatabase) -> usize {
    (0..db.psf_count() as u32)
        .filter(|&i| starts_on_axis(db, i))
        .count()
}

/// For each PSF of a physical-lens `db` whose cell starts at eccentricity 0: its average over
/// [`AXIS_TURNS`] turns (each by [`crate::motion_smear::turn`]), over the union of their boxes;
/// with `axis` (the lens's PSFs on the axis, one per inverse-depth box), the average of the PSF
/// of `axis` at the cell's inverse depth instead. A PSF traced at the first box's middle (2.7
/// mm off axis through the double Gauss at 512 px) is lopsided already, and its average drew
/// an axial drop's rim 0.5 px softer than the lens does.
fn round_on_axis(db: &PsfDatabase, axis: Option<&PsfDatabase>) -> Vec<Option<DenseImage>> {
    use crate::motion_smear::{psf_image, turn, PsfImage};
    use rayon::prelude::*;
    (0..db.psf_count())
        .into_par_iter()
        .map(|i| {
            if !starts_on_axis(db, i as u32) {
                return None;
            }
            let psf = match axis {
                Some(axis) => {
                    let centre = db.space().cell_center(i as u32)?;
                    let (k, _) = axis.space().lookup([centre[0] as f32, 0.0]);
                    psf_image(axis, k as usize)?
                }
                None => psf_image(db, i)?,
            };
            let turned: Vec<PsfImage> = (0..AXIS_TURNS)
                .map(|k| turn(&psf, k as f32 * std::f32::consts::TAU / AXIS_TURNS as f32))
                .collect();
            let share = 1.0 / AXIS_TURNS as f32;
            let weighted: Vec<(&PsfImage, f32)> = turned.iter().map(|t| (t, share)).collect();
            into_dense_image(crate::motion_smear::weighted_sum(&weighted)?)
        })
        .collect()
}

/// The header of a database holding the PSFs of `dbs` in order, then dense images of shapes
/// `extra`: the last database's, with a one-dimensional index space large enough for all,
/// labelled thin-lens (lookups are never made in it; unused trailing cells are empty PSFs),
/// and a PSF bound that reaches every image.
fn combined_header(dbs: &[&PsfDatabase], extra: &[DenseShape]) -> Result<DbHeader, DbError> {
    let Some(last) = dbs.last() else {
        return Err(DbError::Invalid("no database to combine".into()));
    };
    let channels = last.channels();
    let total = (dbs.iter().map(|d| d.psf_count()).sum::<usize>() + extra.len()) as u32;
    // The combined database's space only indexes its PSFs (lookups go through the sources'
    // own spaces): one dimension while a 1-D nested grid holds them (at most 361 cells), two
    // beyond (the paper profile's 404 lens-motion PSFs plus their HDR twins).
    // RGB PSFs (a real lens's) keep their model's label, whose space is two-dimensional.
    let range = [0.0, f64::from(total)];
    let one_dimension = ParamSpace::resolution_for_count(1, total).filter(|_| channels == 1);
    let model = match one_dimension {
        Some(_) => PsfModel::ThinLens,
        None if channels == 1 => PsfModel::LensMotion,
        None => PsfModel::PhysicalLens,
    };
    let space = match one_dimension {
        Some(n) => ParamSpace::for_model(model, &[range], n),
        None => {
            let n = ParamSpace::resolution_for_count(2, total)
                .ok_or_else(|| DbError::Invalid(format!("no index space holds {total} PSFs")))?;
            ParamSpace::for_model(model, &[range, range], n)
        }
    }
    .map_err(|e| DbError::Invalid(e.to_string()))?;
    let capacity = space.psf_count();
    let mut header: DbHeader = last.header().clone();
    header.model = model;
    // The extra images (twins, PSFs smeared along a motion) may reach beyond the sources' PSF
    // bound, which the file format checks every dense PSF against.
    for shape in extra {
        let (x0, y0) = (i32::from(shape.origin[0]), i32::from(shape.origin[1]));
        let (w, h) = (i32::from(shape.width), i32::from(shape.height));
        let reach = [x0, y0, x0 + w - 1, y0 + h - 1]
            .into_iter()
            .map(i32::unsigned_abs)
            .max()
            .unwrap_or(0);
        header.psf_resolution = header.psf_resolution.max(reach);
    }
    header.space = space;
    header.stats = dbs
        .iter()
        .flat_map(|d| d.header().stats.iter().copied())
        .collect();
    let filler = header.stats.last().copied().unwrap_or(psf_db::PsfStats {
        coords: [0.0; 2],
        spreadlets: 0,
        dense_support: 0,
        l1: 0.0,
        ssim: 0.0,
        extent_px: 0.0,
    });
    header.stats.resize(capacity as usize, filler);
    Ok(header)
}

/// The PSFs of `dbs` in order, then the dense `extra` ones, in one database (same channel
/// count). The header is the last database's with a one-dimensional index space large enough
/// for all, labelled thin-lens (lookups are never made in it; unused trailing cells are empty
/// PSFs).
fn concatenate(dbs: &[&PsfDatabase], extra: &[DenseImage]) -> Result<PsfDatabase, DbError> {
    let Some(last) = dbs.last() else {
        return Err(DbError::Invalid("no database to combine".into()));
    };
    let channels = last.channels();
    if let Some(other) = dbs.iter().find(|d| d.channels() != channels) {
        return Err(DbError::Invalid(format!(
            "cannot combine databases of {} and {} channels",
            other.channels(),
            channels
        )));
    }
    let shapes: Vec<DenseShape> = extra
        .iter()
        .map(|&(origin, width, height, _)| DenseShape {
            origin,
            width,
            height,
        })
        .collect();
    let header = combined_header(dbs, &shapes)?;
    let total = (dbs.iter().map(|d| d.psf_count()).sum::<usize>() + extra.len()) as u32;
    let capacity = header.stored_psf_count() as u32;
    let mut builder = DatabaseBuilder::new(header);
    builder.reserve(
        capacity as usize,
        dbs.iter().map(|d| d.dense_data().len()).sum::<usize>()
            + extra.iter().map(|e| e.3.len() * channels).sum::<usize>(),
    );
    for db in dbs {
        for i in 0..db.psf_count() {
            builder.push_copy(db, i)?;
        }
    }
    for (origin, w, h, data) in extra {
        if data.len() == usize::from(*w) * usize::from(*h) && channels > 1 {
            let values: Vec<f32> = data
                .iter()
                .flat_map(|&v| std::iter::repeat_n(v, channels))
                .collect();
            builder.push_dense(*origin, *w, *h, &values)?;
        } else {
            builder.push_dense(*origin, *w, *h, data)?;
        }
    }
    for _ in total..capacity {
        builder.push_sparse(&[], &[])?;
    }
    builder.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_db(model: PsfModel) -> PsfDatabase {
        precompute::build_database(
            &precompute::BuildConfig::new(model, precompute::Profile::Test),
            false,
        )
        .expect("test database")
        .0
    }

    /// Each pair of neighbouring dense thin-lens PSFs gets its premixed blends, pixel by pixel
    /// `(1 - s) P_i + s P_j` at the shares `s = k / (2 BLEND_STEPS)`, and a share picks the
    /// nearest step: 0 the PSF itself, 1/2 the last blend.
    #[test]
    fn neighbouring_dense_psfs_get_premixed_blends() {
        let set = DbSet::new(Some(test_db(PsfModel::ThinLens)), None).expect("set");
        let all = set.combined.as_ref().expect("combined");
        let count = set.dense_blends.len();
        let value = |v: &psf_db::DenseView, x: i32, y: i32, c: usize| -> f32 {
            let (u, w) = (x - v.origin[0], y - v.origin[1]);
            if u < 0 || w < 0 || u >= v.width as i32 || w >= v.height as i32 {
                return 0.0;
            }
            v.data[(w as usize * v.width + u as usize) * v.channels + c]
        };
        let mut pairs = 0;
        for (i, sides) in set.dense_blends.iter().enumerate() {
            for (side, &first) in sides.iter().enumerate() {
                let j = if side == 0 {
                    i.checked_sub(1)
                } else {
                    Some(i + 1)
                };
                let j = j.filter(|&j| j < count);
                let dense_pair =
                    j.is_some_and(|j| all.dense(i).is_some() && all.dense(j).is_some());
                assert_eq!(first != NO_TWIN, dense_pair, "PSF {i}, side {side}");
                let Some(j) = j.filter(|_| dense_pair) else {
                    continue;
                };
                let (a, b) = (all.dense(i).expect("dense"), all.dense(j).expect("dense"));
                for k in 1..=BLEND_STEPS {
                    let s = k as f32 / (2 * BLEND_STEPS) as f32;
                    let m = all.dense((first + k - 1) as usize).expect("a blend");
                    // The blend covers both PSFs and is their mix everywhere.
                    let x0 = a.origin[0].min(b.origin[0]);
                    let y0 = a.origin[1].min(b.origin[1]);
                    assert!(
                        m.origin[0] <= x0 && m.origin[1] <= y0,
                        "PSF {i}/{j} blend {k}"
                    );
                    for y in y0 - 1..y0 + (a.height.max(b.height) as i32) + 1 {
                        for x in x0 - 1..x0 + (a.width.max(b.width) as i32) + 1 {
                            for c in 0..m.channels {
                                let want = (1.0 - s) * value(&a, x, y, c) + s * value(&b, x, y, c);
                                let got = value(&m, x, y, c);
                                assert!(
                                    (got - want).abs() <= 1e-6,
                                    "PSF {i}/{j} blend {k} at ({x}, {y}): {got} against {want}"
                                );
                            }
                        }
                    }
                }
                let (i32_, j32) = (i as u32, j as u32);
                assert_eq!(set.dense_blend_for(i32_, j32, 0.0), Some(i32_));
                assert_eq!(
                    set.dense_blend_for(i32_, j32, 0.5),
                    Some(first + BLEND_STEPS - 1)
                );
                let near_step_5 = 5.2 / (2 * BLEND_STEPS) as f32;
                assert_eq!(set.dense_blend_for(i32_, j32, near_step_5), Some(first + 4));
                pairs += 1;
            }
        }
        assert!(pairs > 0, "no neighbouring dense PSFs in the test database");
        // Not neighbours: no premixed blend.
        assert_eq!(set.dense_blend_for(0, 5, 0.3), None);
    }

    /// Every non-empty PSF of a circular thin-lens or lens-motion database gets dense twins (one
    /// per sub-cell of its cell) that each sum to one in every channel and are centred like
    /// its cell's PSF (centroid within a pixel, since the analytic PSF is symmetric); a
    /// fragment picks the sub-cell holding its parameters.
    #[test]
    fn psfs_get_unit_dense_twins_per_sub_cell() {
        let set = DbSet::new(
            Some(test_db(PsfModel::ThinLens)),
            Some(test_db(PsfModel::LensMotion)),
        )
        .expect("set");
        let all = set.combined.as_ref().expect("combined");
        let base = set.hdr_twins.len();
        let mut twins = 0;
        let mut divided = 0;
        for (i, &t) in set.hdr_twins.iter().enumerate() {
            let non_empty = all.dense(i).is_some() || !all.spreadlets(i).0.is_empty();
            assert_eq!(t != NO_TWIN, non_empty, "PSF {i}: twin {t}");
            if t == NO_TWIN {
                continue;
            }
            let cell = set.hdr_twin_cells[i].expect("a twin's cell");
            let count = cell.splits[0] * cell.splits[1];
            divided += usize::from(count > 1);
            // The corners of the cell pick the first and the last sub-cell.
            assert_eq!(
                set.hdr_twin_for(i as u32, [cell.min[0] as f32, cell.min[1] as f32]),
                t
            );
            let last = [cell.max[0] as f32 - 1e-3, cell.max[1] as f32 - 1e-3];
            assert_eq!(set.hdr_twin_for(i as u32, last), t + count - 1, "PSF {i}");
            for sub in t..t + count {
                twins += 1;
                assert!(sub as usize >= base, "twins follow the original PSFs");
                let d = all.dense(sub as usize).expect("twin is dense");
                for c in 0..d.channels {
                    let (mut sum, mut mx, mut my) = (0.0f64, 0.0f64, 0.0f64);
                    for y in 0..d.height {
                        for x in 0..d.width {
                            let v = f64::from(d.data[(y * d.width + x) * d.channels + c]);
                            sum += v;
                            mx += v * (x as f64 + f64::from(d.origin[0]));
                            my += v * (y as f64 + f64::from(d.origin[1]));
                        }
                    }
                    assert!((sum - 1.0).abs() < 1e-4, "PSF {i} twin {sub} sums to {sum}");
                    assert!((mx / sum).abs() < 1.0 && (my / sum).abs() < 1.0);
                }
            }
        }
        assert!(
            twins > 0 && divided > 0,
            "{twins} twins, {divided} cells divided"
        );
    }

    /// A physical-lens PSF's sparse fit can integrate to small negative values (its
    /// residue); times a bright drop they are dark specks. Its dense twin, which bright
    /// fragments draw, is the same image with them clamped and each channel's sum kept.
    #[test]
    fn physical_lens_psfs_get_non_negative_twins() {
        let space = ParamSpace::for_model(PsfModel::PhysicalLens, &[[0.5, 4.0], [0.0, 10.0]], 2)
            .expect("space");
        let count = space.psf_count() as usize;
        let mut b = DatabaseBuilder::new(DbHeader::new(PsfModel::PhysicalLens, space, 16));
        // A 5x5 box with a ring of negative residue one pixel outside it, per channel scaled.
        let mut image = poisson::Plane::new(13, 13);
        for y in 2..11 {
            for x in 2..11 {
                let inner = (4..9).contains(&x) && (4..9).contains(&y);
                let ring = (3..10).contains(&x) && (3..10).contains(&y) && !inner;
                let v = if inner {
                    1.0 / 25.0
                } else if ring {
                    -0.002
                } else {
                    0.0
                };
                image.set(x, y, v);
            }
        }
        let lap = poisson::laplacian(&image);
        let (mut pos, mut val) = (Vec::new(), Vec::new());
        for y in 0..13 {
            for x in 0..13 {
                let v = lap.get(x, y);
                if v != 0.0 {
                    pos.push([x as i16 - 6, y as i16 - 6]);
                    val.extend([v, 0.9 * v, 1.1 * v]);
                }
            }
        }
        for _ in 0..count {
            b.push_sparse(&pos, &val).expect("push");
        }
        let set = DbSet::single(b.finish().expect("db")).expect("set");
        let all = set.combined.as_ref().expect("combined");
        for i in 0..count {
            let t = set.hdr_twin_for(i as u32, [0.0, 0.0]);
            assert_ne!(t, NO_TWIN, "PSF {i} has no twin");
            let d = all.dense(t as usize).expect("twin is dense");
            assert_eq!(d.channels, 3);
            let sum_of = |c: usize| -> f64 {
                (0..d.width * d.height)
                    .map(|k| f64::from(d.data[k * 3 + c]))
                    .sum()
            };
            assert!(d.data.iter().all(|&v| v >= 0.0), "a negative twin value");
            let box_sum = 1.0 - 24.0 * 0.002;
            for (c, scale) in [1.0, 0.9, 1.1].into_iter().enumerate() {
                let want = box_sum * scale;
                assert!(
                    (sum_of(c) - want).abs() < 1e-4,
                    "channel {c}: {} vs {want}",
                    sum_of(c)
                );
            }
        }
    }

    /// A PSF smeared along a long motion reaches far beyond the database's own PSF bound (the
    /// camera pan through a real lens failed with "dense PSF ... outside +-29"): the frame's
    /// database widens its bound to hold it.
    #[test]
    fn smeared_psfs_may_reach_beyond_the_database_bound() {
        let db = test_db(PsfModel::ThinLens);
        let bound = db.header().psf_resolution as i32;
        let (w, h) = (2 * bound as usize + 41, 3);
        let streak = ([-(w as i32) / 2, -1], w, h);
        let extended = extend_with_dense(&db, &[streak])
            .expect("extended")
            .fill(|_, out| out.fill(1.0 / (w * h) as f32))
            .expect("filled");
        let i = db.psf_count();
        let d = extended.dense(i).expect("the streak is dense");
        assert_eq!((d.width, d.height), (w, h));
        assert!(extended.header().psf_resolution as i32 >= (w as i32) / 2);
        // And it survives the file format's checks.
        let bytes = extended.to_bytes().expect("bytes");
        assert_eq!(
            PsfDatabase::from_bytes(&bytes).expect("read back"),
            extended
        );
    }

    /// More PSFs than a 1-D nested grid holds (361): the paper profile's 404 lens-motion PSFs
    /// plus their twins failed with "no index space holds 623 PSFs". The combined database
    /// then indexes them on a 2-D grid, every PSF copied in order.
    #[test]
    fn more_psfs_than_a_one_dimensional_grid_holds() {
        let space = ParamSpace::for_model(
            PsfModel::LensMotion,
            &[[0.0, 8.0], [0.0, 8.0]],
            ParamSpace::resolution_for_count(2, 400).expect("resolution"),
        )
        .expect("space");
        let count = space.psf_count();
        assert!(count > 361, "{count}");
        let mut b =
            psf_db::DatabaseBuilder::new(psf_db::DbHeader::new(PsfModel::LensMotion, space, 64));
        for i in 0..count {
            // A delta's Laplacian, scaled so that every PSF can be told apart.
            let v = 1.0 + i as f32;
            b.push_sparse(
                &[[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]],
                &[-4.0 * v, v, v, v, v],
            )
            .expect("push");
        }
        let db = b.finish().expect("db");
        let set = DbSet::new(Some(test_db(PsfModel::ThinLens)), Some(db)).expect("set");
        let all = set.combined.as_ref().expect("combined");
        let offset = set.main_offset as usize;
        assert!(all.psf_count() >= offset + count as usize);
        for i in 0..count as usize {
            assert_eq!(all.spreadlets(offset + i).1[1], 1.0 + i as f32, "PSF {i}");
        }
    }
}
