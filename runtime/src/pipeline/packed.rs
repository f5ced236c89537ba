//! [`PackedImages`]: a frame's own dense PSF images kept as their rows' non-zero spans alone.
//!
//! A PSF smeared along a motion ([`crate::motion_smear`]) is a thin streak across its box: on
//! a spinning disc in focus, tens of thousands of them, each drawn by one pixel, whose boxes
//! add up to hundreds of MB of mostly zeros. Written into the frame's database, every page of
//! those boxes is faulted in and cleared by the kernel before a value lands in it. Packed, the
//! streaks are written and read while in cache (on Cycles' spinning disc the process's peak
//! memory drops from 387 to 156 MB). The frame's database keeps
//! each packed image's box (its reach, what the splat and the composite ask of it) with
//! values that are never written or read. The GPU path reads the database's images itself,
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
        let mut values = Vec::new();
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

/// A frame's packed images, by the index of the database PSF each stands for.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedImages {
    /// Database index of `images[0]`.
    pub first: u32,
    /// Per PSF from `first` on, its packed image (`None`: stored in the database).
    pub images: Vec<Option<PackedImage>>,
}

impl PackedImages {
    /// The packed image of database PSF `psf`, if it is one.
    #[inline]
    pub fn get(&self, psf: u32) -> Option<&PackedImage> {
        let i = psf.checked_sub(self.first)?;
        self.images.get(i as usize)?.as_ref()
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
    fn a_value_that_is_not_finite_is_refused() {
        let values = [0.0, f32::NAN, 1.0, 0.0];
        assert!(PackedImage::pack([0, 0], 2, 1, &values, &[[0, 2], [0, 2]]).is_none());
        // Outside the written columns it is never read.
        assert!(PackedImage::pack([0, 0], 2, 1, &values, &[[0, 1], [0, 2]]).is_some());
    }
}
