//! Stage 2, splatting: every record adds its PSF, scaled by its premultiplied RGBA, into its
//! layer: sparse PSFs as spreadlets into the layer's Laplacian planes, dense (fast-track) PSFs
//! and copies into the layer's direct planes.
//!
//! Rotation (lens-motion, physical lens): each spreadlet offset (or dense pixel offset) `o` is
//! rotated, `o' = (c o.x - s o.y, s o.x + c o.y)`, and either rounded to the nearest pixel or
//! split bilinearly onto the four surrounding pixels. Bilinear splitting is linear, so in the
//! Laplacian domain it equals splatting the Laplacian of the bilinearly shifted PSF: it stays
//! exact under integration and keeps a rotated streak straight instead of stair-stepped.
//!
//! Determinism: the padded layer is cut into fixed bands of rows; each (layer, band) task
//! walks the layer's records in their order, then the layer's runs of sparse records
//! (`sparse_runs`), and adds only inside its band, so every pixel sums its contributions in the
//! same order whatever the thread count.

use poisson::Plane;
use psf_db::PsfDatabase;
use rayon::prelude::*;

use super::packed::{MirroredImage, PackedImages};
use super::sparse_runs::{draw_run, drawn_in_run, find_runs, LayerRuns};
use super::types::{frame_psf_reach, Classified, FrameParams, SplatPath, SplatRecord};
use super::wide::{WideImage, WideImages};

/// Rows per band of the deterministic parallel splat. A pixel sums its records in record
/// order whatever the band, so the height changes no byte; 64 rows halve the streaks that
/// span two bands against 32 (10 % of a camera pan's splat) and leave a 512 px frame about a
/// dozen bands per layer to share among threads.
pub const BAND_ROWS: usize = 64;

/// How rotated offsets land on the pixel grid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum RotationSampling {
    /// Laplacian spreadlets go onto the 3x3 quadratic B-spline around the nearest pixel
    /// (`bspline_footprint`), which adds the same variance to every spreadlet, so a rotated
    /// PSF keeps its energy (a quarter of its Laplacian's second moment) to rounding; dense
    /// PSFs are split bilinearly, which keeps theirs.
    #[default]
    Bspline,
    /// Split each rotated spreadlet or dense pixel bilinearly onto four pixels. On a
    /// Laplacian this adds the split's variance `tx (1 - tx) + ty (1 - ty)` to every
    /// spreadlet's squared distance, which changes a PSF's energy by up to about 1 %.
    Bilinear,
    /// Round each rotated offset to the nearest pixel.
    Nearest,
}

impl RotationSampling {
    /// The placement for image-space (dense) PSFs: bilinear splitting already keeps their
    /// energy, and the B-spline's fixed variance would blur them more.
    pub fn for_image_space(self) -> Self {
        match self {
            RotationSampling::Bspline => RotationSampling::Bilinear,
            other => other,
        }
    }
}

/// Weights of the quadratic B-spline on the pixels `n - 1, n, n + 1` for a point at offset
/// `d` in `[-0.5, 0.5]` (px) from pixel `n`: `(0.5 - d)^2 / 2`, `0.75 - d^2`,
/// `(0.5 + d)^2 / 2`. They are non-negative and sum to 1, their mean is `d` and their
/// variance is 1/4 px^2 whatever `d` is.
#[inline]
pub fn quadratic_bspline_weights(d: f32) -> [f32; 3] {
    [
        0.5 * (0.5 - d) * (0.5 - d),
        0.75 - d * d,
        0.5 * (0.5 + d) * (0.5 + d),
    ]
}

/// One pixel of a placement footprint: offset `(dx, dy)` (px) and weight.
pub type FootprintTap = (i32, i32, f32);

/// The 3x3 footprint of [`RotationSampling::Bspline`] for a point at `(rx, ry)` (px): the
/// nearest pixel `(nx, ny)` and, for offsets `(i, j)` in `-1..=1` from it, the tensor product
/// of [`quadratic_bspline_weights`]. Every spreadlet keeps its value and centroid and gains
/// the same variance (1/4 px^2 per axis); as a PSF's spreadlets sum to zero, a quarter of
/// their second moment, which is the primal PSF's energy, does not change. Bilinear splitting
/// adds `t (1 - t)` per axis instead, different for every spreadlet.
#[inline]
pub fn bspline_footprint(rx: f32, ry: f32) -> ((i32, i32), [FootprintTap; 9]) {
    let (nx, ny) = (round_exact(rx), round_exact(ry));
    let wx = quadratic_bspline_weights(rx - nx);
    let wy = quadratic_bspline_weights(ry - ny);
    let mut taps = [(0, 0, 0.0f32); 9];
    for (j, &wj) in wy.iter().enumerate() {
        for (i, &wi) in wx.iter().enumerate() {
            taps[j * 3 + i] = (i as i32 - 1, j as i32 - 1, wi * wj);
        }
    }
    ((nx as i32, ny as i32), taps)
}

/// `v.floor()` for `|v| < 2^31`, without the libm call that `f32::floor` compiles to on a
/// target without SSE4.1: a rotated dense pixel's bilinear split calls it twice per pixel.
#[inline(always)]
pub(crate) fn floor_exact(v: f32) -> f32 {
    let t = v as i32 as f32;
    if t > v {
        t - 1.0
    } else {
        t
    }
}

/// `v.round()` (half away from zero) for `|v| < 2^31`, without a libm call. `v - trunc(v)` is
/// exact in f32, so the comparisons with 1/2 are too.
#[inline(always)]
fn round_exact(v: f32) -> f32 {
    let t = v as i32 as f32;
    let f = v - t;
    if f >= 0.5 {
        t + 1.0
    } else if f <= -0.5 {
        t - 1.0
    } else {
        t
    }
}

/// Knobs of splatting.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SplatOptions {
    /// Placement of rotated offsets.
    pub rotation: RotationSampling,
}

/// Per layer, four Laplacian and four direct planes (R, G, B, A), padded.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerStack {
    /// Frame constants (sizes, padding, layers).
    pub frame: FrameParams,
    /// Index `layer * 4 + channel`; `padded_width x padded_height`, or empty (0x0) when the
    /// layer has no sparse record.
    pub laplacian: Vec<Plane>,
    /// Index `layer * 4 + channel`; `padded_width x padded_height`, or empty (0x0) when the
    /// layer has no dense or copied record.
    pub direct: Vec<Plane>,
    /// Per layer, the padded rows `[first, end)` outside which its direct planes are zero
    /// (a layer of a slanted surface draws a strip of the frame); `[0, 0]` for a layer
    /// without direct planes.
    pub direct_rows: Vec<[usize; 2]>,
}

