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

use std::path::Path;

use crate::gbuffer::Overscan;
use crate::limits::{MAX_DEEP_SAMPLES, MAX_PIXELS};

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

    /// The bytes [`DeepImage::write`] writes.
    pub fn to_bytes(&self, compression: DeepCompression) -> Vec<u8> {
        let volumes = self.samples.iter().any(|s| s.depth_back != s.depth);
        let mut channels: Vec<WrittenChannel> = vec![
            ("A", |s| s.color[3]),
            ("B", |s| s.color[2]),
            ("G", |s| s.color[1]),
            ("R", |s| s.color[0]),
            ("Z", |s| s.depth),
        ];
        if volumes {
            channels.push(("ZBack", |s| s.depth_back));
        }
        // OpenEXR lists channels sorted by name, bytewise: upper case first.
        if self.has_motion {
            channels.push(("motion.x", |s| s.motion[0]));
            channels.push(("motion.y", |s| s.motion[1]));
        }
        let (w, h) = (self.width, self.height);
        let data_window = [0i32, 0, w as i32 - 1, h as i32 - 1];
        let o = self.overscan;
        let display_window = [
            o.left as i32,
            o.top as i32,
            (w - o.right) as i32 - 1,
            (h - o.bottom) as i32 - 1,
        ];
        let mut out = Vec::new();
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&(VERSION_2 | FLAG_DEEP).to_le_bytes());
        let mut attribute = |name: &str, kind: &str, value: &[u8]| {
            out.extend_from_slice(name.as_bytes());
            out.push(0);
            out.extend_from_slice(kind.as_bytes());
            out.push(0);
            out.extend_from_slice(&(value.len() as i32).to_le_bytes());
            out.extend_from_slice(value);
        };
        let mut chlist = Vec::new();
        for (channel, _) in &channels {
            chlist.extend_from_slice(channel.as_bytes());
            chlist.push(0);
            chlist.extend_from_slice(&2i32.to_le_bytes()); // FLOAT
            chlist.extend_from_slice(&[0, 0, 0, 0]); // pLinear, reserved
            chlist.extend_from_slice(&1i32.to_le_bytes());
            chlist.extend_from_slice(&1i32.to_le_bytes());
        }
        chlist.push(0);
        let box2i = |b: [i32; 4]| b.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>();
        attribute("channels", "chlist", &chlist);
        attribute("chunkCount", "int", &(h as i32).to_le_bytes());
        attribute("compression", "compression", &[compression.code()]);
        attribute("dataWindow", "box2i", &box2i(data_window));
        attribute("displayWindow", "box2i", &box2i(display_window));
        attribute("lineOrder", "lineOrder", &[0]);
        let max_samples = self.max_samples_per_pixel() as i32;
        attribute("maxSamplesPerPixel", "int", &max_samples.to_le_bytes());
        attribute("pixelAspectRatio", "float", &1f32.to_le_bytes());
        attribute("screenWindowCenter", "v2f", &[0; 8]);
        attribute("screenWindowWidth", "float", &1f32.to_le_bytes());
        attribute("type", "string", b"deepscanline");
        attribute("version", "int", &1i32.to_le_bytes());
        out.push(0);

        let table_at = out.len();
        out.resize(table_at + 8 * h, 0);
        for y in 0..h {
            let chunk_at = out.len() as u64;
            out[table_at + 8 * y..table_at + 8 * y + 8].copy_from_slice(&chunk_at.to_le_bytes());
            let row = &self.offsets[y * w..=(y + 1) * w];
            let mut counts = Vec::with_capacity(4 * w);
            for &end in &row[1..] {
                counts.extend_from_slice(&((end - row[0]) as i32).to_le_bytes());
            }
            let samples = &self.samples[row[0]..row[w]];
            let mut data = Vec::with_capacity(4 * channels.len() * samples.len());
            for (_, value) in &channels {
                for s in samples {
                    data.extend_from_slice(&value(s).to_le_bytes());
                }
            }
            let packed_counts = compress(compression, &counts);
            let packed_data = compress(compression, &data);
            out.extend_from_slice(&(y as i32).to_le_bytes());
            out.extend_from_slice(&(packed_counts.len() as u64).to_le_bytes());
            out.extend_from_slice(&(packed_data.len() as u64).to_le_bytes());
            out.extend_from_slice(&(data.len() as u64).to_le_bytes());
            out.extend_from_slice(&packed_counts);
            out.extend_from_slice(&packed_data);
        }
        out
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

