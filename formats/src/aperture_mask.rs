//! A user-drawn aperture: a greyscale image (PNG) whose brightness is the lens' transmission,
//! as Nuke's ZDefocus filter image. The image spans the aperture's square, `[-1, 1]` in units
//! of the aperture radius along its longer side, row 0 at the top: a background highlight
//! (behind the focus plane) shows the image upright, a foreground one turned half a turn.

use std::path::Path;

/// Largest mask edge, pixels.
pub const MAX_MASK_EDGE: usize = 1024;

/// Errors of reading a mask.
#[derive(Debug, thiserror::Error)]
pub enum MaskError {
    /// The file could not be read or decoded.
    #[error("aperture image {path}: {message}")]
    Read {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// The image cannot be an aperture.
    #[error("aperture image {path}: {message}")]
    Unusable {
        /// The file.
        path: String,
        /// Why.
        message: String,
    },
}

/// A greyscale aperture mask: transmission in [0, 1], row-major from the top left.
#[derive(Clone, PartialEq)]
pub struct ApertureMask {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Transmission per pixel, in [0, 1] (the image's luminance, linear in its code values).
    pub values: Vec<f32>,
}

impl std::fmt::Debug for ApertureMask {
    // The values would make every debug print (and the database cache key) megabytes long:
    // the size and the content hash say which mask it is.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "ApertureMask({}x{}, {:016x})",
            self.width,
            self.height,
            self.content_hash()
        )
    }
}

impl ApertureMask {
    /// Reads a PNG (any bit depth, colour or grey; colour is averaged, alpha ignored).
    pub fn read_png(path: &Path) -> Result<Self, MaskError> {
        let name = path.display().to_string();
        let read = |message: String| MaskError::Read {
            path: name.clone(),
            message,
        };
        let reader = ::image::ImageReader::open(path)
            .map_err(|e| read(e.to_string()))?
            .with_guessed_format()
            .map_err(|e| read(e.to_string()))?;
        // The header first: a huge image is refused before anything is decoded.
        let (w, h) = reader.into_dimensions().map_err(|e| read(e.to_string()))?;
        let (w, h) = (w as usize, h as usize);
        if w == 0 || h == 0 || w > MAX_MASK_EDGE || h > MAX_MASK_EDGE {
            return Err(MaskError::Unusable {
                path: name,
                message: format!("{w}x{h} pixels: edges must be 1 to {MAX_MASK_EDGE}"),
            });
        }
        let decoded = ::image::ImageReader::open(path)
            .map_err(|e| read(e.to_string()))?
            .with_guessed_format()
            .map_err(|e| read(e.to_string()))?
            .decode()
            .map_err(|e| read(e.to_string()))?
            .into_rgb32f();
        let values = decoded
            .pixels()
            .map(|p| ((p[0] + p[1] + p[2]) / 3.0).clamp(0.0, 1.0))
            .collect();
        Self::new(w, h, values).map_err(|message| MaskError::Unusable {
            path: name,
            message,
        })
    }

    /// A mask from values in memory; an error when the size does not match or nothing is
    /// transmitted.
    pub fn new(width: usize, height: usize, values: Vec<f32>) -> Result<Self, String> {
        if values.len() != width * height || width == 0 || height == 0 {
            return Err(format!(
                "{} values for {width}x{height} pixels",
                values.len()
            ));
        }
        if values.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return Err("transmission must be finite and non-negative".into());
        }
        if values.iter().all(|&v| v == 0.0) {
            return Err("the image is black everywhere: no light would pass".into());
        }
        Ok(ApertureMask {
            width,
            height,
            values,
        })
    }

    /// FNV-1a 64 of the size and the values' bits: which mask a database was traced with.
    pub fn content_hash(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |bytes: &[u8]| {
            for &b in bytes {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        };
        eat(&(self.width as u64).to_le_bytes());
        eat(&(self.height as u64).to_le_bytes());
        for v in &self.values {
            eat(&v.to_bits().to_le_bytes());
        }
        h
    }
}