/// Splats every record of `classified`. `db` may be `None` only when every record is a copy.
pub fn splat(
    classified: &Classified,
    db: Option<&PsfDatabase>,
    options: &SplatOptions,
) -> LayerStack {
    let frame = classified.frame;
    let (pw, ph) = (frame.padded_width as usize, frame.padded_height as usize);
    let bands = ph.div_ceil(BAND_ROWS);
    let n_layers = frame.layers as usize;
    let drawing = Drawing::new(classified, db, options);
    let runs = match db {
        Some(db) if classified.layers.iter().any(|l| l.sparse > 0) => {
            let layers: Vec<(usize, usize)> = classified
                .layers
                .iter()
                .map(|l| {
                    (
                        l.first_record,
                        if l.sparse > 0 { l.record_count } else { 0 },
                    )
                })
                .collect();
            find_runs(
                &classified.records,
                &layers,
                db,
                &drawing.reach,
                pw as i32,
                drawing.in_row_order,
            )
        }
        _ => Vec::new(),
    };
    let no_runs = LayerRuns::default();

    // Per (layer, kind), with kind 0 = Laplacian, 1 = direct: whether any record draws in it.
    let present = |l: usize, kind: usize| {
        let info = &classified.layers[l];
        [info.sparse > 0, info.dense + info.copied > 0][kind]
    };
    // The planes first, zeroed on every thread by the allocator, four per present layer and
    // kind (`planes[kind][layer * 4 + channel]`): each band is drawn into a buffer of its
    // thread's, reused from band to band, and written into its rows of its planes, so that
    // the bands' rows are never held twice and no band allocates fresh memory.
    let mut planes: [Vec<Plane>; 2] = [0, 1].map(|kind| {
        (0..n_layers * 4)
            .into_par_iter()
            .map(|index| {
                if present(index / 4, kind) {
                    Plane::new(pw, ph)
                } else {
                    Plane::default()
                }
            })
            .collect()
    });
    // Tasks: (layer, band, kind) and the band's rows of the four planes.
    let mut tasks = Vec::new();
    for (kind, kind_planes) in planes.iter_mut().enumerate() {
        for (l, layer_planes) in kind_planes.chunks_mut(4).enumerate() {
            if !present(l, kind) {
                continue;
            }
            let mut rows = layer_planes
                .iter_mut()
                .map(|p| p.data.chunks_mut(BAND_ROWS * pw))
                .collect::<Vec<_>>();
            for b in 0..bands {
                let mut channel = rows.iter_mut().filter_map(|r| r.next());
                let band_rows = [(); 4].map(|_| channel.next().unwrap_or_default());
                tasks.push(((l, b, kind), band_rows));
            }
        }
    }
    let drawn: Vec<Option<(usize, usize, usize)>> = tasks
        .into_par_iter()
        .map_init(
            Vec::new,
            |buffer: &mut Vec<[f32; 4]>, ((l, b, kind), out)| {
                let info = &classified.layers[l];
                let recs =
                    &classified.records[info.first_record..info.first_record + info.record_count];
                let y0 = (b * BAND_ROWS) as i32;
                let y1 = ((b + 1) * BAND_ROWS).min(ph) as i32;
                let kind = if kind == 0 {
                    Planes::Laplacian
                } else {
                    Planes::Direct
                };
                let rows = BandRows { y0, y1, width: pw };
                let layer_runs = runs.get(l).unwrap_or(&no_runs);
                let band = draw_band(recs, layer_runs, kind, rows, &drawing, buffer)?;
                let [r, g, bl, a] = out;
                for ((((px, r), g), bl), a) in band.data.iter().zip(r).zip(g).zip(bl).zip(a) {
                    (*r, *g, *bl, *a) = (px[0], px[1], px[2], px[3]);
                }
                *buffer = band.data;
                Some((l, b, kind as usize))
            },
        )
        .collect();

    // A layer and kind no band drew in keeps no planes.
    let mut drawn_bands: Vec<Vec<usize>> = vec![Vec::new(); n_layers * 2];
    for &(l, b, kind) in drawn.iter().flatten() {
        drawn_bands[l * 2 + kind].push(b);
    }
    for (kind, kind_planes) in planes.iter_mut().enumerate() {
        for (l, layer_planes) in kind_planes.chunks_mut(4).enumerate() {
            if drawn_bands[l * 2 + kind].is_empty() {
                layer_planes.fill_with(Plane::default);
            }
        }
    }
    let [laplacian, direct] = planes;
    let direct_rows = (0..n_layers)
        .map(|l| {
            let bands = &drawn_bands[l * 2 + 1];
            match (bands.iter().min(), bands.iter().max()) {
                (Some(&first), Some(&last)) => {
                    [first * BAND_ROWS, ((last + 1) * BAND_ROWS).min(ph)]
                }
                _ => [0, 0],
            }
        })
        .collect();
    LayerStack {
        frame,
        laplacian,
        direct,
        direct_rows,
    }
}

/// The two kinds of plane a layer has: spreadlets go into the Laplacian planes, dense images
/// and copied pixels into the direct planes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Planes {
    Laplacian = 0,
    Direct = 1,
}

/// A band's rows of a padded layer: `[y0, y1)`, each `width` pixels.
#[derive(Clone, Copy, Debug)]
pub(super) struct BandRows {
    pub y0: i32,
    pub y1: i32,
    pub width: usize,
}

/// What drawing any band of a frame needs.
pub(super) struct Drawing<'a> {
    /// The database the records index; `None` only when every record is a copy.
    pub db: Option<&'a PsfDatabase>,
    /// [`frame_psf_reach`] of `db` (px, rounded up, +1 for bilinear splitting): a record only visits
    /// the bands its own PSF reaches.
    pub reach: Vec<i32>,
    /// Rows beyond which no record's PSF reaches from its centre: the padding and 2.
    pub extent: i32,
    /// Whether `db`'s spreadlets are in row order.
    pub in_row_order: bool,
    /// The images of `db` kept packed, drawn from here.
    pub packed: Option<&'a PackedImages>,
    /// The RGB images of `db` many records draw upright, widened to four lanes.
    pub wide: WideImages,
    /// Splat options.
    pub options: SplatOptions,
}

impl<'a> Drawing<'a> {
    /// What drawing `classified`'s records from `db` needs.
    pub(super) fn new(
        classified: &'a Classified,
        db: Option<&'a PsfDatabase>,
        options: &SplatOptions,
    ) -> Self {
        Drawing {
            db,
            reach: db.map_or_else(Vec::new, |db| {
                frame_psf_reach(db, classified.packed.as_deref())
            }),
            extent: classified.frame.pad as i32 + 2,
            in_row_order: db.is_some_and(PsfDatabase::spreadlets_in_row_order),
            packed: classified.packed.as_deref(),
            wide: db.map_or_else(WideImages::default, |db| {
                WideImages::for_records(&classified.records, db, classified.packed.as_deref())
            }),
            options: *options,
        }
    }
}

/// Draws the records of one layer (`recs`, in row order) that go into planes of `kind` and
/// reach `rows`, in record order, then (Laplacian planes) the layer's `runs` of sparse
/// records, into a band that takes `buffer`'s memory (give it back with `*buffer =
/// band.data`); `None`, and `buffer` untouched, where no record draws there.
pub(super) fn draw_band(
    recs: &[SplatRecord],
    runs: &LayerRuns,
    kind: Planes,
    rows: BandRows,
    drawing: &Drawing,
    buffer: &mut Vec<[f32; 4]>,
) -> Option<Band> {
    let BandRows { y0, y1, width } = rows;
    let Drawing {
        db,
        ref reach,
        extent,
        in_row_order,
        packed,
        ref wide,
        ref options,
    } = *drawing;
    let packed_image = |r: &SplatRecord| packed.and_then(|p| p.get(r.psf_index));
    // Records are in row order within a layer: the ones that can reach the band.
    let lo = recs.partition_point(|r| r.center_y < y0 - extent);
    let hi = recs.partition_point(|r| r.center_y < y1 + extent);
    // A band no record draws in stays zero: its buffer is cleared at its first record, so the
    // rows no record reaches are never cleared or written (a depth layer of a slanted surface
    // covers a strip of the frame).
    let mut band: Option<Band> = None;
    let new_band = |buffer: &mut Vec<[f32; 4]>| {
        let mut data = std::mem::take(buffer);
        data.clear();
        data.resize((y1 - y0) as usize * width, [0.0f32; 4]);
        Band {
            data,
            width: width as i32,
            y0,
            y1,
        }
    };
    let channels = db.map_or(0, PsfDatabase::channels);
    let all_recs = recs;
    let recs = &recs[lo..hi];
    let mut i = 0;
    while i < recs.len() {
        let r = &recs[i];
        i += 1;
        if let Some(&k) = reach.get(r.psf_index as usize) {
            if r.center_y + k < y0 || r.center_y - k >= y1 {
                continue;
            }
        }
        let drawn_here = match kind {
            Planes::Laplacian => r.path == SplatPath::Sparse as u32,
            Planes::Direct => r.path == SplatPath::Dense as u32 || r.path == SplatPath::Copy as u32,
        };
        if !drawn_here
            || (kind == Planes::Laplacian
                && drawn_in_run(r, reach, width as i32, in_row_order, channels))
        {
            continue;
        }
        let band = band.get_or_insert_with(|| new_band(buffer));
        match (kind, r.path) {
            (Planes::Laplacian, _) => {
                if let Some(db) = db {
                    let reach = reach.get(r.psf_index as usize).copied();
                    splat_sparse(band, r, db, options.rotation, in_row_order, reach);
                }
            }
            (Planes::Direct, p) if p == SplatPath::Dense as u32 => {
                if let Some(image) = packed_image(r) {
                    splat_packed(band, r, image, options.rotation);
                    continue;
                }
                let Some(db) = db else { continue };
                // Two dense records at one centre and one rotation (a fragment blended across
                // a cell boundary, or a split pixel's two parts): drawn as one image, their
                // sum.
                let next = recs
                    .get(i)
                    .filter(|next| drawn_together(r, next) && packed_image(next).is_none());
                if next.is_some() {
                    i += 1;
                }
                if next.is_none() && is_identity(r) {
                    if let Some(image) = wide.get(r.psf_index) {
                        splat_wide(band, r.color, (r.center_x, r.center_y), image);
                        continue;
                    }
                }
                if is_identity(r) {
                    splat_dense_upright(band, r, next, db);
                    continue;
                }
                match next {
                    Some(next) => splat_dense_pair(band, [r, next], db, options.rotation),
                    None => splat_dense(band, r, db, options.rotation),
                }
            }
            (Planes::Direct, _) => {
                band.add(r.center_x, r.center_y, r.color);
            }
        }
    }
    // Then the records drawn a row of pixels at a time, in the runs' order.
    if let (Planes::Laplacian, Some(db)) = (kind, db) {
        let lo = runs.runs.partition_point(|r| r.center_y < y0 - extent);
        let hi = runs.runs.partition_point(|r| r.center_y < y1 + extent);
        let mut colors = Vec::new();
        for run in &runs.runs[lo..hi] {
            let k = reach.get(run.psf_index as usize).copied().unwrap_or(extent);
            if run.center_y + k < y0 || run.center_y - k >= y1 {
                continue;
            }
            let band = band.get_or_insert_with(|| new_band(buffer));
            draw_run(band, run, runs, all_recs, db, &mut colors);
        }
    }
    band
}

