//! Stochastic frames: N labelled samples per pixel (one ray each at a random lens position and
//! time), their EXR layout (documented in `docs/STOCHASTIC.md`), writer and reader.

use std::path::Path;

use crate::error::{Error, Result};
use crate::exr_io;

/// The text attribute that marks and sizes a stochastic-frames file.
pub const ATTRIBUTE: &str = "spreadlet";
/// Layout version written and accepted.
pub const VERSION: u32 = 1;
/// Channel names, in [`Sample`] field order.
pub const CHANNELS: [&str; 12] = [
    "R", "G", "B", "A", "Z", "lens.u", "lens.v", "time", "motion.x", "motion.y", "jitter.x",
    "jitter.y",
];

/// One sample: a single ray's result and the labels needed to reconstruct from it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sample {
    /// Premultiplied linear RGBA: alpha 1 on a hit, 0 on a miss (RGB = background then).
    pub color: [f32; 4],
    /// Planar depth of the hit from the camera at the sample's time, metres; 1e10 on a miss.
    pub depth: f32,
    /// Lens position in unit-aperture coordinates (u right, v down; unit disk or the blade
    /// polygon inscribed in it); multiply by the aperture radius f/(2N) for metres. (0, 0) for
    /// a pinhole.
    pub lens: [f32; 2],
    /// Time in frames relative to the frame time, in [-shutter/2, +shutter/2].
    pub time: f32,
    /// Instantaneous forward image motion of the hit surface point at `time` (pinhole
    /// projection, pixels per frame, x right, y down); 0 on a miss.
    pub motion: [f32; 2],
    /// Sensor position of the ray relative to the pixel centre, pixels, in [-0.5, 0.5)
    /// (0 when not jittered).
    pub jitter: [f32; 2],
}

impl Sample {
    /// The sample as its channels, in [`CHANNELS`] order.
    pub fn to_channels(self) -> [f32; 12] {
        [
            self.color[0],
            self.color[1],
            self.color[2],
            self.color[3],
            self.depth,
            self.lens[0],
            self.lens[1],
            self.time,
            self.motion[0],
            self.motion[1],
            self.jitter[0],
            self.jitter[1],
        ]
    }

    /// A sample from its channels, in [`CHANNELS`] order.
    pub fn from_channels(c: [f32; 12]) -> Self {
        Self {
            color: [c[0], c[1], c[2], c[3]],
            depth: c[4],
            lens: [c[5], c[6]],
            time: c[7],
            motion: [c[8], c[9]],
            jitter: [c[10], c[11]],
        }
    }
}

/// All samples of a frame, pixel-major: sample k of pixel (x, y) is
/// `samples[(y * width + x) * spp + k]`.
#[derive(Clone, Debug, PartialEq)]
pub struct StochasticFrames {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Samples per pixel.
    pub spp: usize,
    /// `width * height * spp` samples.
    pub samples: Vec<Sample>,
}

impl StochasticFrames {
    /// The samples of pixel (x, y).
    pub fn pixel(&self, x: usize, y: usize) -> &[Sample] {
        let start = (y * self.width + x) * self.spp;
        &self.samples[start..start + self.spp]
    }

    /// The plain per-pixel average of the samples' colours (the naive estimate).
    pub fn average(&self) -> crate::RgbaImage {
        let mut image = crate::RgbaImage::new(self.width, self.height);
        let inv = 1.0 / self.spp.max(1) as f64;
        for (i, out) in image.pixels.iter_mut().enumerate() {
            let mut sum = [0.0f64; 4];
            for s in &self.samples[i * self.spp..(i + 1) * self.spp] {
                for (acc, c) in sum.iter_mut().zip(s.color) {
                    *acc += f64::from(c);
                }
            }
            *out = sum.map(|v| (v * inv) as f32);
        }
        image
    }

    /// The header attribute's value: `stochastic-frames version=1 width=W height=H spp=N`.
    fn attribute_value(&self) -> String {
        format!(
            "stochastic-frames version={VERSION} width={} height={} spp={}",
            self.width, self.height, self.spp
        )
    }

