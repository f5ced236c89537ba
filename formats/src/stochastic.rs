//! Stochastic frames: N labelled samples per pixel (one ray each at a random lens position and
//! time), their EXR layout (documented in `docs/STOCHASTIC.md`), writer and reader.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::exr_blocks::ScanlineBlocks;
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
/// The optional guide channels, in [`SampleGuides`] field order: the denoiser's albedo and
/// normal of each sample's first hit (Cycles' Denoising Albedo and Normal passes).
pub const GUIDE_CHANNELS: [&str; 6] = [
    "albedo.R", "albedo.G", "albedo.B", "normal.X", "normal.Y", "normal.Z",
];

/// One sample: a single ray's result and the labels needed to reconstruct from it.
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Zeroable)]
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

/// A denoiser's guides for one sample: what its ray first hit, without lighting.
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Zeroable)]
pub struct SampleGuides {
    /// Linear reflectance of the first hit (emission on emitters, as Cycles writes it), RGB.
    pub albedo: [f32; 3],
    /// Shading normal of the first hit in camera space: x right, y up, z along the view (as
    /// Cycles writes it); unit length on a hit, zero on a miss.
    pub normal: [f32; 3],
}

impl SampleGuides {
    /// The guides as their channels, in [`GUIDE_CHANNELS`] order.
    pub fn to_channels(self) -> [f32; 6] {
        [
            self.albedo[0],
            self.albedo[1],
            self.albedo[2],
            self.normal[0],
            self.normal[1],
            self.normal[2],
        ]
    }

    /// Guides from their channels, in [`GUIDE_CHANNELS`] order.
    pub fn from_channels(c: [f32; 6]) -> Self {
        Self {
            albedo: [c[0], c[1], c[2]],
            normal: [c[3], c[4], c[5]],
        }
    }
}

/// Guides that do not fit their frames.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GuidesError {
    /// Not one guide per sample.
    #[error("{guides} guides for {samples} samples: the guides must come one per sample")]
    Count {
        /// Guides given.
        guides: usize,
        /// Samples in the frames.
        samples: usize,
    },
    /// A guide value that is not a number or infinite.
    #[error("guide channel {channel} is {value} at pixel ({x}, {y}), sample {sample}: guides must be finite (a miss has albedo and normal 0)")]
    NotFinite {
        /// The channel's name.
        channel: &'static str,
        /// The value found.
        value: f32,
        /// Pixel column.
        x: usize,
        /// Pixel row.
        y: usize,
        /// Sample index within the pixel.
        sample: usize,
    },
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
    /// The denoiser's guides, one per sample in the order of `samples`, when the frames carry
    /// them (files without the guide channels read as `None`).
    pub guides: Option<Vec<SampleGuides>>,
}

impl StochasticFrames {
    /// Frames without guides.
    pub fn new(width: usize, height: usize, spp: usize, samples: Vec<Sample>) -> Self {
        Self {
            width,
            height,
            spp,
            samples,
            guides: None,
        }
    }

    /// These frames with `guides`, one per sample in the order of `samples`; an error when
    /// their count differs or a value is not finite.
    pub fn with_guides(
        mut self,
        guides: Vec<SampleGuides>,
    ) -> std::result::Result<Self, GuidesError> {
        if guides.len() != self.samples.len() {
            return Err(GuidesError::Count {
                guides: guides.len(),
                samples: self.samples.len(),
            });
        }
        for (i, g) in guides.iter().enumerate() {
            let channels = g.to_channels();
            if let Some(c) = channels.iter().position(|v| !v.is_finite()) {
                let (pixel, k) = (i / self.spp.max(1), i % self.spp.max(1));
                return Err(GuidesError::NotFinite {
                    channel: GUIDE_CHANNELS[c],
                    value: channels[c],
                    x: pixel % self.width.max(1),
                    y: pixel / self.width.max(1),
                    sample: k,
                });
            }
        }
        self.guides = Some(guides);
        Ok(self)
    }

