//! An RGBA float image (linear, premultiplied alpha, row-major, (0,0) top-left, y down) and its
//! atomic writers: OpenEXR (f32) and an sRGB PNG preview.

use std::io::{BufWriter, Seek, Write};
use std::path::Path;

/// A linear, premultiplied RGBA image, row-major from the top-left pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbaImage {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// `width * height` pixels, row-major, y down.
    pub pixels: Vec<[f32; 4]>,
}

/// Errors of writing images.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// Creating, writing or renaming the file failed.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The destination.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The EXR encoder failed.
    #[error("cannot encode EXR {path}: {message}")]
    Exr {
        /// The destination.
        path: String,
        /// The encoder's message.
        message: String,
    },
    /// The PNG encoder failed.
    #[error("cannot encode PNG {path}: {message}")]
    Png {
        /// The destination.
        path: String,
        /// The encoder's message.
        message: String,
    },
}

impl RgbaImage {
    /// A black, fully transparent image.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            pixels: vec![[0.0; 4]; width * height],
        }
    }

    /// The pixel at column `x`, row `y`.
    pub fn get(&self, x: usize, y: usize) -> [f32; 4] {
        self.pixels[y * self.width + x]
    }

    /// Sum of each channel in f64.
    pub fn channel_sums(&self) -> [f64; 4] {
        let mut s = [0.0f64; 4];
        for p in &self.pixels {
            for c in 0..4 {
                s[c] += f64::from(p[c]);
            }
        }
        s
    }

    /// Writes an OpenEXR file with channels R, G, B, A (f32), atomically: a temporary file in
    /// the destination folder renamed into place, so a failure leaves no partial file. The
    /// blocks are compressed in parallel but stored in increasing order, so the same image
    /// always gives the same bytes.
    pub fn write_exr(&self, path: &Path) -> Result<(), WriteError> {
        use exr::prelude::*;
        let io = |source| WriteError::Io {
            path: path.display().to_string(),
            source,
        };
        let w = self.width;
        let channels = SpecificChannels::rgba(|pos: Vec2<usize>| {
            let p = self.pixels[pos.y() * w + pos.x()];
            (p[0], p[1], p[2], p[3])
        });
        // Unspecified line order would store the blocks in whichever order the threads finish.
        let encoding = Encoding {
            line_order: LineOrder::Increasing,
            ..Encoding::FAST_LOSSLESS
        };
        let image = Image::from_encoded_channels((self.width, self.height), encoding, channels);
        write_atomically(path, |file| {
            let mut buffered = BufWriter::new(file);
            image
                .write()
                .to_buffered(&mut buffered)
                .map_err(|e| WriteError::Exr {
                    path: path.display().to_string(),
                    message: e.to_string(),
                })?;
            buffered.flush().map_err(io)?;
            Ok(())
        })
    }

    /// Writes an 8-bit sRGB PNG preview (the premultiplied colour over black, clamped to
    /// [0, 1]), atomically.
    pub fn write_preview_png(&self, path: &Path) -> Result<(), WriteError> {
        let mut bytes = Vec::with_capacity(self.pixels.len() * 3);
        for p in &self.pixels {
            for &v in &p[..3] {
                bytes.push((linear_to_srgb(v) * 255.0 + 0.5) as u8);
            }
        }
        let png_err = |e: ::image::ImageError| WriteError::Png {
            path: path.display().to_string(),
            message: e.to_string(),
        };
        let buffer = ::image::RgbImage::from_raw(self.width as u32, self.height as u32, bytes)
            .ok_or_else(|| WriteError::Png {
                path: path.display().to_string(),
                message: "image size does not match its data".into(),
            })?;
        write_atomically(path, |file| {
            let mut buffered = BufWriter::new(file);
            buffer
                .write_to(&mut buffered, ::image::ImageFormat::Png)
                .map_err(png_err)?;
            buffered.flush().map_err(|source| WriteError::Io {
                path: path.display().to_string(),
                source,
            })
        })
    }
}

/// sRGB transfer function of a linear value clamped to [0, 1] (NaN maps to 0).
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Writes through `write` into a temporary file beside `path`, then renames it into place.
pub fn write_atomically<F>(path: &Path, write: F) -> Result<(), WriteError>
where
    F: FnOnce(&mut std::fs::File) -> Result<(), WriteError>,
{
    let io = |source| WriteError::Io {
        path: path.display().to_string(),
        source,
    };
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    let mut tmp = tempfile::Builder::new()
        .prefix(".spreadlet-tmp-")
        .tempfile_in(&dir)
        .map_err(io)?;
    write(tmp.as_file_mut())?;
    tmp.as_file_mut().rewind().map_err(io)?;
    tmp.as_file().sync_all().map_err(io)?;
    tmp.persist(path).map_err(|e| io(e.error))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_image_is_written_as_the_same_bytes() {
        let (w, h) = (320, 256);
        let pixels = (0..w * h)
            .map(|i| {
                let v = ((i * 7919) % 1013) as f32 / 1013.0;
                [v, 1.0 - v, (i % w) as f32 / w as f32, 1.0]
            })
            .collect();
        let image = RgbaImage {
            width: w,
            height: h,
            pixels,
        };
        let dir = tempfile::tempdir().expect("temp dir");
        let files: Vec<Vec<u8>> = (0..4)
            .map(|k| {
                let path = dir.path().join(format!("{k}.exr"));
                image.write_exr(&path).expect("write");
                std::fs::read(&path).expect("read")
            })
            .collect();
        assert!(
            files.windows(2).all(|p| p[0] == p[1]),
            "the same image gave different files"
        );
    }
}