/// Rows `[y0, y1)` of a padded layer, RGBA interleaved.
pub(super) struct Band {
    pub(super) data: Vec<[f32; 4]>,
    pub(super) width: i32,
    pub(super) y0: i32,
    pub(super) y1: i32,
}

impl Band {
    /// The band's rows that an image `height` rows tall with its top row at band row `top`
    /// covers, each with the image's row index; none where they do not meet.
    fn image_rows(
        &mut self,
        top: i32,
        height: usize,
    ) -> impl Iterator<Item = (usize, &mut [[f32; 4]])> {
        let (first, end) = (top.max(self.y0), (top + height as i32).min(self.y1));
        let width = self.width as usize;
        let (first_row, count, start) = if first < end {
            (
                (first - top) as usize,
                (end - first) as usize,
                (first - self.y0) as usize * width,
            )
        } else {
            (0, 0, self.data.len())
        };
        (first_row..first_row + count).zip(self.data[start..].chunks_exact_mut(width.max(1)))
    }

    #[inline]
    fn add(&mut self, x: i32, y: i32, v: [f32; 4]) {
        if y < self.y0 || y >= self.y1 || x < 0 || x >= self.width {
            return;
        }
        let px = &mut self.data[((y - self.y0) * self.width + x) as usize];
        for c in 0..4 {
            px[c] += v[c];
        }
    }

    /// Adds `v` at the rotated offset `(ox, oy)` from the record's centre.
    #[inline]
    fn add_rotated(
        &mut self,
        r: &SplatRecord,
        ox: f32,
        oy: f32,
        v: [f32; 4],
        sampling: RotationSampling,
    ) {
        let rx = r.rot_cos * ox - r.rot_sin * oy;
        let ry = r.rot_sin * ox + r.rot_cos * oy;
        // Every placement lands within a pixel and a half of the rotated offset: one that
        // lands two rows or more outside the band adds nothing here, so skip its taps (a
        // record spanning several bands is visited by each).
        let y = r.center_y as f32 + ry;
        if y < (self.y0 - 2) as f32 || y >= (self.y1 + 2) as f32 {
            return;
        }
        match sampling {
            RotationSampling::Nearest => {
                self.add(
                    r.center_x + round_exact(rx) as i32,
                    r.center_y + round_exact(ry) as i32,
                    v,
                );
            }
            // A quarter turn maps pixels onto pixels: nothing to interpolate.
            RotationSampling::Bspline if r.rot_cos == 0.0 || r.rot_sin == 0.0 => {
                self.add(
                    r.center_x + round_exact(rx) as i32,
                    r.center_y + round_exact(ry) as i32,
                    v,
                );
            }
            RotationSampling::Bspline => {
                let ((nx, ny), taps) = bspline_footprint(rx, ry);
                for (dx, dy, wgt) in taps {
                    if wgt != 0.0 {
                        self.add(
                            r.center_x + nx + dx,
                            r.center_y + ny + dy,
                            v.map(|c| c * wgt),
                        );
                    }
                }
            }
            RotationSampling::Bilinear => {
                let (fx, fy) = (floor_exact(rx), floor_exact(ry));
                let (tx, ty) = (rx - fx, ry - fy);
                let (x0, y0) = (r.center_x + fx as i32, r.center_y + fy as i32);
                let ws = [
                    (0, 0, (1.0 - tx) * (1.0 - ty)),
                    (1, 0, tx * (1.0 - ty)),
                    (0, 1, (1.0 - tx) * ty),
                    (1, 1, tx * ty),
                ];
                if y0 >= self.y0 && y0 + 1 < self.y1 && x0 >= 0 && x0 + 1 < self.width {
                    // All four pixels in the band: the same sums without a test per pixel.
                    let at = ((y0 - self.y0) * self.width + x0) as usize;
                    let row = self.width as usize;
                    for (k, (_, _, wgt)) in ws.into_iter().enumerate() {
                        if wgt != 0.0 {
                            let px = &mut self.data[at + (k & 1) + (k >> 1) * row];
                            for c in 0..4 {
                                px[c] += v[c] * wgt;
                            }
                        }
                    }
                } else {
                    for (dx, dy, wgt) in ws {
                        if wgt != 0.0 {
                            self.add(x0 + dx, y0 + dy, v.map(|c| c * wgt));
                        }
                    }
                }
            }
        }
    }
}

/// The value a PSF sample contributes to each of R, G, B, A for a record: grey databases
/// multiply every channel by the one value; RGB databases give alpha the mean of R, G, B.
#[inline]
fn weighted(color: [f32; 4], values: &[f32]) -> [f32; 4] {
    match values {
        [v] => color.map(|c| c * v),
        [r, g, b] => [
            color[0] * r,
            color[1] * g,
            color[2] * b,
            color[3] * (r + g + b) / 3.0,
        ],
        _ => [0.0; 4],
    }
}

#[inline]
fn is_identity(r: &SplatRecord) -> bool {
    r.rot_cos == 1.0 && r.rot_sin == 0.0
}

/// `reach` is the PSF's [`frame_psf_reach`], where known.
fn splat_sparse(
    band: &mut Band,
    r: &SplatRecord,
    db: &PsfDatabase,
    sampling: RotationSampling,
    in_row_order: bool,
    reach: Option<i32>,
) {
    let (positions, values) = db.spreadlets(r.psf_index as usize);
    let ch = db.channels();
    if is_identity(r) {
        // Spreadlets in row order: only those whose row falls into the band.
        let (lo, hi) = if in_row_order {
            (
                positions.partition_point(|p| r.center_y + i32::from(p[1]) < band.y0),
                positions.partition_point(|p| r.center_y + i32::from(p[1]) < band.y1),
            )
        } else {
            (0, positions.len())
        };
        let inside = reach.is_some_and(|k| r.center_x - k >= 0 && r.center_x + k < band.width);
        if in_row_order && inside && ch == 1 {
            // Every spreadlet from `lo` to `hi` lands in the band, rows and columns: the same
            // sums as `Band::add` makes, without its tests.
            let width = band.width as isize;
            let centre = (r.center_y - band.y0) as isize * width + r.center_x as isize;
            for (p, &v) in positions[lo..hi].iter().zip(&values[lo..hi]) {
                let at = centre + isize::from(p[1]) * width + isize::from(p[0]);
                let value = r.color.map(|c| c * v);
                let px = &mut band.data[at as usize];
                for c in 0..4 {
                    px[c] += value[c];
                }
            }
            return;
        }
        for (k, p) in positions.iter().enumerate().take(hi).skip(lo) {
            band.add(
                r.center_x + i32::from(p[0]),
                r.center_y + i32::from(p[1]),
                weighted(r.color, &values[k * ch..(k + 1) * ch]),
            );
        }
    } else {
        let (y_lo, y_hi) = ((band.y0 - 2) as f32, (band.y1 + 2) as f32);
        for (k, p) in positions.iter().enumerate() {
            let (ox, oy) = (f32::from(p[0]), f32::from(p[1]));
            // The band test of `add_rotated`, before the spreadlet's value is weighted.
            let y = r.center_y as f32 + (r.rot_sin * ox + r.rot_cos * oy);
            if y < y_lo || y >= y_hi {
                continue;
            }
            band.add_rotated(
                r,
                ox,
                oy,
                weighted(r.color, &values[k * ch..(k + 1) * ch]),
                sampling,
            );
        }
    }
}

fn splat_dense(band: &mut Band, r: &SplatRecord, db: &PsfDatabase, sampling: RotationSampling) {
    let Some(view) = db.dense(r.psf_index as usize) else {
        return;
    };
    let ch = view.channels;
    let image = DenseImage {
        origin: view.origin,
        width: view.width,
        height: view.height,
    };
    draw_dense(band, r, image, sampling, |u, v| {
        let at = (v * view.width + u) * ch;
        let vals = &view.data[at..at + ch];
        (!vals.iter().all(|&x| x == 0.0)).then(|| weighted(r.color, vals))
    });
}

