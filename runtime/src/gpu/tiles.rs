//! The tiled splat stage's binning and fixed-point arithmetic on the CPU: the mirror of
//! `shaders/bin.wgsl` (which records go into which screen tiles, and each tile's bound) and of
//! the scale choice in `shaders/splat_tiled.wgsl`, over the same buffers.
//!
//! A tile sums its pixels in i32 workgroup memory at a power-of-two scale `s` chosen from `B`,
//! a bound on the sum of |added values| of any one accumulator (pixel and channel) of the tile:
//! `s B < 2^(29 + b)`, with the sums in two words: a high part in units of `2^b` and `b` (up to
//! 16) fraction bits in a low word. Every add rounds by at most half a unit, so with `n` adds into one
//! accumulator its integer sum stays under `2^29 + n`, which is below `2^31` while
//! `n < 2^30` ([`low_bits`] keeps the low words under `2^30` as well).
//!
//! The bound of a record on one pixel is `max |colour| * min(l1, k * max_abs)`: a pixel gets
//! each sample's value at most once with a weight of at most 1 (so never more than the
//! record's l1), and from at most `k` samples (`stack` per offset, times the samples a rotated
//! placement can bring to one pixel, see [`rotated_samples_per_pixel`]).

use psf_db::PsfDatabase;
use rayon::prelude::*;

use super::layout::{PsfFootprint, TileGrid};
use crate::pipeline::splat::RotationSampling;
use crate::pipeline::types::{FrameParams, SplatPath, SplatRecord};

/// Edge of a splat tile, px (`SPLAT_TILE` in `shaders/common.wgsl`).
pub const SPLAT_TILE: u32 = 16;

/// Words of per-tile state in the tile buffer (`TILE_META` in `shaders/bin.wgsl`).
pub const TILE_META_WORDS: u32 = 8;

/// Workgroup memory the tiled splat needs, bytes (two words for each of 4 channels of the
/// Laplacian and of the direct planes per pixel, and the entry count).
pub const TILED_WORKGROUP_BYTES: u32 = 4 * 4 * 4 * SPLAT_TILE * SPLAT_TILE + 4;

/// Storage buffers the tiled splat binds in one stage.
pub const TILED_STORAGE_BUFFERS: u32 = 11;

/// The footprints of every PSF of `db`: index `2 psf` for its spreadlets, `2 psf + 1` for its
/// dense image's non-zero pixels.
pub fn footprints(db: &PsfDatabase) -> Vec<PsfFootprint> {
    let ch = db.channels().max(1);
    let mut out = Vec::with_capacity(2 * db.psf_count());
    for i in 0..db.psf_count() {
        let (pos, val) = db.spreadlets(i);
        out.push(footprint(
            pos.iter()
                .zip(val.chunks_exact(ch))
                .map(|(p, v)| ((p[0] as i32, p[1] as i32), max_abs(v))),
        ));
        out.push(match db.dense(i) {
            Some(d) => footprint((0..d.height).flat_map(|y| {
                (0..d.width).map(move |x| {
                    let v = &d.data[(y * d.width + x) * d.channels..][..d.channels];
                    ((d.origin[0] + x as i32, d.origin[1] + y as i32), max_abs(v))
                })
            })),
            None => PsfFootprint {
                min_x: 1,
                max_x: 0,
                ..Default::default()
            },
        });
    }
    out
}

fn max_abs(v: &[f32]) -> f32 {
    v.iter().fold(0.0f32, |m, x| m.max(x.abs()))
}

/// The footprint of samples `(offset, largest |value| over channels)`; zero samples are left
/// out (the splat skips them).
fn footprint(samples: impl Iterator<Item = ((i32, i32), f32)>) -> PsfFootprint {
    let mut f = PsfFootprint {
        min_x: i32::MAX,
        min_y: i32::MAX,
        max_x: i32::MIN,
        max_y: i32::MIN,
        ..Default::default()
    };
    let mut seen = std::collections::HashMap::<(i32, i32), u32>::new();
    for ((x, y), m) in samples {
        if m == 0.0 {
            continue;
        }
        f.min_x = f.min_x.min(x);
        f.min_y = f.min_y.min(y);
        f.max_x = f.max_x.max(x);
        f.max_y = f.max_y.max(y);
        let r = ((x as f64).hypot(y as f64)).ceil() as i32;
        f.radius = f.radius.max(r);
        f.max_abs = f.max_abs.max(m);
        f.l1 += m;
        let n = seen.entry((x, y)).or_insert(0);
        *n += 1;
        f.stack = f.stack.max(*n);
    }
    if f.stack == 0 {
        return PsfFootprint {
            min_x: 1,
            max_x: 0,
            ..Default::default()
        };
    }
    f
}

