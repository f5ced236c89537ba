//! A scanline EXR file's first part read as its compressed blocks, each decoded on whichever
//! thread asks for it. A reader that wants the pixels in a layout of its own (a sample per
//! struct, rows of several frames interleaved) decodes each block straight into it, on every
//! thread, instead of first decoding the whole file into one list per channel
//! ([`crate::exr_io::read_channels`]) and copying from there: for a 512 x 512 stochastic frame
//! of 4 spp those lists are 75 MB that are written, faulted in and read once.

use std::collections::BTreeMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use exr::block::chunk::Chunk;
use exr::block::UncompressedBlock;
use exr::meta::attribute::{AttributeValue, SampleType};
use exr::meta::{BlockDescription, MetaData};
use exr::prelude::f16;

use crate::error::{Error, Result};
use crate::exr_io::{check_expansion, MAX_CHANNEL_SAMPLES};

/// The first part of a scanline EXR file: its layout, and its blocks still compressed.
pub struct ScanlineBlocks {
    path: PathBuf,
    meta: MetaData,
    /// Each block's compressed data by block number (top to bottom); `None` where the file
    /// holds none.
    blocks: Vec<Option<Chunk>>,
    /// Width of the data window, pixels.
    pub width: usize,
    /// Height of the data window, pixels (rows).
    pub height: usize,
    /// Rows per block (1 to 256, by compression), the last block perhaps fewer.
    pub rows_per_block: usize,
    /// Text attributes of the part (key to value).
    pub text_attributes: BTreeMap<String, String>,
    /// Channel names, in the file's (alphabetical) order.
    pub channel_names: Vec<String>,
    /// Each channel's sample type and byte offset within a row of a decoded block.
    channels: Vec<(SampleType, usize)>,
    /// Bytes of one row of a decoded block: every channel's samples of that row in turn.
    row_bytes: usize,
}

/// One block decoded: rows `first_row..first_row + rows` of the data window, in the file's
/// native layout (per row, each channel's `width` samples in turn).
pub struct DecodedBlock<'a> {
    file: &'a ScanlineBlocks,
    /// The block's first row in the data window.
    pub first_row: usize,
    /// How many rows it holds.
    pub rows: usize,
    data: Vec<u8>,
}

impl ScanlineBlocks {
    /// Reads the header and every compressed block of `path`'s first part, checking its size
    /// against [`MAX_CHANNEL_SAMPLES`] and its declared pixels against the file's length
    /// ([`check_expansion`]) first. `Ok(None)` for a tiled part or one with subsampled
    /// channels, which [`crate::exr_io::read_channels`] reads instead; an error for a deep one.
    pub fn open(path: &Path) -> Result<Option<Self>> {
        let exr_error = |source| Error::Exr {
            path: path.to_path_buf(),
            source,
        };
        let layout = |message: String| Error::Layout {
            path: path.to_path_buf(),
            message,
        };
        let file = std::fs::File::open(path).map_err(|e| exr_error(e.into()))?;
        let file_len = file.metadata().map_err(|e| exr_error(e.into()))?.len();
        let reader = exr::block::read(BufReader::new(file), false).map_err(exr_error)?;
        let meta = reader.meta_data().clone();
        let header = meta
            .headers
            .first()
            .ok_or_else(|| layout("no image part".to_string()))?;
        let (width, height) = (header.layer_size.0, header.layer_size.1);
        if width
            .checked_mul(height)
            .is_none_or(|n| n > MAX_CHANNEL_SAMPLES)
        {
            return Err(layout(format!(
                "image of {width}x{height} pixels is too large"
            )));
        }
        if header.deep {
            return Err(layout("deep images are not supported".to_string()));
        }
        check_expansion(&meta, file_len).map_err(layout)?;
        let subsampled = header
            .channels
            .list
            .iter()
            .any(|c| c.sampling != exr::math::Vec2(1, 1));
        if !matches!(header.blocks, BlockDescription::ScanLines) || subsampled {
            return Ok(None);
        }
        let rows_per_block = header.compression.scan_lines_per_block();
        let mut channels = Vec::with_capacity(header.channels.list.len());
        let mut offset = 0;
        for channel in &header.channels.list {
            channels.push((channel.sample_type, offset));
            offset += width * channel.sample_type.bytes_per_sample();
        }
        let channel_names = header
            .channels
            .list
            .iter()
            .map(|c| c.name.to_string())
            .collect();
        let text_attributes = header
            .own_attributes
            .other
            .iter()
            .filter_map(|(key, value)| match value {
                AttributeValue::Text(text) => Some((key.to_string(), text.to_string())),
                _ => None,
            })
            .collect();
        let mut blocks: Vec<Option<Chunk>> = vec![None; height.div_ceil(rows_per_block)];
        for chunk in reader.all_chunks(false).map_err(exr_error)? {
            let chunk = chunk.map_err(exr_error)?;
            // Blocks of later parts are not this part's pixels.
            if chunk.layer_index != 0 {
                continue;
            }
            let index = header
                .get_block_data_indices(&chunk.compressed_block)
                .map_err(exr_error)?
                .tile_index
                .1;
            let slot = blocks
                .get_mut(index)
                .ok_or_else(|| layout(format!("pixel block {index} lies below the image")))?;
            if slot.is_some() {
                return Err(layout(format!("pixel block {index} comes twice: corrupt")));
            }
            *slot = Some(chunk);
        }
        Ok(Some(Self {
            path: path.to_path_buf(),
            meta,
            blocks,
            width,
            height,
            rows_per_block,
            text_attributes,
            channel_names,
            channels,
            row_bytes: offset,
        }))
    }

