//! [`WideImages`]: a frame's RGB dense PSF images with four lanes a pixel, for the CPU splat.
//!
//! An upright RGB image is drawn one pixel at a time as `[r, g, b, r + g + b]` weighted by the
//! record's colour (alpha takes the mean of the three weights). Read from the database's three
//! channels, building that four-lane value costs more than the multiply and add that use it:
//! the sum and four shuffles a pixel. Through a physical lens a frame draws hundreds of
//! thousands of records from a few thousand such images (the backdrop's bokeh, turned once
//! per frame and drawn upright), so each image drawn by at least [`MIN_WIDE_USES`] upright
//! records is stored once with its fourth lane summed, and drawn as one four-wide load,
//! multiply and add a pixel. The lanes hold the same sums in the same order, so the splat's
//! result is bit for bit the same.

use rayon::prelude::*;

use psf_db::PsfDatabase;

use super::packed::PackedImages;
use super::types::{SplatPath, SplatRecord};

/// Upright records that must draw an RGB image for it to be widened: widening costs about
/// what drawing it once costs.
pub const MIN_WIDE_USES: u32 = 2;

/// Most pixels the widened images of one frame hold, summed (16 bytes each): beyond it, the
/// images fewest records draw are left in the database.
pub const MAX_WIDE_PIXELS: usize = 4 << 20;

/// One RGB dense image's rows' non-zero spans as `[r, g, b, r + g + b]`: row `v`'s pixels are
/// columns `spans[v][0]..spans[v][1]` of the image's box, at `values[starts[v]..]`.
#[derive(Clone, Debug, PartialEq)]
pub struct WideImage {
    /// Top-left pixel of the image's box relative to the PSF centre, px.
    pub origin: [i32; 2],
    /// Per row, the columns `[first, end)` holding its pixels (`[0, 0]`: a zero row).
    pub spans: Vec<[u16; 2]>,
    /// Per row, the index in `values` of its first pixel.
    pub starts: Vec<u32>,
    /// The rows' pixels, in row order (primal PSF values; the fourth lane their sum).
    pub values: Vec<[f32; 4]>,
}

impl WideImage {
    /// `view` (three channels) widened; `None` for another channel count or a malformed view.
    pub fn of(view: &psf_db::DenseView) -> Option<Self> {
        if view.channels != 3 {
            return None;
        }
        let height = view.height.min(view.row_spans.len());
        let mut spans = Vec::with_capacity(height);
        let mut starts = Vec::with_capacity(height);
        let mut values = Vec::new();
        for (y, &span) in view.row_spans[..height].iter().enumerate() {
            let [first, end] = span.map(usize::from);
            let (at, stop) = ((y * view.width + first) * 3, (y * view.width + end) * 3);
            let row = view.data.get(at..stop)?;
            starts.push(u32::try_from(values.len()).ok()?);
            spans.push(span);
            values.extend(
                row.chunks_exact(3)
                    .map(|p| [p[0], p[1], p[2], p[0] + p[1] + p[2]]),
            );
        }
        Some(WideImage {
            origin: view.origin,
            spans,
            starts,
            values,
        })
    }

    /// Row `v`'s span and its pixels.
    #[inline]
    pub fn row(&self, v: usize) -> ([u16; 2], &[[f32; 4]]) {
        let span = self.spans[v];
        let start = self.starts[v] as usize;
        let n = usize::from(span[1].saturating_sub(span[0]));
        (span, &self.values[start..start + n])
    }

    /// Rows.
    pub fn height(&self) -> usize {
        self.spans.len()
    }
}

/// A frame's widened images, by database PSF index.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WideImages {
    /// Per PSF index, its image in `images` (`u32::MAX`: not widened).
    slots: Vec<u32>,
    images: Vec<WideImage>,
}

impl WideImages {
    /// The RGB images of `db` that at least [`MIN_WIDE_USES`] of `records` draw upright on
    /// their own (dense, not turned, not packed), the most used first within
    /// [`MAX_WIDE_PIXELS`].
    pub fn for_records(
        records: &[SplatRecord],
        db: &PsfDatabase,
        packed: Option<&PackedImages>,
    ) -> Self {
        if db.channels() != 3 {
            return Self::default();
        }
        let count = db.psf_count();
        let mut uses = vec![0u32; count];
        for r in records {
            let upright = r.path == SplatPath::Dense as u32 && r.rot_cos == 1.0 && r.rot_sin == 0.0;
            if let Some(n) = uses.get_mut(r.psf_index as usize).filter(|_| upright) {
                *n = n.saturating_add(1);
            }
        }
        let rgb_pixels = |i: usize| -> Option<usize> {
            if packed.is_some_and(|p| p.get(i as u32).is_some()) {
                return None;
            }
            let view = db.dense(i).filter(|v| v.channels == 3)?;
            Some(
                view.row_spans
                    .iter()
                    .map(|s| usize::from(s[1].saturating_sub(s[0])))
                    .sum(),
            )
        };
        let mut wanted: Vec<(u32, usize, usize)> = uses
            .iter()
            .enumerate()
            .filter(|(_, &n)| n >= MIN_WIDE_USES)
            .filter_map(|(i, &n)| rgb_pixels(i).map(|pixels| (n, i, pixels)))
            .collect();
        if wanted.is_empty() {
            return Self::default();
        }
        // The most drawn first, then by index, so that the bound keeps the same images on
        // every run.
        wanted.sort_unstable_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut budget = MAX_WIDE_PIXELS;
        let mut chosen: Vec<usize> = Vec::with_capacity(wanted.len());
        for &(_, i, pixels) in &wanted {
            if pixels <= budget {
                budget -= pixels;
                chosen.push(i);
            }
        }
        chosen.sort_unstable();
        let built: Vec<Option<WideImage>> = chosen
            .par_iter()
            .map(|&i| db.dense(i).as_ref().and_then(WideImage::of))
            .collect();
        let mut slots = vec![u32::MAX; count];
        let mut images = Vec::with_capacity(built.len());
        for (&i, image) in chosen.iter().zip(built) {
            if let Some(image) = image {
                slots[i] = images.len() as u32;
                images.push(image);
            }
        }
        WideImages { slots, images }
    }

    /// The widened image of database PSF `psf`, if it is one.
    #[inline]
    pub fn get(&self, psf: u32) -> Option<&WideImage> {
        let slot = *self.slots.get(psf as usize)?;
        self.images.get(slot as usize)
    }

    /// Number of widened images.
    pub fn count(&self) -> usize {
        self.images.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A widened image holds each non-zero span's pixels with their sum, and nothing else.
    #[test]
    fn a_widened_image_holds_each_spans_pixels_and_their_sum() {
        let data: Vec<f32> = (0..2 * 3 * 3).map(|v| v as f32).collect();
        let spans = [[1u16, 3u16], [0, 0]];
        let view = psf_db::DenseView {
            width: 3,
            height: 2,
            origin: [-1, -1],
            channels: 3,
            data: &data,
            row_spans: &spans,
        };
        let wide = WideImage::of(&view).expect("three channels");
        assert_eq!(wide.height(), 2);
        assert_eq!(wide.origin, [-1, -1]);
        let (span, pixels) = wide.row(0);
        assert_eq!(span, [1, 3]);
        assert_eq!(pixels, &[[3.0, 4.0, 5.0, 12.0], [6.0, 7.0, 8.0, 21.0]]);
        assert_eq!(wide.row(1).1.len(), 0);
        let grey = psf_db::DenseView {
            channels: 1,
            ..view
        };
        assert!(WideImage::of(&grey).is_none());
    }
}
