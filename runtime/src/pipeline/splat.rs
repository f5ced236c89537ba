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
//! walks the layer's records in their order and adds only inside its band, so every pixel
//! sums its contributions in the same order whatever the thread count.

use poisson::Plane;
use psf_db::PsfDatabase;
use rayon::prelude::*;

use super::classify::Classified;
use super::types::{FrameParams, SplatPath, SplatRecord};

/// Rows per band of the deterministic parallel splat.
pub const BAND_ROWS: usize = 32;

/// How rotated offsets land on the pixel grid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum RotationSampling {
    /// Laplacian spreadlets go onto the 3x3 quadratic B-spline around the nearest pixel
    /// ([`bspline_footprint`]), which adds the same variance to every spreadlet, so a rotated
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
    let (nx, ny) = (rx.round(), ry.round());
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
    let extent = frame.pad as i32 + 2;
    // Reach of each PSF (px, rounded up, +1 for bilinear splitting): a record only visits the
    // bands its own PSF reaches.
    let reach: Vec<i32> = db.map_or_else(Vec::new, psf_reach);
    let in_row_order = db.is_some_and(PsfDatabase::spreadlets_in_row_order);

    // Tasks: (layer, band, kind) with kind 0 = Laplacian, 1 = direct.
    let mut tasks = Vec::new();
    for (l, info) in classified.layers.iter().enumerate() {
        for (kind, present) in [(0, info.sparse > 0), (1, info.dense + info.copied > 0)] {
            if present {
                tasks.extend((0..bands).map(|b| (l, b, kind)));
            }
        }
    }
    let results: Vec<BandResult> = tasks
        .par_iter()
        .map(|&(l, b, kind)| {
            let info = &classified.layers[l];
            let recs =
                &classified.records[info.first_record..info.first_record + info.record_count];
            let y0 = (b * BAND_ROWS) as i32;
            let y1 = ((b + 1) * BAND_ROWS).min(ph) as i32;
            // Records are in row order within a layer: the ones that can reach the band.
            let lo = recs.partition_point(|r| r.center_y < y0 - extent);
            let hi = recs.partition_point(|r| r.center_y < y1 + extent);
            let mut band = Band {
                data: vec![[0.0f32; 4]; (y1 - y0) as usize * pw],
                width: pw as i32,
                y0,
                y1,
            };
            for r in &recs[lo..hi] {
                if let Some(&k) = reach.get(r.psf_index as usize) {
                    if r.center_y + k < y0 || r.center_y - k >= y1 {
                        continue;
                    }
                }
                match (kind, r.path) {
                    (0, p) if p == SplatPath::Sparse as u32 => {
                        if let Some(db) = db {
                            splat_sparse(&mut band, r, db, options.rotation, in_row_order);
                        }
                    }
                    (1, p) if p == SplatPath::Dense as u32 => {
                        if let Some(db) = db {
                            splat_dense(&mut band, r, db, options.rotation);
                        }
                    }
                    (1, p) if p == SplatPath::Copy as u32 => {
                        band.add(r.center_x, r.center_y, r.color);
                    }
                    _ => {}
                }
            }
            ((l, b, kind), band.data)
        })
        .collect();

    let empty = || vec![Plane::default(); n_layers * 4];
    let mut laplacian = empty();
    let mut direct = empty();
    for ((l, b, kind), data) in results {
        let planes = if kind == 0 {
            &mut laplacian
        } else {
            &mut direct
        };
        for c in 0..4 {
            let plane = &mut planes[l * 4 + c];
            if plane.is_empty() {
                *plane = Plane::new(pw, ph);
            }
            let start = b * BAND_ROWS * pw;
            for (dst, src) in plane.data[start..start + data.len()].iter_mut().zip(&data) {
                *dst = src[c];
            }
        }
    }
    LayerStack {
        frame,
        laplacian,
        direct,
    }
}

/// For every PSF of `db`, the largest distance (px, rounded up, plus one) of any of its
/// spreadlets or dense pixels from its centre.
pub fn psf_reach(db: &PsfDatabase) -> Vec<i32> {
    (0..db.psf_count())
        .map(|i| {
            let r2 = match db.dense(i) {
                Some(d) => {
                    let xs = [d.origin[0], d.origin[0] + d.width as i32 - 1];
                    let ys = [d.origin[1], d.origin[1] + d.height as i32 - 1];
                    let mx = xs.iter().map(|x| x.abs()).max().unwrap_or(0);
                    let my = ys.iter().map(|y| y.abs()).max().unwrap_or(0);
                    mx * mx + my * my
                }
                None => db
                    .spreadlets(i)
                    .0
                    .iter()
                    .map(|p| i32::from(p[0]).pow(2) + i32::from(p[1]).pow(2))
                    .max()
                    .unwrap_or(0),
            };
            (f64::from(r2).sqrt().ceil() as i32) + 1
        })
        .collect()
}

/// A finished band: (layer, band, kind) and its RGBA rows.
type BandResult = ((usize, usize, usize), Vec<[f32; 4]>);

/// Rows `[y0, y1)` of a padded layer, RGBA interleaved.
struct Band {
    data: Vec<[f32; 4]>,
    width: i32,
    y0: i32,
    y1: i32,
}

impl Band {
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
                    r.center_x + rx.round() as i32,
                    r.center_y + ry.round() as i32,
                    v,
                );
            }
            // A quarter turn maps pixels onto pixels: nothing to interpolate.
            RotationSampling::Bspline if r.rot_cos == 0.0 || r.rot_sin == 0.0 => {
                self.add(
                    r.center_x + rx.round() as i32,
                    r.center_y + ry.round() as i32,
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
                let (fx, fy) = (rx.floor(), ry.floor());
                let (tx, ty) = (rx - fx, ry - fy);
                let (x0, y0) = (r.center_x + fx as i32, r.center_y + fy as i32);
                let ws = [
                    (0, 0, (1.0 - tx) * (1.0 - ty)),
                    (1, 0, tx * (1.0 - ty)),
                    (0, 1, (1.0 - tx) * ty),
                    (1, 1, tx * ty),
                ];
                for (dx, dy, wgt) in ws {
                    if wgt != 0.0 {
                        self.add(x0 + dx, y0 + dy, v.map(|c| c * wgt));
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

fn splat_sparse(
    band: &mut Band,
    r: &SplatRecord,
    db: &PsfDatabase,
    sampling: RotationSampling,
    in_row_order: bool,
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
    let identity = is_identity(r);
    let sampling = sampling.for_image_space();
    // Unrotated: only the rows that fall inside the band.
    let (v0, v1) = if identity {
        let top = r.center_y + view.origin[1];
        (
            (band.y0 - top).clamp(0, view.height as i32) as usize,
            (band.y1 - top).clamp(0, view.height as i32) as usize,
        )
    } else {
        (0, view.height)
    };
    for v in v0..v1 {
        for u in 0..view.width {
            let at = (v * view.width + u) * ch;
            let vals = &view.data[at..at + ch];
            if vals.iter().all(|&x| x == 0.0) {
                continue;
            }
            let ox = view.origin[0] + u as i32;
            let oy = view.origin[1] + v as i32;
            let value = weighted(r.color, vals);
            if identity {
                band.add(r.center_x + ox, r.center_y + oy, value);
            } else {
                band.add_rotated(r, ox as f32, oy as f32, value, sampling);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
