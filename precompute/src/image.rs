//! A traced PSF image: planar channels, a known centre pixel, a zero border.

/// A PSF image of `width x height` pixels and `channels` planes (row-major, y down).
///
/// Pixel `(cx, cy)` = [`Self::centre`] is the PSF origin: the pixel where the pinhole camera puts
/// the point. A ray landing at offset `(x, y)` pixels from the origin falls into pixel
/// `(cx + round(x), cy + round(y))`, i.e. each pixel integrates the light over its unit square.
#[derive(Clone, Debug, PartialEq)]
pub struct PsfImage {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Centre pixel `[x, y]` (PSF origin).
    pub centre: [usize; 2],
    /// One plane per channel, `width * height` values each (light per pixel, unitless).
    pub planes: Vec<Vec<f32>>,
}

impl PsfImage {
    /// A black image.
    pub fn zeros(width: usize, height: usize, centre: [usize; 2], channels: usize) -> Self {
        PsfImage {
            width,
            height,
            centre,
            planes: vec![vec![0.0; width * height]; channels],
        }
    }

    /// Number of channels.
    pub fn channels(&self) -> usize {
        self.planes.len()
    }

    /// Number of pixels where some channel is non-zero (the dense support, pixels).
    pub fn support(&self) -> usize {
        (0..self.width * self.height)
            .filter(|&i| self.planes.iter().any(|p| p[i] != 0.0))
            .count()
    }

    /// Largest distance of a non-zero pixel from the centre, pixels.
    pub fn extent(&self) -> f32 {
        let mut best = 0.0f32;
        for y in 0..self.height {
            for x in 0..self.width {
                let i = y * self.width + x;
                if self.planes.iter().any(|p| p[i] != 0.0) {
                    let dx = x as f32 - self.centre[0] as f32;
                    let dy = y as f32 - self.centre[1] as f32;
                    best = best.max((dx * dx + dy * dy).sqrt());
                }
            }
        }
        best
    }

    /// Sum of each channel.
    pub fn sums(&self) -> Vec<f64> {
        self.planes
            .iter()
            .map(|p| p.iter().map(|&v| f64::from(v)).sum())
            .collect()
    }

    /// Largest value over all channels.
    pub fn max_value(&self) -> f32 {
        self.planes
            .iter()
            .flat_map(|p| p.iter().copied())
            .fold(0.0, f32::max)
    }

    /// Centroid `[x, y]` of channel `c`, pixels relative to the centre.
    pub fn centroid(&self, c: usize) -> [f64; 2] {
        let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
        for y in 0..self.height {
            for x in 0..self.width {
                let v = f64::from(self.planes[c][y * self.width + x]);
                sx += v * (x as f64 - self.centre[0] as f64);
                sy += v * (y as f64 - self.centre[1] as f64);
                s += v;
            }
        }
        if s == 0.0 {
            [0.0, 0.0]
        } else {
            [sx / s, sy / s]
        }
    }

    /// Root-mean-square distance of channel `c`'s light from its centroid, pixels.
    pub fn rms_radius(&self, c: usize) -> f64 {
        let [mx, my] = self.centroid(c);
        let (mut s2, mut s) = (0.0, 0.0);
        for y in 0..self.height {
            for x in 0..self.width {
                let v = f64::from(self.planes[c][y * self.width + x]);
                let dx = x as f64 - self.centre[0] as f64 - mx;
                let dy = y as f64 - self.centre[1] as f64 - my;
                s2 += v * (dx * dx + dy * dy);
                s += v;
            }
        }
        if s == 0.0 {
            0.0
        } else {
            (s2 / s).sqrt()
        }
    }

    /// The channel-interleaved values (`data[(y * width + x) * channels + c]`).
    pub fn interleaved(&self) -> Vec<f32> {
        let ch = self.channels();
        let mut out = vec![0.0; self.width * self.height * ch];
        for (c, p) in self.planes.iter().enumerate() {
            for (i, &v) in p.iter().enumerate() {
                out[i * ch + c] = v;
            }
        }
        out
    }
}
