//! Conditioning a database before splatting: enforce the two moments of each sparse PSF that
//! decide how it behaves when millions are summed and integrated.
//!
//! - **Monopole** (sum of the spreadlet values, per channel): the Laplacian of a compactly
//!   supported PSF sums to zero. A residual `m` integrates to a far field `m/(2 pi) log r` that
//!   does not decay; summed over every pixel of a layer it becomes a visible offset across the
//!   whole image. It is removed by subtracting it from the values in proportion to `|v|`.
//! - **Dipole and quadrupole** (moments against x, y, xy, x^2 - y^2): they vanish, like the
//!   monopole, for the Laplacian of a compactly supported image; residuals leave far fields
//!   decaying as 1/r and 1/r^2 whose area integral does not converge. All five are zeroed
//!   together with the energy below by the smallest change of the values (weighted by |v|).
//! - **Energy** `sum v |x|^2 / 4` (the integrated PSF's sum: `L(|x|^2/4) = 1` for the 5-point
//!   stencil): 1 for the light-conserving models (thin-lens, lens-motion); each PSF is scaled to
//!   it, and dense PSFs to a sum of 1. The physical lens keeps its energy (vignetting is real).
//!
//! A sparse thin-lens or lens-motion PSF whose recorded error is large (L1 above
//! [`MAX_SPARSE_L1`]) is replaced by its analytic dense PSF (disk convolved with the motion
//! segment, at its cell's centre), drawn by the fast track.
//!
//! A sparse PSF with no spreadlets, or whose energy is below [`MIN_ENERGY`] (nothing usable to
//! scale), is replaced by the Laplacian of a single pixel (the 5-point stencil itself), so the
//! pixel's light is kept. Every change is counted in [`ConditionReport`].

use psf_db::{DatabaseBuilder, DbError, PsfDatabase, PsfModel};

/// Sparse PSFs with less energy than this are replaced by a single pixel.
pub const MIN_ENERGY: f64 = 0.25;

/// Sparse thin-lens and lens-motion PSFs whose recorded L1 error (against their pre-filtered
/// PSF, relative to its unit sum) exceeds this are replaced by a dense analytic PSF.
pub const MAX_SPARSE_L1: f32 = 0.15;

/// Subsamples per pixel edge when rendering an analytic PSF.
const SUBSAMPLES: usize = 6;

/// The analytic PSF of a circular thin lens of CoC radius `coc` (px) moving `len` px along +x
/// over the shutter (box shutter), as a dense image: `(origin, width, height, data)` with the
/// pixel values summing to 1. Each pixel is the mean over `SUBSAMPLES`^2 points of the
/// disk-convolved-with-segment intensity.
pub fn analytic_psf(coc: f64, len: f64) -> ([i16; 2], u16, u16, Vec<f32>) {
    let (rx, ry) = analytic_half_size(coc, len);
    let (w, h) = ((2 * rx + 1) as usize, (2 * ry + 1) as usize);
    let mut data = vec![0.0f64; w * h];
    accumulate_analytic::<SUBSAMPLES>(coc, len, rx, ry, &mut data);
    let sum: f64 = data.iter().sum();
    let data = data.iter().map(|&v| (v / sum) as f32).collect();
    ([-rx as i16, -ry as i16], w as u16, h as u16, data)
}

/// The analytic PSF pre-filtered over a cell of the PSF space like the database's own (CoC
/// radius in `[coc.0, coc.1]` px, motion length in `[len.0, len.1]` px): the mean of the
/// analytic PSFs at `CELL_SAMPLES`^2 stratified points of the cell, as a dense image summing to
/// 1. Used for the dense twins of sparse PSFs that very bright pixels are drawn with.
pub fn analytic_cell_psf(coc: (f64, f64), len: (f64, f64)) -> ([i16; 2], u16, u16, Vec<f32>) {
    let (rx, ry) = analytic_half_size(coc.1, len.1);
    let (w, h) = ((2 * rx + 1) as usize, (2 * ry + 1) as usize);
    let mut data = vec![0.0f64; w * h];
    let mut one = vec![0.0f64; w * h];
    let k = CELL_SAMPLES as f64;
    for i in 0..CELL_SAMPLES {
        for j in 0..CELL_SAMPLES {
            let c = coc.0 + (coc.1 - coc.0) * (i as f64 + 0.5) / k;
            let l = len.0 + (len.1 - len.0) * (j as f64 + 0.5) / k;
            one.fill(0.0);
            accumulate_analytic::<2>(c, l, rx, ry, &mut one);
            let sum: f64 = one.iter().sum();
            if sum > 0.0 {
                for (d, o) in data.iter_mut().zip(&one) {
                    *d += o / sum;
                }
            }
        }
    }
    let sum: f64 = data.iter().sum();
    let data = data.iter().map(|&v| (v / sum) as f32).collect();
    ([-rx as i16, -ry as i16], w as u16, h as u16, data)
}