/// One or two unturned dense records at one centre (`r`, and `next` when the two are drawn
/// together), row by row: each row is clipped to the band and to each PSF's non-zero span once,
/// and a pair's row split where one PSF, the other or both reach, so the loops over pixels test
/// nothing. The sums, and their order, are those of [`splat_dense`] and [`splat_dense_pair`]: a
/// pixel where only one PSF reaches adds that PSF's weighted value, one where both do adds
/// their sum (a zero adds nothing: colours are finite, and no pixel holds -0).
fn splat_dense_upright(
    band: &mut Band,
    r: &SplatRecord,
    next: Option<&SplatRecord>,
    db: &PsfDatabase,
) {
    let Some(a) = db.dense(r.psf_index as usize) else {
        if let Some(next) = next {
            splat_dense(band, next, db, RotationSampling::Nearest);
        }
        return;
    };
    let b = next.and_then(|n| db.dense(n.psf_index as usize).map(|view| (view, n.color)));
    if next.is_some() && b.is_none() {
        // The second record has no dense image: drawn on its own, as the general path does.
        splat_dense_upright(band, r, None, db);
        if let Some(next) = next {
            splat_dense(band, next, db, RotationSampling::Nearest);
        }
        return;
    }
    let ch = a.channels;
    if b.is_none() && (ch == 1 || ch == 3) {
        splat_upright_rows(band, r.color, (r.center_x, r.center_y), &a);
        return;
    }
    if b.as_ref().is_some_and(|(view, _)| view.channels != ch) {
        return;
    }
    let (cx, cy) = (r.center_x, r.center_y);
    // A PSF's pixel rows and columns in band coordinates: [y0, y1) x [x0, x1).
    let span = |v: &psf_db::DenseView| {
        let (x0, y0) = (cx + v.origin[0], cy + v.origin[1]);
        (x0, y0, x0 + v.width as i32, y0 + v.height as i32)
    };
    let sa = span(&a);
    let b = b.map(|(view, color)| {
        let s = span(&view);
        (view, color, s)
    });
    let (ux0, uy0, ux1, uy1) = match &b {
        Some((_, _, sb)) => (
            sa.0.min(sb.0),
            sa.1.min(sb.1),
            sa.2.max(sb.2),
            sa.3.max(sb.3),
        ),
        None => sa,
    };
    let (x_lo, x_hi) = (ux0.max(0), ux1.min(band.width));
    if x_lo >= x_hi {
        return;
    }
    let width = band.width as usize;
    // The non-zero part of a PSF's row at band row y, as (first column in band coordinates,
    // pixels, their values channel-interleaved): the zeros around it add nothing, and a
    // streak's box is mostly zeros.
    fn row_of<'v>(
        v: &psf_db::DenseView<'v>,
        s: (i32, i32, i32, i32),
        y: i32,
    ) -> Option<(i32, usize, &'v [f32])> {
        if y < s.1 || y >= s.3 {
            return None;
        }
        let row = (y - s.1) as usize;
        let [first, end] = v.row_spans.get(row).map_or([0, 0], |s| s.map(usize::from));
        if first >= end {
            return None;
        }
        let (at, ch) = (row * v.width, v.channels);
        Some((
            s.0 + first as i32,
            end - first,
            &v.data[(at + first) * ch..(at + end) * ch],
        ))
    }
    let ca = r.color;
    // Two records of one image (a reconstructed pixel's samples of one surface that did not
    // merge): its own spans, each pixel weighted by both colours and the two summed, as the
    // general pair below sums them, without looking each pixel up in two rows.
    if let (Some(next), Some((_, cb, _))) = (next, &b) {
        if next.psf_index == r.psf_index {
            for y in sa.1.max(band.y0)..sa.3.min(band.y1) {
                let Some((ax0, n, values)) = row_of(&a, sa, y) else {
                    continue;
                };
                let (lo, hi) = (ax0.max(x_lo), (ax0 + n as i32).min(x_hi));
                if lo >= hi {
                    continue;
                }
                let start = (y - band.y0) as usize * width;
                let pixels = &mut band.data[start + lo as usize..start + hi as usize];
                let values = &values[(lo - ax0) as usize * ch..(hi - ax0) as usize * ch];
                add_pair_row(pixels, values, values, ch, (ca, *cb));
            }
            return;
        }
    }
    for y in uy0.max(band.y0)..uy1.min(band.y1) {
        let start = (y - band.y0) as usize * width;
        let row = &mut band.data[start..start + width];
        let ra = row_of(&a, sa, y);
        match &b {
            None => {
                let Some((ax0, n, values)) = ra else { continue };
                let (lo, hi) = (ax0.max(x_lo), (ax0 + n as i32).min(x_hi));
                if lo >= hi {
                    continue;
                }
                let values = &values[(lo - ax0) as usize * ch..(hi - ax0) as usize * ch];
                // Grey and RGB images are drawn by `splat_upright_rows`; other channel
                // counts here.
                add_row(&mut row[lo as usize..hi as usize], values, ch, ca);
            }
            Some((bv, cb, sb)) => {
                // Each PSF's non-zero span of the row clipped to the band: its columns and
                // their values.
                fn clip(
                    rv: Option<(i32, usize, &[f32])>,
                    width: i32,
                    ch: usize,
                ) -> Option<(usize, usize, &[f32])> {
                    let (x0, n, values) = rv?;
                    let (lo, hi) = (x0.max(0), (x0 + n as i32).min(width));
                    let at = |x: i32| (x - x0) as usize * ch;
                    (lo < hi).then(|| (lo as usize, hi as usize, &values[at(lo)..at(hi)]))
                }
                let (ra, rb) = (
                    clip(ra, band.width, ch),
                    clip(row_of(bv, *sb, y), band.width, ch),
                );
                match (ra, rb) {
                    (None, None) => {}
                    (Some((lo, hi, va)), None) => add_row(&mut row[lo..hi], va, ch, ca),
                    (None, Some((lo, hi, vb))) => add_row(&mut row[lo..hi], vb, ch, *cb),
                    (Some((a_lo, a_hi, va)), Some((b_lo, b_hi, vb))) => {
                        // Where one PSF alone reaches a pixel it adds its value, where both do
                        // they add their sum: each pixel one addition, in stretches of plain
                        // loops.
                        let (lo, hi) = (a_lo.max(b_lo), a_hi.min(b_hi));
                        if lo >= hi {
                            add_row(&mut row[a_lo..a_hi], va, ch, ca);
                            add_row(&mut row[b_lo..b_hi], vb, ch, *cb);
                            continue;
                        }
                        for (from, to, values, colour) in
                            [(a_lo, a_hi, va, ca), (b_lo, b_hi, vb, *cb)]
                        {
                            let at = |x: usize| (x - from) * ch;
                            if from < lo {
                                add_row(&mut row[from..lo], &values[..at(lo)], ch, colour);
                            }
                            if hi < to {
                                add_row(&mut row[hi..to], &values[at(hi)..], ch, colour);
                            }
                        }
                        let a = &va[(lo - a_lo) * ch..(hi - a_lo) * ch];
                        let b = &vb[(lo - b_lo) * ch..(hi - b_lo) * ch];
                        add_pair_row(&mut row[lo..hi], a, b, ch, (ca, *cb));
                    }
                }
            }
        }
    }
}

/// `pixels[i] += weighted(colour, values of pixel i)` along a row (`values` channel-interleaved,
/// `channels` a pixel). A PSF's zeros add nothing to a pixel (colours are finite and no pixel
/// holds -0), so they are added rather than tested, and the loop is straight.
#[inline]
fn add_row(pixels: &mut [[f32; 4]], values: &[f32], channels: usize, colour: [f32; 4]) {
    let add = |px: &mut [f32; 4], value: [f32; 4]| {
        for k in 0..4 {
            px[k] += value[k];
        }
    };
    match channels {
        1 => pixels
            .iter_mut()
            .zip(values)
            .for_each(|(px, &v)| add(px, weighted(colour, &[v]))),
        3 => pixels
            .iter_mut()
            .zip(values.chunks_exact(3))
            .for_each(|(px, v)| add(px, weighted(colour, &[v[0], v[1], v[2]]))),
        _ => pixels
            .iter_mut()
            .zip(values.chunks_exact(channels.max(1)))
            .for_each(|(px, v)| add(px, weighted(colour, v))),
    }
}

/// `pixels[i] += weighted(colours.0, a_i) + weighted(colours.1, b_i)` along a row: two PSFs at
/// one centre (or one PSF under two records' colours), their sum added in one step, as
/// [`splat_dense_pair`] adds it. Zeros are added, not tested, as in [`add_row`].
#[inline]
fn add_pair_row(
    pixels: &mut [[f32; 4]],
    a: &[f32],
    b: &[f32],
    channels: usize,
    colours: ([f32; 4], [f32; 4]),
) {
    let add = |px: &mut [f32; 4], p: [f32; 4], q: [f32; 4]| {
        for k in 0..4 {
            px[k] += p[k] + q[k];
        }
    };
    let (ca, cb) = colours;
    match channels {
        1 => pixels
            .iter_mut()
            .zip(a.iter().zip(b))
            .for_each(|(px, (&u, &v))| add(px, weighted(ca, &[u]), weighted(cb, &[v]))),
        3 => pixels
            .iter_mut()
            .zip(a.chunks_exact(3).zip(b.chunks_exact(3)))
            .for_each(|(px, (u, v))| {
                add(
                    px,
                    weighted(ca, &[u[0], u[1], u[2]]),
                    weighted(cb, &[v[0], v[1], v[2]]),
                )
            }),
        _ => pixels
            .iter_mut()
            .zip(
                a.chunks_exact(channels.max(1))
                    .zip(b.chunks_exact(channels.max(1))),
            )
            .for_each(|(px, (u, v))| add(px, weighted(ca, u), weighted(cb, v))),
    }
}