    /// The index of channel `name` among [`Self::channel_names`].
    pub fn channel(&self, name: &str) -> Option<usize> {
        self.channel_names.iter().position(|n| n == name)
    }

    /// Decodes block `index` (rows `index * rows_per_block` onwards); an error naming the file
    /// where it is missing, does not decompress, or decompresses to the wrong size.
    pub fn decode(&self, index: usize) -> Result<DecodedBlock<'_>> {
        let layout = |message: String| Error::Layout {
            path: self.path.clone(),
            message,
        };
        let first_row = index * self.rows_per_block;
        let rows = self
            .rows_per_block
            .min(self.height.saturating_sub(first_row));
        let chunk = self
            .blocks
            .get(index)
            .and_then(Option::as_ref)
            .ok_or_else(|| {
                layout(format!(
                    "no pixel block for rows {first_row}..{}: truncated or corrupt",
                    first_row + rows
                ))
            })?;
        let block = UncompressedBlock::decompress_chunk(chunk.clone(), &self.meta, false).map_err(
            |source| Error::Exr {
                path: self.path.clone(),
                source,
            },
        )?;
        if block.index.pixel_position.1 != first_row
            || block.index.pixel_size.1 != rows
            || block.data.len() != rows * self.row_bytes
        {
            return Err(layout(format!(
                "pixel block for rows {first_row}..{} decodes to {} bytes, not {}: corrupt",
                first_row + rows,
                block.data.len(),
                rows * self.row_bytes
            )));
        }
        Ok(DecodedBlock {
            file: self,
            first_row,
            rows,
            data: block.data,
        })
    }
}

impl DecodedBlock<'_> {
    /// Channel `channel`'s samples along row `row` of the block (0 is its first) into `out`
    /// (one per column, `width` of them), as f32: half widened, u32 converted as `as f32` does.
    pub fn read_row(&self, row: usize, channel: usize, out: &mut [f32]) {
        let (kind, offset) = self.file.channels[channel];
        let start = row * self.file.row_bytes + offset;
        let bytes = &self.data[start..start + self.file.width * kind.bytes_per_sample()];
        match kind {
            SampleType::F32 => {
                for (o, b) in out.iter_mut().zip(bytes.chunks_exact(4)) {
                    *o = f32::from_ne_bytes([b[0], b[1], b[2], b[3]]);
                }
            }
            SampleType::F16 => {
                for (o, b) in out.iter_mut().zip(bytes.chunks_exact(2)) {
                    *o = f16::from_bits(u16::from_ne_bytes([b[0], b[1]])).to_f32();
                }
            }
            SampleType::U32 => {
                for (o, b) in out.iter_mut().zip(bytes.chunks_exact(4)) {
                    *o = u32::from_ne_bytes([b[0], b[1], b[2], b[3]]) as f32;
                }
            }
        }
    }
}