/// A channel the writer writes: its name and how to get its value from a sample.
type WrittenChannel = (&'static str, fn(&DeepSample) -> f32);

/// Sample value types of OpenEXR channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PixelType {
    Uint,
    Half,
    Float,
}

impl PixelType {
    fn bytes(self) -> usize {
        match self {
            PixelType::Half => 2,
            PixelType::Uint | PixelType::Float => 4,
        }
    }
}

/// Where each channel the image needs sits among the file's channels.
struct ChannelMap {
    color: [usize; 4],
    depth: usize,
    depth_back: Option<usize>,
    motion: Option<[usize; 2]>,
}

/// A cursor over the file's bytes that turns every overrun into an error naming what was read.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    name: &'a str,
}

impl<'a> Reader<'a> {
    fn new(bytes: &'a [u8], name: &'a str) -> Self {
        Reader { bytes, at: 0, name }
    }

    fn error(&self, message: impl Into<String>) -> DeepError {
        DeepError::Format {
            path: self.name.to_string(),
            message: message.into(),
        }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DeepError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(self.error(format!(
                "the file ends inside {what} (at byte {}, {n} bytes wanted, {} left)",
                self.at,
                self.bytes.len() - self.at.min(self.bytes.len())
            )));
        };
        let out = &self.bytes[self.at..end];
        self.at = end;
        Ok(out)
    }

    fn u32(&mut self, what: &str) -> Result<u32, DeepError> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn i32(&mut self, what: &str) -> Result<i32, DeepError> {
        Ok(self.u32(what)? as i32)
    }

    fn u64(&mut self, what: &str) -> Result<u64, DeepError> {
        let b = self.take(8, what)?;
        Ok(u64::from_le_bytes([
            b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7],
        ]))
    }

    /// A NUL-terminated name of at most `max` bytes.
    fn name(&mut self, max: usize, what: &str) -> Result<String, DeepError> {
        let rest = &self.bytes[self.at.min(self.bytes.len())..];
        let Some(len) = rest.iter().take(max + 1).position(|&b| b == 0) else {
            return Err(self.error(format!(
                "{what} at byte {} is not NUL-terminated within {max} bytes",
                self.at
            )));
        };
        let text = String::from_utf8_lossy(&rest[..len]).into_owned();
        self.at += len + 1;
        Ok(text)
    }

    fn read(mut self) -> Result<DeepImage, DeepError> {
        if self.take(4, "the magic number")? != MAGIC {
            return Err(self.error("not an OpenEXR file (wrong magic number)"));
        }
        let version = self.u32("the version field")?;
        if version & 0xff != VERSION_2 {
            return Err(self.error(format!(
                "OpenEXR file format version {} is not 2",
                version & 0xff
            )));
        }
        if version & FLAG_DEEP == 0 {
            return Err(self.error("the file holds no deep data (read it as a flat G-buffer)"));
        }
        if version & FLAG_MULTI_PART != 0 {
            return Err(
                self.error("multi-part deep files are not read; write the deep image as one part")
            );
        }
        if version & FLAG_TILED != 0 {
            return Err(self.error("tiled deep files are not read; write deep scanlines"));
        }
        let max_name = if version & FLAG_LONG_NAMES != 0 {
            255
        } else {
            31
        };

        let mut channels: Option<Vec<(String, PixelType)>> = None;
        let mut compression = None;
        let mut data_window = None;
        let mut display_window = None;
        let mut kind = None;
        let mut chunk_count = None;
        let mut deep_version = None;
        loop {
            let attribute = self.name(max_name, "an attribute name")?;
            if attribute.is_empty() {
                break;
            }
            let type_name = self.name(max_name, "an attribute type")?;
            let size = self.i32("an attribute size")?;
            let size = usize::try_from(size)
                .map_err(|_| self.error(format!("attribute {attribute} has size {size}")))?;
            let value = self.take(size, &format!("attribute {attribute}"))?;
            let int = |v: &[u8]| -> Option<i32> {
                (v.len() == 4).then(|| i32::from_le_bytes([v[0], v[1], v[2], v[3]]))
            };
            let wrong = |what: &str| self.error(format!("attribute {attribute} is not {what}"));
            match attribute.as_str() {
                "channels" => channels = Some(parse_channels(value, &|m| self.error(m))?),
                "compression" => compression = Some(*value.first().ok_or_else(|| wrong("a byte"))?),
                "dataWindow" | "displayWindow" => {
                    if value.len() != 16 {
                        return Err(wrong("a box2i"));
                    }
                    let b: Vec<i32> = value
                        .chunks_exact(4)
                        .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                        .collect();
                    let bounds = [b[0], b[1], b[2], b[3]];
                    if attribute == "dataWindow" {
                        data_window = Some(bounds);
                    } else {
                        display_window = Some(bounds);
                    }
                }
                "type" => kind = Some(String::from_utf8_lossy(value).into_owned()),
                "chunkCount" => chunk_count = Some(int(value).ok_or_else(|| wrong("an int"))?),
                "version" if type_name == "int" => {
                    deep_version = Some(int(value).ok_or_else(|| wrong("an int"))?)
                }
                _ => {}
            }
        }
        let missing = |what: &str| self.error(format!("the header has no {what} attribute"));
        let channels = channels.ok_or_else(|| missing("channels"))?;
        let compression = compression.ok_or_else(|| missing("compression"))?;
        let [x0, y0, x1, y1] = data_window.ok_or_else(|| missing("dataWindow"))?;
        let display = display_window.ok_or_else(|| missing("displayWindow"))?;
        match kind.as_deref() {
            Some("deepscanline") => {}
            Some("deeptile") => {
                return Err(self.error("tiled deep files are not read; write deep scanlines"))
            }
            Some(other) => {
                return Err(self.error(format!("part type {other:?} is not deepscanline")))
            }
            None => return Err(missing("type")),
        }
        if let Some(v) = deep_version.filter(|&v| v != 1) {
            return Err(self.error(format!("deep data version {v} is not 1")));
        }
        let compression =
            match compression {
                0 => DeepCompression::None,
                1 => DeepCompression::Rle,
                2 => DeepCompression::Zips,
                3 => return Err(self.error(
                    "ZIP (16-scanline) compression is not valid for deep data (OpenEXR refuses \
                     it too); use ZIPS, RLE or none",
                )),
                other => {
                    return Err(self.error(format!(
                        "compression {other} is not valid for deep data; use ZIPS, RLE or none"
                    )))
                }
            };
        let (width, height) = (
            i64::from(x1) - i64::from(x0) + 1,
            i64::from(y1) - i64::from(y0) + 1,
        );
        if width <= 0 || height <= 0 || width * height > MAX_PIXELS as i64 {
            return Err(self.error(format!(
                "the data window is {width}x{height} pixels: empty or above the limit of \
                 {MAX_PIXELS}"
            )));
        }
        let (width, height) = (width as usize, height as usize);
        let overscan = overscan_of([x0, y0, x1, y1], display).ok_or_else(|| {
            self.error(format!(
                "the data window {:?} does not cover the display window {display:?}; render \
                 the whole frame",
                [x0, y0, x1, y1]
            ))
        })?;
        let map = map_channels(&channels, &|m| self.error(m))?;
        if let Some(count) = chunk_count {
            if count as i64 != height as i64 {
                return Err(self.error(format!(
                    "chunkCount is {count}, but {height} scanlines need {height} chunks"
                )));
            }
        }
        let table_bytes = 8 * height;
        if self.bytes.len().saturating_sub(self.at) < table_bytes {
            return Err(self.error(format!(
                "the file is too short for the offset table of {height} chunks"
            )));
        }
        let mut chunk_starts = Vec::with_capacity(height);
        for _ in 0..height {
            chunk_starts.push(self.u64("the offset table")?);
        }

        let sample_bytes: usize = channels.iter().map(|(_, t)| t.bytes()).sum();
        let mut counts = vec![0u32; width * height];
        // First pass, per scanline: where its packed samples are, and how many bytes they
        // unpack to; the samples are decoded once every count (and so every offset) is known.
        let mut rows: Vec<Option<(usize, usize, usize)>> = vec![None; height];
        let mut total_samples: usize = 0;
        for (c, &start) in chunk_starts.iter().enumerate() {
            let Some(start) = usize::try_from(start)
                .ok()
                .filter(|&s| s < self.bytes.len())
            else {
                return Err(self.error(format!(
                    "chunk {c} starts at byte {start}, beyond the file's {} bytes",
                    self.bytes.len()
                )));
            };
            self.at = start;
            let y = self.i32("a chunk's scanline")?;
            let row = i64::from(y) - i64::from(y0);
            if !(0..height as i64).contains(&row) {
                return Err(self.error(format!(
                    "chunk {c} is for scanline {y}, outside the data window"
                )));
            }
            let row = row as usize;
            if rows[row].is_some() {
                return Err(self.error(format!("scanline {y} is stored twice")));
            }
            let packed_table = self.u64("a chunk's table size")?;
            let packed_data = self.u64("a chunk's sample data size")?;
            let unpacked_data = self.u64("a chunk's unpacked sample data size")?;
            let left = (self.bytes.len() - self.at) as u64;
            if packed_table > left || packed_data > left - packed_table {
                return Err(self.error(format!(
                    "scanline {y} declares {packed_table} + {packed_data} bytes, but the file \
                     has {left} left"
                )));
            }
            let table = self.take(packed_table as usize, "a sample count table")?;
            let table = uncompress(compression, table, 4 * width)
                .map_err(|m| self.error(format!("scanline {y}'s sample count table: {m}")))?;
            let mut previous = 0u32;
            for x in 0..width {
                let t = &table[4 * x..4 * x + 4];
                let cumulative = i32::from_le_bytes([t[0], t[1], t[2], t[3]]);
                let cumulative = u32::try_from(cumulative).ok().filter(|&v| v >= previous);
                let Some(cumulative) = cumulative else {
                    return Err(self.error(format!(
                        "scanline {y}: the cumulative sample count at pixel {x} decreases or \
                         is negative"
                    )));
                };
                counts[row * width + x] = cumulative - previous;
                previous = cumulative;
            }
            let in_row = previous as usize;
            total_samples += in_row;
            if total_samples > MAX_DEEP_SAMPLES {
                return Err(self.error(format!(
                    "the file holds more than the limit of {MAX_DEEP_SAMPLES} deep samples"
                )));
            }
            let expected = in_row * sample_bytes;
            if unpacked_data != expected as u64 {
                return Err(self.error(format!(
                    "scanline {y} declares {unpacked_data} bytes of samples, but its {in_row} \
                     samples of {sample_bytes} bytes need {expected}"
                )));
            }
            let packed_data = packed_data as usize;
            if expected > packed_data.saturating_mul(compression.max_expansion()) {
                return Err(self.error(format!(
                    "scanline {y} claims {expected} bytes of samples from {packed_data} packed \
                     bytes, more than {compression:?} can unpack"
                )));
            }
            rows[row] = Some((self.at, packed_data, expected));
        }

        let mut offsets = Vec::with_capacity(width * height + 1);
        offsets.push(0usize);
        for &n in &counts {
            offsets.push(offsets[offsets.len() - 1] + n as usize);
        }
        let mut samples = vec![
            DeepSample {
                color: [0.0; 4],
                depth: 0.0,
                depth_back: 0.0,
                motion: [0.0; 2],
            };
            total_samples
        ];
        // Every scanline was stored once: height distinct chunks, each for a scanline inside
        // the data window.
        for (row, place) in rows.iter().enumerate() {
            let Some((at, packed, expected)) = *place else {
                return Err(self.error(format!(
                    "scanline {} is missing",
                    i64::from(y0) + row as i64
                )));
            };
            let data =
                uncompress(compression, &self.bytes[at..at + packed], expected).map_err(|m| {
                    let y = i64::from(y0) + row as i64;
                    self.error(format!("scanline {y}'s sample data: {m}"))
                })?;
            let first = offsets[row * width];
            let n = offsets[(row + 1) * width] - first;
            let mut at = 0;
            for (k, (_, kind)) in channels.iter().enumerate() {
                let size = kind.bytes();
                let values = &data[at..at + n * size];
                at += n * size;
                for (j, v) in values.chunks_exact(size).enumerate() {
                    let value = decode(*kind, v);
                    let s = &mut samples[first + j];
                    if let Some(c) = map.color.iter().position(|&m| m == k) {
                        s.color[c] = value;
                    }
                    if map.depth == k {
                        s.depth = value;
                    }
                    if map.depth_back == Some(k) {
                        s.depth_back = value;
                    }
                    if let Some(m) = map.motion {
                        if let Some(axis) = m.iter().position(|&m| m == k) {
                            s.motion[axis] = value;
                        }
                    }
                }
            }
        }
        if map.depth_back.is_none() {
            samples.iter_mut().for_each(|s| s.depth_back = s.depth);
        }
        Ok(DeepImage {
            width,
            height,
            overscan,
            offsets,
            samples,
            has_motion: map.motion.is_some(),
            dropped_samples: 0,
            channels_present: channels.into_iter().map(|(n, _)| n).collect(),
        })
    }
}

