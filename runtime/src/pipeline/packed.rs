//! [`PackedImages`]: a frame's own dense PSF images kept as their rows' non-zero spans alone.
//!
//! A PSF smeared along a motion ([`crate::motion_smear`]) is a thin streak across its box: on
//! a spinning disc in focus, tens of thousands of them, each drawn by one pixel, whose boxes
//! add up to hundreds of MB of mostly zeros. Written into the frame's database, every page of
//! those boxes is faulted in and cleared by the kernel before a value lands in it. Packed, the
//! streaks are written and read while in cache (on Cycles' spinning disc the process's peak
//! memory drops from 387 to 156 MB). The frame's database holds an empty image in each packed
//! one's place, so its values take no memory there (a box of zeros, never written, still had
//! to be cleared wherever the allocator handed back memory a frame before had used); what
//! asks a PSF's reach asks [`crate::pipeline::types::frame_psf_reach`], which reads a packed
//! image's box from here. The GPU path reads the database's images itself,
//! so frames for it are classified with the images written there
//! ([`super::ClassifyOptions::pack_images`] off).

/// One dense image as its rows' non-zero spans: row `v`'s values are those of columns
/// `spans[v][0]..spans[v][1]` of the image's box, channel-interleaved, one row after another
/// in `values`.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedImage {
    /// Top-left pixel of the image's box relative to the PSF centre, px.
    pub origin: [i32; 2],
    /// Width of the image's box, px.
    pub width: usize,
    /// Channels per pixel (1 or 3).
    pub channels: usize,
    /// Per row, the columns `[first, end)` holding its values (`[0, 0]`: a zero row).
    pub spans: Vec<[u16; 2]>,
    /// Per row, the index in `values` of its first value.
    pub starts: Vec<u32>,
    /// The rows' values, in row order (primal PSF values).
    pub values: Vec<f32>,
}

impl PackedImage {
    /// The image of a box at `origin`, `width` px wide with `channels` channels, from its values
    /// (`box_values`, row-major) and per row the columns `[first, end)` outside which they are
    /// zero (`written`): each row trimmed to its non-zero pixels. `None` where a value is not
    /// finite.
    pub fn pack(
        origin: [i32; 2],
        width: usize,
        channels: usize,
        box_values: &[f32],
        written: &[[u16; 2]],
    ) -> Option<Self> {
        let ch = channels;
        if width == 0 || ch == 0 {
            return Some(Self {
                origin,
                width,
                channels,
                spans: vec![[0, 0]; written.len()],
                starts: vec![0; written.len()],
                values: Vec::new(),
            });
        }
        let mut spans = Vec::with_capacity(written.len());
        let mut starts = Vec::with_capacity(written.len());
        // At most the written columns' values: one allocation rather than one per doubling.
        let most: usize = written
            .iter()
            .map(|w| {
                usize::from(w[1])
                    .min(width)
                    .saturating_sub(usize::from(w[0]))
            })
            .sum();
        let mut values = Vec::with_capacity(most * ch);
        for (row, w) in box_values.chunks_exact(width * ch).zip(written) {
            let end = usize::from(w[1]).min(width);
            let first = usize::from(w[0]).min(end);
            starts.push(u32::try_from(values.len()).ok()?);
            let lit = &row[first * ch..end * ch];
            if lit.iter().any(|v| !v.is_finite()) {
                return None;
            }
            let nonzero = |px: &[f32]| px.iter().any(|&v| v != 0.0);
            let Some(a) = lit.chunks_exact(ch).position(nonzero) else {
                spans.push([0, 0]);
                continue;
            };
            let b = lit.chunks_exact(ch).rposition(nonzero).map_or(a, |b| b) + 1;
            values.extend_from_slice(&lit[a * ch..b * ch]);
            // Box widths are the format's u16 widths.
            spans.push([(first + a) as u16, (first + b) as u16]);
        }
        Some(Self {
            origin,
            width,
            channels,
            spans,
            starts,
            values,
        })
    }

    /// Row `v`'s span and its values.
    #[inline]
    pub fn row(&self, v: usize) -> ([u16; 2], &[f32]) {
        let span = self.spans[v];
        let start = self.starts[v] as usize;
        let n = usize::from(span[1].saturating_sub(span[0])) * self.channels;
        (span, &self.values[start..start + n])
    }