/// Draws points with density proportional to a mask's transmission, in units of the aperture
/// radius (the longer side spans `[-1, 1]`, y down): the row by its marginal distribution, the
/// column by the row's conditional one, uniformly within the pixel, keeping stratification
/// (nearby inputs give nearby points).
#[derive(Clone, Debug, PartialEq)]
pub struct MaskSampler {
    mask: ApertureMask,
    /// Cumulative row sums, normalised: `rows[k]` = share of the rows before k + 1.
    rows: Vec<f64>,
    /// Per row, the cumulative column sums, normalised within the row.
    columns: Vec<f64>,
}

impl MaskSampler {
    /// The sampler of `mask`.
    pub fn new(mask: ApertureMask) -> Self {
        let (w, h) = (mask.width, mask.height);
        let mut rows = Vec::with_capacity(h);
        let mut columns = Vec::with_capacity(w * h);
        let mut total = 0.0f64;
        for y in 0..h {
            let mut acc = 0.0f64;
            for x in 0..w {
                acc += f64::from(mask.values[y * w + x]);
                columns.push(acc);
            }
            if acc > 0.0 {
                for c in &mut columns[y * w..(y + 1) * w] {
                    *c /= acc;
                }
            }
            total += acc;
            rows.push(total);
        }
        for r in &mut rows {
            *r /= total;
        }
        MaskSampler {
            mask,
            rows,
            columns,
        }
    }

    /// The mask sampled.
    pub fn mask(&self) -> &ApertureMask {
        &self.mask
    }

    /// Maps `(u0, u1)` in `[0, 1)^2` to a point of the aperture, in units of its radius.
    pub fn sample(&self, u0: f64, u1: f64) -> [f64; 2] {
        let (w, h) = (self.mask.width, self.mask.height);
        let row = self.rows.partition_point(|&c| c <= u0).min(h - 1);
        let below = if row == 0 { 0.0 } else { self.rows[row - 1] };
        let fy = ((u0 - below) / (self.rows[row] - below).max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
        let cols = &self.columns[row * w..(row + 1) * w];
        let col = cols.partition_point(|&c| c <= u1).min(w - 1);
        let left = if col == 0 { 0.0 } else { cols[col - 1] };
        let fx = ((u1 - left) / (cols[col] - left).max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
        let scale = 2.0 / w.max(h) as f64;
        [
            (col as f64 + fx - 0.5 * w as f64) * scale,
            (row as f64 + fy - 0.5 * h as f64) * scale,
        ]
    }

    /// The mask's transmission at `p` (units of the radius), 0 outside its square.
    pub fn transmission(&self, p: [f64; 2]) -> f64 {
        let (w, h) = (self.mask.width, self.mask.height);
        let scale = 0.5 * w.max(h) as f64;
        let x = p[0] * scale + 0.5 * w as f64;
        let y = p[1] * scale + 0.5 * h as f64;
        if x < 0.0 || y < 0.0 || x >= w as f64 || y >= h as f64 {
            return 0.0;
        }
        f64::from(self.mask.values[y as usize * w + x as usize])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_follow_the_mask() {
        // Light only in the top-left quarter of a 4x4 mask: every point is left of and above
        // the centre, spread evenly over that quarter.
        let mut values = vec![0.0; 16];
        for y in 0..2 {
            for x in 0..2 {
                values[y * 4 + x] = 1.0;
            }
        }
        let s = MaskSampler::new(ApertureMask::new(4, 4, values).expect("mask"));
        let n = 64;
        let (mut mx, mut my) = (0.0, 0.0);
        for i in 0..n {
            for j in 0..n {
                let p = s.sample((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                assert!(
                    p[0] <= 0.0 && p[0] >= -1.0 && p[1] <= 0.0 && p[1] >= -1.0,
                    "{p:?}"
                );
                assert!(s.transmission(p) > 0.0);
                mx += p[0];
                my += p[1];
            }
        }
        let c = (n * n) as f64;
        assert!((mx / c + 0.5).abs() < 1e-3 && (my / c + 0.5).abs() < 1e-3);
        assert!(ApertureMask::new(2, 2, vec![0.0; 4]).is_err());
    }
}
