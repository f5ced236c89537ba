//! The PSF database file: header, flat arrays for the GPU, checksum.
//!
//! Byte layout (all integers little-endian):
//!
//! | offset | size | content |
//! | --- | --- | --- |
//! | 0 | 8 | magic [`MAGIC`] = `SPRDLT\0\x01` |
//! | 8 | 4 | format version `u32` ([`FORMAT_VERSION`]) |
//! | 12 | 8 | header length `H` in bytes, `u64` |
//! | 20 | H | [`DbHeader`], bincode 2 (serde, `config::standard()`) |
//! | 20+H | 40 | array counts, five `u64`: `n_psf`, `n_spreadlets`, `channels`, `n_dense`, `n_dense_data` |
//! | ... | 4 (n_psf+1) | `cumulative: [u32]`, start of each PSF's spreadlets, last = `n_spreadlets` |
//! | ... | 4 n_spreadlets | `positions: [[i16; 2]]`, offset (x right, y down) from the PSF centre, px |
//! | ... | 4 n_spreadlets channels | `values: [f32]`, Laplacian values, channel-interleaved |
//! | ... | 4 n_psf | `dense_slot: [u32]`, `u32::MAX` for a sparse PSF, else an index into `dense` |
//! | ... | 12 n_dense | `dense: [DenseEntry]` (`offset u32, width u16, height u16, origin_x i16, origin_y i16`) |
//! | ... | 4 n_dense_data | `dense_data: [f32]`, dense PSF images, row-major, channel-interleaved |
//! | end-4 | 4 | CRC32 (crc32fast / IEEE) of every byte before it |
//!
//! Readers check, in this order: magic, version, that the header length and the array counts
//! fit the bytes present (before allocating anything), the checksum, the header, and finally
//! that every count, index, offset and position is in bounds. Any failure is a [`DbError`].
//! bincode is used only inside this module.

use std::path::Path;

use bytemuck::{Pod, Zeroable};

use crate::error::DbError;
pub use crate::header::{Aperture, BuildInfo, DbHeader, Dispersion, LensPrescription, PsfStats};
use crate::model::PsfModel;
use crate::space::ParamSpace;

pub use crate::builder::DatabaseBuilder;

/// The first 8 bytes of every database file.
pub const MAGIC: [u8; 8] = *b"SPRDLT\0\x01";
/// The format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 5;
/// `dense_slot` value of a PSF stored as spreadlets.
pub const SPARSE_SLOT: u32 = u32::MAX;
/// Largest header accepted, bytes (the header holds per-PSF statistics: a few MB at most).
pub const MAX_HEADER_BYTES: u64 = 64 << 20;

const PREAMBLE: usize = 20;
const COUNTS: usize = 40;
const CRC: usize = 4;

/// Where a dense (fast-track) PSF image lies in `dense_data`; the GPU struct (12 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct DenseEntry {
    /// Index of the first `f32` in `dense_data`.
    pub offset: u32,
    /// Image width, px.
    pub width: u16,
    /// Image height, px.
    pub height: u16,
    /// x of the image's top-left pixel relative to the PSF centre, px.
    pub origin_x: i16,
    /// y of the image's top-left pixel relative to the PSF centre, px (y down).
    pub origin_y: i16,
}

/// A dense PSF image borrowed from a database.
#[derive(Clone, Copy, Debug)]
pub struct DenseView<'a> {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Offset of the top-left pixel from the PSF centre, px (x right, y down).
    pub origin: [i32; 2],
    /// Channels per pixel.
    pub channels: usize,
    /// `width * height * channels` values, row-major, channel-interleaved (primal PSF values).
    pub data: &'a [f32],
    /// Per row, the columns `[first, end)` outside which the row is zero in every channel
    /// (`[0, 0]` for a zero row): a splat need not visit the rest (a streak's box is mostly
    /// zeros). Empty for an image without pixels.
    pub row_spans: &'a [[u16; 2]],
}

impl DenseView<'_> {
    /// Value at pixel `(x, y)` of the image (not relative to the centre), channel `c`.
    #[inline]
    pub fn get(&self, x: usize, y: usize, c: usize) -> f32 {
        self.data[(y * self.width + x) * self.channels + c]
    }
}