fn parse_channels(
    value: &[u8],
    error: &dyn Fn(String) -> DeepError,
) -> Result<Vec<(String, PixelType)>, DeepError> {
    let mut out = Vec::new();
    let mut at = 0;
    loop {
        let rest = &value[at.min(value.len())..];
        let Some(len) = rest.iter().take(256).position(|&b| b == 0) else {
            return Err(error("the channel list is not NUL-terminated".into()));
        };
        if len == 0 {
            break;
        }
        let name = String::from_utf8_lossy(&rest[..len]).into_owned();
        let fields = rest
            .get(len + 1..len + 17)
            .ok_or_else(|| error(format!("the channel list ends inside channel {name}")))?;
        let int =
            |k: usize| i32::from_le_bytes([fields[k], fields[k + 1], fields[k + 2], fields[k + 3]]);
        let kind = match int(0) {
            0 => PixelType::Uint,
            1 => PixelType::Half,
            2 => PixelType::Float,
            other => return Err(error(format!("channel {name} has pixel type {other}"))),
        };
        if (int(8), int(12)) != (1, 1) {
            return Err(error(format!(
                "channel {name} is subsampled ({}, {}); deep channels must not be",
                int(8),
                int(12)
            )));
        }
        out.push((name, kind));
        if out.len() > MAX_CHANNELS {
            return Err(error(format!("more than {MAX_CHANNELS} channels")));
        }
        at += len + 17;
    }
    Ok(out)
}