    /// The first `spp` samples of every pixel (clamped to 1..=`self.spp`), with their guides:
    /// the frames a smaller sample count would have given.
    pub fn first_samples(&self, spp: usize) -> Self {
        let spp = spp.clamp(1, self.spp.max(1));
        let keep = |i: &usize| i % self.spp.max(1) < spp;
        Self {
            width: self.width,
            height: self.height,
            spp,
            samples: (0..self.samples.len())
                .filter(keep)
                .map(|i| self.samples[i])
                .collect(),
            guides: self
                .guides
                .as_ref()
                .map(|g| (0..g.len()).filter(keep).map(|i| g[i]).collect()),
        }
    }

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
        if let Some(guides) = &self.guides {
            if guides.len() != n {
                return Err(Error::Layout {
                    path: path.to_path_buf(),
                    message: format!("{} guides for {n} samples", guides.len()),
                });
            }
        }
        let pixels = self.width * self.height;
        let row_of = |i: usize| (i % self.spp) * pixels + i / self.spp;
        let mut channels: Vec<Vec<f32>> = vec![vec![0.0; n]; CHANNELS.len()];
        for (i, sample) in self.samples.iter().enumerate() {
            for (c, v) in sample.to_channels().into_iter().enumerate() {
                channels[c][row_of(i)] = v;
            }
        }
        let mut named: Vec<(String, Vec<f32>)> = CHANNELS
            .iter()
            .map(|s| s.to_string())
            .zip(channels)
            .collect();
        if let Some(guides) = &self.guides {
            let mut columns: Vec<Vec<f32>> = vec![vec![0.0; n]; GUIDE_CHANNELS.len()];
            for (i, g) in guides.iter().enumerate() {
                for (c, v) in g.to_channels().into_iter().enumerate() {
                    columns[c][row_of(i)] = v;
                }
            }
            named.extend(GUIDE_CHANNELS.iter().map(|s| s.to_string()).zip(columns));
        }
        exr_io::write_channels(
            path,
            self.width,
            self.height * self.spp,
            named,
            Some((ATTRIBUTE, self.attribute_value())),
        )
    }

    /// Reads a file written by [`StochasticFrames::write_exr`], checking its marker, version
    /// and that the data size matches the recorded width, height and spp. A scanline file
    /// (any this crate or Blender writes) is decoded block by block on every thread, each
    /// block's rows straight into the samples they hold.
    pub fn read_exr(path: &Path) -> Result<Self> {
        match ScanlineBlocks::open(path)? {
            Some(file) => Self::read_blocks(path, &file),
            None => Self::read_channel_lists(path),
        }
    }

    /// [`Self::read_exr`] of a scanline file: each band of pixel rows (one block's worth)
    /// decodes the blocks that hold its rows of every sample and writes its samples whole.
    fn read_blocks(path: &Path, file: &ScanlineBlocks) -> Result<Self> {
        let layout = |message: String| Error::Layout {
            path: path.to_path_buf(),
            message,
        };
        let (width, height, spp) =
            frames_layout(path, &file.text_attributes, file.width, file.height)?;
        let channel = |name: &str| {
            file.channel(name).ok_or_else(|| {
                layout(format!(
                    "missing channel {name:?} (has: {})",
                    file.channel_names.join(", ")
                ))
            })
        };
        let mut sample_channels = [0usize; CHANNELS.len()];
        for (slot, name) in sample_channels.iter_mut().zip(CHANNELS) {
            *slot = channel(name)?;
        }
        let guide_channels = if guides_present(path, |name| file.channel(name).is_some())? {
            let mut columns = [0usize; GUIDE_CHANNELS.len()];
            for (slot, name) in columns.iter_mut().zip(GUIDE_CHANNELS) {
                *slot = channel(name)?;
            }
            Some(columns)
        } else {
            None
        };
        let n = width * height * spp;
        // Zeroed by the allocator: fresh pages stay unmapped until a band writes them, on its
        // own thread.
        let mut samples: Vec<Sample> = bytemuck::zeroed_vec(n);
        let mut guides: Vec<SampleGuides> =
            bytemuck::zeroed_vec(if guide_channels.is_some() { n } else { 0 });
        let band_rows = file.rows_per_block.min(height);
        let band = band_rows * width * spp;
        let guide_bands: Vec<Option<&mut [SampleGuides]>> = if guide_channels.is_some() {
            guides.chunks_mut(band).map(Some).collect()
        } else {
            (0..height.div_ceil(band_rows)).map(|_| None).collect()
        };
        samples
            .par_chunks_mut(band)
            .zip(guide_bands)
            .enumerate()
            .try_for_each(|(b, (out, mut guides_out))| -> Result<()> {
                let (first, last) = (b * band_rows, ((b + 1) * band_rows).min(height));
                // One row of every channel read, as f32, then the row's samples written whole.
                let mut sample_rows = vec![[0.0f32; CHANNELS.len()]; width];
                let mut guide_rows = vec![[0.0f32; GUIDE_CHANNELS.len()]; width];
                let mut column = vec![0.0f32; width];
                // Sample `k` of pixel (x, y) is data row `k * height + y`.
                for k in 0..spp {
                    let mut row = k * height + first;
                    let end = k * height + last;
                    while row < end {
                        let block = file.decode(row / file.rows_per_block)?;
                        let block_end = (block.first_row + block.rows).min(end);
                        for data_row in row..block_end {
                            let line = data_row - block.first_row;
                            let y = data_row - k * height - first;
                            let at = |x: usize| (y * width + x) * spp + k;
                            for (c, &channel) in sample_channels.iter().enumerate() {
                                block.read_row(line, channel, &mut column);
                                for (s, &v) in sample_rows.iter_mut().zip(&column) {
                                    s[c] = v;
                                }
                            }
                            for (x, &values) in sample_rows.iter().enumerate() {
                                out[at(x)] = Sample::from_channels(values);
                            }
                            if let (Some(guide_channels), Some(dst)) =
                                (guide_channels, guides_out.as_deref_mut())
                            {
                                for (c, &channel) in guide_channels.iter().enumerate() {
                                    block.read_row(line, channel, &mut column);
                                    for (g, &v) in guide_rows.iter_mut().zip(&column) {
                                        g[c] = v;
                                    }
                                }
                                for (x, &values) in guide_rows.iter().enumerate() {
                                    dst[at(x)] = SampleGuides::from_channels(values);
                                }
                            }
                        }
                        row = block_end;
                    }
                }
                Ok(())
            })?;
        let frames = Self::new(width, height, spp, samples);
        match guide_channels {
            None => Ok(frames),
            Some(_) => frames
                .with_guides(guides)
                .map_err(|e| layout(e.to_string())),
        }
    }

    /// [`Self::read_exr`] of a tiled file or one with subsampled channels: the whole image
    /// decoded into one list per channel first.
    fn read_channel_lists(path: &Path) -> Result<Self> {
        let layout = |message: String| Error::Layout {
            path: path.to_path_buf(),
            message,
        };
        let mut channels = exr_io::read_channels(path)?;
        let (width, height, spp) = frames_layout(
            path,
            &channels.text_attributes,
            channels.width,
            channels.height,
        )?;
        let mut columns = Vec::with_capacity(CHANNELS.len());
        for name in CHANNELS {
            columns.push(channels.take(name, path)?);
        }
        let guide_columns = if guides_present(path, |name| channels.data.contains_key(name))? {
            let mut columns = Vec::with_capacity(GUIDE_CHANNELS.len());
            for name in GUIDE_CHANNELS {
                columns.push(channels.take(name, path)?);
            }
            Some(columns)
        } else {
            None
        };
        let pixels = width * height;
        let n = pixels * spp;
        let row_of = |i: usize| (i % spp) * pixels + i / spp;
        // Gathered on every thread: one thread's strided reads of twelve columns were most of
        // the file's read after its blocks were decompressed.
        let samples = (0..n)
            .into_par_iter()
            .map(|i| Sample::from_channels(std::array::from_fn(|c| columns[c][row_of(i)])))
            .collect();
        let frames = Self::new(width, height, spp, samples);
        match guide_columns {
            None => Ok(frames),
            Some(columns) => {
                let guides = (0..n)
                    .into_par_iter()
                    .map(|i| {
                        SampleGuides::from_channels(std::array::from_fn(|c| columns[c][row_of(i)]))
                    })
                    .collect();
                frames
                    .with_guides(guides)
                    .map_err(|e| layout(e.to_string()))
            }
        }
    }
}