/// One grey or RGB dense image `v` weighted by `colour`, drawn upright centred on `centre`
/// (band coordinates): [`splat_upright_spans`] of its rows' non-zero spans.
fn splat_upright_rows(
    band: &mut Band,
    colour: [f32; 4],
    centre: (i32, i32),
    v: &psf_db::DenseView,
) {
    let ch = v.channels;
    if v.width == 0 {
        return;
    }
    let row = |y: usize| {
        let span = v.row_spans[y];
        let [first, end] = span.map(usize::from);
        let at = y * v.width;
        (span, &v.data[(at + first) * ch..(at + end) * ch])
    };
    let top_left = (centre.0 + v.origin[0], centre.1 + v.origin[1]);
    let height = v.height.min(v.row_spans.len());
    splat_upright_spans(band, colour, top_left, height, ch, false, row);
}

/// A grey or RGB image of `height` rows weighted by `colour`, drawn upright with its box's
/// top-left pixel at `top_left` (band coordinates): `row(v)` is row `v`'s span `[first, end)`
/// of columns and their values (right to left where `reversed`), each pixel one four-wide
/// multiply and add (`Vec4` is a SIMD register where the target has one). A PSF's rows are
/// short, so the rows are walked together with the band's, with no per-row lookups beyond the
/// span.
fn splat_upright_spans<'v>(
    band: &mut Band,
    colour: [f32; 4],
    top_left: (i32, i32),
    height: usize,
    ch: usize,
    reversed: bool,
    row: impl Fn(usize) -> ([u16; 2], &'v [f32]),
) {
    let (x0, y0) = top_left;
    let band_width = band.width;
    let colour4 = glam::Vec4::from_array(colour);
    // Red, green and blue by the colour, alpha by the mean of the three weights, as `weighted`
    // does.
    let rgb_weights = glam::Vec4::new(colour[0], colour[1], colour[2], colour[3] / 3.0);
    let add_grey = |px: &mut [f32; 4], v: f32| {
        *px = (glam::Vec4::from_array(*px) + colour4 * v).to_array();
    };
    let add_rgb = |px: &mut [f32; 4], vals: &[f32]| {
        let (r, g, b) = (vals[0], vals[1], vals[2]);
        let value = rgb_weights * glam::Vec4::new(r, g, b, r + g + b);
        *px = (glam::Vec4::from_array(*px) + value).to_array();
    };
    for (v, band_row) in band.image_rows(y0, height) {
        let (span, values) = row(v);
        let start = x0 + i32::from(span[0]);
        let (lo, hi) = (start.max(0), (x0 + i32::from(span[1])).min(band_width));
        if lo >= hi {
            continue;
        }
        let pixels = &mut band_row[lo as usize..hi as usize];
        if reversed {
            // Column `start + i` holds value `n - 1 - i` of the row's `n`.
            let n = (i32::from(span[1]) - i32::from(span[0])) as usize;
            let (a, b) = (n - (hi - start) as usize, n - (lo - start) as usize);
            let values = &values[a * ch..b * ch];
            if ch == 1 {
                pixels
                    .iter_mut()
                    .zip(values.iter().rev())
                    .for_each(|(px, &v)| add_grey(px, v));
            } else {
                pixels
                    .iter_mut()
                    .zip(values.chunks_exact(3).rev())
                    .for_each(|(px, v)| add_rgb(px, v));
            }
            continue;
        }
        let values = &values[(lo - start) as usize * ch..(hi - start) as usize * ch];
        if ch == 1 {
            pixels
                .iter_mut()
                .zip(values)
                .for_each(|(px, &v)| add_grey(px, v));
        } else {
            pixels
                .iter_mut()
                .zip(values.chunks_exact(3))
                .for_each(|(px, v)| add_rgb(px, v));
        }
    }
}

/// An upright record drawn from its widened image ([`WideImage`]): each pixel one four-wide
/// load, multiply and add, with the values `splat_upright_rows` would compute from the
/// database's three channels.
fn splat_wide(band: &mut Band, colour: [f32; 4], centre: (i32, i32), image: &WideImage) {
    let (x0, y0) = (centre.0 + image.origin[0], centre.1 + image.origin[1]);
    let band_width = band.width;
    let weights = glam::Vec4::new(colour[0], colour[1], colour[2], colour[3] / 3.0);
    for (v, band_row) in band.image_rows(y0, image.height()) {
        let (span, values) = image.row(v);
        let start = x0 + i32::from(span[0]);
        let (lo, hi) = (start.max(0), (x0 + i32::from(span[1])).min(band_width));
        if lo >= hi {
            continue;
        }
        let pixels = &mut band_row[lo as usize..hi as usize];
        let values = &values[(lo - start) as usize..(hi - start) as usize];
        for (px, v) in pixels.iter_mut().zip(values) {
            *px = (glam::Vec4::from_array(*px) + weights * glam::Vec4::from_array(*v)).to_array();
        }
    }
}

/// A dense record whose image is packed ([`super::packed::PackedImage`]): upright from its rows' spans, as
/// [`splat_upright_rows`] draws the same image from the database; turned (no packed image is
/// today) from its box.
fn splat_packed(
    band: &mut Band,
    r: &SplatRecord,
    image: MirroredImage,
    sampling: RotationSampling,
) {
    let ch = image.image.channels;
    let height = image.height();
    let origin = image.origin();
    if is_identity(r) && (ch == 1 || ch == 3) {
        let top_left = (r.center_x + origin[0], r.center_y + origin[1]);
        splat_upright_spans(band, r.color, top_left, height, ch, image.mirrors[0], |v| {
            image.row(v)
        });
        return;
    }
    let boxed = image.unpacked_box();
    let width = image.image.width;
    let dense = DenseImage {
        origin,
        width,
        height,
    };
    draw_dense(band, r, dense, sampling, |u, v| {
        let at = (v * width + u) * ch;
        let vals = &boxed[at..at + ch];
        (!vals.iter().all(|&x| x == 0.0)).then(|| weighted(r.color, vals))
    });
}

/// Whether `next` can be drawn in one pass with `r`: both dense, at the same centre, turned
/// by the same rotation (the two PSFs of a fragment blended across a cell boundary).
#[inline]
fn drawn_together(r: &SplatRecord, next: &SplatRecord) -> bool {
    next.path == SplatPath::Dense as u32
        && (next.center_x, next.center_y) == (r.center_x, r.center_y)
        && next.rot_cos.to_bits() == r.rot_cos.to_bits()
        && next.rot_sin.to_bits() == r.rot_sin.to_bits()
}

/// Two dense records at one centre with one rotation, drawn as one RGBA image: the sum of
/// their weighted PSFs over the union of their boxes, summed where a pixel is placed. Placing
/// is linear in the values, so this is the sum of drawing each, to rounding, at the cost of
/// drawing one: a fragment blended across a cell boundary costs little more than one that is
/// not.
fn splat_dense_pair(
    band: &mut Band,
    records: [&SplatRecord; 2],
    db: &PsfDatabase,
    sampling: RotationSampling,
) {
    let (Some(a), Some(b)) = (
        db.dense(records[0].psf_index as usize),
        db.dense(records[1].psf_index as usize),
    ) else {
        for r in records {
            splat_dense(band, r, db, sampling);
        }
        return;
    };
    let x0 = a.origin[0].min(b.origin[0]);
    let y0 = a.origin[1].min(b.origin[1]);
    let x1 = (a.origin[0] + a.width as i32).max(b.origin[0] + b.width as i32);
    let y1 = (a.origin[1] + a.height as i32).max(b.origin[1] + b.height as i32);
    let image = DenseImage {
        origin: [x0, y0],
        width: (x1 - x0) as usize,
        height: (y1 - y0) as usize,
    };
    // One PSF's weighted value at union pixel (u, v), if it has a non-zero one there.
    let value_of = |view: &psf_db::DenseView, color: [f32; 4], u: usize, v: usize| {
        let lu = (x0 + u as i32 - view.origin[0]) as usize;
        let lv = (y0 + v as i32 - view.origin[1]) as usize;
        if lu >= view.width || lv >= view.height {
            return None;
        }
        let ch = view.channels;
        let at = (lv * view.width + lu) * ch;
        let vals = &view.data[at..at + ch];
        (!vals.iter().all(|&x| x == 0.0)).then(|| weighted(color, vals))
    };
    draw_dense(band, records[0], image, sampling, |u, v| {
        match (
            value_of(&a, records[0].color, u, v),
            value_of(&b, records[1].color, u, v),
        ) {
            (Some(p), Some(q)) => Some(std::array::from_fn(|c| p[c] + q[c])),
            (p, q) => p.or(q),
        }
    });
}

