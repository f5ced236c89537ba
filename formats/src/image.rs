//! An RGBA float image (linear, premultiplied alpha, row-major, (0,0) top-left, y down): its
//! EXR reader and its atomic writers, OpenEXR (f32) and an sRGB PNG preview.

use std::io::{BufWriter, Write};
use std::path::Path;

use crate::atomic::write_atomically;
use crate::error::{Error, Result};
use crate::exr_io;
use crate::srgb::srgb8;

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
    pub fn at(&self, x: usize, y: usize) -> [f32; 4] {
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
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        use exr::prelude::*;
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
                .map_err(|source| crate::Error::Exr {
                    path: path.to_path_buf(),
                    source,
                })?;
            buffered.flush().map_err(|e| crate::Error::io(path, e))?;
            Ok(())
        })
    }

    /// Reads channels `R, G, B` and optionally `A` (1 when absent) of an EXR file's first
    /// part, as written by [`RgbaImage::write_exr`] or a renderer's beauty pass.
    pub fn read_exr(path: &Path) -> Result<Self> {
        let mut channels = exr_io::read_channels(path)?;
        let r = channels.take("R", path)?;
        let g = channels.take("G", path)?;
        let b = channels.take("B", path)?;
        let a = channels
            .data
            .remove("A")
            .unwrap_or_else(|| vec![1.0; r.len()]);
        let pixels = (0..r.len()).map(|i| [r[i], g[i], b[i], a[i]]).collect();
        Ok(Self {
            width: channels.width,
            height: channels.height,
            pixels,
        })
    }

    /// Writes an 8-bit sRGB PNG preview (the premultiplied colour over black, clamped to
    /// [0, 1]), atomically.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        let bytes = self
            .pixels
            .iter()
            .flat_map(|p| p[..3].iter().map(|&v| srgb8(v)))
            .collect();
        let buffer = ::image::RgbImage::from_raw(self.width as u32, self.height as u32, bytes)
            .ok_or_else(|| Error::Layout {
                path: path.to_path_buf(),
                message: "image size does not match its data".into(),
            })?;
        write_atomically(path, |file| {
            let mut buffered = BufWriter::new(file);
            buffer
                .write_to(&mut buffered, ::image::ImageFormat::Png)
                .map_err(|source| Error::Png {
                    path: path.to_path_buf(),
                    source,
                })?;
            buffered.flush().map_err(|e| Error::io(path, e))
        })
    }
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