/// Points per cell axis that [`analytic_cell_psf`] averages.
const CELL_SAMPLES: usize = 4;

/// Half width and half height (px) of the image that holds the analytic PSF.
fn analytic_half_size(coc: f64, len: f64) -> (i32, i32) {
    let r = coc.max(0.5);
    let half = 0.5 * len.max(0.0);
    ((r + half + 1.0).ceil() as i32, (r + 1.0).ceil() as i32)
}

/// Adds the analytic PSF (unnormalised: each pixel the fraction of its `SUB`^2 points inside
/// the disk swept along the segment) into `data`, an image of half size `(rx, ry)`.
fn accumulate_analytic<const SUB: usize>(coc: f64, len: f64, rx: i32, ry: i32, data: &mut [f64]) {
    // Radii under half a pixel are drawn as half a pixel: the PSF then covers about a pixel.
    let r = coc.max(0.5);
    let half = 0.5 * len.max(0.0);
    let (w, h) = ((2 * rx + 1) as usize, (2 * ry + 1) as usize);
    let k = SUB as f64;
    // The points' places across a pixel, from its left edge.
    let fractions: [f64; SUB] = std::array::from_fn(|sx| (sx as f64 + 0.5) / k);
    for v in 0..h {
        // A row of points' chord of the disk does not depend on x: found once per row, not once
        // per pixel of it (`None` where the row misses the disk).
        let chords: [Option<f64>; SUB] = std::array::from_fn(|sy| {
            let y = (v as i32 - ry) as f64 - 0.5 + (sy as f64 + 0.5) / k;
            (y.abs() < r).then(|| (r * r - y * y).sqrt())
        });
        for u in 0..w {
            let left = (u as i32 - rx) as f64 - 0.5;
            let mut acc = 0.0;
            for chord in chords {
                let Some(chord) = chord else { continue };
                for within in fractions {
                    let x = left + within;
                    acc += if half < 1e-3 {
                        f64::from(u8::from(x.abs() <= chord))
                    } else {
                        // Length of the segment [-half, half] within the disk around (x, y).
                        ((x + chord).min(half) - (x - chord).max(-half)).max(0.0) / (2.0 * half)
                    };
                }
            }
            data[v * w + u] += acc;
        }
    }
}

/// What conditioning changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ConditionReport {
    /// PSFs examined.
    pub psfs: usize,
    /// Largest |monopole| found, relative to the PSF's sum of |values|.
    pub max_relative_monopole: f64,
    /// Smallest energy found among the sparse PSFs kept.
    pub min_energy: f64,
    /// Largest energy found among the sparse PSFs kept.
    pub max_energy: f64,
    /// Sparse PSFs replaced by a single pixel (empty or without usable energy).
    pub replaced_by_pixel: usize,
    /// Dense PSFs rescaled to sum 1.
    pub dense_rescaled: usize,
    /// Sparse PSFs whose recorded L1 exceeded [`MAX_SPARSE_L1`], replaced by dense analytic
    /// PSFs (thin-lens, lens-motion).
    pub replaced_by_analytic: usize,
}

/// The Laplacian of a unit pixel at the centre under the 5-point stencil.
const PIXEL_POSITIONS: [[i16; 2]; 5] = [[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]];
const PIXEL_VALUES: [f32; 5] = [-4.0, 1.0, 1.0, 1.0, 1.0];