fn map_channels(
    channels: &[(String, PixelType)],
    error: &dyn Fn(String) -> DeepError,
) -> Result<ChannelMap, DeepError> {
    let find = |name: &str| channels.iter().position(|(n, _)| n == name);
    let present = || {
        channels
            .iter()
            .map(|(n, _)| n.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let need = |name: &str| {
        find(name).ok_or_else(|| {
            error(format!(
                "missing channel {name}; a deep image needs R, G, B, A and Z, the file has: {}",
                present()
            ))
        })
    };
    let motion = match (find("forward.u"), find("forward.v")) {
        (Some(u), Some(v)) => Some([u, v]),
        _ => match (find("motion.x"), find("motion.y")) {
            (Some(x), Some(y)) => Some([x, y]),
            _ => None,
        },
    };
    Ok(ChannelMap {
        color: [need("R")?, need("G")?, need("B")?, need("A")?],
        depth: need("Z")?,
        depth_back: find("ZBack"),
        motion,
    })
}

fn decode(kind: PixelType, v: &[u8]) -> f32 {
    match kind {
        PixelType::Half => half::f16::from_le_bytes([v[0], v[1]]).to_f32(),
        PixelType::Float => f32::from_le_bytes([v[0], v[1], v[2], v[3]]),
        PixelType::Uint => u32::from_le_bytes([v[0], v[1], v[2], v[3]]) as f32,
    }
}

fn overscan_of(data: [i32; 4], display: [i32; 4]) -> Option<Overscan> {
    let sides = [
        i64::from(display[0]) - i64::from(data[0]),
        i64::from(display[1]) - i64::from(data[1]),
        i64::from(data[2]) - i64::from(display[2]),
        i64::from(data[3]) - i64::from(display[3]),
    ];
    if sides.iter().any(|&s| s < 0) || display[2] < display[0] || display[3] < display[1] {
        return None;
    }
    Some(Overscan {
        left: sides[0] as usize,
        top: sides[1] as usize,
        right: sides[2] as usize,
        bottom: sides[3] as usize,
    })
}

/// The bytes of a chunk part after its compression: `packed` unpacked to exactly `expected`
/// bytes. A part stored no smaller than it unpacks is raw (what OpenEXR writes when
/// compressing would not pay).
fn uncompress(
    compression: DeepCompression,
    packed: &[u8],
    expected: usize,
) -> Result<Vec<u8>, String> {
    if compression == DeepCompression::None || packed.len() >= expected {
        if packed.len() != expected {
            return Err(format!(
                "{} bytes stored, {expected} expected",
                packed.len()
            ));
        }
        return Ok(packed.to_vec());
    }
    let mut split = match compression {
        DeepCompression::Rle => rle_decode(packed, expected)?,
        DeepCompression::Zips => {
            miniz_oxide::inflate::decompress_to_vec_zlib_with_limit(packed, expected)
                .map_err(|e| format!("zlib: {:?}", e.status))?
        }
        DeepCompression::None => unreachable!("handled above"),
    };
    if split.len() != expected {
        return Err(format!(
            "unpacks to {} bytes, {expected} expected",
            split.len()
        ));
    }
    // Undo the delta predictor, then the split into even and odd bytes.
    for i in 1..split.len() {
        split[i] = split[i - 1].wrapping_add(split[i]).wrapping_sub(128);
    }
    let half = split.len().div_ceil(2);
    let mut out = Vec::with_capacity(expected);
    for k in 0..half {
        out.push(split[k]);
        if half + k < split.len() {
            out.push(split[half + k]);
        }
    }
    Ok(out)
}

/// `raw` compressed as OpenEXR does (byte split, delta predictor, then RLE or zlib); raw
/// where that is not smaller.
fn compress(compression: DeepCompression, raw: &[u8]) -> Vec<u8> {
    if compression == DeepCompression::None || raw.is_empty() {
        return raw.to_vec();
    }
    let half = raw.len().div_ceil(2);
    let mut split: Vec<u8> = Vec::with_capacity(raw.len());
    split.extend(raw.iter().step_by(2));
    split.extend(raw.iter().skip(1).step_by(2));
    debug_assert_eq!(split.len(), raw.len());
    debug_assert!(half <= split.len());
    for i in (1..split.len()).rev() {
        split[i] = split[i].wrapping_sub(split[i - 1]).wrapping_add(128);
    }
    let packed = match compression {
        DeepCompression::Rle => rle_encode(&split),
        DeepCompression::Zips => miniz_oxide::deflate::compress_to_vec_zlib(&split, 6),
        DeepCompression::None => unreachable!("handled above"),
    };
    if packed.len() < raw.len() {
        packed
    } else {
        raw.to_vec()
    }
}

/// OpenEXR's run-length code: a signed count byte; `n >= 0`: the next byte `n + 1` times;
/// `n < 0`: `-n` bytes as they are.
fn rle_decode(packed: &[u8], expected: usize) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(expected);
    let mut at = 0;
    while at < packed.len() {
        let count = packed[at] as i8;
        at += 1;
        if count < 0 {
            let n = usize::from(count.unsigned_abs());
            let literal = packed
                .get(at..at + n)
                .ok_or("a literal run overruns the data")?;
            out.extend_from_slice(literal);
            at += n;
        } else {
            let byte = *packed.get(at).ok_or("a repeat run has no byte")?;
            at += 1;
            out.extend(std::iter::repeat_n(byte, count as usize + 1));
        }
        if out.len() > expected {
            return Err(format!("unpacks to more than {expected} bytes"));
        }
    }
    Ok(out)
}

/// The encoder of [`rle_decode`]'s code, as OpenEXR's `rleCompress`: runs of three or more
/// equal bytes (up to 128) as repeats, the rest as literals (up to 127).
fn rle_encode(raw: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(raw.len() + raw.len() / 64 + 2);
    let n = raw.len();
    let mut start = 0;
    while start < n {
        let mut end = start + 1;
        while end < n && raw[end] == raw[start] && end - start < 128 {
            end += 1;
        }
        if end - start >= 3 {
            out.push((end - start - 1) as u8);
            out.push(raw[start]);
            start = end;
        } else {
            while end < n
                && !(end + 2 < n && raw[end] == raw[end + 1] && raw[end + 1] == raw[end + 2])
                && end - start < 127
            {
                end += 1;
            }
            out.push((-((end - start) as i32)) as i8 as u8);
            out.extend_from_slice(&raw[start..end]);
            start = end;
        }
    }
    out
}

#[cfg(test)]
mod tests {
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
