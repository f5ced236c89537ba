//! Deep OpenEXR (deep scanline): every pixel holds any number of samples, each with its own
//! colour, alpha and depth, front to back, as Arnold, RenderMan, Karma and Nuke write them.
//!
//! The `exr` crate does not read deep data, so this is a reader (and writer) of our own for the
//! single-part deep scanline layout of the OpenEXR file-layout specification: the header's
//! attributes, the offset table, and per chunk (one scanline) the scanline's `y`, the packed
//! size of its pixel offset table, the packed and unpacked sizes of its sample data, the
//! compressed table of cumulative sample counts (one `i32` per pixel, restarting each
//! scanline), then the samples, channel by channel in the header's (alphabetical) order, pixel
//! by pixel, sample by sample. Compression: NONE, RLE and ZIPS, each with OpenEXR's byte split
//! and delta predictor before RLE or zlib, and stored raw where that would not be smaller (as
//! the library writes). OpenEXR 3 itself refuses ZIP (16 scanlines) for deep data, so it is
//! refused here too; tiled and multi-part deep files are refused with a message saying so.
//! Why our own and not a binding: the layout is small and fully specified, a C++ binding
//! would bring a C++ toolchain into every build (the Blender add-on and the Python module
//! included), and our reader shares the bounds of the other readers ([`crate::limits`]):
//! sizes are checked against the file before anything is allocated.
//!
//! Channels: `R, G, B, A` (premultiplied), `Z` (planar depth, scene units), optionally `ZBack`
//! (a volume sample's back depth) and forward motion `forward.u/forward.v` or
//! `motion.x/motion.y` (pixels per frame, x right, y down, as the plain G-buffer). Sample
//! values may be HALF, FLOAT or UINT.
//!
//! Policy: a pixel's samples must be sorted front to back (`Z` not decreasing); a NaN, zero or
//! negative `Z`, a `ZBack` before `Z`, a non-finite motion or an alpha outside [0, 1] is an
//! error naming the pixel and sample; a sample whose colour is NaN or infinite is dropped and
//! counted, as the flat reader drops such pixels.

mod compression;
mod read;
mod write;

use read::Reader;

use std::path::Path;

use crate::gbuffer::Overscan;
use crate::limits::MAX_PIXELS;

/// OpenEXR's magic number, the file's first four bytes.
const MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];
/// Version field: the file format version (low byte) and its flags.
const VERSION_2: u32 = 2;
const FLAG_TILED: u32 = 0x200;
const FLAG_LONG_NAMES: u32 = 0x400;
const FLAG_DEEP: u32 = 0x800;
const FLAG_MULTI_PART: u32 = 0x1000;
/// Most channels a deep file may declare.
const MAX_CHANNELS: usize = 64;

/// Errors of reading and writing deep OpenEXR.
#[derive(Debug, thiserror::Error)]
pub enum DeepError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },
    /// The bytes are not a deep scanline OpenEXR this reader takes, or are inconsistent.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: String,
        /// What is wrong, and where.
        message: String,
    },
    /// A sample value the runtime cannot use.
    #[error("{path}: {what} of sample {sample} at pixel ({x}, {y}) is {value}: {why}")]
    BadSample {
        /// The file.
        path: String,
        /// Which quantity.
        what: &'static str,
        /// Column in the data window.
        x: usize,
        /// Row in the data window.
        y: usize,
        /// The sample's index in its pixel (0 = nearest).
        sample: usize,
        /// The value found.
        value: f32,
        /// What is expected.
        why: &'static str,
    },
}

/// Compression of a deep file's chunks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeepCompression {
    /// Stored as is.
    None,
    /// OpenEXR's run-length encoding (after its byte split and delta predictor).
    Rle,
    /// zlib, one scanline per chunk (after the same split and predictor).
    Zips,
}

impl DeepCompression {
    /// The most bytes one packed byte can unpack to: RLE's repeat of 128 bytes from 2, zlib's
    /// deflate limit of 1032 to 1, none 1. A chunk that claims more is refused before
    /// anything is unpacked.
    fn max_expansion(self) -> usize {
        match self {
            DeepCompression::None => 1,
            DeepCompression::Rle => 64,
            DeepCompression::Zips => 1032,
        }
    }