/// A loaded (or freshly built) PSF database.
#[derive(Clone, Debug, PartialEq)]
pub struct PsfDatabase {
    pub(crate) header: DbHeader,
    pub(crate) cumulative: Vec<u32>,
    pub(crate) positions: Vec<[i16; 2]>,
    pub(crate) values: Vec<f32>,
    pub(crate) dense_slot: Vec<u32>,
    pub(crate) dense: Vec<DenseEntry>,
    pub(crate) dense_data: Vec<f32>,
    pub(crate) max_extent_px: u32,
    /// Per dense entry, the index of its first row in `dense_row_spans`; computed on
    /// validation, not stored in the file.
    pub(crate) dense_row_start: Vec<u32>,
    /// Per row of every dense image, the columns `[first, end)` outside which the row is zero
    /// in every channel (`[0, 0]` for a zero row); computed on validation.
    pub(crate) dense_row_spans: Vec<[u16; 2]>,
}

impl PsfDatabase {
    /// The header.
    pub fn header(&self) -> &DbHeader {
        &self.header
    }

    /// The PSF model (shortcut for `header().model`).
    pub fn model(&self) -> PsfModel {
        self.header.model
    }

    /// `Ok` when the database holds `expected` PSFs, else [`DbError::WrongModel`].
    /// A partial file of a sharded build is refused too ([`DbError::Partial`]): it lacks PSFs.
    pub fn expect_model(&self, expected: PsfModel) -> Result<(), DbError> {
        if let Some(r) = &self.header.shard {
            return Err(DbError::Partial {
                index: r.index,
                count: r.count,
            });
        }
        if self.header.model == expected {
            Ok(())
        } else {
            Err(DbError::WrongModel {
                found: self.header.model,
                expected,
            })
        }
    }

    /// The parameter space (shortcut for `header().space`).
    pub fn space(&self) -> &ParamSpace {
        &self.header.space
    }

    /// Number of PSFs.
    pub fn psf_count(&self) -> usize {
        self.dense_slot.len()
    }

    /// Channels per value (1 or 3).
    pub fn channels(&self) -> usize {
        self.header.channels as usize
    }

    /// Spreadlets of PSF `i`: positions (px from the centre) and values
    /// (`channels` per position, interleaved). Empty for a dense PSF. Panics if `i >= psf_count()`.
    #[inline]
    pub fn spreadlets(&self, i: usize) -> (&[[i16; 2]], &[f32]) {
        let a = self.cumulative[i] as usize;
        let b = self.cumulative[i + 1] as usize;
        let c = self.channels();
        (&self.positions[a..b], &self.values[a * c..b * c])
    }

    /// Whether every PSF's spreadlets are in row order (offset y, then x, ascending). The
    /// order of a PSF's spreadlets carries no meaning in the format; row order lets a renderer
    /// that works in bands of rows visit only the spreadlets that fall into a band.
    pub fn spreadlets_in_row_order(&self) -> bool {
        (0..self.psf_count()).all(|i| {
            self.spreadlets(i)
                .0
                .windows(2)
                .all(|w| (w[0][1], w[0][0]) <= (w[1][1], w[1][0]))
        })
    }

    /// `self` with every PSF's spreadlets in row order: unchanged when they already are, else
    /// [`PsfDatabase::with_spreadlets_in_row_order`].
    pub fn into_spreadlets_in_row_order(self) -> PsfDatabase {
        if self.spreadlets_in_row_order() {
            self
        } else {
            self.with_spreadlets_in_row_order()
        }
    }

    /// A copy whose every PSF's spreadlets are in row order (see
    /// [`PsfDatabase::spreadlets_in_row_order`]); everything else is unchanged.
    pub fn with_spreadlets_in_row_order(&self) -> PsfDatabase {
        let mut out = self.clone();
        let ch = self.channels();
        for i in 0..self.psf_count() {
            let (a, b) = (self.cumulative[i] as usize, self.cumulative[i + 1] as usize);
            let mut order: Vec<usize> = (a..b).collect();
            order.sort_by_key(|&k| (self.positions[k][1], self.positions[k][0]));
            for (slot, &k) in (a..b).zip(&order) {
                out.positions[slot] = self.positions[k];
                out.values[slot * ch..(slot + 1) * ch]
                    .copy_from_slice(&self.values[k * ch..(k + 1) * ch]);
            }
        }
        out
    }