    /// Each row's span and its values, top to bottom.
    pub fn rows(&self) -> impl Iterator<Item = ([u16; 2], &[f32])> + '_ {
        (0..self.spans.len()).map(|v| self.row(v))
    }

    /// The image's values over its whole box, row-major (zeros where the rows hold none).
    pub fn unpacked_box(&self) -> Vec<f32> {
        let ch = self.channels;
        let mut out = vec![0.0; self.width * self.spans.len() * ch];
        if self.width == 0 || ch == 0 {
            return out;
        }
        for ((span, values), row) in self.rows().zip(out.chunks_exact_mut(self.width * ch)) {
            let [a, b] = span.map(usize::from);
            row[a * ch..b * ch].copy_from_slice(values);
        }
        out
    }
}

/// A frame's packed images, by the index of the database PSF each stands for. Images that are
/// one image mirrored (a sharp point's smears along arcs that the grid's mirrors map onto each
/// other, [`crate::smear_symmetry`]) share it.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedImages {
    /// Database index of `slots[0]`.
    pub first: u32,
    /// The distinct images.
    pub pool: Vec<PackedImage>,
    /// Per PSF from `first` on, its image in `pool` and whether it is that image mirrored left
    /// to right and top to bottom within its box (`None`: stored in the database).
    pub slots: Vec<Option<(u32, [bool; 2])>>,
}

impl PackedImages {
    /// The packed image of database PSF `psf`, if it is one.
    #[inline]
    pub fn get(&self, psf: u32) -> Option<MirroredImage<'_>> {
        let i = psf.checked_sub(self.first)?;
        let (index, mirrors) = (*self.slots.get(i as usize)?)?;
        Some(MirroredImage {
            image: self.pool.get(index as usize)?,
            mirrors,
        })
    }

    /// Each packed PSF's database index and its image, in index order.
    pub fn images(&self) -> impl Iterator<Item = (u32, MirroredImage<'_>)> {
        (self.first..).zip(&self.slots).filter_map(|(psf, slot)| {
            let (index, mirrors) = (*slot)?;
            let image = self.pool.get(index as usize)?;
            Some((psf, MirroredImage { image, mirrors }))
        })
    }

    /// How many database PSFs are packed here.
    pub fn count(&self) -> usize {
        self.slots.iter().flatten().count()
    }
}

/// A packed image as a PSF draws it: mirrored left to right (`mirrors[0]`) and top to bottom
/// (`mirrors[1]`) within its box.
#[derive(Clone, Copy, Debug)]
pub struct MirroredImage<'a> {
    /// The image as stored.
    pub image: &'a PackedImage,
    /// Whether it is drawn mirrored left to right and top to bottom.
    pub mirrors: [bool; 2],
}

impl<'a> MirroredImage<'a> {
    /// Top-left pixel of the drawn box relative to the PSF centre, px: the stored box's
    /// mirrored about the centre on each mirrored axis.
    pub fn origin(&self) -> [i32; 2] {
        let [ox, oy] = self.image.origin;
        let (w, h) = (self.image.width as i32, self.image.spans.len() as i32);
        [
            if self.mirrors[0] { -(ox + w - 1) } else { ox },
            if self.mirrors[1] { -(oy + h - 1) } else { oy },
        ]
    }

    /// Rows of the box.
    pub fn height(&self) -> usize {
        self.image.spans.len()
    }

    /// Row `v`'s span as drawn and its values as stored: right to left where the image is
    /// mirrored left to right.
    #[inline]
    pub fn row(&self, v: usize) -> ([u16; 2], &'a [f32]) {
        let v = if self.mirrors[1] {
            self.height() - 1 - v
        } else {
            v
        };
        let (span, values) = self.image.row(v);
        if self.mirrors[0] {
            // Box widths are the format's u16 widths.
            let w = self.image.width as u16;
            ([w - span[1], w - span[0]], values)
        } else {
            (span, values)
        }
    }