    /// Writes the file atomically: one part of `width x (height * spp)` pixels, image k (rows
    /// `k * height ..`) holding sample k of every pixel, channels [`CHANNELS`] in f32, ZIP.
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        let n = self.width * self.height * self.spp;
        if self.samples.len() != n || n == 0 {
            return Err(Error::Layout {
                path: path.to_path_buf(),
                message: format!(
                    "{} samples for {}x{} pixels at {} spp",
                    self.samples.len(),
                    self.width,
                    self.height,
                    self.spp
                ),
            });
        }
        let pixels = self.width * self.height;
        let mut channels: Vec<Vec<f32>> = vec![vec![0.0; n]; CHANNELS.len()];
        for (i, sample) in self.samples.iter().enumerate() {
            let (pixel, k) = (i / self.spp, i % self.spp);
            let row = k * pixels + pixel;
            for (c, v) in sample.to_channels().into_iter().enumerate() {
                channels[c][row] = v;
            }
        }
        exr_io::write_channels(
            path,
            self.width,
            self.height * self.spp,
            CHANNELS
                .iter()
                .map(|s| s.to_string())
                .zip(channels)
                .collect(),
            Some((ATTRIBUTE, self.attribute_value())),
        )
    }

    /// Reads a file written by [`StochasticFrames::write_exr`], checking its marker, version
    /// and that the data size matches the recorded width, height and spp.
    pub fn read_exr(path: &Path) -> Result<Self> {
        let layout = |message: String| Error::Layout {
            path: path.to_path_buf(),
            message,
        };
        let mut channels = exr_io::read_channels(path)?;
        let value = channels
            .text_attributes
            .get(ATTRIBUTE)
            .cloned()
            .ok_or_else(|| {
                layout(format!(
                    "no {ATTRIBUTE:?} attribute: not a stochastic-frames file"
                ))
            })?;
        let (width, height, spp) = parse_attribute(&value)
            .ok_or_else(|| layout(format!("unreadable {ATTRIBUTE:?} attribute {value:?}")))?;
        if width == 0
            || height == 0
            || spp == 0
            || channels.width != width
            || height.checked_mul(spp) != Some(channels.height)
        {
            return Err(layout(format!(
                "data of {}x{} pixels does not hold {width}x{height} pixels at {spp} spp",
                channels.width, channels.height
            )));
        }
        let mut columns = Vec::with_capacity(CHANNELS.len());
        for name in CHANNELS {
            columns.push(channels.take(name, path)?);
        }
        let pixels = width * height;
        let n = pixels * spp;
        let mut samples = Vec::with_capacity(n);
        for i in 0..n {
            let (pixel, k) = (i / spp, i % spp);
            let row = k * pixels + pixel;
            samples.push(Sample::from_channels(std::array::from_fn(|c| {
                columns[c][row]
            })));
        }
        Ok(Self {
            width,
            height,
            spp,
            samples,
        })
    }
}

/// Parses `stochastic-frames version=1 width=W height=H spp=N`.
fn parse_attribute(value: &str) -> Option<(usize, usize, usize)> {
    let mut words = value.split_whitespace();
    if words.next()? != "stochastic-frames" {
        return None;
    }
    let (mut version, mut width, mut height, mut spp) = (None, None, None, None);
    for word in words {
        let (key, number) = word.split_once('=')?;
        let number: usize = number.parse().ok()?;
        match key {
            "version" => version = Some(number),
            "width" => width = Some(number),
            "height" => height = Some(number),
            "spp" => spp = Some(number),
            _ => {}
        }
    }
    if version? != VERSION as usize {
        return None;
    }
    Some((width?, height?, spp?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn attribute_round_trips() {
        let frames = StochasticFrames {
            width: 3,
            height: 2,
            spp: 5,
            samples: vec![],
        };
        assert_eq!(parse_attribute(&frames.attribute_value()), Some((3, 2, 5)));
        assert_eq!(
            parse_attribute("stochastic-frames version=2 width=1 height=1 spp=1"),
            None
        );
        assert_eq!(parse_attribute("other"), None);
    }
}