/// The width, height and spp that a stochastic-frames file's marker attribute records, checked
/// against its data window of `data_width x data_height` pixels (the `spp` frames stacked).
fn frames_layout(
    path: &Path,
    text_attributes: &BTreeMap<String, String>,
    data_width: usize,
    data_height: usize,
) -> Result<(usize, usize, usize)> {
    let layout = |message: String| Error::Layout {
        path: path.to_path_buf(),
        message,
    };
    let value = text_attributes.get(ATTRIBUTE).ok_or_else(|| {
        layout(format!(
            "no {ATTRIBUTE:?} attribute: not a stochastic-frames file"
        ))
    })?;
    let (width, height, spp) = parse_attribute(value)
        .ok_or_else(|| layout(format!("unreadable {ATTRIBUTE:?} attribute {value:?}")))?;
    if width == 0
        || height == 0
        || spp == 0
        || data_width != width
        || height.checked_mul(spp) != Some(data_height)
    {
        return Err(layout(format!(
            "data of {data_width}x{data_height} pixels does not hold {width}x{height} pixels at \
             {spp} spp"
        )));
    }
    Ok((width, height, spp))
}

/// Whether a file whose channels `has` names carries the guide channels: all of
/// [`GUIDE_CHANNELS`] (true) or none (false); an error when it has only some. Their values
/// must be finite everywhere (a denoiser's guide must be a number; a miss has albedo and normal
/// 0), which [`StochasticFrames::with_guides`] checks.
fn guides_present(path: &Path, has: impl Fn(&str) -> bool) -> Result<bool> {
    let present: Vec<&str> = GUIDE_CHANNELS
        .iter()
        .copied()
        .filter(|name| has(name))
        .collect();
    if present.is_empty() {
        return Ok(false);
    }
    if present.len() != GUIDE_CHANNELS.len() {
        let missing: Vec<&str> = GUIDE_CHANNELS
            .iter()
            .copied()
            .filter(|name| !present.contains(name))
            .collect();
        return Err(Error::Layout {
            path: path.to_path_buf(),
            message: format!(
                "guide channels come as all of {} or none; missing {}",
                GUIDE_CHANNELS.join(", "),
                missing.join(", ")
            ),
        });
    }
    Ok(true)
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

    fn frames_with_guides() -> StochasticFrames {
        let (w, h, spp) = (3, 2, 2);
        let samples: Vec<Sample> = (0..w * h * spp)
            .map(|i| Sample {
                color: [i as f32, 0.5, 0.25, 1.0],
                depth: 1.0 + i as f32,
                ..Sample::default()
            })
            .collect();
        let guides = (0..w * h * spp)
            .map(|i| SampleGuides {
                albedo: [0.1 * i as f32, 0.2, 0.3],
                normal: [0.0, 0.6, -0.8],
            })
            .collect();
        StochasticFrames::new(w, h, spp, samples)
            .with_guides(guides)
            .expect("guides")
    }

    #[test]
    fn guides_round_trip_and_old_files_read_without_them() {
        let dir = tempfile::tempdir().expect("dir");
        let with = frames_with_guides();
        let path = dir.path().join("guided.exr");
        with.write_exr(&path).expect("write");
        assert_eq!(StochasticFrames::read_exr(&path).expect("read"), with);
        let mut without = with.clone();
        without.guides = None;
        let path = dir.path().join("plain.exr");
        without.write_exr(&path).expect("write");
        let read = StochasticFrames::read_exr(&path).expect("read");
        assert_eq!(read.guides, None);
        assert_eq!(read.samples, with.samples);
        // Smaller sample counts keep each sample's guide with it.
        let first = with.first_samples(1);
        assert_eq!(first.samples.len(), 6);
        assert_eq!(first.samples[1], with.samples[2]);
        assert_eq!(
            first.guides.as_ref().expect("guides")[1],
            with.guides.as_ref().expect("guides")[2]
        );
    }

    #[test]
    fn guides_of_the_wrong_count_or_not_finite_are_refused() {
        let frames = frames_with_guides();
        let mut guides = frames.guides.clone().expect("guides");
        guides.pop();
        let mut plain = frames.clone();
        plain.guides = None;
        assert!(matches!(
            plain.clone().with_guides(guides),
            Err(GuidesError::Count {
                guides: 11,
                samples: 12
            })
        ));
        let mut guides = frames.guides.clone().expect("guides");
        guides[7].normal[1] = f32::NAN;
        let err = plain.clone().with_guides(guides.clone()).expect_err("NaN");
        assert!(
            matches!(
                err,
                GuidesError::NotFinite {
                    channel: "normal.Y",
                    x: 0,
                    y: 1,
                    sample: 1,
                    ..
                }
            ),
            "{err}"
        );
        // The same NaN in a file is a clear error naming the channel, not a panic.
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("nan.exr");
        let mut bad = frames.clone();
        bad.guides = Some(guides);
        bad.write_exr(&path).expect("write");
        let err = StochasticFrames::read_exr(&path).expect_err("NaN guide");
        assert!(err.to_string().contains("normal.Y"), "{err}");
    }

    #[test]
    fn attribute_round_trips() {
        let frames = StochasticFrames::new(3, 2, 5, vec![]);
        assert_eq!(parse_attribute(&frames.attribute_value()), Some((3, 2, 5)));
        assert_eq!(
            parse_attribute("stochastic-frames version=2 width=1 height=1 spp=1"),
            None
        );
        assert_eq!(parse_attribute("other"), None);
    }

    /// Frames of `w x h` pixels at `spp` whose every channel value differs (and fits half
    /// exactly), written with `compression`, `Z` stored as half: the file's data rows as the
    /// format lays them out (row `k * h + y` holds sample `k` of row `y`).
    fn write_with(path: &Path, frames: &StochasticFrames, compression: exr::prelude::Compression) {
        use exr::prelude::*;
        let (w, h, spp) = (frames.width, frames.height, frames.spp);
        let guides = frames.guides.as_ref().expect("guides");
        let row_of = |i: usize| (i % spp) * w * h + i / spp;
        let mut columns: Vec<(&str, Vec<f32>)> = Vec::new();
        for (c, name) in CHANNELS.iter().enumerate() {
            let mut column = vec![0.0; w * h * spp];
            for (i, s) in frames.samples.iter().enumerate() {
                let v = [
                    s.color[0],
                    s.color[1],
                    s.color[2],
                    s.color[3],
                    s.depth,
                    s.lens[0],
                    s.lens[1],
                    s.time,
                    s.motion[0],
                    s.motion[1],
                    s.jitter[0],
                    s.jitter[1],
                ];
                column[row_of(i)] = v[c];
            }
            columns.push((name, column));
        }
        for (c, name) in GUIDE_CHANNELS.iter().enumerate() {
            let mut column = vec![0.0; w * h * spp];
            for (i, g) in guides.iter().enumerate() {
                column[row_of(i)] = g.to_channels()[c];
            }
            columns.push((name, column));
        }
        let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = columns
            .into_iter()
            .map(|(name, v)| {
                let samples = if name == "Z" {
                    FlatSamples::F16(v.into_iter().map(f16::from_f32).collect())
                } else {
                    FlatSamples::F32(v)
                };
                AnyChannel::new(Text::from(name), samples)
            })
            .collect();
        let mut attributes = LayerAttributes::default();
        attributes.other.insert(
            Text::from(ATTRIBUTE),
            AttributeValue::Text(Text::from(frames.attribute_value().as_str())),
        );
        let encoding = Encoding {
            compression,
            blocks: Blocks::ScanLines,
            line_order: LineOrder::Increasing,
        };
        let layer = Layer::new((w, h * spp), attributes, encoding, AnyChannels::sort(list));
        Image::from_layer(layer)
            .write()
            .to_file(path)
            .expect("write");
    }

    fn distinct_frames(w: usize, h: usize, spp: usize) -> StochasticFrames {
        let n = w * h * spp;
        // Small integers and halves: exact in half as well as in f32.
        let v = |i: usize, c: usize| ((i * 19 + c * 7) % 1024) as f32 * 0.5;
        let samples = (0..n)
            .map(|i| Sample::from_channels(std::array::from_fn(|c| v(i, c))))
            .collect();
        let guides = (0..n)
            .map(|i| SampleGuides::from_channels(std::array::from_fn(|c| v(i, 20 + c))))
            .collect();
        StochasticFrames::new(w, h, spp, samples)
            .with_guides(guides)
            .expect("guides")
    }

    /// Block by block, every compression's rows land on their samples, whether or not the
    /// blocks (1 to 32 rows) divide the frames' height, with a half channel among the floats:
    /// the same as the whole-image read and as written.
    #[test]
    fn a_block_by_block_read_places_every_row_of_every_compression() {
        use exr::prelude::Compression;
        let dir = tempfile::tempdir().expect("dir");
        for (w, h, spp) in [(5, 7, 3), (9, 40, 2), (4, 1, 1)] {
            let frames = distinct_frames(w, h, spp);
            for compression in [
                Compression::Uncompressed,
                Compression::RLE,
                Compression::ZIP1,
                Compression::ZIP16,
                Compression::PIZ,
            ] {
                let path = dir
                    .path()
                    .join(format!("{compression:?}-{w}x{h}x{spp}.exr"));
                write_with(&path, &frames, compression);
                assert!(
                    ScanlineBlocks::open(&path).expect("open").is_some(),
                    "{compression:?}: a scanline file"
                );
                let blocks = StochasticFrames::read_exr(&path).expect("read");
                let lists = StochasticFrames::read_channel_lists(&path).expect("read lists");
                assert_eq!(blocks, lists, "{compression:?} {w}x{h}x{spp}");
                assert_eq!(blocks, frames, "{compression:?} {w}x{h}x{spp}");
            }
        }
    }

    /// A file cut short anywhere, or with any byte changed, is an error or other frames of the
    /// same size: never a panic.
    #[test]
    fn cut_or_changed_files_are_errors_not_panics() {
        let dir = tempfile::tempdir().expect("dir");
        let frames = distinct_frames(6, 5, 2);
        let good = dir.path().join("good.exr");
        write_with(&good, &frames, exr::prelude::Compression::ZIP1);
        let bytes = std::fs::read(&good).expect("bytes");
        let path = dir.path().join("bad.exr");
        for len in 0..bytes.len() {
            std::fs::write(&path, &bytes[..len]).expect("write");
            assert!(StochasticFrames::read_exr(&path).is_err(), "cut at {len}");
        }
        for at in (0..bytes.len()).step_by(3) {
            let mut changed = bytes.clone();
            changed[at] ^= 0x5a;
            std::fs::write(&path, &changed).expect("write");
            if let Ok(read) = StochasticFrames::read_exr(&path) {
                assert_eq!(read.samples.len(), frames.samples.len(), "byte {at}");
            }
        }
    }
}
