//! The pinhole G-buffer in Blender's multilayer EXR layout (see `../shared/examples/README.md`):
//! `ViewLayer.Combined.R/G/B/A`, `ViewLayer.Depth.Z` (1e10 on misses) and
//! `ViewLayer.Vector.X/Y/Z/W` with Blender's signs (y up): X,Y = previous minus now and
//! Z,W = now minus next, so the forward motion per frame (x right, y down) is (-Z, +W).

use std::path::Path;

use glam::DVec2;

use crate::error::{Error, Result};
use crate::exr_io;
use crate::image::RgbaImage;

/// The view layer name written into channel names.
pub const VIEW_LAYER: &str = "ViewLayer";

/// A pinhole render with per-pixel depth and motion, row-major, pixel (0,0) top-left.
#[derive(Clone, Debug, PartialEq)]
pub struct GBuffer {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Anti-aliased premultiplied linear RGBA (pinhole, frame time).
    pub color: Vec<[f32; 4]>,
    /// Planar depth at the pixel centre, metres; 1e10 on a miss.
    pub depth: Vec<f32>,
    /// Blender's Vector pass `[X, Y, Z, W]` at the pixel centre, pixels (y up).
    pub vector: Vec<[f32; 4]>,
}

impl GBuffer {
    /// Forward motion per frame (pixels, x right, y down) of pixel `(x, y)`: `(-Z, +W)`.
    pub fn forward_motion(&self, x: usize, y: usize) -> DVec2 {
        let v = self.vector[y * self.width + x];
        DVec2::new(-f64::from(v[2]), f64::from(v[3]))
    }

    /// Every pixel's motion at the frame time, row-major (pixels per frame, x right, y down),
    /// as a reader of the written file takes it: the centred difference of the previous and
    /// next frames' positions, or the forward motion where the backward vector is zero.
    pub fn motion_plane(&self) -> Vec<[f32; 2]> {
        self.vector
            .iter()
            .map(|&v| formats::gbuffer::blender_motion(v))
            .collect()
    }

    /// Every pixel's acceleration at the frame time, row-major (pixels per frame squared, x
    /// right, y down), as a reader of the written file takes it: `(next - now) +
    /// (previous - now)`.
    pub fn acceleration_plane(&self) -> Vec<[f32; 2]> {
        self.vector
            .iter()
            .map(|&v| formats::gbuffer::blender_acceleration(v))
            .collect()
    }

    /// Blender's `[X, Y, Z, W]` from the image positions (pixels, y down) of a surface point in
    /// the previous frame, now and in the next frame.
    pub fn blender_vector(previous: DVec2, now: DVec2, next: DVec2) -> [f32; 4] {
        // Blender's y axis points up: a y-down difference changes sign.
        [
            (previous.x - now.x) as f32,
            -(previous.y - now.y) as f32,
            (now.x - next.x) as f32,
            -(now.y - next.y) as f32,
        ]
    }

    /// The colour as an image.
    pub fn color_image(&self) -> RgbaImage {
        RgbaImage {
            width: self.width,
            height: self.height,
            pixels: self.color.clone(),
        }
    }

