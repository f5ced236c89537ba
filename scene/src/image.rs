//! A plain RGBA float image (the converged reference), with EXR and PNG output.

use std::path::Path;

use crate::error::{Error, Result};
use crate::exr_io;

/// Row-major linear premultiplied RGBA, pixel (0,0) top-left.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbaImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width * height` pixels.
    pub pixels: Vec<[f32; 4]>,
}

impl RgbaImage {
    /// A black transparent image.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            pixels: vec![[0.0; 4]; width * height],
        }
    }

    /// Pixel at column `x`, row `y`.
    pub fn at(&self, x: usize, y: usize) -> [f32; 4] {
        self.pixels[y * self.width + x]
    }

    /// Writes channels `R, G, B, A` (f32, ZIP), as the examples' `reference.exr` (plus alpha).
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        let channel = |c: usize| self.pixels.iter().map(|p| p[c]).collect::<Vec<f32>>();
        exr_io::write_channels(
            path,
            self.width,
            self.height,
            vec![
                ("R".to_string(), channel(0)),
                ("G".to_string(), channel(1)),
                ("B".to_string(), channel(2)),
                ("A".to_string(), channel(3)),
            ],
            None,
        )
    }

    /// Reads an image written by [`RgbaImage::write_exr`] (alpha defaults to 1 if absent).
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

    /// Writes an 8-bit sRGB PNG (colour clamped to [0, 1], alpha dropped), atomically.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        let mut bytes = Vec::with_capacity(self.pixels.len() * 3);
        for p in &self.pixels {
            for c in &p[..3] {
                bytes.push((srgb_encode(*c) * 255.0 + 0.5) as u8);
            }
        }
        let io_error = |source| Error::Io {
            path: path.to_path_buf(),
            source,
        };
        let dir = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => std::path::PathBuf::from("."),
        };
        let temp = tempfile::Builder::new()
            .prefix(".spreadlet-")
            .suffix(".png.tmp")
            .tempfile_in(dir)
            .map_err(io_error)?;
        image::save_buffer_with_format(
            temp.path(),
            &bytes,
            self.width as u32,
            self.height as u32,
            image::ColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|e| io_error(std::io::Error::other(e.to_string())))?;
        temp.persist(path).map_err(|e| io_error(e.error))?;
        Ok(())
    }
}

/// The sRGB transfer function on a value clamped to [0, 1].
pub fn srgb_encode(linear: f32) -> f32 {
    let v = linear.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}
