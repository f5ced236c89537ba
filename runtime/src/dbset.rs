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
}

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
        let (combined, main_offset) = match (&thin_lens, &main) {
            (None, None) => (None, 0),
            (Some(t), None) => (Some(t.clone()), 0),
            (None, Some(m)) => (Some(m.clone()), 0),
            (Some(t), Some(m)) => (Some(concatenate(t, m)?), t.psf_count() as u32),
        };
        Ok(Self {
            thin_lens,
            main,
            combined,
            main_offset,
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

/// `a`'s PSFs then `b`'s in one database (same channel count). The header is `b`'s with a
/// one-dimensional index space large enough for both, labelled thin-lens (lookups are never
/// made in it; unused trailing cells are empty PSFs).
fn concatenate(a: &PsfDatabase, b: &PsfDatabase) -> Result<PsfDatabase, DbError> {
    if a.channels() != b.channels() {
        return Err(DbError::Invalid(format!(
            "cannot combine databases of {} and {} channels",
            a.channels(),
            b.channels()
        )));
    }
    let total = (a.psf_count() + b.psf_count()) as u32;
    let n = ParamSpace::resolution_for_count(1, total)
        .ok_or_else(|| DbError::Invalid(format!("no index space holds {total} PSFs")))?;
    let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, f64::from(total)]], n)
        .map_err(|e| DbError::Invalid(e.to_string()))?;
    let capacity = space.psf_count();
    // Validation ties the model to the space's dimensions: the index space is 1-D, so the
    // combined header says thin-lens (both parts are single-channel grey PSFs).
    let mut header: DbHeader = b.header().clone();
    header.model = PsfModel::ThinLens;
    header.space = space;
    header.stats = a
        .header()
        .stats
        .iter()
        .chain(&b.header().stats)
        .copied()
        .collect();
    header.stats.resize(
        capacity as usize,
        header.stats.last().copied().unwrap_or(psf_db::PsfStats {
            coords: [0.0; 2],
            spreadlets: 0,
            dense_support: 0,
            l1: 0.0,
            ssim: 0.0,
            extent_px: 0.0,
        }),
    );
    let mut builder = DatabaseBuilder::new(header);
    for db in [a, b] {
        for i in 0..db.psf_count() {
            match db.dense(i) {
                Some(d) => {
                    builder.push_dense(
                        [d.origin[0] as i16, d.origin[1] as i16],
                        d.width as u16,
                        d.height as u16,
                        d.data,
                    )?;
                }
                None => {
                    let (p, v) = db.spreadlets(i);
                    builder.push_sparse(p, v)?;
                }
            }
        }
    }
    for _ in total..capacity {
        builder.push_sparse(&[], &[])?;
    }
    builder.finish()
}