/// Where a dense image lies around its record's centre, px.
#[derive(Clone, Copy)]
struct DenseImage {
    /// Offset of the top-left pixel from the centre (x right, y down).
    origin: [i32; 2],
    width: usize,
    height: usize,
}

/// Draws a dense image placed at `r`'s centre and turned by its rotation into `band`;
/// `value_at(u, v)` is the RGBA value of pixel `(u, v)`, `None` where it is zero.
#[inline]
fn draw_dense(
    band: &mut Band,
    r: &SplatRecord,
    image: DenseImage,
    sampling: RotationSampling,
    value_at: impl Fn(usize, usize) -> Option<[f32; 4]>,
) {
    let identity = is_identity(r);
    let sampling = sampling.for_image_space();
    // Unrotated: only the rows that fall inside the band.
    let (v0, v1) = if identity {
        let top = r.center_y + image.origin[1];
        (
            (band.y0 - top).clamp(0, image.height as i32) as usize,
            (band.y1 - top).clamp(0, image.height as i32) as usize,
        )
    } else {
        (0, image.height)
    };
    let (y_lo, y_hi) = ((band.y0 - 2) as f32, (band.y1 + 2) as f32);
    for v in v0..v1 {
        let (u0, u1) = if identity {
            (0, image.width)
        } else {
            let oy = (image.origin[1] + v as i32) as f32;
            match rotated_row_span(r, image.origin[0], oy, image.width, y_lo, y_hi) {
                Some(span) => span,
                None => continue,
            }
        };
        for u in u0..u1 {
            let Some(value) = value_at(u, v) else {
                continue;
            };
            let ox = image.origin[0] + u as i32;
            let oy = image.origin[1] + v as i32;
            if identity {
                band.add(r.center_x + ox, r.center_y + oy, value);
            } else {
                band.add_rotated(r, ox as f32, oy as f32, value, sampling);
            }
        }
    }
}