/// A copy of `db` with zero-sum spreadlets and (for thin-lens and lens-motion) unit energy.
pub fn condition(db: &PsfDatabase) -> Result<(PsfDatabase, ConditionReport), DbError> {
    let ch = db.channels();
    let normalise = db.model() != PsfModel::PhysicalLens;
    let mut report = ConditionReport {
        psfs: db.psf_count(),
        min_energy: f64::INFINITY,
        max_energy: 0.0,
        ..ConditionReport::default()
    };
    let mut builder = DatabaseBuilder::new(db.header().clone());
    for i in 0..db.psf_count() {
        if let Some(d) = db.dense(i) {
            let mut data = d.data.to_vec();
            if normalise {
                let sum: f64 = data.iter().map(|&v| f64::from(v)).sum::<f64>() / ch as f64;
                if sum > 0.0 && (sum - 1.0).abs() > 1e-6 {
                    let s = (1.0 / sum) as f32;
                    data.iter_mut().for_each(|v| *v *= s);
                    report.dense_rescaled += 1;
                }
            }
            let (w, h) = (d.width as u16, d.height as u16);
            builder.push_dense([d.origin[0] as i16, d.origin[1] as i16], w, h, &data)?;
            continue;
        }
        let (positions, values) = db.spreadlets(i);
        let recorded_l1 = db.header().stats.get(i).map_or(0.0, |s| s.l1);
        if normalise && recorded_l1 > MAX_SPARSE_L1 {
            if let Some(c) = db.space().cell_center(i as u32) {
                let len = if db.model() == PsfModel::LensMotion {
                    c[1]
                } else {
                    0.0
                };
                let (origin, w, h, data) = analytic_psf(c[0], len);
                builder.push_dense(origin, w, h, &data)?;
                report.replaced_by_analytic += 1;
                continue;
            }
        }
        let mut vals: Vec<f64> = values.iter().map(|&v| f64::from(v)).collect();
        let mut energy_sum = 0.0;
        for c in 0..ch {
            let (mut m0, mut abs) = (0.0f64, 0.0f64);
            for k in 0..positions.len() {
                m0 += vals[k * ch + c];
                abs += vals[k * ch + c].abs();
            }
            if abs > 0.0 {
                report.max_relative_monopole = report.max_relative_monopole.max(m0.abs() / abs);
            }
            let e = moment(positions, &vals, ch, c, 5);
            energy_sum += e;
            if e < MIN_ENERGY {
                continue;
            }
            let target = if normalise { 1.0 } else { e };
            if !project_moments(positions, &mut vals, ch, c, target) {
                // Too few spreadlets to fix every moment: at least remove the monopole.
                for k in 0..positions.len() {
                    let v = &mut vals[k * ch + c];
                    *v -= m0 * v.abs() / abs;
                }
            }
        }
        let energy = energy_sum / ch as f64;
        if positions.is_empty() || energy < MIN_ENERGY {
            report.replaced_by_pixel += 1;
            let pixel: Vec<f32> = PIXEL_VALUES
                .iter()
                .flat_map(|&v| std::iter::repeat_n(v, ch))
                .collect();
            builder.push_sparse(&PIXEL_POSITIONS, &pixel)?;
            continue;
        }
        report.min_energy = report.min_energy.min(energy);
        report.max_energy = report.max_energy.max(energy);
        let vals: Vec<f32> = vals.iter().map(|&v| v as f32).collect();
        builder.push_sparse(positions, &vals)?;
    }
    if !report.min_energy.is_finite() {
        report.min_energy = 0.0;
    }
    Ok((builder.finish()?, report))
}

/// The moment `sum v_k p(x_k)` of channel `c` for the polynomial `p` number `which`:
/// 0: 1, 1: x, 2: y, 3: x y, 4: x^2 - y^2 (the harmonic ones, which vanish for the Laplacian
/// of a compactly supported image), 5: (x^2 + y^2) / 4 (the energy: the image's sum).
fn moment(positions: &[[i16; 2]], vals: &[f64], ch: usize, c: usize, which: usize) -> f64 {
    positions
        .iter()
        .enumerate()
        .map(|(k, p)| vals[k * ch + c] * poly(which, p))
        .sum()
}

