//! [`DatabaseBuilder`]: a database assembled PSF by PSF, in index order, checked as it grows.

use crate::error::DbError;
use crate::format::{DbHeader, DenseEntry, PsfDatabase, SPARSE_SLOT};

/// Builds a database PSF by PSF, in index order.
#[derive(Clone, Debug)]
pub struct DatabaseBuilder {
    db: PsfDatabase,
}

impl DatabaseBuilder {
    /// A builder for `header` (its stats may be filled any time before [`Self::finish`]).
    pub fn new(header: DbHeader) -> Self {
        let n = header.stored_psf_count();
        DatabaseBuilder {
            db: PsfDatabase {
                header,
                cumulative: {
                    let mut c = Vec::with_capacity(n + 1);
                    c.push(0);
                    c
                },
                positions: Vec::new(),
                values: Vec::new(),
                dense_slot: Vec::with_capacity(n),
                dense: Vec::new(),
                dense_data: Vec::new(),
                max_extent_px: 0,
                dense_row_start: Vec::new(),
                dense_row_spans: Vec::new(),
            },
        }
    }

    /// The header, to fill stats or build info while pushing.
    pub fn header_mut(&mut self) -> &mut DbHeader {
        &mut self.db.header
    }

    /// Makes room for `psfs` more PSFs holding `dense_values` more dense values in all (a
    /// builder fed many large dense images then grows its arrays once).
    pub fn reserve(&mut self, psfs: usize, dense_values: usize) {
        self.db.dense_slot.reserve(psfs);
        self.db.cumulative.reserve(psfs);
        self.db.dense.reserve(psfs);
        self.db.dense_data.reserve(dense_values);
    }

    /// Number of PSFs pushed so far (= index of the next one).
    pub fn pushed(&self) -> usize {
        self.db.dense_slot.len()
    }

    fn check_room(&self) -> Result<(), DbError> {
        if self.pushed() >= self.db.header.stored_psf_count() {
            return Err(DbError::Invalid(format!(
                "more PSFs pushed than the {} the header stores",
                self.db.header.stored_psf_count()
            )));
        }
        Ok(())
    }

    /// Appends the next PSF as spreadlets: offsets (px) and `channels` values per offset.
    /// Returns its index.
    pub fn push_sparse(&mut self, positions: &[[i16; 2]], values: &[f32]) -> Result<u32, DbError> {
        self.check_room()?;
        let ch = self.db.header.channels as usize;
        if values.len() != positions.len() * ch {
            return Err(DbError::Invalid(format!(
                "{} values for {} spreadlets x {ch} channels",
                values.len(),
                positions.len()
            )));
        }
        let total = self.db.positions.len() + positions.len();
        let total = u32::try_from(total)
            .map_err(|_| DbError::Invalid("more than u32::MAX spreadlets".into()))?;
        self.db.positions.extend_from_slice(positions);
        self.db.values.extend_from_slice(values);
        self.db.cumulative.push(total);
        self.db.dense_slot.push(SPARSE_SLOT);
        Ok(self.pushed() as u32 - 1)
    }

    /// Appends the next PSF as a dense image of `width x height` pixels (row-major,
    /// channel-interleaved primal values) whose top-left pixel is at `origin` (px from the
    /// centre). Returns its index.
    pub fn push_dense(
        &mut self,
        origin: [i16; 2],
        width: u16,
        height: u16,
        data: &[f32],
    ) -> Result<u32, DbError> {
        self.check_room()?;
        let ch = self.db.header.channels as usize;
        if data.len() != width as usize * height as usize * ch {
            return Err(DbError::Invalid(format!(
                "{} dense values for {width}x{height} px x {ch} channels",
                data.len()
            )));
        }
        let offset = u32::try_from(self.db.dense_data.len())
            .map_err(|_| DbError::Invalid("dense data beyond u32 offsets".into()))?;
        let slot = self.db.dense.len() as u32;
        self.db.dense.push(DenseEntry {
            offset,
            width,
            height,
            origin_x: origin[0],
            origin_y: origin[1],
        });
        self.db.dense_data.extend_from_slice(data);
        let last = *self.db.cumulative.last().unwrap_or(&0);
        self.db.cumulative.push(last);
        self.db.dense_slot.push(slot);
        Ok(self.pushed() as u32 - 1)
    }