    /// The image's values over its drawn box, row-major (zeros where the rows hold none).
    pub fn unpacked_box(&self) -> Vec<f32> {
        let stored = self.image.unpacked_box();
        let (ch, w, h) = (self.image.channels, self.image.width, self.height());
        if self.mirrors == [false, false] || ch == 0 || w == 0 {
            return stored;
        }
        let mut out = vec![0.0; stored.len()];
        for (v, row) in out.chunks_exact_mut(w * ch).enumerate() {
            let from = if self.mirrors[1] { h - 1 - v } else { v };
            let src = &stored[from * w * ch..(from + 1) * w * ch];
            for (u, px) in row.chunks_exact_mut(ch).enumerate() {
                let x = if self.mirrors[0] { w - 1 - u } else { u };
                px.copy_from_slice(&src[x * ch..(x + 1) * ch]);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_are_trimmed_to_their_non_zero_pixels_and_unpack_to_the_box() {
        // 4 x 3, grey: row 0 written over columns 0..4 but lit at 1..3, row 1 zero, row 2 not
        // written at all (its garbage is outside its span).
        let values = [0.0, 0.5, 0.25, 0.0, 0.0, 0.0, 0.0, 0.0, 7.0, 7.0, 7.0, 7.0];
        let written = [[0, 4], [0, 4], [0, 0]];
        let image = PackedImage::pack([-2, -1], 4, 1, &values, &written).expect("finite");
        assert_eq!(image.spans, vec![[1, 3], [0, 0], [0, 0]]);
        assert_eq!(image.values, vec![0.5, 0.25]);
        assert_eq!(image.starts, vec![0, 2, 2]);
        let rows: Vec<_> = image.rows().collect();
        assert_eq!(rows[0], ([1, 3], &[0.5f32, 0.25][..]));
        assert_eq!(
            image.unpacked_box(),
            vec![0.0, 0.5, 0.25, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        );
    }

    #[test]
    fn a_mirrored_view_draws_the_mirrored_box() {
        // 3 x 2, two channels.
        let values = [1.0, 2.0, 3.0, 4.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0, 6.0];
        let written = [[0, 3], [0, 3]];
        let stored = PackedImage::pack([-1, 0], 3, 2, &values, &written).expect("finite");
        for mirrors in [[false, false], [true, false], [false, true], [true, true]] {
            // The box mirrored pixel by pixel, and packed.
            let mut box_mirrored = [0.0; 12];
            for v in 0..2 {
                for u in 0..3 {
                    let (x, y) = (
                        if mirrors[0] { 2 - u } else { u },
                        if mirrors[1] { 1 - v } else { v },
                    );
                    let (to, from) = ((v * 3 + u) * 2, (y * 3 + x) * 2);
                    box_mirrored[to..to + 2].copy_from_slice(&values[from..from + 2]);
                }
            }
            let want = PackedImage::pack([0, 0], 3, 2, &box_mirrored, &written).expect("finite");
            let view = MirroredImage {
                image: &stored,
                mirrors,
            };
            assert_eq!(view.unpacked_box(), box_mirrored.to_vec(), "{mirrors:?}");
            for v in 0..2 {
                let (span, vals) = view.row(v);
                let (want_span, want_values) = want.row(v);
                assert_eq!(span, want_span, "{mirrors:?} row {v}");
                let drawn: Vec<f32> = if mirrors[0] {
                    vals.chunks_exact(2).rev().flatten().copied().collect()
                } else {
                    vals.to_vec()
                };
                assert_eq!(drawn, want_values, "{mirrors:?} row {v}");
            }
        }
        let view = MirroredImage {
            image: &stored,
            mirrors: [true, true],
        };
        // The box [-1, 1] x [0, 1] mirrored about the centre: [-1, 1] x [-1, 0].
        assert_eq!(view.origin(), [-1, -1]);
    }

    #[test]
    fn a_value_that_is_not_finite_is_refused() {
        let values = [0.0, f32::NAN, 1.0, 0.0];
        assert!(PackedImage::pack([0, 0], 2, 1, &values, &[[0, 2], [0, 2]]).is_none());
        // Outside the written columns it is never read.
        assert!(PackedImage::pack([0, 0], 2, 1, &values, &[[0, 1], [0, 2]]).is_some());
    }
}