/// Samples of one rotated record that can reach one pixel. A PSF's offsets are distinct
/// integer points, so rotated they stay at least 1 px apart, and a square of side `s` holds at
/// most `(s + 1)^2 / (pi / 4)` of them; a sample reaches pixels within a square of side 1
/// (nearest), 2 (bilinear) or 3 (quadratic B-spline, Laplacian only; dense pixels are split
/// bilinearly).
pub fn rotated_samples_per_pixel(rotation: RotationSampling, to_laplacian: bool) -> u32 {
    match rotation {
        RotationSampling::Nearest => 5,
        RotationSampling::Bspline if to_laplacian => 20,
        _ => 11,
    }
}

/// Where one record goes: the tiles its samples can touch (inclusive) and its bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordSpan {
    /// Layer within the chunk.
    pub layer: u32,
    /// First tile column.
    pub x0: u32,
    /// First tile row.
    pub y0: u32,
    /// Last tile column (inclusive).
    pub x1: u32,
    /// Last tile row (inclusive).
    pub y1: u32,
    /// Whether it draws into the Laplacian planes (else the direct planes).
    pub to_laplacian: bool,
    /// Bound on the sum of |values| it adds to any one accumulator.
    pub bound: f32,
    /// Bound on the number of its adds into any one accumulator.
    pub adds: u32,
    /// Whether it touches few enough tiles to be drawn by them (else by global atomics).
    pub tiled: bool,
}

impl RecordSpan {
    /// Tiles touched.
    pub fn tiles(&self) -> u64 {
        (self.x1 - self.x0 + 1) as u64 * (self.y1 - self.y0 + 1) as u64
    }
}

/// What the binning of one chunk of layers reads besides the records.
#[derive(Clone, Copy, Debug)]
pub struct BinSetup<'a> {
    /// The frame.
    pub frame: &'a FrameParams,
    /// First layer of the chunk.
    pub layer_base: u32,
    /// Layers in the chunk.
    pub layer_count: u32,
    /// PSFs in the database.
    pub psf_count: u32,
    /// Rotated placement.
    pub rotation: RotationSampling,
    /// [`footprints`] of the database.
    pub footprints: &'a [PsfFootprint],
    /// Records touching more tiles are drawn with global atomics.
    pub max_tiles: u32,
}

/// The tiles `r` goes into (`record_span` in `shaders/bin.wgsl`); `None` when it draws nothing
/// in this chunk. Integer arithmetic wraps, as on the GPU.
pub fn record_span(setup: &BinSetup<'_>, r: &SplatRecord) -> Option<RecordSpan> {
    let f = setup.frame;
    if r.layer >= f.layers
        || r.layer < setup.layer_base
        || r.layer - setup.layer_base >= setup.layer_count
    {
        return None;
    }
    let c = r.color;
    let cmax = c[0].abs().max(c[1].abs()).max(c[2].abs().max(c[3].abs()));
    let (mut lo, mut hi) = ((r.center_x, r.center_y), (r.center_x, r.center_y));
    let (to_laplacian, bound, adds);
    if r.path == SplatPath::Copy as u32 {
        (to_laplacian, bound, adds) = (false, cmax, 1);
    } else {
        if r.psf_index >= setup.psf_count
            || (r.path != SplatPath::Sparse as u32 && r.path != SplatPath::Dense as u32)
        {
            return None;
        }
        to_laplacian = r.path == SplatPath::Sparse as u32;
        let fp = setup
            .footprints
            .get(2 * r.psf_index as usize + usize::from(!to_laplacian))?;
        if fp.stack == 0 {
            return None;
        }
        let mut k = fp.stack;
        if r.rot_cos == 1.0 && r.rot_sin == 0.0 {
            lo = (lo.0.wrapping_add(fp.min_x), lo.1.wrapping_add(fp.min_y));
            hi = (hi.0.wrapping_add(fp.max_x), hi.1.wrapping_add(fp.max_y));
        } else {
            k = k.wrapping_mul(rotated_samples_per_pixel(setup.rotation, to_laplacian));
            let m = fp.radius.wrapping_add(2);
            lo = (lo.0.wrapping_sub(m), lo.1.wrapping_sub(m));
            hi = (hi.0.wrapping_add(m), hi.1.wrapping_add(m));
        }
        adds = k;
        bound = cmax * fp.l1.min(k as f32 * fp.max_abs);
    }
    let lo = (lo.0.max(0), lo.1.max(0));
    let hi = (
        hi.0.min(f.padded_width as i32 - 1),
        hi.1.min(f.padded_height as i32 - 1),
    );
    if lo.0 > hi.0 || lo.1 > hi.1 {
        return None;
    }
    let mut s = RecordSpan {
        layer: r.layer - setup.layer_base,
        x0: lo.0 as u32 / SPLAT_TILE,
        y0: lo.1 as u32 / SPLAT_TILE,
        x1: hi.0 as u32 / SPLAT_TILE,
        y1: hi.1 as u32 / SPLAT_TILE,
        to_laplacian,
        bound,
        adds,
        tiled: false,
    };
    s.tiled = s.tiles() <= setup.max_tiles as u64;
    Some(s)
}