#[inline]
fn poly(which: usize, p: &[i16; 2]) -> f64 {
    let (x, y) = (f64::from(p[0]), f64::from(p[1]));
    match which {
        0 => 1.0,
        1 => x,
        2 => y,
        3 => x * y,
        4 => x * x - y * y,
        _ => (x * x + y * y) / 4.0,
    }
}

/// The smallest change of channel `c`'s values (weighted by `|v|`, so every spreadlet moves
/// in proportion to its size) that zeroes the harmonic moments up to second order and sets
/// the energy to `energy`: the integrated PSF then has no far field decaying slower than
/// `1/r^3` and sums to `energy`. False when the system is singular (too few spreadlets).
fn project_moments(
    positions: &[[i16; 2]],
    vals: &mut [f64],
    ch: usize,
    c: usize,
    energy: f64,
) -> bool {
    const M: usize = 6;
    let n = positions.len();
    if n < M {
        return false;
    }
    let vmax = (0..n).map(|k| vals[k * ch + c].abs()).fold(0.0, f64::max);
    let weights: Vec<f64> = (0..n)
        .map(|k| vals[k * ch + c].abs() + 1e-3 * vmax)
        .collect();
    // Residuals r = A v - b.
    let mut r = [0.0f64; M];
    for (i, ri) in r.iter_mut().enumerate() {
        *ri = moment(positions, vals, ch, c, i);
    }
    r[5] -= energy;
    // Normal matrix A W A^T.
    let mut a = [[0.0f64; M + 1]; M];
    for (k, p) in positions.iter().enumerate() {
        let w = weights[k];
        let ph: [f64; M] = std::array::from_fn(|i| poly(i, p));
        for i in 0..M {
            for j in 0..M {
                a[i][j] += w * ph[i] * ph[j];
            }
        }
    }
    for i in 0..M {
        a[i][M] = r[i];
    }
    // Gaussian elimination with partial pivoting.
    for col in 0..M {
        let piv = (col..M)
            .max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))
            .unwrap_or(col);
        let scale = a.iter().map(|row| row[col].abs()).fold(0.0, f64::max);
        if a[piv][col].abs() <= 1e-12 * scale.max(1e-300) {
            return false;
        }
        a.swap(col, piv);
        let pivot_row = a[col];
        for (i, row) in a.iter_mut().enumerate() {
            if i != col {
                let f = row[col] / pivot_row[col];
                for (x, p) in row[col..].iter_mut().zip(&pivot_row[col..]) {
                    *x -= f * p;
                }
            }
        }
    }
    let lambda: [f64; M] = std::array::from_fn(|i| a[i][M] / a[i][i]);
    for (k, p) in positions.iter().enumerate() {
        let w = weights[k];
        let delta: f64 = (0..M).map(|i| lambda[i] * poly(i, p)).sum();
        vals[k * ch + c] -= w * delta;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use psf_db::{DbHeader, ParamSpace};

    #[test]
    fn analytic_psf_sums_to_one_and_has_the_right_support() {
        let (origin, w, h, data) = analytic_psf(3.0, 10.0);
        let sum: f64 = data.iter().map(|&v| f64::from(v)).sum();
        assert!((sum - 1.0).abs() < 1e-5);
        assert_eq!((origin[0], origin[1]), (-9, -4));
        let at = |x: i32, y: i32| {
            data[((y - origin[1] as i32) as usize) * w as usize + (x - origin[0] as i32) as usize]
        };
        assert!(at(7, 0) > 0.0 && at(0, 2) > 0.0);
        assert_eq!(at(9, 0), 0.0);
        assert_eq!(at(0, 4), 0.0);
        assert!(h == 9);
        // Symmetric in x.
        assert!((at(5, 1) - at(-5, 1)).abs() < 1e-7);
    }

    /// Every point of every pixel tested on its own, as written out in the module's maths: the
    /// images a row's chords found once give are the same, to the bit.
    #[test]
    fn chords_found_once_per_row_give_the_same_images_as_point_by_point() {
        fn point_by_point(coc: f64, len: f64, sub: usize, rx: i32, ry: i32) -> Vec<f64> {
            let r = coc.max(0.5);
            let half = 0.5 * len.max(0.0);
            let (w, h) = ((2 * rx + 1) as usize, (2 * ry + 1) as usize);
            let k = sub as f64;
            let mut data = vec![0.0; w * h];
            for v in 0..h {
                for u in 0..w {
                    let mut acc = 0.0;
                    for sy in 0..sub {
                        for sx in 0..sub {
                            let x = (u as i32 - rx) as f64 - 0.5 + (sx as f64 + 0.5) / k;
                            let y = (v as i32 - ry) as f64 - 0.5 + (sy as f64 + 0.5) / k;
                            if y.abs() >= r {
                                continue;
                            }
                            let chord = (r * r - y * y).sqrt();
                            acc += if half < 1e-3 {
                                f64::from(u8::from(x.abs() <= chord))
                            } else {
                                ((x + chord).min(half) - (x - chord).max(-half)).max(0.0)
                                    / (2.0 * half)
                            };
                        }
                    }
                    data[v * w + u] += acc;
                }
            }
            data
        }
        for (coc, len, sub) in [(0.2, 0.0, 2), (2.7, 0.0, 4), (3.3, 9.5, 2), (11.0, 40.0, 3)] {
            let (rx, ry) = analytic_half_size(coc, len);
            let mut data = vec![0.0; ((2 * rx + 1) * (2 * ry + 1)) as usize];
            match sub {
                2 => accumulate_analytic::<2>(coc, len, rx, ry, &mut data),
                3 => accumulate_analytic::<3>(coc, len, rx, ry, &mut data),
                _ => accumulate_analytic::<4>(coc, len, rx, ry, &mut data),
            }
            let expected = point_by_point(coc, len, sub, rx, ry);
            assert!(data.iter().any(|&v| v > 0.0), "{coc} {len}");
            let same = data
                .iter()
                .zip(&expected)
                .all(|(a, b)| a.to_bits() == b.to_bits());
            assert!(same, "coc {coc} len {len} sub {sub}");
        }
    }

    #[test]
    fn monopole_is_removed_and_energy_normalised() {
        let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 2).expect("space");
        let n = space.psf_count();
        let mut b = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space, 16));
        // A 3x3 box's Laplacian, scaled by 2 and with a monopole of 0.1 added at the centre.
        let mut pos = Vec::new();
        let mut val = Vec::new();
        for y in -2i16..=2 {
            for x in -2i16..=2 {
                let inside = |x: i16, y: i16| (x.abs() <= 1 && y.abs() <= 1) as i32 as f32;
                let l = inside(x - 1, y) + inside(x + 1, y) + inside(x, y - 1) + inside(x, y + 1)
                    - 4.0 * inside(x, y);
                if l != 0.0 {
                    pos.push([x, y]);
                    val.push(2.0 * l + if x == 0 && y == 0 { 0.1 } else { 0.0 });
                }
            }
        }
        b.push_sparse(&pos, &val).expect("push");
        for _ in 1..n {
            b.push_sparse(&[], &[]).expect("push empty");
        }
        let db = b.finish().expect("db");
        let (out, report) = condition(&db).expect("condition");
        assert_eq!(report.replaced_by_pixel, n as usize - 1);
        let (p, v) = out.spreadlets(0);
        let sum: f64 = v.iter().map(|&x| f64::from(x)).sum();
        let energy: f64 = p
            .iter()
            .zip(v)
            .map(|(p, &v)| f64::from(v) * f64::from(p[0] * p[0] + p[1] * p[1]) / 4.0)
            .sum();
        assert!(sum.abs() < 1e-5, "{sum}");
        assert!((energy - 1.0).abs() < 1e-5, "{energy}");
        // The empty ones became one pixel: energy 1.
        let (p, v) = out.spreadlets(1);
        assert_eq!(p.len(), 5);
        assert_eq!(v.iter().sum::<f32>(), 0.0);
    }
}