    fn code(self) -> u8 {
        match self {
            DeepCompression::None => 0,
            DeepCompression::Rle => 1,
            DeepCompression::Zips => 2,
        }
    }
}

/// One deep sample: premultiplied colour, planar depth and forward motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeepSample {
    /// Linear premultiplied RGBA.
    pub color: [f32; 4],
    /// Planar depth of the sample's front, scene units.
    pub depth: f32,
    /// Planar depth of the sample's back (a volume sample), scene units; equal to `depth`
    /// for a surface.
    pub depth_back: f32,
    /// Forward motion per frame, pixels (x right, y down); zero when the file has none.
    pub motion: [f32; 2],
}

/// A deep image: per pixel of the data window, its samples front to back.
#[derive(Clone, Debug, PartialEq)]
pub struct DeepImage {
    /// Width of the data window, pixels.
    pub width: usize,
    /// Height of the data window, pixels.
    pub height: usize,
    /// Pixels beyond the frame (the display window) on each side.
    pub overscan: Overscan,
    /// Pixel `i`'s samples are `samples[offsets[i]..offsets[i + 1]]` (row-major from the top
    /// left, `width x height + 1` entries).
    pub offsets: Vec<usize>,
    /// All samples, pixel after pixel, each pixel's front to back.
    pub samples: Vec<DeepSample>,
    /// Whether the file has motion channels.
    pub has_motion: bool,
    /// Samples dropped because their colour was NaN or infinite.
    pub dropped_samples: usize,
    /// The names of the channels in the file (for messages).
    pub channels_present: Vec<String>,
}

/// Whether `bytes` (a file's start, at least 8 bytes) are an OpenEXR with deep data.
pub fn is_deep_exr(bytes: &[u8]) -> bool {
    bytes.len() >= 8
        && bytes[..4] == MAGIC
        && u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]) & FLAG_DEEP != 0
}

/// Whether the file at `path` is an OpenEXR with deep data (false when it cannot be read).
pub fn is_deep_exr_file(path: &Path) -> bool {
    use std::io::Read;
    let mut start = [0u8; 8];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut start))
        .is_ok()
        && is_deep_exr(&start)
}

impl DeepImage {
    /// An image from samples in memory (`offsets` as in [`DeepImage::offsets`]); applies the
    /// reader's policy (see the module documentation).
    pub fn from_samples(
        width: usize,
        height: usize,
        offsets: Vec<usize>,
        samples: Vec<DeepSample>,
        has_motion: bool,
    ) -> Result<Self, DeepError> {
        let mut image = DeepImage {
            width,
            height,
            overscan: Overscan::NONE,
            offsets,
            samples,
            has_motion,
            dropped_samples: 0,
            channels_present: Vec::new(),
        };
        image.sanitize("<memory>")?;
        Ok(image)
    }

    /// Samples of pixel `(x, y)` of the data window, front to back.
    pub fn pixel(&self, x: usize, y: usize) -> &[DeepSample] {
        let i = y * self.width + x;
        &self.samples[self.offsets[i]..self.offsets[i + 1]]
    }

    /// Width of the frame (the display window), pixels.
    pub fn frame_width(&self) -> usize {
        self.width - self.overscan.left - self.overscan.right
    }

    /// Height of the frame (the display window), pixels.
    pub fn frame_height(&self) -> usize {
        self.height - self.overscan.top - self.overscan.bottom
    }

    /// Most samples any pixel holds.
    pub fn max_samples_per_pixel(&self) -> usize {
        self.offsets
            .windows(2)
            .map(|w| w[1] - w[0])
            .max()
            .unwrap_or(0)
    }

