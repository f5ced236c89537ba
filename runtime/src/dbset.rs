//! The databases one synthesis uses, and their concatenation that the splat stage reads.
//!
//! "Simulate only what the scene calls for" holds per pixel: in a frame with motion blur, the
//! pixels that do not move are looked up in the thin-lens database (fine steps in CoC) and only
//! the moving ones in the lens-motion database (whose first cells in motion length are many
//! pixels wide). The splat stage, CPU or GPU, sees one database: the thin-lens PSFs first, then
//! the other database's, so a [`crate::pipeline::SplatRecord::psf_index`] addresses either.

use psf_db::{DatabaseBuilder, DbError, DbHeader, ParamSpace, PsfDatabase, PsfModel};

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
    /// For each PSF of `combined` stored sparse: the index (in `combined`) of its dense twin,
    /// or [`NO_TWIN`]. Twins are the analytic PSF pre-filtered over the same cell
    /// ([`crate::condition::analytic_cell_psf`]), made for the thin-lens and lens-motion models
    /// with a circular aperture. Very bright (HDR) pixels are drawn with them: a sparse PSF's
    /// small relative error, multiplied by a highlight of 100, shows as dark holes and haze
    /// beside it (the comets example: SSIM 0.9710 without, see docs/BENCHMARKS.md).
    pub hdr_twins: Vec<u32>,
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
        let mut twins = Vec::new();
        let mut first = 0usize;
        // The combined database keeps the last one's header, so its PSF bound.
        let bound = sources
            .last()
            .map_or(0, |d| d.header().psf_resolution as i32);
        for db in &sources {
            for (i, twin) in dense_twins(db, bound).into_iter().enumerate() {
                if let Some(t) = twin {
                    hdr_twins[first + i] = (base + twins.len()) as u32;
                    twins.push(t);
                }
            }
            first += db.psf_count();
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
        })
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
/// one value per pixel (single channel, broadcast to the database's channels).
type DenseImage = ([i16; 2], u16, u16, Vec<f32>);

/// The dense twins of `db`'s sparse PSFs (see [`DbSet::hdr_twins`]); `None` where a PSF is
/// dense already, empty, of a model or aperture the analytic PSF does not describe, or where
/// the twin would reach beyond `bound` px from the centre (the database's PSF resolution).
fn dense_twins(db: &PsfDatabase, bound: i32) -> Vec<Option<DenseImage>> {
    use rayon::prelude::*;
    let analytic = matches!(db.model(), PsfModel::ThinLens | PsfModel::LensMotion)
        && db.header().aperture.blades == 0;
    (0..db.psf_count())
        .into_par_iter()
        .map(|i| {
            if !analytic || db.dense(i).is_some() || db.spreadlets(i).0.is_empty() {
                return None;
            }
            let cell = db.space().cell_box(i as u32)?;
            let len = if db.model() == PsfModel::LensMotion {
                (cell.min[1], cell.max[1])
            } else {
                (0.0, 0.0)
            };
            let twin = crate::condition::analytic_cell_psf((cell.min[0], cell.max[0]), len);
            let (origin, w, h) = (twin.0, i32::from(twin.1), i32::from(twin.2));
            let fits = i32::from(origin[0]) >= -bound
                && i32::from(origin[1]) >= -bound
                && i32::from(origin[0]) + w - 1 <= bound
                && i32::from(origin[1]) + h - 1 <= bound;
            fits.then_some(twin)
        })
        .collect()
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
    let total = (dbs.iter().map(|d| d.psf_count()).sum::<usize>() + extra.len()) as u32;
    // The combined database's space only indexes its PSFs (lookups go through the sources'
    // own spaces): one dimension while a 1-D nested grid holds them (at most 361 cells), two
    // beyond (the paper profile's 404 lens-motion PSFs plus their HDR twins).
    let range = [0.0, f64::from(total)];
    let space = match ParamSpace::resolution_for_count(1, total) {
        Some(n) => ParamSpace::for_model(PsfModel::ThinLens, &[range], n),
        None => {
            let n = ParamSpace::resolution_for_count(2, total)
                .ok_or_else(|| DbError::Invalid(format!("no index space holds {total} PSFs")))?;
            ParamSpace::for_model(PsfModel::LensMotion, &[range, range], n)
        }
    }
    .map_err(|e| DbError::Invalid(e.to_string()))?;
    let capacity = space.psf_count();
    let mut header: DbHeader = last.header().clone();
    header.model = if space.dim_count() == 1 {
        PsfModel::ThinLens
    } else {
        PsfModel::LensMotion
    };
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
    let mut builder = DatabaseBuilder::new(header);
    for db in dbs {
        for i in 0..db.psf_count() {
            builder.push_copy(db, i)?;
        }
    }
    for (origin, w, h, data) in extra {
        let values: Vec<f32> = data
            .iter()
            .flat_map(|&v| std::iter::repeat_n(v, channels))
            .collect();
        builder.push_dense(*origin, *w, *h, &values)?;
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

    /// Every sparse PSF of a circular thin-lens or lens-motion database gets a dense twin that
    /// sums to one in every channel and is centred like its cell's PSF (centroid within a
    /// pixel, since the analytic PSF is symmetric); dense PSFs get none.
    #[test]
    fn sparse_psfs_get_unit_dense_twins() {
        let set = DbSet::new(
            Some(test_db(PsfModel::ThinLens)),
            Some(test_db(PsfModel::LensMotion)),
        )
        .expect("set");
        let all = set.combined.as_ref().expect("combined");
        let base = set.hdr_twins.len();
        let mut twins = 0;
        for (i, &t) in set.hdr_twins.iter().enumerate() {
            let sparse = all.dense(i).is_none() && !all.spreadlets(i).0.is_empty();
            assert_eq!(t != NO_TWIN, sparse, "PSF {i}: twin {t}, sparse {sparse}");
            if t == NO_TWIN {
                continue;
            }
            twins += 1;
            assert!(t as usize >= base, "twins follow the original PSFs");
            let d = all.dense(t as usize).expect("twin is dense");
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
                assert!((sum - 1.0).abs() < 1e-4, "PSF {i} twin sums to {sum}");
                assert!((mx / sum).abs() < 1.0 && (my / sum).abs() < 1.0);
            }
        }
        assert!(twins > 0, "the test databases have sparse PSFs");
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