    /// Writes the multilayer EXR (f32, ZIP) atomically.
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        self.write_exr_with_overscan(path, 0)
    }

    /// Writes the multilayer EXR (f32, ZIP) atomically, declaring the outer `overscan_px`
    /// pixels on every side as overscan: the display window is the inner frame at (0, 0), the
    /// data window starts at `(-overscan_px, -overscan_px)`, as renderers write overscan.
    pub fn write_exr_with_overscan(&self, path: &Path, overscan_px: usize) -> Result<()> {
        if 2 * overscan_px >= self.width.min(self.height) {
            return Err(Error::Layout {
                path: path.to_path_buf(),
                message: format!(
                    "an overscan of {overscan_px} px leaves no frame inside {}x{} pixels",
                    self.width, self.height
                ),
            });
        }
        Ok(exr_io::write_channels_with_overscan(
            path,
            self.width,
            self.height,
            overscan_px,
            self.channels(VIEW_LAYER),
            None,
        )?)
    }

    /// Writes several view layers of one frame into one multilayer EXR (f32, ZIP), atomically,
    /// as one Blender render with several view layers does: `<name>.Combined.RGBA`,
    /// `<name>.Depth.Z`, `<name>.Vector.XYZW` per layer. The layers must have one size.
    pub fn write_view_layers(path: &Path, layers: &[(String, GBuffer)]) -> Result<()> {
        let Some((_, first)) = layers.first() else {
            return Err(Error::Layout {
                path: path.to_path_buf(),
                message: "no view layers to write".into(),
            });
        };
        let mut channels = Vec::new();
        for (name, g) in layers {
            if (g.width, g.height) != (first.width, first.height) {
                return Err(Error::Layout {
                    path: path.to_path_buf(),
                    message: format!("view layer {name:?} differs in size from the first"),
                });
            }
            channels.extend(g.channels(name));
        }
        Ok(exr_io::write_channels(
            path,
            first.width,
            first.height,
            channels,
            None,
        )?)
    }

    /// The channels of this G-buffer as the view layer `layer`.
    fn channels(&self, layer: &str) -> Vec<(String, Vec<f32>)> {
        let name = |pass: &str, c: &str| format!("{layer}.{pass}.{c}");
        let color = |c: usize| self.color.iter().map(|p| p[c]).collect::<Vec<f32>>();
        let vector = |c: usize| self.vector.iter().map(|p| p[c]).collect::<Vec<f32>>();
        vec![
            (name("Combined", "R"), color(0)),
            (name("Combined", "G"), color(1)),
            (name("Combined", "B"), color(2)),
            (name("Combined", "A"), color(3)),
            (name("Depth", "Z"), self.depth.clone()),
            (name("Vector", "X"), vector(0)),
            (name("Vector", "Y"), vector(1)),
            (name("Vector", "Z"), vector(2)),
            (name("Vector", "W"), vector(3)),
        ]
    }

    /// Reads a G-buffer in Blender's layout; the view layer name is whatever precedes
    /// `.Combined.R` (so Blender files with other layer names read too).
    pub fn read_exr(path: &Path) -> Result<Self> {
        let mut channels = exr_io::read_channels(path)?;
        let layer = channels
            .data
            .keys()
            .find_map(|k| k.strip_suffix(".Combined.R").map(str::to_string))
            .ok_or_else(|| Error::Layout {
                path: path.to_path_buf(),
                message: "no <layer>.Combined.R channel: not a Blender multilayer G-buffer"
                    .to_string(),
            })?;
        let mut take = |pass: &str| channels.take(&format!("{layer}.{pass}"), path);
        let r = take("Combined.R")?;
        let g = take("Combined.G")?;
        let b = take("Combined.B")?;
        let a = take("Combined.A")?;
        let depth = take("Depth.Z")?;
        let vx = take("Vector.X")?;
        let vy = take("Vector.Y")?;
        let vz = take("Vector.Z")?;
        let vw = take("Vector.W")?;
        let n = r.len();
        Ok(Self {
            width: channels.width,
            height: channels.height,
            color: (0..n).map(|i| [r[i], g[i], b[i], a[i]]).collect(),
            depth,
            vector: (0..n).map(|i| [vx[i], vy[i], vz[i], vw[i]]).collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blender_signs_match_the_examples_readme() {
        // A point moving right and down: negative X and Z, positive Y and W.
        let v = GBuffer::blender_vector(
            DVec2::new(9.0, 19.0),
            DVec2::new(10.0, 20.0),
            DVec2::new(11.0, 21.0),
        );
        assert!(v[0] < 0.0 && v[2] < 0.0 && v[1] > 0.0 && v[3] > 0.0);
        let g = GBuffer {
            width: 1,
            height: 1,
            color: vec![[0.0; 4]],
            depth: vec![1.0],
            vector: vec![v],
        };
        assert_eq!(g.forward_motion(0, 0), DVec2::new(1.0, 1.0));
    }
}
