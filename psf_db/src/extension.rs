//! [`DenseExtension`]: a database followed by many dense images that are written in place.
//!
//! A renderer that builds PSFs per frame (a lens PSF smeared along each motion the frame
//! holds: tens of thousands of images, tens of MB) would otherwise build each image in a
//! buffer of its own, copy it into a [`crate::DatabaseBuilder`], and check and scan the whole
//! database again. Here the images are laid out once and filled in place in parallel, and
//! each is checked and scanned while it is still in cache.

use crate::error::DbError;
use crate::format::{row_span, rows_of, DbHeader, DenseEntry, PsfDatabase};

/// Where an appended dense image lies relative to its PSF's centre, and its size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DenseShape {
    /// Offset of the top-left pixel from the PSF centre, px (x right, y down).
    pub origin: [i16; 2],
    /// Width, px.
    pub width: u16,
    /// Height, px.
    pub height: u16,
}

/// A database grown from a checked one by dense images whose values are written in place.
#[derive(Debug)]
pub struct DenseExtension {
    db: PsfDatabase,
    /// Index of the first appended entry in the database's dense entries.
    first_entry: usize,
    /// Index of the first appended value in the database's dense data.
    first_value: usize,
}

impl DenseExtension {
    /// `base`'s PSFs (as stored), then one dense image of zeros per shape of `shapes`, then
    /// `empty` PSFs without spreadlets, under `header`. `header` must hold `base`'s channel
    /// count and a space storing exactly that many PSFs; its PSF resolution must reach every
    /// image (checked by [`DenseExtension::fill`]).
    pub fn new(
        base: &PsfDatabase,
        header: DbHeader,
        shapes: &[DenseShape],
        empty: usize,
    ) -> Result<Self, DbError> {
        let ch = base.channels();
        if header.channels as usize != ch {
            return Err(DbError::Invalid(format!(
                "cannot extend a database of {ch} channels under a header of {}",
                header.channels
            )));
        }
        let count = base
            .psf_count()
            .checked_add(shapes.len())
            .and_then(|n| n.checked_add(empty));
        let Some(count) = count.filter(|&n| n == header.stored_psf_count()) else {
            return Err(DbError::Invalid(format!(
                "{} + {} + {empty} PSFs for a space that stores {}",
                base.psf_count(),
                shapes.len(),
                header.stored_psf_count()
            )));
        };
        let first_value = base.dense_data.len();
        let added: u64 = shapes
            .iter()
            .map(|s| u64::from(s.width) * u64::from(s.height) * ch as u64)
            .sum();
        let total = first_value as u64 + added;
        if total > u64::from(u32::MAX) {
            return Err(DbError::Invalid(format!(
                "{total} dense values, beyond the format's u32 offsets"
            )));
        }
        let mut dense = Vec::with_capacity(base.dense.len() + shapes.len());
        dense.extend_from_slice(&base.dense);
        let first_entry = dense.len();
        let mut dense_slot = Vec::with_capacity(count);
        dense_slot.extend_from_slice(&base.dense_slot);
        let mut offset = first_value as u64;
        for shape in shapes {
            dense_slot.push(dense.len() as u32);
            dense.push(DenseEntry {
                offset: offset as u32,
                width: shape.width,
                height: shape.height,
                origin_x: shape.origin[0],
                origin_y: shape.origin[1],
            });
            offset += u64::from(shape.width) * u64::from(shape.height) * ch as u64;
        }
        // Dense and empty PSFs hold no spreadlets.
        let spreadlets = *base.cumulative.last().unwrap_or(&0);
        let mut cumulative = Vec::with_capacity(count + 1);
        cumulative.extend_from_slice(&base.cumulative);
        cumulative.resize(count + 1, spreadlets);
        dense_slot.resize(count, crate::SPARSE_SLOT);
        // In one allocation: fresh zero pages are then touched first by the threads that fill
        // them, not by one thread clearing them all beforehand.
        let mut dense_data = vec![0f32; total as usize];
        dense_data[..first_value].copy_from_slice(&base.dense_data);
        let db = PsfDatabase {
            header,
            cumulative,
            positions: base.positions.clone(),
            values: base.values.clone(),
            dense_slot,
            dense,
            dense_data,
            max_extent_px: 0,
            dense_row_start: base.dense_row_start.clone(),
            dense_row_spans: base.dense_row_spans.clone(),
        };
        Ok(Self {
            db,
            first_entry,
            first_value,
        })
    }

