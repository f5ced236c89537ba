//! The deep scanline reader: the header's attributes, the offset table and every chunk, each
//! size checked against the file before anything is allocated.

use super::compression::uncompress;
use super::*;
use crate::gbuffer::Overscan;
use crate::limits::{MAX_DEEP_SAMPLES, MAX_PIXELS};

/// Sample value types of OpenEXR channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum PixelType {
    Uint,
    Half,
    Float,
}

impl PixelType {
    pub(super) fn bytes(self) -> usize {
        match self {
            PixelType::Half => 2,
            PixelType::Uint | PixelType::Float => 4,
        }
    }
}

/// Where each channel the image needs sits among the file's channels.
pub(super) struct ChannelMap {
    pub(super) color: [usize; 4],
    pub(super) depth: usize,
    pub(super) depth_back: Option<usize>,
    pub(super) motion: Option<[usize; 2]>,
}

/// A cursor over the file's bytes that turns every overrun into an error naming what was read.
pub(super) struct Reader<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) at: usize,
    pub(super) name: &'a str,
}

impl<'a> Reader<'a> {
    pub(super) fn new(bytes: &'a [u8], name: &'a str) -> Self {
        Reader { bytes, at: 0, name }
    }

    pub(super) fn error(&self, message: impl Into<String>) -> DeepError {
        DeepError::Format {
            path: self.name.to_string(),
            message: message.into(),
        }
    }

    pub(super) fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DeepError> {
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

    pub(super) fn u32(&mut self, what: &str) -> Result<u32, DeepError> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    pub(super) fn i32(&mut self, what: &str) -> Result<i32, DeepError> {
        Ok(self.u32(what)? as i32)
    }

    pub(super) fn u64(&mut self, what: &str) -> Result<u64, DeepError> {
        let b = self.take(8, what)?;
        Ok(u64::from_le_bytes([
            b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7],
        ]))
    }

    /// A NUL-terminated name of at most `max` bytes.
    pub(super) fn name(&mut self, max: usize, what: &str) -> Result<String, DeepError> {
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

    pub(super) fn read(mut self) -> Result<DeepImage, DeepError> {
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

pub(super) fn parse_channels(
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

pub(super) fn map_channels(
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

pub(super) fn decode(kind: PixelType, v: &[u8]) -> f32 {
    match kind {
        PixelType::Half => half::f16::from_le_bytes([v[0], v[1]]).to_f32(),
        PixelType::Float => f32::from_le_bytes([v[0], v[1], v[2], v[3]]),
        PixelType::Uint => u32::from_le_bytes([v[0], v[1], v[2], v[3]]) as f32,
    }
}

pub(super) fn overscan_of(data: [i32; 4], display: [i32; 4]) -> Option<Overscan> {
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