/// The tile grid of a chunk of `layers` layers of `frame` (entry capacity 0).
pub fn tile_grid(frame: &FrameParams, layers: u32) -> TileGrid {
    let tiles_x = frame.padded_width.div_ceil(SPLAT_TILE);
    let tiles_y = frame.padded_height.div_ceil(SPLAT_TILE);
    TileGrid {
        tiles_x,
        tiles_y,
        tile_count: tiles_x.saturating_mul(tiles_y).saturating_mul(layers),
        entry_capacity: 0,
    }
}

/// Entries (record, tile pairs) the binning of one chunk writes.
pub fn entry_count(setup: &BinSetup<'_>, records: &[SplatRecord]) -> u64 {
    records
        .par_iter()
        .with_min_len(4096)
        .map(|r| match record_span(setup, r) {
            Some(s) if s.tiled => s.tiles(),
            _ => 0,
        })
        .sum()
}

/// Per tile of one chunk, as the GPU's tile state after binning: record count, bound of the
/// Laplacian and of the direct accumulators, adds bound.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TileBin {
    /// Records binned into the tile.
    pub count: u32,
    /// Bound on any Laplacian accumulator's sum of |values|.
    pub laplacian_bound: f32,
    /// Bound on any direct accumulator's sum of |values|.
    pub direct_bound: f32,
    /// Bound on the adds into any one accumulator.
    pub adds: u32,
}

/// The binning of one chunk on the CPU (bounds summed in record order; the GPU's order varies,
/// so its bounds agree to rounding).
pub fn bin_tiles(setup: &BinSetup<'_>, records: &[SplatRecord]) -> Vec<TileBin> {
    let grid = tile_grid(setup.frame, setup.layer_count);
    let mut bins = vec![TileBin::default(); grid.tile_count as usize];
    for r in records {
        let Some(s) = record_span(setup, r).filter(|s| s.tiled) else {
            continue;
        };
        for ty in s.y0..=s.y1 {
            for tx in s.x0..=s.x1 {
                let t = ((s.layer * grid.tiles_y + ty) * grid.tiles_x + tx) as usize;
                let b = &mut bins[t];
                b.count += 1;
                b.adds = b.adds.wrapping_add(s.adds);
                if s.to_laplacian {
                    b.laplacian_bound += s.bound;
                } else {
                    b.direct_bound += s.bound;
                }
            }
        }
    }
    bins
}

/// The largest power of two `s` with `s * bound < 2^bits` (1 for a bound that is zero,
/// subnormal, above 3e38 or NaN), exponent clamped to f32's normal range: `tile_scale` in `shaders/splat_tiled.wgsl`.
pub fn tile_scale(bound: f32, bits: i32) -> f32 {
    // NaN fails the range test too (subnormals are out: GPUs may flush them).
    if !(f32::MIN_POSITIVE..=3.0e38).contains(&bound) {
        return 1.0;
    }
    // bound = m 2^e with m in [0.5, 1), so bound < 2^e.
    let e = (bound as f64).log2().floor() as i32 + 1;
    let e = if 2f64.powi(e - 1) > bound as f64 {
        e - 1
    } else {
        e
    };
    2f32.powi((bits - e).clamp(-126, 127))
}

/// Fraction bits of the low Laplacian words for a tile whose accumulators get at most `adds`
/// adds: as many (up to 16) as keep `adds * 2^bits <= 2^30`.
pub fn low_bits(adds: u32) -> i32 {
    if adds <= 1 {
        return 16;
    }
    let ceil_log2 = 32 - (adds - 1).leading_zeros() as i32;
    (30 - ceil_log2).clamp(0, 16)
}