    /// Writes the appended images with `fill(i, values)` for image `i` (in the order of the
    /// shapes; `values`: its `width * height * channels` values, row-major,
    /// channel-interleaved primal values, all zero, to be written) in parallel; checks the
    /// database's structure and each image's values as it is written (`base`'s were checked
    /// when it was), finds its rows' spans, and returns the database.
    pub fn fill<F>(self, fill: F) -> Result<PsfDatabase, DbError>
    where
        F: Fn(usize, &mut [f32]) + Sync,
    {
        self.fill_within(|i, values, _| fill(i, values))
    }

    /// [`DenseExtension::fill`] for images whose rows are mostly zero, such as a thin streak in
    /// its box: `fill(i, values, written)` also gives, per row of image `i`, the columns
    /// `[first, end)` outside which it left the row's zeros untouched (`written` holds the
    /// whole row when it is called). Only those columns are read back, to check them and to
    /// find the row's span; the rest of the image is never touched, so its memory is not
    /// faulted in. Columns beyond the row are ignored.
    pub fn fill_within<F>(self, fill: F) -> Result<PsfDatabase, DbError>
    where
        F: Fn(usize, &mut [f32], &mut [[u16; 2]]) + Sync,
    {
        use rayon::prelude::*;
        let mut db = self.db;
        db.validate_structure()?;
        let ch = db.channels();
        let first_row = db.dense_row_spans.len();
        let new_rows = db.append_dense_row_starts(self.first_entry);
        db.dense_row_spans.resize(first_row + new_rows, [0, 0]);
        // Each image's values and rows, as slices of their own.
        let entries = &db.dense[self.first_entry..];
        let mut values = &mut db.dense_data[self.first_value..];
        let mut rows = &mut db.dense_row_spans[first_row..];
        let mut pieces = Vec::with_capacity(entries.len());
        for e in entries {
            let len = e.width as usize * e.height as usize * ch;
            let (image, rest) = std::mem::take(&mut values).split_at_mut(len);
            values = rest;
            let (spans, rest) = std::mem::take(&mut rows).split_at_mut(rows_of(e));
            rows = rest;
            pieces.push((e.width as usize, image, spans));
        }
        let not_finite: Vec<Option<usize>> = pieces
            .into_par_iter()
            .enumerate()
            .map(|(i, (width, image, spans))| {
                // The format's widths are u16, so every row's width fits.
                spans.fill([0, width as u16]);
                fill(i, image, spans);
                if image.is_empty() {
                    return None;
                }
                for (r, span) in spans.iter_mut().enumerate() {
                    let end = usize::from(span[1]).min(width);
                    let first = usize::from(span[0]).min(end);
                    // A row left untouched: nothing to read (most of a packed streak's box).
                    if first == end {
                        *span = [0, 0];
                        continue;
                    }
                    let written = &image[(r * width + first) * ch..(r * width + end) * ch];
                    if let Some(k) = written.iter().position(|v| !v.is_finite()) {
                        return Some((r * width + first) * ch + k);
                    }
                    *span = match row_span(written, ch) {
                        [0, 0] => [0, 0],
                        [a, b] => [a + first as u16, b + first as u16],
                    };
                }
                None
            })
            .collect();
        let mut offset = self.first_value;
        for (e, bad) in entries.iter().zip(not_finite) {
            if let Some(k) = bad {
                return Err(DbError::OutOfBounds {
                    what: format!("dense value {} is not finite", offset + k),
                });
            }
            offset += e.width as usize * e.height as usize * ch;
        }
        Ok(db)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{DatabaseBuilder, ParamSpace, PsfModel};

    fn base_and_header() -> (PsfDatabase, DbHeader) {
        let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 4).unwrap();
        let n = space.psf_count();
        let mut b = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space, 16));
        b.push_dense([-1, 0], 3, 1, &[0.0, 1.0, 0.5]).unwrap();
        b.push_sparse(&[[0, 0], [1, 0]], &[1.0, -1.0]).unwrap();
        for _ in 2..n {
            b.push_dense([0, 0], 1, 1, &[0.25]).unwrap();
        }
        let base = b.finish().unwrap();
        let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 64).unwrap();
        assert!(space.psf_count() as usize >= n as usize + 3);
        let header = DbHeader::new(PsfModel::ThinLens, space, 16);
        (base, header)
    }

    /// Images written in place give the database that the builder gives from the same
    /// images: the same arrays, the same row spans, the same extent.
    #[test]
    fn images_written_in_place_equal_the_builders() {
        let (base, header) = base_and_header();
        let extra = header.stored_psf_count() - base.psf_count();
        let shapes = [
            DenseShape {
                origin: [-2, -1],
                width: 4,
                height: 3,
            },
            DenseShape {
                origin: [0, 0],
                width: 0,
                height: 0,
            },
            DenseShape {
                origin: [-5, 0],
                width: 2,
                height: 1,
            },
        ];
        let images: [&[f32]; 3] = [
            &[0.0, 0.5, 0.0, 0.0, 0.0, -0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 2.0],
            &[],
            &[0.0, 3.0],
        ];
        let empty = extra - shapes.len();
        let ext = DenseExtension::new(&base, header.clone(), &shapes, empty).unwrap();
        let grown = ext.fill(|i, out| out.copy_from_slice(images[i])).unwrap();

        let mut b = DatabaseBuilder::new(header);
        for i in 0..base.psf_count() {
            b.push_copy(&base, i).unwrap();
        }
        for (s, image) in shapes.iter().zip(images) {
            b.push_dense(s.origin, s.width, s.height, image).unwrap();
        }
        for _ in 0..empty {
            b.push_sparse(&[], &[]).unwrap();
        }
        let built = b.finish().unwrap();
        assert_eq!(grown, built);
        assert_eq!(grown.max_extent_px(), 5);
        let first = grown.dense(base.psf_count()).expect("dense");
        assert_eq!(first.row_spans, &[[1, 2], [0, 0], [0, 4]]);
    }

    /// Images written within the columns they name give the database that whole images give,
    /// spans included; columns named beyond a row are ignored, and a value that is not finite
    /// within them is refused.
    #[test]
    fn images_written_within_columns_equal_whole_ones() {
        let (base, header) = base_and_header();
        let extra = header.stored_psf_count() - base.psf_count();
        let shape = DenseShape {
            origin: [-3, -1],
            width: 6,
            height: 3,
        };
        #[rustfmt::skip]
        let image: [f32; 18] = [
            0.0, 0.0, 0.5, 0.25, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
        ];
        let columns = [[1u16, 5], [2, 2], [3, 60]];
        let whole = DenseExtension::new(&base, header.clone(), &[shape], extra - 1)
            .unwrap()
            .fill(|_, out| out.copy_from_slice(&image))
            .unwrap();
        let within = DenseExtension::new(&base, header.clone(), &[shape], extra - 1)
            .unwrap()
            .fill_within(|_, out, written| {
                assert_eq!(written, &[[0, 6]; 3]);
                for (r, c) in columns.iter().enumerate() {
                    let end = usize::from(c[1]).min(6);
                    for x in usize::from(c[0])..end {
                        out[r * 6 + x] = image[r * 6 + x];
                    }
                }
                written.copy_from_slice(&columns);
            })
            .unwrap();
        assert_eq!(within, whole);
        let spans = within.dense(base.psf_count()).expect("dense").row_spans;
        assert_eq!(spans, &[[2, 4], [0, 0], [4, 5]]);

        let err = DenseExtension::new(&base, header, &[shape], extra - 1)
            .unwrap()
            .fill_within(|_, out, written| {
                out[13] = f32::INFINITY;
                written.copy_from_slice(&[[0, 0], [0, 0], [1, 2]]);
            })
            .unwrap_err()
            .to_string();
        assert!(err.contains("not finite"), "{err}");
    }

    /// A value that is not finite, an image beyond the resolution, or a count that does not
    /// fill the space is refused, naming what is wrong.
    #[test]
    fn bad_extensions_are_refused() {
        let (base, header) = base_and_header();
        let extra = header.stored_psf_count() - base.psf_count();
        let one = DenseShape {
            origin: [0, 0],
            width: 2,
            height: 1,
        };
        let ext = DenseExtension::new(&base, header.clone(), &[one], extra - 1).unwrap();
        let err = ext
            .fill(|_, out| out[1] = f32::NAN)
            .unwrap_err()
            .to_string();
        assert!(err.contains("not finite"), "{err}");

        let far = DenseShape {
            origin: [16, 0],
            width: 2,
            height: 1,
        };
        let ext = DenseExtension::new(&base, header.clone(), &[far], extra - 1).unwrap();
        let err = ext.fill(|_, _| ()).unwrap_err().to_string();
        assert!(err.contains("outside"), "{err}");

        let err = DenseExtension::new(&base, header, &[one], extra).unwrap_err();
        assert!(err.to_string().contains("stores"), "{err}");
    }
}
