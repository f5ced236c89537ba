//! Thin EXR helpers: single-part scanline files of named f32 channels, written atomically
//! (temporary file in the target folder, then rename) and read with size checks first.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::Path;

use exr::prelude::*;

use crate::error::{Error, Result};

pub use crate::limits::MAX_CHANNEL_SAMPLES;

/// Channels read from a file: name to row-major samples (row 0 at the top).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Channels {
    /// Width of the data window in pixels.
    pub width: usize,
    /// Height of the data window in pixels.
    pub height: usize,
    /// Every channel, as f32.
    pub data: BTreeMap<String, Vec<f32>>,
    /// Text attributes of the layer that this crate writes (key to value).
    pub text_attributes: BTreeMap<String, String>,
}

impl Channels {
    /// The channel `name`, or a layout error naming the file.
    pub fn take(&mut self, name: &str, path: &Path) -> Result<Vec<f32>> {
        self.data.remove(name).ok_or_else(|| Error::Layout {
            path: path.to_path_buf(),
            message: format!(
                "missing channel {name:?} (has: {})",
                self.data.keys().cloned().collect::<Vec<_>>().join(", ")
            ),
        })
    }
}

/// Writes `channels` (name, row-major samples of `width * height`) as one ZIP-compressed
/// scanline part, plus at most one text attribute (one, so the header bytes never depend on
/// hash-map order). The file appears only when complete.
pub fn write_channels(
    path: &Path,
    width: usize,
    height: usize,
    channels: Vec<(String, Vec<f32>)>,
    text_attribute: Option<(&str, String)>,
) -> Result<()> {
    write_channels_with_overscan(path, width, height, 0, channels, text_attribute)
}

/// [`write_channels`] for an image whose outer `overscan_px` pixels on every side lie outside
/// the frame: the data window is `width x height` from `(-overscan_px, -overscan_px)`, the
/// display window the inner frame from `(0, 0)`.
pub fn write_channels_with_overscan(
    path: &Path,
    width: usize,
    height: usize,
    overscan_px: usize,
    channels: Vec<(String, Vec<f32>)>,
    text_attribute: Option<(&str, String)>,
) -> Result<()> {
    let exr_error = |source| Error::Exr {
        path: path.to_path_buf(),
        source,
    };
    let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    for (name, samples) in channels {
        debug_assert_eq!(samples.len(), width * height, "channel {name}");
        let text = Text::new_or_none(&name).ok_or_else(|| Error::Layout {
            path: path.to_path_buf(),
            message: format!("channel name {name:?} is not valid EXR text"),
        })?;
        list.push(AnyChannel::new(text, FlatSamples::F32(samples)));
    }
    let mut attributes = LayerAttributes::default();
    let overscan = i32::try_from(overscan_px).map_err(|_| Error::Layout {
        path: path.to_path_buf(),
        message: format!("an overscan of {overscan_px} px does not fit the file format"),
    })?;
    attributes.layer_position = Vec2(-overscan, -overscan);
    if let Some((key, value)) = text_attribute {
        let key = Text::new_or_none(key);
        let value = Text::new_or_none(&value);
        if let (Some(key), Some(value)) = (key, value) {
            attributes.other.insert(key, AttributeValue::Text(value));
        }
    }
    let layer = Layer::new(
        (width, height),
        attributes,
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(list),
    );
    let mut image = Image::from_layer(layer);
    image.attributes.display_window = IntegerBounds::new(
        (0, 0),
        (
            width.saturating_sub(2 * overscan_px),
            height.saturating_sub(2 * overscan_px),
        ),
    );
    crate::atomic::write_atomically(path, |file| {
        let writer = BufWriter::new(file);
        image.write().to_buffered(writer).map_err(exr_error)
    })
}

/// Most a compressed EXR's pixel data may expand over the whole file's size (uncompressed
/// files: 1). Deflate (ZIP, ZIPS) cannot exceed 1032:1, RLE 64:1, PIZ, PXR24 and B44 less on
/// any real image; twice deflate's limit leaves room for headers and odd files.
pub const MAX_EXR_EXPANSION: u64 = 2048;