/// The pixels `u0..u1` of a dense PSF row at offset `oy` (first pixel at offset `ox0`,
/// `width` pixels) that the record's rotation can place in rows `[y_lo, y_hi)`, or `None` when
/// none can. The rotated row is the line `y(u) = centre_y + sin (ox0 + u) + cos oy`; its span
/// is widened by a pixel either side against rounding, and `Band::add_rotated` still tests
/// each pixel, so a band sums exactly what it summed when it visited the whole row.
#[inline]
fn rotated_row_span(
    r: &SplatRecord,
    ox0: i32,
    oy: f32,
    width: usize,
    y_lo: f32,
    y_hi: f32,
) -> Option<(usize, usize)> {
    let base = r.center_y as f32 + r.rot_sin * ox0 as f32 + r.rot_cos * oy;
    let slope = r.rot_sin;
    if slope.abs() * (width as f32) < 0.5 {
        // Nearly level: the row is in the band or not as a whole.
        return (base >= y_lo - 1.0 && base < y_hi + 1.0).then_some((0, width));
    }
    let (a, b) = ((y_lo - base) / slope, (y_hi - base) / slope);
    let (lo, hi) = (a.min(b).floor() - 1.0, a.max(b).ceil() + 1.0);
    let u0 = lo.clamp(0.0, width as f32) as usize;
    let u1 = (hi + 1.0).clamp(0.0, width as f32) as usize;
    (u0 < u1).then_some((u0, u1))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One layer of `records` on a `w x h` frame padded by `pad`, each record counted on the
    /// path it names.
    fn one_layer(records: &[SplatRecord], w: u32, h: u32, pad: u32) -> Classified {
        use crate::pipeline::types::{LayerInfo, PathCounts};
        let mut layer = LayerInfo {
            first_record: 0,
            record_count: records.len(),
            ..LayerInfo::default()
        };
        layer.count_paths(records);
        Classified {
            frame: FrameParams {
                width: w,
                height: h,
                pad,
                layers: 1,
                padded_width: w + 2 * pad,
                padded_height: h + 2 * pad,
                record_count: records.len() as u32,
                db_channels: 1,
            },
            layers: vec![layer],
            records: records.to_vec(),
            counts: PathCounts::default(),
            database: None,
            packed: None,
            coarse: Vec::new(),
        }
    }

    /// Asserts that the four planes (R, G, B, A of a layer `width` px wide) hold `expected`
    /// to 1e-6, and that something was drawn.
    fn assert_planes_hold(planes: &[Plane], expected: &[[f64; 4]], width: i32) {
        let mut largest = 0.0f64;
        for (c, plane) in planes[..4].iter().enumerate() {
            for (k, &got) in plane.data.iter().enumerate() {
                let want = expected[k][c];
                largest = largest.max(want.abs());
                assert!(
                    (f64::from(got) - want).abs() <= 1e-6,
                    "channel {c}, pixel ({}, {}): {got} against {want}",
                    k as i32 % width,
                    k as i32 / width
                );
            }
        }
        assert!(largest > 0.01, "something was drawn");
    }

    /// Unturned sparse records, whole inside the band's columns and cut by the padded frame's
    /// edges, across a band boundary, add each spreadlet times the record's colour at the
    /// record's centre plus the spreadlet's offset: checked against a plain sum.
    #[test]
    fn unturned_sparse_records_land_where_their_spreadlets_say() {
        let (db, psfs) = patterned_sparse_database();
        let n = psfs.len();
        let (w, h, pad) = (30u32, 120u32, 6u32);
        let (pw, ph) = ((w + 2 * pad) as i32, (h + 2 * pad) as i32);
        let centres = [
            (20, 30),
            (3, 63),
            (pw - 1, 64),
            (17, 65),
            (pw - 2, ph - 1),
            (10, 127),
        ];
        let records: Vec<SplatRecord> = centres
            .iter()
            .enumerate()
            .map(|(k, &(cx, cy))| SplatRecord {
                center_x: cx,
                center_y: cy,
                psf_index: (k % n) as u32,
                layer: 0,
                rot_cos: 1.0,
                rot_sin: 0.0,
                weight: 1.0,
                path: SplatPath::Sparse as u32,
                color: [0.9, 0.5, 0.2, 1.0],
            })
            .collect();
        let classified = one_layer(&records, w, h, pad);
        let stack = splat(&classified, Some(&db), &SplatOptions::default());
        let expected = sparse_sum(&records, &psfs, pw, ph);
        assert_planes_hold(&stack.laplacian, &expected, pw);
    }

    /// A sparse PSF's spreadlets: offsets and values.
    type Spreadlets = (Vec<[i16; 2]>, Vec<f32>);

    /// A thin-lens database of sparse PSFs of radius 2 to 7 px with patterned spreadlets of
    /// both signs, in row order, and each PSF's spreadlets.
    fn patterned_sparse_database() -> (PsfDatabase, Vec<Spreadlets>) {
        use psf_db::{DatabaseBuilder, DbHeader, ParamSpace, PsfModel};
        let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 8).expect("space");
        let n = space.psf_count() as usize;
        let mut builder = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space, 32));
        let mut psfs = Vec::new();
        for i in 0..n {
            let r = 2 + (i % 6) as i16;
            let mut positions = Vec::new();
            let mut values = Vec::new();
            for y in -r..=r {
                for x in -r..=r {
                    if (x * 3 + y * 5 + i as i16).rem_euclid(4) == 0 {
                        positions.push([x, y]);
                        values.push(0.01 * f32::from(1 + (x - y).rem_euclid(7)) - 0.03);
                    }
                }
            }
            builder.push_sparse(&positions, &values).expect("sparse");
            psfs.push((positions, values));
        }
        let db = builder.finish().expect("database");
        assert!(db.spreadlets_in_row_order());
        (db, psfs)
    }

    /// Every record's spreadlets times its colour, summed in f64 on a `pw x ph` padded
    /// layer, clipped to it.
    fn sparse_sum(records: &[SplatRecord], psfs: &[Spreadlets], pw: i32, ph: i32) -> Vec<[f64; 4]> {
        let mut expected = vec![[0.0f64; 4]; (pw * ph) as usize];
        for r in records {
            let (positions, values) = &psfs[r.psf_index as usize];
            for (p, &v) in positions.iter().zip(values) {
                let (x, y) = (r.center_x + i32::from(p[0]), r.center_y + i32::from(p[1]));
                if x < 0 || y < 0 || x >= pw || y >= ph {
                    continue;
                }
                for (sum, &c) in expected[(y * pw + x) as usize].iter_mut().zip(&r.color) {
                    *sum += f64::from(c) * f64::from(v);
                }
            }
        }
        expected
    }

    /// Rows of sparse records as a defocused surface gives them: every pixel draws two PSFs
    /// (a blend across a cell boundary), interleaved, the PSFs changing along the row and
    /// from row to row, a pixel drawn twice with one PSF, rows across a band boundary and
    /// pixels near the padded frame's edges (drawn alone). Drawn in runs, they add what a plain
    /// sum of every record's spreadlets adds.
    #[test]
    fn rows_of_sparse_records_drawn_in_runs_land_where_their_spreadlets_say() {
        let (db, psfs) = patterned_sparse_database();
        let n = psfs.len() as u32;
        let (w, h, pad) = (40u32, 100u32, 8u32);
        let (pw, ph) = ((w + 2 * pad) as i32, (h + 2 * pad) as i32);
        let mut records = Vec::new();
        for y in (BAND_ROWS as i32 - 6)..(BAND_ROWS as i32 + 6) {
            for x in 0..pw {
                let psf = ((x / 9 + y / 4) as u32) % n;
                for (k, index) in [psf, (psf + 1) % n].into_iter().enumerate() {
                    let t = (x * 7 + y * 3 + k as i32) as f32 * 0.01;
                    records.push(SplatRecord {
                        center_x: x,
                        center_y: y,
                        psf_index: index,
                        layer: 0,
                        rot_cos: 1.0,
                        rot_sin: 0.0,
                        weight: 0.5,
                        path: SplatPath::Sparse as u32,
                        color: [0.5 + t.sin() * 0.4, 0.3, 0.2 + t.cos() * 0.1, 0.5],
                    });
                }
                if x % 13 == 5 {
                    let mut again = records[records.len() - 1];
                    again.color = [0.1, 0.2, 0.3, 0.4];
                    records.push(again);
                }
            }
        }
        let classified = one_layer(&records, w, h, pad);
        let drawing = Drawing::new(&classified, Some(&db), &SplatOptions::default());
        let runs = find_runs(
            &records,
            &[(0, records.len())],
            &db,
            &drawing.reach,
            pw,
            drawing.in_row_order,
        );
        let longest = runs[0].runs.iter().map(|r| r.len).max().unwrap_or(0);
        assert!(longest >= 5, "runs of neighbours found (longest {longest})");
        let stack = splat(&classified, Some(&db), &SplatOptions::default());
        assert_planes_hold(&stack.laplacian, &sparse_sum(&records, &psfs, pw, ph), pw);
    }

    /// Unturned dense records, alone and in blended pairs whose PSFs differ in size and
    /// origin, some cut by the padded frame's edges and some across a band boundary, add each
    /// PSF pixel times the record's colour at the record's centre plus the pixel's offset:
    /// checked against a plain sum over every record's every pixel.
    #[test]
    fn unturned_dense_records_land_where_their_pixels_say() {
        use psf_db::{DatabaseBuilder, DbHeader, ParamSpace, PsfModel};
        let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 8).expect("space");
        let n = space.psf_count() as usize;
        let mut builder = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space, 32));
        let mut images = Vec::new();
        for i in 0..n {
            let (w, h) = (3 + 2 * (i % 5) as u16, 1 + 3 * (i % 4) as u16);
            let origin = [
                -(w as i16) / 2 - (i % 3) as i16,
                -(h as i16) / 2 + (i % 2) as i16,
            ];
            let data: Vec<f32> = (0..w as usize * h as usize)
                .map(|k| {
                    if (k + i) % 4 == 0 {
                        0.0
                    } else {
                        0.01 * (1 + k % 9) as f32
                    }
                })
                .collect();
            builder.push_dense(origin, w, h, &data).expect("dense");
            images.push((origin, w as usize, h as usize, data));
        }
        let db = builder.finish().expect("database");
        let (w, h, pad) = (30u32, 120u32, 6u32);
        let (pw, ph) = ((w + 2 * pad) as i32, (h + 2 * pad) as i32);
        let mut records = Vec::new();
        let centres = [
            (0, 0),
            (3, 63),
            (pw - 1, 64),
            (17, 65),
            (pw - 2, ph - 1),
            (10, 127),
        ];
        for (k, &(cx, cy)) in centres.iter().enumerate() {
            let pair = k % 2 == 0;
            let parts: &[(usize, f32)] = if pair {
                &[(k % n, 0.6), ((k + 3) % n, 0.4)]
            } else {
                &[(k % n, 1.0)]
            };
            for &(psf, share) in parts {
                records.push(SplatRecord {
                    center_x: cx,
                    center_y: cy,
                    psf_index: psf as u32,
                    layer: 0,
                    rot_cos: 1.0,
                    rot_sin: 0.0,
                    weight: share,
                    path: SplatPath::Dense as u32,
                    color: [0.9 * share, 0.5 * share, 0.2 * share, share],
                });
            }
        }
        let classified = one_layer(&records, w, h, pad);
        let stack = splat(&classified, Some(&db), &SplatOptions::default());
        let mut expected = vec![[0.0f64; 4]; (pw * ph) as usize];
        for r in &records {
            let (origin, iw, ih, data) = &images[r.psf_index as usize];
            for v in 0..*ih {
                for u in 0..*iw {
                    let (x, y) = (
                        r.center_x + i32::from(origin[0]) + u as i32,
                        r.center_y + i32::from(origin[1]) + v as i32,
                    );
                    if x < 0 || y < 0 || x >= pw || y >= ph {
                        continue;
                    }
                    let value = f64::from(data[v * iw + u]);
                    for (sum, &c) in expected[(y * pw + x) as usize].iter_mut().zip(&r.color) {
                        *sum += f64::from(c) * value;
                    }
                }
            }
        }
        assert_planes_hold(&stack.direct, &expected, pw);
        // Rows no record reaches are not drawn, and the stack says which rows hold light.
        let [first, end] = stack.direct_rows[0];
        assert!(
            first <= 63 - 12 && end >= ph as usize,
            "rows {first}..{end}"
        );

        // Taking the stack moves its planes and gives the same layers; compositing skips the
        // rows outside a layer's and gives the same image as reading every row.
        use crate::pipeline::{
            composite, integrate, integrate_owned, CompositeOptions, Integrator,
        };
        let borrowed = integrate(&stack, Integrator::Exact);
        let owned = integrate_owned(stack, Integrator::Exact);
        assert_eq!(borrowed, owned);
        let every_row = crate::pipeline::IntegratedLayers {
            rows: Vec::new(),
            ..owned.clone()
        };
        let options = CompositeOptions::default();
        assert_eq!(composite(&owned, &options), composite(&every_row, &options));
    }

    /// Two dense records at one centre and rotation are drawn as one image: the same planes as
    /// drawing each on its own, to rounding, at every rotation sampling, turned or not, of two
    /// PSFs or of one.
    #[test]
    fn a_blended_pair_of_dense_records_draws_what_each_draws() {
        use psf_db::{DatabaseBuilder, DbHeader, ParamSpace, PsfModel};
        let space = ParamSpace::for_model(PsfModel::LensMotion, &[[0.0, 8.0], [0.0, 16.0]], 4)
            .expect("space");
        let n = space.psf_count() as usize;
        let mut builder = DatabaseBuilder::new(DbHeader::new(PsfModel::LensMotion, space, 32));
        for i in 0..n {
            let (w, h) = (3 + 4 * (i % 6) as u16, 2 + (i % 6) as u16);
            let data: Vec<f32> = (0..w as usize * h as usize)
                .map(|k| {
                    if (k + i) % 5 == 0 {
                        0.0
                    } else {
                        0.01 * (1 + k % 7) as f32
                    }
                })
                .collect();
            builder
                .push_dense(
                    [-(w as i16) / 2 - (i % 6) as i16, -(h as i16) / 2],
                    w,
                    h,
                    &data,
                )
                .expect("dense");
        }
        let db = builder.finish().expect("database");
        let (w, h, pad) = (40u32, 70u32, 24u32);
        let classified = |records: Vec<SplatRecord>| one_layer(&records, w, h, pad);
        // The second record of a pair of another PSF, or of the same one (drawn from its
        // image's own spans).
        for (angle, second) in [0.0f32, 0.3, 1.9, -2.4]
            .into_iter()
            .flat_map(|a| [(a, 1), (a, 0)])
        {
            let mut records = Vec::new();
            for k in 0..5 {
                let centre = (pad as i32 + 5 + 7 * k, pad as i32 + 9 + 13 * k);
                for (psf, share) in [(k as u32, 0.7f32), (k as u32 + second, 0.3)] {
                    records.push(SplatRecord {
                        center_x: centre.0,
                        center_y: centre.1,
                        psf_index: psf,
                        layer: 0,
                        rot_cos: angle.cos(),
                        rot_sin: angle.sin(),
                        weight: share,
                        path: SplatPath::Dense as u32,
                        color: [0.9 * share, 0.5 * share, 0.2 * share, share],
                    });
                }
            }
            for rotation in [
                RotationSampling::Nearest,
                RotationSampling::Bilinear,
                RotationSampling::Bspline,
            ] {
                let options = SplatOptions { rotation };
                let together = splat(&classified(records.clone()), Some(&db), &options);
                assert!(
                    records.windows(2).any(|p| drawn_together(&p[0], &p[1])),
                    "the records come in pairs"
                );
                let mut apart = vec![0.0f32; together.direct[0].data.len() * 4];
                for r in &records {
                    let one = splat(&classified(vec![*r]), Some(&db), &options);
                    for c in 0..4 {
                        for (k, v) in one.direct[c].data.iter().enumerate() {
                            apart[c * one.direct[c].data.len() + k] += v;
                        }
                    }
                }
                let mut largest = 0.0f32;
                let mut worst = 0.0f32;
                for c in 0..4 {
                    let len = together.direct[c].data.len();
                    for (k, v) in together.direct[c].data.iter().enumerate() {
                        largest = largest.max(v.abs());
                        worst = worst.max((v - apart[c * len + k]).abs());
                    }
                }
                assert!(largest > 0.01, "something was drawn");
                assert!(
                    worst <= 1e-6 * largest,
                    "angle {angle}, {rotation:?}: {worst} of {largest}"
                );
            }
        }
    }

    /// Upright records of RGB images drawn many times are drawn from the images widened to
    /// four lanes ([`super::super::wide`]): bit for bit what drawing each record alone (its
    /// image then drawn from the database's three channels) adds up to, in record order.
    #[test]
    fn widened_rgb_images_draw_what_the_databases_images_draw() {
        use psf_db::{DatabaseBuilder, DbHeader, ParamSpace, PsfModel};
        let space = ParamSpace::for_model(PsfModel::PhysicalLens, &[[0.1, 3.0], [0.0, 20.0]], 4)
            .expect("space");
        let n = space.psf_count() as usize;
        let mut header = DbHeader::new(PsfModel::PhysicalLens, space, 32);
        header.channels = 3;
        let mut builder = DatabaseBuilder::new(header);
        for i in 0..n {
            let (w, h) = (2 + (i % 5) as u16, 1 + 2 * (i % 4) as u16);
            let data: Vec<f32> = (0..w as usize * h as usize * 3)
                .map(|k| {
                    if (k / 3 + i) % 4 == 0 {
                        0.0
                    } else {
                        0.013 * (1 + k % 11) as f32
                    }
                })
                .collect();
            let origin = [-(w as i16) / 2 - (i % 3) as i16, -(h as i16) / 2];
            builder.push_dense(origin, w, h, &data).expect("dense");
        }
        let db = builder.finish().expect("database");
        let (w, h, pad) = (30u32, 90u32, 6u32);
        let records: Vec<SplatRecord> = (0..40)
            .map(|k: i32| SplatRecord {
                center_x: (k * 7) % (w as i32 + 12) - 1,
                center_y: (k * 5) % (h as i32 + 12),
                // Three images drawn many times, one drawn once.
                psf_index: if k == 11 { 4 } else { (k % 3) as u32 },
                layer: 0,
                rot_cos: 1.0,
                rot_sin: 0.0,
                weight: 1.0,
                path: SplatPath::Dense as u32,
                color: [0.9 + k as f32 * 0.01, 0.5, 0.2, 0.7],
            })
            .collect();
        let mut sorted = records.clone();
        sorted.sort_by_key(|r| r.center_y);
        let classified = one_layer(&sorted, w, h, pad);
        let wide = WideImages::for_records(&classified.records, &db, None);
        assert_eq!(wide.count(), 3, "the images drawn many times are widened");
        let together = splat(&classified, Some(&db), &SplatOptions::default());
        let mut apart: Vec<Vec<f32>> = together
            .direct
            .iter()
            .map(|p| vec![0.0; p.data.len()])
            .collect();
        for r in &sorted {
            let one = splat(
                &one_layer(&[*r], w, h, pad),
                Some(&db),
                &SplatOptions::default(),
            );
            for (sum, plane) in apart.iter_mut().zip(&one.direct) {
                for (s, v) in sum.iter_mut().zip(&plane.data) {
                    *s += v;
                }
            }
        }
        assert!(
            together.direct[0].data.iter().any(|&v| v > 0.0),
            "something was drawn"
        );
        for (plane, sum) in together.direct.iter().zip(&apart) {
            assert!(
                plane
                    .data
                    .iter()
                    .zip(sum)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "widened images draw other values"
            );
        }
    }

    /// Every pixel of a rotated dense row that `Band::add_rotated` would place in a band lies
    /// in the span the row is cut to, whatever the angle, offsets and band: the cut skips only
    /// pixels that add nothing, so the bytes do not change.
    #[test]
    fn rotated_row_span_keeps_every_pixel_that_lands_in_the_band() {
        let mut checked = 0;
        for step in 0..720 {
            let angle = step as f32 * 0.5_f32.to_radians() + 0.013;
            let r = SplatRecord {
                center_x: 40,
                center_y: 37 + step % 7,
                rot_cos: angle.cos(),
                rot_sin: angle.sin(),
                ..SplatRecord::default()
            };
            for (ox0, width) in [(-20, 41), (-3, 7), (0, 1), (-30, 64)] {
                for oy in -12..=12 {
                    for y0 in [0, 20, 32, 40, 64] {
                        let (y_lo, y_hi) = ((y0 - 2) as f32, (y0 + 32 + 2) as f32);
                        let span = rotated_row_span(&r, ox0, oy as f32, width, y_lo, y_hi);
                        for u in 0..width {
                            let ox = (ox0 + u as i32) as f32;
                            // The test of `Band::add_rotated`, as it computes it.
                            let y = r.center_y as f32 + (r.rot_sin * ox + r.rot_cos * oy as f32);
                            if y >= y_lo && y < y_hi {
                                checked += 1;
                                let inside = span.is_some_and(|(u0, u1)| u0 <= u && u < u1);
                                assert!(inside, "angle {angle}, row {oy}, pixel {u}: {span:?}");
                            }
                        }
                    }
                }
            }
        }
        assert!(checked > 100_000, "only {checked} pixels checked");
    }

    /// The libm-free floor and round agree with `f32::floor` and `f32::round` (up to the sign
    /// of a zero, which no caller sees), halves included, over the offsets a PSF can reach.
    #[test]
    fn exact_floor_and_round_match_the_standard_ones() {
        let mut values = vec![
            0.0f32,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            -2.5,
            0.49999997,
            -0.49999997,
        ];
        let mut v = -3000.0f32;
        while v < 3000.0 {
            values.push(v);
            v += 0.0371;
        }
        for k in 1..2000 {
            let x = k as f32 * 0.25;
            values.extend([
                x,
                -x,
                x.next_up(),
                x.next_down(),
                -x.next_up(),
                -x.next_down(),
            ]);
        }
        for v in values {
            assert_eq!(floor_exact(v), v.floor(), "floor {v}");
            assert_eq!(round_exact(v), v.round(), "round {v}");
        }
    }

    /// Sum 1, mean `d`, variance 1/4 and no negative weight for offsets across the range,
    /// the properties that keep a rotated PSF's energy.
    #[test]
    fn bspline_weights_have_fixed_variance() {
        for k in 0..=100 {
            let d = -0.5 + k as f32 / 100.0;
            let w = quadratic_bspline_weights(d);
            let sum: f32 = w.iter().sum();
            let mean = w[2] - w[0];
            let second = w[2] + w[0];
            assert!(w.iter().all(|&x| x >= 0.0), "{d}: {w:?}");
            assert!((sum - 1.0).abs() < 1e-6, "{d}: sum {sum}");
            assert!((mean - d).abs() < 1e-6, "{d}: mean {mean}");
            assert!((second - mean * mean - 0.25).abs() < 1e-6, "{d}: variance");
        }
        let ((nx, ny), taps) = bspline_footprint(2.7, -1.2);
        assert_eq!((nx, ny), (3, -1));
        let (s, mx, my) = taps
            .iter()
            .fold((0.0, 0.0, 0.0), |(s, mx, my), &(i, j, w)| {
                (s + w, mx + w * i as f32, my + w * j as f32)
            });
        assert!((s - 1.0).abs() < 1e-6 && (mx + 0.3).abs() < 1e-6 && (my + 0.2).abs() < 1e-6);
    }
}
