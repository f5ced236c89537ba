//! Stages 2 to 4 at once for a frame drawn all direct: every record a dense image or a copied
//! pixel, so that no layer has a Laplacian plane to integrate (a defocused frame of small
//! CoCs, a still frame through a real lens).
//!
//! [`super::splat::splat`] draws such a frame into four direct planes per layer, which the
//! compositor then reads back. Here the image is cut into bands of rows instead, and each band
//! draws every layer's records into one buffer of its thread, farthest layer first, folding
//! each layer into the band's "over" as soon as it is drawn. The layers are never held as
//! planes: at 512 x 512 with four layers that is 25 MB the frame no longer writes, and faults
//! in, and reads back. Only the image's rows are drawn, not the layers' padding.
//!
//! The output is the same, byte for byte, as splatting, integrating and compositing: each
//! pixel sums its records in record order and folds the layers in layer order, whatever the
//! band.

use rayon::prelude::*;

use formats::RgbaImage;
use psf_db::PsfDatabase;

use super::composite::{finish_pixel, fold_layer_pixel, CompositeOptions};
use super::sparse_runs::LayerRuns;
use super::splat::{draw_band, BandRows, Drawing, Planes, SplatOptions};
use super::types::Classified;

/// Image rows per band: a band draws every layer, so a 512 px frame has only its bands to
/// share among threads; 32 rows were faster than 16 and 64 on `rain`, comets and the studio.
pub const BAND_ROWS: usize = 32;

/// Whether [`splat_composite`] draws `classified` as splatting, integrating and compositing
/// would: no layer holds a sparse record, and there is no coarse level to add.
pub fn all_direct(classified: &Classified) -> bool {
    classified.coarse.is_empty() && classified.layers.iter().all(|l| l.sparse == 0)
}

/// Splats and composites a frame for which [`all_direct`] holds, band by band, into a
/// `width x height` image; `sharpness` as [`super::composite::composite_with_sharpness`]
/// takes it. `db` may be `None` only when every record is a copy.
pub fn splat_composite(
    classified: &Classified,
    db: Option<&PsfDatabase>,
    splat: &SplatOptions,
    composite: &CompositeOptions,
    sharpness: &[f32],
) -> RgbaImage {
    let frame = classified.frame;
    let (w, h) = (frame.width as usize, frame.height as usize);
    let (pw, pad) = (frame.padded_width as usize, frame.pad as usize);
    let drawing = Drawing::new(classified, db, splat);
    let mut out = RgbaImage::new(w, h);
    if w == 0 {
        return out;
    }
    /// One thread's memory, reused from band to band: the band being drawn, and the band's
    /// plain sum and sharpness sums (its "over" is the output's rows).
    #[derive(Default)]
    struct Scratch {
        band: Vec<[f32; 4]>,
        total: Vec<[f32; 4]>,
        sharp: Vec<[f32; 3]>,
    }
    out.pixels
        .par_chunks_mut(w * BAND_ROWS)
        .enumerate()
        .for_each_init(Scratch::default, |scratch, (b, over)| {
            let first_row = b * BAND_ROWS;
            let rows = over.len() / w;
            let band_rows = BandRows {
                y0: (pad + first_row) as i32,
                y1: (pad + first_row + rows) as i32,
                width: pw,
            };
            scratch.total.clear();
            scratch.total.resize(over.len(), [0.0; 4]);
            scratch.sharp.clear();
            scratch.sharp.resize(over.len(), [0.0; 3]);
            for (l, info) in classified.layers.iter().enumerate() {
                if info.dense + info.copied == 0 {
                    continue;
                }
                let recs = &classified.records[info.first_record..][..info.record_count];
                let Some(band) = draw_band(
                    recs,
                    &LayerRuns::default(),
                    Planes::Direct,
                    band_rows,
                    &drawing,
                    &mut scratch.band,
                ) else {
                    continue;
                };
                let s = sharpness.get(l).copied().unwrap_or(1.0);
                for (y, ((over, total), sharp)) in over
                    .chunks_exact_mut(w)
                    .zip(scratch.total.chunks_exact_mut(w))
                    .zip(scratch.sharp.chunks_exact_mut(w))
                    .enumerate()
                {
                    let drawn = &band.data[y * pw + pad..][..w];
                    for (((&c, acc), total), sharp) in drawn.iter().zip(over).zip(total).zip(sharp)
                    {
                        fold_layer_pixel(c, s, acc, total, sharp);
                    }
                }
                scratch.band = band.data;
            }
            for ((px, total), sharp) in over.iter_mut().zip(&scratch.total).zip(&scratch.sharp) {
                finish_pixel(px, total, sharp, composite);
            }
        });
    out
}