/// Declared pixel bytes any file may have whatever its size (16 MiB), so that small images
/// with large constant areas are never refused.
pub const EXR_EXPANSION_ALLOWANCE: u64 = 16 << 20;

/// Pixel bytes the parts of `meta` declare (at their stored sample types), and whether any
/// part is compressed.
pub fn declared_pixel_bytes(meta: &exr::meta::MetaData) -> (u64, bool) {
    let mut bytes = 0u64;
    let mut compressed = false;
    for h in meta.headers.iter() {
        let pixels = (h.layer_size.width() as u64).saturating_mul(h.layer_size.height() as u64);
        for c in h.channels.list.iter() {
            let per_sample = match c.sample_type {
                SampleType::F16 => 2u64,
                SampleType::F32 | SampleType::U32 => 4u64,
            };
            let sampling = (c.sampling.x().max(1) as u64) * (c.sampling.y().max(1) as u64);
            bytes = bytes.saturating_add(pixels.saturating_mul(per_sample) / sampling);
        }
        compressed |= h.compression != Compression::Uncompressed;
    }
    (bytes, compressed)
}

/// The decoder allocates a part's declared image before it reads its chunks: refuses a
/// header that declares more pixel bytes than a file of `file_len` bytes can hold
/// ([`MAX_EXR_EXPANSION`], at least [`EXR_EXPANSION_ALLOWANCE`]), so that what a file makes
/// the reader allocate grows with the file, not with what it claims. The message says why.
pub fn check_expansion(
    meta: &exr::meta::MetaData,
    file_len: u64,
) -> std::result::Result<(), String> {
    let (declared, compressed) = declared_pixel_bytes(meta);
    let expansion = if compressed { MAX_EXR_EXPANSION } else { 1 };
    let allowed = file_len
        .saturating_mul(expansion)
        .max(EXR_EXPANSION_ALLOWANCE);
    if declared > allowed {
        return Err(format!(
            "the file declares {declared} bytes of pixels in {file_len} bytes, more than its \
             compression can expand to (at most {expansion}x, or {EXR_EXPANSION_ALLOWANCE} bytes \
             for any file): truncated or corrupt"
        ));
    }
    Ok(())
}

/// Reads the first part of an EXR file: checks the header's size against
/// [`MAX_CHANNEL_SAMPLES`] and [`check_expansion`] before any pixel is decoded.
pub fn read_channels(path: &Path) -> Result<Channels> {
    let exr_error = |source| Error::Exr {
        path: path.to_path_buf(),
        source,
    };
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(exr_error)?;
    let header = meta.headers.first().ok_or_else(|| Error::Layout {
        path: path.to_path_buf(),
        message: "no image part".to_string(),
    })?;
    let size = header.layer_size;
    if size
        .0
        .checked_mul(size.1)
        .is_none_or(|n| n > MAX_CHANNEL_SAMPLES)
    {
        return Err(Error::Layout {
            path: path.to_path_buf(),
            message: format!("image of {}x{} pixels is too large", size.0, size.1),
        });
    }
    if header.deep {
        return Err(Error::Layout {
            path: path.to_path_buf(),
            message: "deep images are not supported".to_string(),
        });
    }
    let file_len = std::fs::metadata(path)
        .map_err(|e| exr_error(e.into()))?
        .len();
    check_expansion(&meta, file_len).map_err(|message| Error::Layout {
        path: path.to_path_buf(),
        message,
    })?;
    let image = read_first_flat_layer_from_file(path).map_err(exr_error)?;
    let layer = image.layer_data;
    let mut out = Channels {
        width: layer.size.0,
        height: layer.size.1,
        ..Channels::default()
    };
    for (key, value) in &layer.attributes.other {
        if let AttributeValue::Text(text) = value {
            out.text_attributes
                .insert(key.to_string(), text.to_string());
        }
    }
    for channel in layer.channel_data.list {
        let samples: Vec<f32> = match channel.sample_data {
            // Already f32: moved, not copied (a stochastic frame's channels are hundreds of MB).
            FlatSamples::F32(values) => values,
            other => other.values_as_f32().collect(),
        };
        out.data.insert(channel.name.to_string(), samples);
    }
    Ok(out)
}
