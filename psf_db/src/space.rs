//! Parameter spaces: physical PSF parameters `s`, their power remapping to grid coordinates `u`,
//! and the O(1) lookup of the PSF that stands for `s`.
//!
//! Per dimension, `u = n * ((s - min) / (max - min))^(1 / beta)` (DESIGN.md, "Power remapping"),
//! so beta > 1 puts finer cells at small `s`. The inverse is `s = min + (max - min) (u / n)^beta`.

use serde::{Deserialize, Serialize};

use crate::error::SpaceError;
use crate::grid::{CellBox, NestedGrid};
use crate::model::PsfModel;

/// One dimension of a parameter space, in the dimension's physical unit (px, scene units, mm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Dimension {
    /// Smallest sampled value (physical units).
    pub min: f64,
    /// Largest sampled value (physical units), `> min`.
    pub max: f64,
    /// Power-remapping exponent, `> 0` (1 = uniform).
    pub beta: f64,
}

/// The serialised form of [`ParamSpace`] (validated on load).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParamSpaceSpec {
    /// One entry per dimension (1 or 2).
    pub dims: Vec<Dimension>,
    /// Grid resolution in grid units per dimension.
    pub n: u32,
}

/// A sampled PSF parameter space: ranges, power remapping and the nested grid over it.
/// Coordinates are `[f64; 2]` / `[f32; 2]` whose second entry is ignored in 1D spaces.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "ParamSpaceSpec", into = "ParamSpaceSpec")]
pub struct ParamSpace {
    dims: Vec<Dimension>,
    grid: NestedGrid,
}

impl TryFrom<ParamSpaceSpec> for ParamSpace {
    type Error = SpaceError;
    fn try_from(spec: ParamSpaceSpec) -> Result<Self, SpaceError> {
        ParamSpace::new(spec.dims, spec.n)
    }
}

impl From<ParamSpace> for ParamSpaceSpec {
    fn from(s: ParamSpace) -> Self {
        ParamSpaceSpec {
            n: s.grid.n(),
            dims: s.dims,
        }
    }
}

impl ParamSpace {
    /// A space over `dims` (1 or 2 entries, finite `min < max`, finite `beta > 0`) with grid
    /// resolution `n`.
    pub fn new(dims: Vec<Dimension>, n: u32) -> Result<Self, SpaceError> {
        for (i, d) in dims.iter().enumerate() {
            let ok = d.min.is_finite()
                && d.max.is_finite()
                && d.min < d.max
                && d.beta.is_finite()
                && d.beta > 0.0;
            if !ok {
                return Err(SpaceError::BadDimension {
                    index: i,
                    min: d.min,
                    max: d.max,
                    beta: d.beta,
                });
            }
        }
        let grid = NestedGrid::new(dims.len(), n)?;
        Ok(ParamSpace { dims, grid })
    }

    /// A space for `model` with the model's default betas, the given `[min, max]` ranges
    /// (one per dimension) and resolution `n`.
    pub fn for_model(model: PsfModel, ranges: &[[f64; 2]], n: u32) -> Result<Self, SpaceError> {
        if ranges.len() != model.dims() {
            return Err(SpaceError::Dims(ranges.len()));
        }
        let dims = ranges
            .iter()
            .zip(model.default_beta())
            .map(|(r, &beta)| Dimension {
                min: r[0],
                max: r[1],
                beta,
            })
            .collect();
        ParamSpace::new(dims, n)
    }

    /// The smallest grid resolution giving at least `target` PSFs in `dims` dimensions
    /// (`None` when unreachable, see [`NestedGrid::resolution_for_count`]).
    pub fn resolution_for_count(dims: usize, target: u32) -> Option<u32> {
        NestedGrid::resolution_for_count(dims, target)
    }

    /// The dimensions (ranges and betas).
    pub fn dims(&self) -> &[Dimension] {
        &self.dims
    }

    /// Number of dimensions (1 or 2).
    pub fn dim_count(&self) -> usize {
        self.dims.len()
    }

    /// The nested grid over the remapped coordinates.
    pub fn grid(&self) -> &NestedGrid {
        &self.grid
    }

    /// Grid resolution n (grid units per dimension).
    pub fn n(&self) -> u32 {
        self.grid.n()
    }

    /// Number of PSFs (grid cells).
    pub fn psf_count(&self) -> u32 {
        self.grid.cell_count()
    }