    /// The flat image: each pixel's samples composited front to back with "over", linear
    /// premultiplied RGBA, row-major over the data window.
    pub fn flatten(&self) -> Vec<[f32; 4]> {
        (0..self.width * self.height)
            .map(|i| {
                let mut acc = [0.0f32; 4];
                let mut through = 1.0f32;
                for s in &self.samples[self.offsets[i]..self.offsets[i + 1]] {
                    for (a, c) in acc.iter_mut().zip(s.color) {
                        *a += through * c;
                    }
                    through *= 1.0 - s.color[3];
                }
                acc
            })
            .collect()
    }

    /// Reads a deep scanline OpenEXR file.
    pub fn read(path: &Path) -> Result<Self, DeepError> {
        let name = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| DeepError::Io {
            path: name.clone(),
            source,
        })?;
        Self::read_bytes(&bytes, &name)
    }

    /// Reads a deep scanline OpenEXR from its bytes; `name` names it in messages.
    pub fn read_bytes(bytes: &[u8], name: &str) -> Result<Self, DeepError> {
        let mut image = Reader::new(bytes, name).read()?;
        image.sanitize(name)?;
        Ok(image)
    }

    /// Writes the image as a single-part deep scanline OpenEXR (FLOAT channels `A, B, G, R,
    /// Z`, `ZBack` where some sample is a volume, and `motion.x, motion.y` when it has
    /// motion), atomically.
    pub fn write(&self, path: &Path, compression: DeepCompression) -> crate::Result<()> {
        crate::atomic::write_bytes_atomically(path, &self.to_bytes(compression))
    }

    /// Applies the policy of the module documentation.
    fn sanitize(&mut self, name: &str) -> Result<(), DeepError> {
        let format = |message: String| DeepError::Format {
            path: name.to_string(),
            message,
        };
        let n = self.width * self.height;
        if self.width == 0 || self.height == 0 || n > MAX_PIXELS {
            return Err(format(format!(
                "image size {}x{} is empty or above the limit of {MAX_PIXELS} pixels",
                self.width, self.height
            )));
        }
        if self.offsets.len() != n + 1
            || self.offsets[0] != 0
            || self.offsets[n] != self.samples.len()
            || self.offsets.windows(2).any(|w| w[1] < w[0])
        {
            return Err(format(format!(
                "the sample offsets do not describe {n} pixels holding {} samples",
                self.samples.len()
            )));
        }
        let mut dropped = 0;
        for i in 0..n {
            let (x, y) = (i % self.width, i / self.width);
            let pixel = &mut self.samples[self.offsets[i]..self.offsets[i + 1]];
            let mut previous = 0.0f32;
            for (k, s) in pixel.iter_mut().enumerate() {
                let bad = |what, value, why| DeepError::BadSample {
                    path: name.to_string(),
                    what,
                    x,
                    y,
                    sample: k,
                    value,
                    why,
                };
                if s.depth.is_nan() || s.depth <= 0.0 {
                    return Err(bad("Z", s.depth, "depth must be positive (or +inf)"));
                }
                if s.depth < previous {
                    return Err(bad(
                        "Z",
                        s.depth,
                        "the samples of a pixel must be sorted front to back",
                    ));
                }
                previous = s.depth;
                if s.depth_back.is_nan() || s.depth_back < s.depth {
                    return Err(bad("ZBack", s.depth_back, "ZBack must not lie before Z"));
                }
                if !(s.motion[0].is_finite() && s.motion[1].is_finite()) {
                    let m = if s.motion[0].is_finite() {
                        s.motion[1]
                    } else {
                        s.motion[0]
                    };
                    return Err(bad("motion", m, "motion vectors must be finite"));
                }
                if s.color.iter().any(|c| !c.is_finite()) {
                    s.color = [0.0; 4];
                    dropped += 1;
                    continue;
                }
                if !(0.0..=1.0).contains(&s.color[3]) {
                    return Err(bad("A", s.color[3], "alpha must lie in [0, 1]"));
                }
            }
        }
        self.dropped_samples += dropped;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::compression::{rle_decode, rle_encode};
    use super::*;

    fn sample(c: f32, a: f32, z: f32) -> DeepSample {
        DeepSample {
            color: [c * a, 0.5 * c * a, 0.25 * a, a],
            depth: z,
            depth_back: z,
            motion: [0.0; 2],
        }
    }

    /// 5x3 pixels with 0, 1, 2 or 3 samples each, front to back.
    fn image(motion: bool) -> DeepImage {
        let (w, h) = (5, 3);
        let mut offsets = vec![0];
        let mut samples = Vec::new();
        for y in 0..h {
            for x in 0..w {
                for k in 0..(x + 2 * y) % 4 {
                    let mut s = sample(x as f32 + 0.5, 0.25 + 0.25 * k as f32, 1.0 + k as f32);
                    if motion {
                        s.motion = [x as f32 - 2.0, 0.5 * y as f32];
                    }
                    samples.push(s);
                }
                offsets.push(samples.len());
            }
        }
        DeepImage::from_samples(w, h, offsets, samples, motion).expect("valid")
    }

    #[test]
    fn every_compression_reads_back_what_was_written() {
        for motion in [false, true] {
            let img = image(motion);
            for c in [
                DeepCompression::None,
                DeepCompression::Rle,
                DeepCompression::Zips,
            ] {
                let bytes = img.to_bytes(c);
                assert!(is_deep_exr(&bytes));
                let back = DeepImage::read_bytes(&bytes, "t").expect("reads");
                assert_eq!(back.offsets, img.offsets, "{c:?}");
                assert_eq!(back.samples, img.samples, "{c:?}");
                assert_eq!(back.has_motion, motion);
            }
        }
    }

    #[test]
    fn rle_round_trips_runs_and_literals() {
        let mut raw: Vec<u8> = (0..300).map(|i| (i * 7 % 13) as u8).collect();
        raw.extend(std::iter::repeat_n(9u8, 400));
        raw.extend([1, 1, 2, 2, 2, 3]);
        let packed = rle_encode(&raw);
        assert_eq!(rle_decode(&packed, raw.len()).expect("decodes"), raw);
        assert!(packed.len() < raw.len());
    }

    #[test]
    fn flatten_is_front_to_back_over() {
        let s = [sample(1.0, 0.5, 1.0), sample(2.0, 1.0, 2.0)];
        let img = DeepImage::from_samples(1, 1, vec![0, 2], s.to_vec(), false).expect("valid");
        let flat = img.flatten()[0];
        for (k, v) in flat.iter().enumerate() {
            assert!((v - (s[0].color[k] + 0.5 * s[1].color[k])).abs() < 1e-6);
        }
    }

    #[test]
    fn unsorted_negative_and_overstated_files_are_errors() {
        let unsorted = vec![sample(1.0, 0.5, 2.0), sample(1.0, 0.5, 1.0)];
        let e = DeepImage::from_samples(1, 1, vec![0, 2], unsorted, false).unwrap_err();
        assert!(e.to_string().contains("sorted front to back"), "{e}");
        let negative = vec![sample(1.0, 0.5, -1.0)];
        let e = DeepImage::from_samples(1, 1, vec![0, 1], negative, false).unwrap_err();
        assert!(e.to_string().contains("positive"), "{e}");

        // A count table that claims one more sample than the data holds.
        let img = image(false);
        let mut bytes = img.to_bytes(DeepCompression::None);
        let table_at = bytes.len()
            - (0..img.height)
                .map(|y| {
                    let n = img.offsets[(y + 1) * img.width] - img.offsets[y * img.width];
                    28 + 4 * img.width + 20 * n
                })
                .sum::<usize>();
        let last_count_at = table_at + 28 + 4 * (img.width - 1);
        let claimed =
            i32::from_le_bytes(bytes[last_count_at..last_count_at + 4].try_into().unwrap());
        bytes[last_count_at..last_count_at + 4].copy_from_slice(&(claimed + 1).to_le_bytes());
        let e = DeepImage::read_bytes(&bytes, "over.exr").unwrap_err();
        assert!(e.to_string().contains("need"), "{e}");
        // Every truncation is an error, never a panic.
        for cut in 0..bytes.len() {
            assert!(DeepImage::read_bytes(&bytes[..cut], "cut").is_err());
        }
    }
}
