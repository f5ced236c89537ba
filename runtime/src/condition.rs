//! Conditioning a database before splatting: enforce the two moments of each sparse PSF that
//! decide how it behaves when millions are summed and integrated.
//!
//! - **Monopole** (sum of the spreadlet values, per channel): the Laplacian of a compactly
//!   supported PSF sums to zero. A residual `m` integrates to a far field `m/(2 pi) log r` that
//!   does not decay; summed over every pixel of a layer it becomes a visible offset across the
//!   whole image. It is removed by subtracting it from the values in proportion to `|v|`.
//! - **Energy** `sum v |x|^2 / 4` (the integrated PSF's sum: `L(|x|^2/4) = 1` for the 5-point
//!   stencil): 1 for the light-conserving models (thin-lens, lens-motion); each PSF is scaled to
//!   it, and dense PSFs to a sum of 1. The physical lens keeps its energy (vignetting is real).
//!
//! A sparse PSF with no spreadlets, or whose energy is below [`MIN_ENERGY`] (nothing usable to
//! scale), is replaced by the Laplacian of a single pixel (the 5-point stencil itself), so the
//! pixel's light is kept. Every change is counted in [`ConditionReport`].

use psf_db::{DatabaseBuilder, DbError, PsfDatabase, PsfModel};

/// Sparse PSFs with less energy than this are replaced by a single pixel.
pub const MIN_ENERGY: f64 = 0.25;

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
                for k in 0..positions.len() {
                    let v = &mut vals[k * ch + c];
                    *v -= m0 * v.abs() / abs;
                }
            }
            let e: f64 = positions
                .iter()
                .enumerate()
                .map(|(k, p)| {
                    let (x, y) = (f64::from(p[0]), f64::from(p[1]));
                    vals[k * ch + c] * (x * x + y * y) / 4.0
                })
                .sum();
            energy_sum += e;
            if normalise && e >= MIN_ENERGY {
                for k in 0..positions.len() {
                    vals[k * ch + c] /= e;
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

#[cfg(test)]
mod tests {
    use super::*;
    use psf_db::{DbHeader, ParamSpace};

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