    /// The dense image of PSF `i` when it is stored dense (fast track), else `None`.
    /// Panics if `i >= psf_count()`.
    #[inline]
    pub fn dense(&self, i: usize) -> Option<DenseView<'_>> {
        let slot = self.dense_slot[i];
        if slot == SPARSE_SLOT {
            return None;
        }
        let e = self.dense[slot as usize];
        let c = self.channels();
        let len = e.width as usize * e.height as usize * c;
        let off = e.offset as usize;
        let rows = self.dense_row_start[slot as usize] as usize;
        let row_count = if len == 0 { 0 } else { e.height as usize };
        Some(DenseView {
            width: e.width as usize,
            height: e.height as usize,
            origin: [e.origin_x as i32, e.origin_y as i32],
            channels: c,
            data: &self.dense_data[off..off + len],
            row_spans: &self.dense_row_spans[rows..rows + row_count],
        })
    }

    /// The PSF for physical parameters `s` and whether `s` was clamped into the space. O(1).
    #[inline]
    pub fn lookup(&self, s: [f32; 2]) -> (u32, bool) {
        self.header.space.lookup(s)
    }

    /// The neighbouring cell a PSF for `s` is blended with along dimension `dim`, and its
    /// share; see [`crate::ParamSpace::neighbour_blend`].
    pub fn neighbour_blend(&self, s: [f32; 2], dim: usize) -> Option<(u32, f32)> {
        self.header.space.neighbour_blend(s, dim)
    }

    /// [`PsfDatabase::lookup`] and [`PsfDatabase::neighbour_blend`] of one `s` at the cost of
    /// one lookup; see [`crate::ParamSpace::lookup_and_blend`].
    #[inline]
    pub fn lookup_and_blend(&self, s: [f32; 2], dim: usize) -> (u32, bool, Option<(u32, f32)>) {
        self.header.space.lookup_and_blend(s, dim)
    }

    /// [`PsfDatabase::lookup_and_blend`] along the first dimension through `memo`; see
    /// [`crate::ParamSpace::lookup_and_blend_memo`].
    #[inline]
    pub fn lookup_and_blend_memo(
        &self,
        s: [f32; 2],
        memo: &mut crate::CellMemo,
    ) -> (u32, bool, Option<(u32, f32)>) {
        self.header.space.lookup_and_blend_memo(s, memo)
    }

    /// [`PsfDatabase::lookup`] of `[s, 0]` and, with `blend`, its neighbour blend along the
    /// first dimension, through `memo`; see [`crate::ParamSpace::lookup_blended_1d`].
    pub fn lookup_blended_1d(
        &self,
        s: f32,
        blend: bool,
        memo: &mut crate::CellMemo,
    ) -> (u32, bool, Option<(u32, f32)>) {
        self.header.space.lookup_blended_1d(s, blend, memo)
    }

    /// Ceiling of the largest Euclidean distance (px) of any spreadlet or dense pixel from its
    /// PSF centre: the padding a layer needs, valid under any rotation of the PSF.
    pub fn max_extent_px(&self) -> u32 {
        self.max_extent_px
    }

    /// `cumulative` array (`psf_count + 1` entries), as uploaded to the GPU.
    pub fn cumulative(&self) -> &[u32] {
        &self.cumulative
    }

    /// `positions` array (one `[x, y]` per spreadlet).
    pub fn positions(&self) -> &[[i16; 2]] {
        &self.positions
    }

    /// `values` array (`channels` per spreadlet).
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// `dense_slot` array (`psf_count` entries, [`SPARSE_SLOT`] for sparse PSFs).
    pub fn dense_slots(&self) -> &[u32] {
        &self.dense_slot
    }

    /// `dense` entries.
    pub fn dense_entries(&self) -> &[DenseEntry] {
        &self.dense
    }

    /// `dense_data` array.
    pub fn dense_data(&self) -> &[f32] {
        &self.dense_data
    }

    /// Total number of spreadlets.
    pub fn spreadlet_count(&self) -> usize {
        self.positions.len()
    }

    /// Reads and validates a database file. The magic and version are checked on the first
    /// bytes before the rest of the file is read, so a foreign file is rejected cheaply.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, DbError> {
        use std::io::Read;
        let path = path.as_ref();
        let io = |source| DbError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut file = std::fs::File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let mut head = Vec::with_capacity(PREAMBLE);
        (&mut file)
            .take(PREAMBLE as u64)
            .read_to_end(&mut head)
            .map_err(io)?;
        if head.len() < PREAMBLE {
            // Too short for a preamble: let the parser say whether it is foreign or truncated.
            return Self::from_bytes(&head);
        }
        if head[..8] != MAGIC {
            return Err(DbError::BadMagic);
        }
        let version = read_u32(&head, 8);
        if version != FORMAT_VERSION {
            return Err(DbError::UnsupportedVersion {
                found: version,
                expected: FORMAT_VERSION,
            });
        }
        let mut bytes = head;
        bytes.reserve(usize::try_from(len).unwrap_or(0).saturating_sub(PREAMBLE));
        file.read_to_end(&mut bytes).map_err(io)?;
        Self::from_bytes(&bytes)
    }

    /// Writes the database to `path` atomically: a temporary file in the same folder, synced,
    /// then renamed over `path`. Never leaves a half-written file at `path`.
    pub fn write_atomic(&self, path: impl AsRef<Path>) -> Result<(), DbError> {
        let path = path.as_ref();
        let bytes = self.to_bytes()?;
        let io = |source| DbError::Io {
            path: path.to_path_buf(),
            source,
        };
        // An ordinary shared file (0666 less the umask), never half written.
        formats::atomic::write_bytes_atomically(path, &bytes).map_err(|e| match e {
            formats::Error::Io { source, .. } => io(source),
            other => io(std::io::Error::other(other)),
        })
    }

    /// The file's bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>, DbError> {
        let header = bincode::serde::encode_to_vec(&self.header, bincode::config::standard())
            .map_err(|e| DbError::Header(e.to_string()))?;
        let mut out = Vec::with_capacity(
            PREAMBLE
                + header.len()
                + COUNTS
                + 4 * (self.cumulative.len()
                    + self.positions.len()
                    + self.values.len()
                    + self.dense_slot.len()
                    + 3 * self.dense.len()
                    + self.dense_data.len())
                + CRC,
        );
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&(header.len() as u64).to_le_bytes());
        out.extend_from_slice(&header);
        for count in [
            self.dense_slot.len(),
            self.positions.len(),
            self.channels(),
            self.dense.len(),
            self.dense_data.len(),
        ] {
            out.extend_from_slice(&(count as u64).to_le_bytes());
        }
        for v in &self.cumulative {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for p in &self.positions {
            out.extend_from_slice(&p[0].to_le_bytes());
            out.extend_from_slice(&p[1].to_le_bytes());
        }
        for v in &self.values {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in &self.dense_slot {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for e in &self.dense {
            out.extend_from_slice(&e.offset.to_le_bytes());
            out.extend_from_slice(&e.width.to_le_bytes());
            out.extend_from_slice(&e.height.to_le_bytes());
            out.extend_from_slice(&e.origin_x.to_le_bytes());
            out.extend_from_slice(&e.origin_y.to_le_bytes());
        }
        for v in &self.dense_data {
            out.extend_from_slice(&v.to_le_bytes());
        }
        let crc = crc32fast::hash(&out);
        out.extend_from_slice(&crc.to_le_bytes());
        Ok(out)
    }

    /// Parses and validates a database from its bytes (see the module docs for the checks).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, DbError> {
        let found = bytes.len() as u64;
        if bytes.len() < MAGIC.len() {
            return Err(if MAGIC.starts_with(bytes) {
                DbError::Truncated {
                    needed: PREAMBLE as u64,
                    found,
                }
            } else {
                DbError::BadMagic
            });
        }
        if bytes[..8] != MAGIC {
            return Err(DbError::BadMagic);
        }
        if bytes.len() < PREAMBLE {
            return Err(DbError::Truncated {
                needed: PREAMBLE as u64,
                found,
            });
        }
        let version = read_u32(bytes, 8);
        if version != FORMAT_VERSION {
            return Err(DbError::UnsupportedVersion {
                found: version,
                expected: FORMAT_VERSION,
            });
        }
        let header_len = read_u64(bytes, 12);
        let min_needed = ((PREAMBLE + COUNTS + CRC) as u64).saturating_add(header_len);
        if min_needed > found {
            return Err(DbError::Truncated {
                needed: min_needed,
                found,
            });
        }
        if header_len > MAX_HEADER_BYTES {
            return Err(DbError::Header(format!(
                "header length {header_len} exceeds the limit of {MAX_HEADER_BYTES} bytes"
            )));
        }
        let counts_at = PREAMBLE + header_len as usize;
        let n_psf = read_u64(bytes, counts_at);
        let n_spreadlets = read_u64(bytes, counts_at + 8);
        let channels = read_u64(bytes, counts_at + 16);
        let n_dense = read_u64(bytes, counts_at + 24);
        let n_dense_data = read_u64(bytes, counts_at + 32);
        // Every array length in bytes, with overflow counted as "needs more than any file".
        let sizes = [
            n_psf.checked_add(1).and_then(|n| n.checked_mul(4)),
            n_spreadlets.checked_mul(4),
            n_spreadlets
                .checked_mul(channels)
                .and_then(|n| n.checked_mul(4)),
            n_psf.checked_mul(4),
            n_dense.checked_mul(12),
            n_dense_data.checked_mul(4),
        ];
        let mut expected = Some(min_needed);
        for s in sizes {
            expected = expected.and_then(|e| s.and_then(|s| e.checked_add(s)));
        }
        let expected = expected.unwrap_or(u64::MAX);
        if expected > found {
            return Err(DbError::Truncated {
                needed: expected,
                found,
            });
        }
        if expected < found {
            return Err(DbError::LengthMismatch { expected, found });
        }
        let body = bytes.len() - CRC;
        let stored = read_u32(bytes, body);
        let computed = crc32fast::hash(&bytes[..body]);
        if stored != computed {
            return Err(DbError::Checksum { stored, computed });
        }

        let header_bytes = &bytes[PREAMBLE..counts_at];
        let config = bincode::config::standard().with_limit::<{ MAX_HEADER_BYTES as usize }>();
        let (header, used): (DbHeader, usize) =
            bincode::serde::decode_from_slice(header_bytes, config)
                .map_err(|e| DbError::Header(e.to_string()))?;
        if used != header_bytes.len() {
            return Err(DbError::Header(format!(
                "header decodes to {used} bytes, length field says {}",
                header_bytes.len()
            )));
        }
        if header.stored_psf_count() as u64 != n_psf {
            return Err(DbError::OutOfBounds {
                what: format!(
                    "{n_psf} PSFs stored, the header says {}",
                    header.stored_psf_count()
                ),
            });
        }
        if u64::from(header.channels) != channels {
            return Err(DbError::OutOfBounds {
                what: format!(
                    "{channels} channels in the arrays, {} in the header",
                    header.channels
                ),
            });
        }

        // All lengths now agree with the bytes present: allocation is bounded by the file size.
        let mut at = counts_at + COUNTS;
        let mut take = |len: usize| {
            let s = &bytes[at..at + len];
            at += len;
            s
        };
        let cumulative = take(4 * (n_psf as usize + 1))
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let positions = take(4 * n_spreadlets as usize)
            .chunks_exact(4)
            .map(|c| {
                [
                    i16::from_le_bytes([c[0], c[1]]),
                    i16::from_le_bytes([c[2], c[3]]),
                ]
            })
            .collect();
        let values = take(4 * (n_spreadlets * channels) as usize)
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let dense_slot = take(4 * n_psf as usize)
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let dense = take(12 * n_dense as usize)
            .chunks_exact(12)
            .map(|c| DenseEntry {
                offset: u32::from_le_bytes([c[0], c[1], c[2], c[3]]),
                width: u16::from_le_bytes([c[4], c[5]]),
                height: u16::from_le_bytes([c[6], c[7]]),
                origin_x: i16::from_le_bytes([c[8], c[9]]),
                origin_y: i16::from_le_bytes([c[10], c[11]]),
            })
            .collect();
        let dense_data = take(4 * n_dense_data as usize)
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let mut db = PsfDatabase {
            header,
            cumulative,
            positions,
            values,
            dense_slot,
            dense,
            dense_data,
            max_extent_px: 0,
            dense_row_start: Vec::new(),
            dense_row_spans: Vec::new(),
        };
        db.validate()?;
        Ok(db)
    }

    /// Checks every count, index, offset, position and value, computes `max_extent_px` and
    /// finds the dense rows' spans.
    pub(crate) fn validate(&mut self) -> Result<(), DbError> {
        self.validate_structure()?;
        if let Some(k) = first_not_finite(&self.dense_data) {
            return Err(DbError::OutOfBounds {
                what: format!("dense value {k} is not finite"),
            });
        }
        self.find_dense_row_spans();
        Ok(())
    }

    /// [`PsfDatabase::validate`] but for the dense images' values and row spans: every count,
    /// index, offset and position, the spreadlets' values, and `max_extent_px`.
    pub(crate) fn validate_structure(&mut self) -> Result<(), DbError> {
        let oob = |what: String| Err(DbError::OutOfBounds { what });
        let h = &self.header;
        if let Some(r) = &h.shard {
            r.validate(h.space.psf_count())?;
        }
        let n_psf = h.stored_psf_count();
        let ch = h.channels as usize;
        if h.space.dim_count() != h.model.dims() {
            return oob(format!(
                "model {} has {} dimensions, the space {}",
                h.model,
                h.model.dims(),
                h.space.dim_count()
            ));
        }
        if ch != h.model.channels() {
            return oob(format!(
                "model {} has {} channels, the header says {ch}",
                h.model,
                h.model.channels()
            ));
        }
        if h.psf_resolution == 0 || h.psf_resolution > i16::MAX as u32 {
            return oob(format!(
                "PSF resolution {} outside 1..=32767",
                h.psf_resolution
            ));
        }
        if !(h.stats.is_empty() || h.stats.len() == n_psf) {
            return oob(format!("{} PSF stats for {n_psf} PSFs", h.stats.len()));
        }
        if self.dense_slot.len() != n_psf || self.cumulative.len() != n_psf + 1 {
            return oob(format!("array lengths do not match {n_psf} PSFs"));
        }
        if self.values.len() != self.positions.len() * ch {
            return oob("values do not match positions x channels".into());
        }
        if self.cumulative[0] != 0 {
            return oob("cumulative[0] is not 0".into());
        }
        if self.cumulative[n_psf] as usize != self.positions.len() {
            return oob(format!(
                "cumulative ends at {}, {} spreadlets stored",
                self.cumulative[n_psf],
                self.positions.len()
            ));
        }
        if let Some(i) = self.cumulative.windows(2).position(|w| w[1] < w[0]) {
            return oob(format!("cumulative decreases at PSF {i}"));
        }
        let r = h.psf_resolution as i32;
        let mut max_sq: i64 = 0;
        for (k, p) in self.positions.iter().enumerate() {
            let (x, y) = (p[0] as i32, p[1] as i32);
            if x.abs() > r || y.abs() > r {
                return oob(format!(
                    "spreadlet {k} at ({x}, {y}) outside the PSF resolution +-{r}"
                ));
            }
            max_sq = max_sq.max((x * x + y * y) as i64);
        }
        if let Some(k) = self.values.iter().position(|v| !v.is_finite()) {
            return oob(format!("spreadlet value {k} is not finite"));
        }
        let mut used = vec![false; self.dense.len()];
        for (i, &slot) in self.dense_slot.iter().enumerate() {
            if slot == SPARSE_SLOT {
                continue;
            }
            let Some(e) = self.dense.get(slot as usize) else {
                return oob(format!(
                    "PSF {i} has dense slot {slot}, {} dense entries",
                    self.dense.len()
                ));
            };
            if std::mem::replace(&mut used[slot as usize], true) {
                return oob(format!("dense entry {slot} used by two PSFs"));
            }
            if self.cumulative[i] != self.cumulative[i + 1] {
                return oob(format!("PSF {i} is both dense and sparse"));
            }
            let len = e.width as u64 * e.height as u64 * ch as u64;
            if e.offset as u64 + len > self.dense_data.len() as u64 {
                return oob(format!(
                    "dense PSF {i} reads dense_data[{}..{}] of {}",
                    e.offset,
                    e.offset as u64 + len,
                    self.dense_data.len()
                ));
            }
            let (x0, y0) = (e.origin_x as i32, e.origin_y as i32);
            let (x1, y1) = (x0 + e.width as i32 - 1, y0 + e.height as i32 - 1);
            if x0 < -r || y0 < -r || x1 > r || y1 > r {
                return oob(format!(
                    "dense PSF {i} spans ({x0}, {y0})..=({x1}, {y1}), outside +-{r}"
                ));
            }
            if e.width > 0 && e.height > 0 {
                let fx = x0.abs().max(x1.abs()) as i64;
                let fy = y0.abs().max(y1.abs()) as i64;
                max_sq = max_sq.max(fx * fx + fy * fy);
            }
        }
        if let Some(k) = used.iter().position(|u| !u) {
            return oob(format!("dense entry {k} belongs to no PSF"));
        }
        self.max_extent_px = (max_sq as f64).sqrt().ceil() as u32;
        // Images that share values would let a small file ask for rows without end below.
        let held: u64 = self
            .dense
            .iter()
            .map(|e| e.width as u64 * e.height as u64 * ch as u64)
            .sum();
        if held > self.dense_data.len() as u64 {
            return oob(format!(
                "dense images hold {held} values, {} are stored: images share values",
                self.dense_data.len()
            ));
        }
        Ok(())
    }

    /// Fills `dense_row_start` and `dense_row_spans` from the dense images (whose bounds
    /// `validate_structure` has checked).
    fn find_dense_row_spans(&mut self) {
        let ch = self.channels();
        self.dense_row_start.clear();
        self.dense_row_spans.clear();
        let rows = self.append_dense_row_starts(0);
        let mut spans = Vec::with_capacity(rows);
        for e in &self.dense {
            let width = e.width as usize;
            let len = width * e.height as usize * ch;
            if len == 0 {
                continue;
            }
            let image = &self.dense_data[e.offset as usize..e.offset as usize + len];
            spans.extend(image.chunks_exact(width * ch).map(|row| row_span(row, ch)));
        }
        self.dense_row_spans = spans;
    }

    /// Appends to `dense_row_start` the first rows of dense entries `first_entry..`, as if
    /// `dense_row_spans` held every row before them; returns how many rows they have.
    pub(crate) fn append_dense_row_starts(&mut self, first_entry: usize) -> usize {
        let mut next = self.dense_row_spans.len();
        for e in self.dense.get(first_entry..).unwrap_or(&[]) {
            self.dense_row_start.push(next as u32);
            next += rows_of(e);
        }
        next - self.dense_row_spans.len()
    }
}