    /// Physical `s` to grid coordinates `u` in `[0, n]` (clamped to the range, NaN to `min`).
    #[inline]
    pub fn to_grid(&self, s: [f64; 2]) -> [f64; 2] {
        let n = self.grid.n() as f64;
        let mut u = [0.0; 2];
        for (k, d) in self.dims.iter().enumerate() {
            let t = (s[k] - d.min) / (d.max - d.min);
            let t = if t > 0.0 { t.min(1.0) } else { 0.0 };
            // The paper's betas are 1 and 2 in most dimensions: skip the general power there.
            u[k] = n * if d.beta == 1.0 {
                t
            } else if d.beta == 2.0 {
                t.sqrt()
            } else {
                t.powf(1.0 / d.beta)
            };
        }
        u
    }

    /// Grid coordinates `u` (clamped to `[0, n]`) to physical `s`.
    #[inline]
    pub fn from_grid(&self, u: [f64; 2]) -> [f64; 2] {
        let n = self.grid.n() as f64;
        let mut s = [0.0; 2];
        for (k, d) in self.dims.iter().enumerate() {
            let t = u[k] / n;
            let t = if t > 0.0 { t.min(1.0) } else { 0.0 };
            s[k] = d.min + (d.max - d.min) * t.powf(d.beta);
        }
        s
    }

    /// The PSF index standing for physical parameters `s`, and whether `s` had to be clamped
    /// into the space (outside `[min, max]` in some dimension, or NaN). O(1).
    #[inline]
    pub fn lookup(&self, s: [f32; 2]) -> (u32, bool) {
        let mut clamped = false;
        let mut sd = [0.0f64; 2];
        for (k, d) in self.dims.iter().enumerate() {
            let v = s[k] as f64;
            // `!(a && b)` so that NaN counts as clamped.
            if !(v >= d.min && v <= d.max) {
                clamped = true;
            }
            sd[k] = v;
        }
        (self.grid.index_of(self.to_grid(sd)), clamped)
    }

    /// The box of PSF `i` in physical units (the region its PSF is pre-filtered over);
    /// `None` when `i >= psf_count()`.
    pub fn cell_box(&self, i: u32) -> Option<CellBox> {
        let b = self.grid.cell_box(i)?;
        // `from_grid` leaves unused dimensions at 0.
        Some(CellBox {
            min: self.from_grid(b.min),
            max: self.from_grid(b.max),
        })
    }

    /// The representative parameters of PSF `i` in physical units: the image of the cell's
    /// centre in grid units (so `lookup(cell_center(i)) == i`); `None` when out of range.
    pub fn cell_center(&self, i: u32) -> Option<[f64; 2]> {
        let b = self.grid.cell_box(i)?;
        let mut c = self.from_grid(b.center());
        if self.dims.len() == 1 {
            c[1] = 0.0;
        }
        Some(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lens_motion() -> ParamSpace {
        ParamSpace::for_model(PsfModel::LensMotion, &[[0.0, 64.0], [0.0, 192.0]], 20).unwrap()
    }

    #[test]
    fn remap_round_trip_and_power_law() {
        let s = lens_motion();
        for &x in &[0.0, 0.5, 3.0, 17.25, 64.0] {
            let u = s.to_grid([x, x]);
            let back = s.from_grid(u);
            assert!((back[0] - x).abs() < 1e-9 && (back[1] - x).abs() < 1e-9);
        }
        // beta = 2: a quarter of the range maps to half of the grid.
        assert!((s.to_grid([16.0, 0.0])[0] - 10.0).abs() < 1e-12);
        // beta = 1: uniform.
        assert!((s.to_grid([0.0, 48.0])[1] - 5.0).abs() < 1e-12);
    }

    #[test]
    fn centres_look_up_to_themselves_and_lie_in_their_boxes() {
        let s = lens_motion();
        for i in 0..s.psf_count() {
            let c = s.cell_center(i).unwrap();
            let b = s.cell_box(i).unwrap();
            assert!(b.contains(c, 2));
            let (j, clamped) = s.lookup([c[0] as f32, c[1] as f32]);
            assert_eq!(j, i);
            assert!(!clamped);
        }
        assert!(s.cell_box(s.psf_count()).is_none());
    }

    #[test]
    fn out_of_range_is_clamped_and_flagged() {
        let s = lens_motion();
        let (i, c) = s.lookup([-3.0, 10.0]);
        assert!(c);
        assert_eq!(i, s.lookup([0.0, 10.0]).0);
        let (i, c) = s.lookup([1e9, 1e9]);
        assert!(c);
        assert_eq!(i, s.psf_count() - 1);
        assert!(s.lookup([f32::NAN, 0.0]).1);
        assert!(!s.lookup([64.0, 192.0]).1);
    }

    #[test]
    fn rejects_bad_dimensions() {
        assert!(ParamSpace::for_model(PsfModel::ThinLens, &[[1.0, 1.0]], 10).is_err());
        assert!(ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, f64::NAN]], 10).is_err());
        assert!(ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 1.0], [0.0, 1.0]], 10).is_err());
        assert!(ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 1.0]], 0).is_err());
    }
}