    /// Appends PSF `index` of `db` as it is stored there (sparse or dense; same channel count).
    /// Returns its index here.
    pub fn push_copy(&mut self, db: &PsfDatabase, index: usize) -> Result<u32, DbError> {
        match db.dense(index) {
            Some(d) => self.push_dense(
                [d.origin[0] as i16, d.origin[1] as i16],
                d.width as u16,
                d.height as u16,
                d.data,
            ),
            None => {
                let (positions, values) = db.spreadlets(index);
                self.push_sparse(positions, values)
            }
        }
    }

    /// Checks that every PSF was pushed and everything is in bounds, and returns the database.
    pub fn finish(self) -> Result<PsfDatabase, DbError> {
        let n = self.db.header.stored_psf_count();
        if self.pushed() != n {
            return Err(DbError::Invalid(format!(
                "{} PSFs pushed, the space has {n}",
                self.pushed()
            )));
        }
        let mut db = self.db;
        db.validate()?;
        Ok(db)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ParamSpace, PsfModel};

    /// Each dense row's span runs from its first to past its last pixel that is non-zero in
    /// any channel, after building and after a round trip through the file's bytes.
    #[test]
    fn dense_rows_know_where_their_light_is() {
        let space =
            ParamSpace::for_model(PsfModel::PhysicalLens, &[[0.1, 3.0], [0.0, 20.0]], 4).unwrap();
        let n = space.psf_count();
        let mut header = DbHeader::new(PsfModel::PhysicalLens, space, 16);
        header.channels = 3;
        let mut b = DatabaseBuilder::new(header);
        // 4 x 3 px, three channels: a row lit in its middle (only blue at column 2), a zero row
        // (with a negative zero), a row lit at both ends.
        #[rustfmt::skip]
        let image = [
            0.0, 0.0, 0.0,  0.5, 0.0, 0.0,   0.0, 0.0, 0.25,  0.0, 0.0, 0.0,
            0.0, 0.0, 0.0,  -0.0, 0.0, 0.0,  0.0, 0.0, 0.0,   0.0, 0.0, 0.0,
            1.0, 0.0, 0.0,  0.0, 0.0, 0.0,   0.0, 0.0, 0.0,   0.0, -2.0, 0.0,
        ];
        b.push_dense([-2, -1], 4, 3, &image).unwrap();
        b.push_sparse(&[[0, 0]], &[1.0, 1.0, 1.0]).unwrap();
        for _ in 2..n {
            b.push_dense([0, 0], 1, 1, &[0.0; 3]).unwrap();
        }
        let db = b.finish().unwrap();
        let again = PsfDatabase::from_bytes(&db.to_bytes().unwrap()).unwrap();
        for db in [&db, &again] {
            let view = db.dense(0).expect("dense");
            assert_eq!(view.row_spans, &[[1, 3], [0, 0], [0, 4]]);
            assert!(db.dense(1).is_none());
            assert_eq!(db.dense(2).expect("dense").row_spans, &[[0, 0]]);
        }
    }

    /// Dense images that share their values are refused: a small file could otherwise ask
    /// for rows without end.
    #[test]
    fn dense_images_that_share_values_are_refused() {
        let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 4).unwrap();
        let n = space.psf_count();
        let mut b = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space, 16));
        for _ in 0..n {
            b.push_dense([0, 0], 2, 2, &[1.0; 4]).unwrap();
        }
        let db = b.finish().unwrap();
        let mut shared = db.clone();
        // The first image grows over the second's values, and the second reads the first's.
        shared.dense[0].height = 4;
        shared.dense[1].offset = 0;
        let err = shared.validate().unwrap_err();
        assert!(err.to_string().contains("share values"), "{err}");
        let mut moved = db.clone();
        moved.dense[1].offset = 0;
        moved
            .validate()
            .expect("the same number of values, one image read twice");
    }
}