/// Rows of a dense image in the row spans: none for an image without pixels.
pub(crate) fn rows_of(e: &DenseEntry) -> usize {
    if e.width == 0 {
        0
    } else {
        e.height as usize
    }
}

/// The columns `[first, end)` outside which `row` (`ch` channels a pixel) is zero in every
/// channel; `[0, 0]` for a zero row.
pub(crate) fn row_span(row: &[f32], ch: usize) -> [u16; 2] {
    let lit = |px: &[f32]| px.iter().any(|&v| v != 0.0);
    match row.chunks_exact(ch).position(lit) {
        None => [0, 0],
        Some(first) => {
            let width = row.len() / ch;
            let end = width - row.chunks_exact(ch).rev().position(lit).unwrap_or(0);
            // Widths are u16 in the format.
            [first as u16, end as u16]
        }
    }
}

/// Index of the first value of `values` that is not finite, the values checked in parallel.
fn first_not_finite(values: &[f32]) -> Option<usize> {
    use rayon::prelude::*;
    const CHUNK: usize = 1 << 16;
    let chunk = values
        .par_chunks(CHUNK)
        .position_first(|c| c.iter().any(|v| !v.is_finite()))?;
    let within = values[chunk * CHUNK..]
        .iter()
        .position(|v| !v.is_finite())?;
    Some(chunk * CHUNK + within)
}

fn read_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn read_u64(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}
