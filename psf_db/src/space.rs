//! Parameter spaces: physical PSF parameters `s`, their power remapping to grid coordinates `u`,
//! and the O(1) lookup of the PSF that stands for `s`.
//!
//! Per dimension, `u = n * ((s - min) / (max - min))^(1 / beta)` (DESIGN.md, "Power remapping"),
//! so beta > 1 puts finer cells at small `s`. The inverse is `s = min + (max - min) (u / n)^beta`.

use serde::{Deserialize, Serialize};

use crate::error::SpaceError;
use crate::grid::{CellBox, Grid, NestedGrid, RegularGrid};
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

/// Least distance from the focus plane, in widths of a cell along inverse depth, of a
/// physical-lens cell whose PSF the runtime scales onto a pixel's own defocus before it
/// blends it with the next cell's ([`ParamSpace::blend_scales_cell`]). Within it a lens's
/// blur is not its defocus scaled (the aberrations that remain at focus are a large part of
/// it), so those cells' PSFs are blended as they are, and pre-filtered over their inverse
/// depths to keep that blend smooth. A scaled PSF grows or shrinks by at most 4/3.
pub const SCALED_BLEND_MIN_CELLS_FROM_FOCUS: f64 = 3.0;

/// The serialised form of [`ParamSpace`] (validated on load).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParamSpaceSpec {
    /// One entry per dimension (1 or 2).
    pub dims: Vec<Dimension>,
    /// Grid resolution in grid units per dimension.
    pub n: u32,
    /// Boxes per dimension of a regular grid (`n` is then their product); `None` for the
    /// nested grid.
    pub regular: Option<[u32; 2]>,
}

/// A sampled PSF parameter space: ranges, power remapping and the grid over it (the paper's
/// nested grid, or a regular one). Coordinates are `[f64; 2]` / `[f32; 2]` whose second entry
/// is ignored in 1D spaces.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "ParamSpaceSpec", into = "ParamSpaceSpec")]
pub struct ParamSpace {
    dims: Vec<Dimension>,
    grid: Grid,
}

impl TryFrom<ParamSpaceSpec> for ParamSpace {
    type Error = SpaceError;
    fn try_from(spec: ParamSpaceSpec) -> Result<Self, SpaceError> {
        match spec.regular {
            None => ParamSpace::new(spec.dims, spec.n),
            Some(cells) => {
                let space = ParamSpace::regular(spec.dims, cells)?;
                if space.n() != spec.n {
                    return Err(SpaceError::RegularCells(cells));
                }
                Ok(space)
            }
        }
    }
}

impl From<ParamSpace> for ParamSpaceSpec {
    fn from(s: ParamSpace) -> Self {
        ParamSpaceSpec {
            n: s.grid.n(),
            regular: match &s.grid {
                Grid::Nested(_) => None,
                Grid::Regular(g) => Some(g.cells()),
            },
            dims: s.dims,
        }
    }
}

/// Checks that every dimension has a finite, non-empty range and a finite positive beta.
fn check_dims(dims: &[Dimension]) -> Result<(), SpaceError> {
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
    Ok(())
}

impl ParamSpace {
    /// A space over `dims` (1 or 2 entries, finite `min < max`, finite `beta > 0`) with grid
    /// resolution `n`.
    pub fn new(dims: Vec<Dimension>, n: u32) -> Result<Self, SpaceError> {
        check_dims(&dims)?;
        let grid = Grid::Nested(NestedGrid::new(dims.len(), n)?);
        Ok(ParamSpace { dims, grid })
    }

    /// A two-dimensional space over `dims` (as [`Self::new`]) sampled by a regular grid of
    /// `cells[0] x cells[1]` boxes, equal in the remapped coordinates.
    pub fn regular(dims: Vec<Dimension>, cells: [u32; 2]) -> Result<Self, SpaceError> {
        if dims.len() != 2 {
            return Err(SpaceError::Dims(dims.len()));
        }
        check_dims(&dims)?;
        let grid = Grid::Regular(RegularGrid::new(cells)?);
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

    /// The grid over the remapped coordinates.
    pub fn grid(&self) -> &Grid {
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
        let mut u = [0.0; 2];
        for (k, d) in self.dims.iter().enumerate() {
            u[k] = self.grid_coordinate(d, s[k]);
        }
        u
    }

    /// Physical `s` along dimension `d` to its grid coordinate ([`ParamSpace::to_grid`]).
    #[inline]
    fn grid_coordinate(&self, d: &Dimension, s: f64) -> f64 {
        let n = self.grid.n() as f64;
        let t = (s - d.min) / (d.max - d.min);
        let t = if t > 0.0 { t.min(1.0) } else { 0.0 };
        // The paper's betas are 1 and 2 in most dimensions: skip the general power there.
        n * if d.beta == 1.0 {
            t
        } else if d.beta == 2.0 {
            t.sqrt()
        } else {
            t.powf(1.0 / d.beta)
        }
    }

    /// Grid coordinates `u` (clamped to `[0, n]`) to physical `s`.
    #[inline]
    pub fn from_grid(&self, u: [f64; 2]) -> [f64; 2] {
        let n = self.grid.n() as f64;
        let mut s = [0.0; 2];
        for (k, d) in self.dims.iter().enumerate() {
            let t = u[k] / n;
            let t = if t > 0.0 { t.min(1.0) } else { 0.0 };
            // `t^1` is `t` exactly: skip the general power there.
            let power = if d.beta == 1.0 { t } else { t.powf(d.beta) };
            s[k] = d.min + (d.max - d.min) * power;
        }
        s
    }

    /// The PSF index standing for physical parameters `s`, and whether `s` had to be clamped
    /// into the space (outside `[min, max]` in some dimension, or NaN). O(1).
    #[inline]
    pub fn lookup(&self, s: [f32; 2]) -> (u32, bool) {
        let (sd, clamped) = self.widened(s);
        (self.grid.index_of(self.to_grid(sd)), clamped)
    }

    /// `s` in f64, and whether it lies outside `[min, max]` in one of the space's dimensions
    /// (NaN counts as outside).
    #[inline]
    fn widened(&self, s: [f32; 2]) -> ([f64; 2], bool) {
        let mut clamped = false;
        let mut sd = [0.0f64; 2];
        for (k, d) in self.dims.iter().enumerate() {
            let v = f64::from(s[k]);
            // `!(a && b)` so that NaN counts as clamped.
            if !(v >= d.min && v <= d.max) {
                clamped = true;
            }
            sd[k] = v;
        }
        (sd, clamped)
    }

    /// The neighbouring cell along dimension `dim` that a PSF for `s` is blended with, so that
    /// the blend changes linearly from one cell's centre to the next: that cell's index and its
    /// share in `(0, 0.5]`.
    /// With `(1 - share)` of the cell holding `s`, the PSF is the tent interpolation between
    /// cell centres, continuous in `s` across cell boundaries, where the cell holding `s`
    /// alone steps: a step in a PSF's size shows as a line on a surface whose blur varies
    /// smoothly. `None` where `s` sits on its cell's centre, at the space's ends (NaN too), or
    /// for a dimension the space lacks.
    pub fn neighbour_blend(&self, s: [f32; 2], dim: usize) -> Option<(u32, f32)> {
        if dim >= self.dims.len() || !s[dim].is_finite() {
            return None;
        }
        let u = self.to_grid([f64::from(s[0]), f64::from(s[1])]);
        self.neighbour_blend_at(u, self.grid.index_of(u), dim)
    }

    /// [`ParamSpace::lookup`] and [`ParamSpace::neighbour_blend`] along `dim` of one `s`,
    /// with its grid coordinates found once: the same results as the two calls.
    pub fn lookup_and_blend(&self, s: [f32; 2], dim: usize) -> (u32, bool, Option<(u32, f32)>) {
        let (sd, clamped) = self.widened(s);
        let u = self.to_grid(sd);
        let index = self.grid.index_of(u);
        let blend = if dim < self.dims.len() && s[dim].is_finite() {
            // `to_grid` reads only the space's dimensions, so `u` is what the blend's own
            // conversion of `s` would give.
            self.neighbour_blend_at(u, index, dim)
        } else {
            None
        };
        (index, clamped, blend)
    }

    /// [`ParamSpace::lookup_and_blend`] along the first dimension of a two-dimensional space
    /// whose first dimension is linear (beta 1), through `memo`: the same results. Where `s`
    /// lies well inside the cell the last lookup found (its second coordinate compared in
    /// physical units, so that its power is not taken), the cell and its neighbour along the
    /// first dimension are the memo's: a row of pixels through a real lens mostly stays in one
    /// cell of inverse depth and eccentricity. One memo serves one space.
    pub fn lookup_and_blend_memo(
        &self,
        s: [f32; 2],
        memo: &mut CellMemo,
    ) -> (u32, bool, Option<(u32, f32)>) {
        let linear_first = self.dims.len() == 2 && self.dims[0].beta == 1.0;
        if !linear_first || !s[0].is_finite() || !s[1].is_finite() {
            return self.lookup_and_blend(s, 0);
        }
        let (d0, d1) = (&self.dims[0], &self.dims[1]);
        let ([s0, s1], clamped) = self.widened(s);
        let u0 = self.grid_coordinate(d0, s0);
        let inside = |b: &MemoBox| b.lo0 < u0 && u0 < b.hi0 && b.s1_lo < s1 && s1 < b.s1_hi;
        let cell = match memo.cell2.filter(inside) {
            Some(cell) => cell,
            None => {
                let (index, clamped, blend) = self.lookup_and_blend(s, 0);
                memo.cell2 = self.memo_box(index);
                return (index, clamped, blend);
            }
        };
        // A neighbour found before serves while `s` lies within its range of the second
        // coordinate too: the point just across the boundary then falls in the same cell.
        let neighbour = |side: &mut Option<MemoNeighbour>, above: bool| {
            if let Some(n) = side.filter(|n| n.s1_lo < s1 && s1 < n.s1_hi) {
                return Some((n.index, n.centre));
            }
            let u = [u0, self.grid_coordinate(d1, s1)];
            let found = self.neighbour_along(u, 0, cell.lo0, cell.hi0, above)?;
            *side = self.memo_neighbour(found);
            Some(found)
        };
        let (mut lower, mut upper) = (cell.lower, cell.upper);
        let blend = self.tent_share(
            u0,
            cell.lo0,
            cell.hi0,
            || neighbour(&mut lower, false),
            || neighbour(&mut upper, true),
        );
        memo.cell2 = Some(MemoBox {
            lower,
            upper,
            ..cell
        });
        (cell.index, clamped, blend)
    }

    /// The memo of cell `index`, its second coordinate's range shrunk
    /// by a millionth of a millionth of the dimension's range at either end (far beyond the
    /// rounding of the power between grid and physical units); `None` for an empty cell.
    fn memo_box(&self, index: u32) -> Option<MemoBox> {
        let b = self.grid.cell_box(index)?;
        if b.max[0] - b.min[0] <= 0.0 || b.max[1] - b.min[1] <= 0.0 {
            return None;
        }
        let (s1_lo, s1_hi) = self.shrunk_second_range(b.min[1], b.max[1])?;
        Some(MemoBox {
            index,
            lo0: b.min[0],
            hi0: b.max[0],
            s1_lo,
            s1_hi,
            lower: None,
            upper: None,
        })
    }

    /// The memo of a neighbour `(index, centre along the first dimension)`.
    fn memo_neighbour(&self, (index, centre): (u32, f64)) -> Option<MemoNeighbour> {
        let b = self.grid.cell_box(index)?;
        let (s1_lo, s1_hi) = self.shrunk_second_range(b.min[1], b.max[1])?;
        Some(MemoNeighbour {
            index,
            centre,
            s1_lo,
            s1_hi,
        })
    }

    /// The physical range of grid coordinates `[lo, hi]` of the second dimension, shrunk as
    /// [`ParamSpace::memo_box`] says; `None` where nothing is left.
    fn shrunk_second_range(&self, lo: f64, hi: f64) -> Option<(f64, f64)> {
        let d = self.dims.get(1)?;
        let margin = 1e-12 * (d.max - d.min);
        let (a, b) = (
            self.from_grid([0.0, lo])[1] + margin,
            self.from_grid([0.0, hi])[1] - margin,
        );
        (a < b).then_some((a, b))
    }

    /// [`ParamSpace::neighbour_blend`] at grid coordinates `u`, which cell `index` holds.
    fn neighbour_blend_at(&self, u: [f64; 2], index: u32, dim: usize) -> Option<(u32, f32)> {
        let cell = self.grid.cell_box(index)?;
        let (lo, hi) = (cell.min[dim], cell.max[dim]);
        self.tent_share(
            u[dim],
            lo,
            hi,
            || self.neighbour_along(u, dim, lo, hi, false),
            || self.neighbour_along(u, dim, lo, hi, true),
        )
    }

    /// The cell next to the cell `[lo, hi]` (grid units along `dim`) holding grid point `u`,
    /// below it or `above` it along `dim`: its index and its centre along `dim`.
    fn neighbour_along(
        &self,
        u: [f64; 2],
        dim: usize,
        lo: f64,
        hi: f64,
        above: bool,
    ) -> Option<(u32, f64)> {
        // A point just inside the neighbour.
        let edge = hi - lo;
        let mut at = u;
        at[dim] = if above {
            hi + 1e-6 * edge
        } else {
            lo - 1e-6 * edge
        };
        let index = self.grid.index_of(at);
        let b = self.grid.cell_box(index)?;
        Some((index, 0.5 * (b.min[dim] + b.max[dim])))
    }

    /// The neighbour and share of [`ParamSpace::neighbour_blend`] for grid coordinate `u` in
    /// the cell `[lo, hi]` along one dimension, given its `lower` and `upper` neighbours
    /// (index and centre), asked for only on the side `u` lies.
    fn tent_share(
        &self,
        u: f64,
        lo: f64,
        hi: f64,
        lower: impl FnOnce() -> Option<(u32, f64)>,
        upper: impl FnOnce() -> Option<(u32, f64)>,
    ) -> Option<(u32, f32)> {
        let n = self.grid.n() as f64;
        if hi - lo <= 0.0 {
            return None;
        }
        let centre = 0.5 * (lo + hi);
        let offset = u - centre;
        let (neighbour_index, neighbour_centre) = if offset > 0.0 && hi < n {
            upper()?
        } else if offset < 0.0 && lo > 0.0 {
            lower()?
        } else {
            return None;
        };
        // From 0 at the own centre to 1/2 at the boundary. A narrower ramp (the cell's own PSF
        // over the middle of the cell) would halve the second splats, but leaves the ramp a
        // step: a ramp over half the distance left dips of 2.5 % on a CoC ramp, 1.7 % on a
        // motion ramp.
        let share = (offset.abs() / (neighbour_centre - centre).abs()).min(0.5);
        if share <= 0.0 {
            return None;
        }
        Some((neighbour_index, share as f32))
    }

    /// [`ParamSpace::lookup`] of `[s, 0]` and, with `blend`, [`ParamSpace::neighbour_blend`]
    /// along the first dimension: the same results, found through `memo` in a
    /// one-dimensional nested space, where the next lookup in the same cell (a row of pixels
    /// whose blur changes slowly) skips the walk into the grid. One memo serves one space.
    pub fn lookup_blended_1d(
        &self,
        s: f32,
        blend: bool,
        memo: &mut CellMemo,
    ) -> (u32, bool, Option<(u32, f32)>) {
        if self.dims.len() != 1 || !matches!(self.grid, Grid::Nested(_)) {
            let (index, clamped) = self.lookup([s, 0.0]);
            let blend = blend.then(|| self.neighbour_blend([s, 0.0], 0)).flatten();
            return (index, clamped, blend);
        }
        let d = &self.dims[0];
        let v = f64::from(s);
        // `!(a && b)` so that NaN counts as clamped.
        let clamped = !(v >= d.min && v <= d.max);
        let u = self.to_grid([v, 0.0]);
        // Strictly inside the remembered cell, the grid's walk finds that cell.
        let cell = match memo.cell.filter(|c| c.lo < u[0] && u[0] < c.hi) {
            Some(cell) => cell,
            None => {
                let cell = self.memo_cell(u);
                memo.cell = Some(cell);
                cell
            }
        };
        let blend = (blend && s.is_finite())
            .then(|| self.tent_share(u[0], cell.lo, cell.hi, || cell.lower, || cell.upper))
            .flatten();
        (cell.index, clamped, blend)
    }

    /// The cell holding grid coordinates `u` of a one-dimensional space, with the neighbours
    /// [`ParamSpace::neighbour_blend`] would find on either side.
    fn memo_cell(&self, u: [f64; 2]) -> MemoCell {
        let n = self.grid.n() as f64;
        let index = self.grid.index_of(u);
        let (lo, hi) = self
            .grid
            .cell_box(index)
            .map_or((0.0, 0.0), |b| (b.min[0], b.max[0]));
        let valid = hi - lo > 0.0;
        MemoCell {
            index,
            lo,
            hi,
            lower: (valid && lo > 0.0)
                .then(|| self.neighbour_along(u, 0, lo, hi, false))
                .flatten(),
            upper: (valid && hi < n)
                .then(|| self.neighbour_along(u, 0, lo, hi, true))
                .flatten(),
        }
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

    /// Whether cell `i` of a physical-lens space (first dimension inverse depth, 1 / scene
    /// units) lies at least [`SCALED_BLEND_MIN_CELLS_FROM_FOCUS`] of its widths from the
    /// focus plane at inverse depth `focus`: the runtime scales its PSF onto a pixel's own
    /// defocus, so the precompute traces it at its inverse depth's middle, not over its box.
    pub fn blend_scales_cell(&self, i: u32, focus: f64) -> bool {
        let (Some(b), Some(c)) = (self.cell_box(i), self.cell_center(i)) else {
            return false;
        };
        let width = b.max[0] - b.min[0];
        width > 0.0 && (c[0] - focus).abs() >= SCALED_BLEND_MIN_CELLS_FROM_FOCUS * width
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

/// The last cell a one-dimensional lookup found ([`ParamSpace::lookup_blended_1d`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct CellMemo {
    cell: Option<MemoCell>,
    cell2: Option<MemoBox>,
}

/// A cell of a two-dimensional space ([`ParamSpace::lookup_and_blend_memo`]): its index, its
/// box along the first dimension (grid units), the physical range of the second coordinate
/// it holds for certain, and its neighbours along the first dimension as found so far.
#[derive(Clone, Copy, Debug)]
struct MemoBox {
    index: u32,
    lo0: f64,
    hi0: f64,
    s1_lo: f64,
    s1_hi: f64,
    lower: Option<MemoNeighbour>,
    upper: Option<MemoNeighbour>,
}

/// A neighbouring cell along the first dimension: its index, its centre along that
/// dimension (grid units), and the physical range of the second coordinate it holds.
#[derive(Clone, Copy, Debug)]
struct MemoNeighbour {
    index: u32,
    centre: f64,
    s1_lo: f64,
    s1_hi: f64,
}

/// A one-dimensional cell: its index, its box along the dimension (grid units), and its
/// lower and upper neighbours' indices and centres (grid units), where it has them.
#[derive(Clone, Copy, Debug)]
struct MemoCell {
    index: u32,
    lo: f64,
    hi: f64,
    lower: Option<(u32, f64)>,
    upper: Option<(u32, f64)>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_remembered_cell_gives_what_a_fresh_lookup_gives() {
        let ranges = [[0.05, 3.0], [0.0, 21.0]];
        let nested = ParamSpace::for_model(PsfModel::PhysicalLens, &ranges, 16).expect("nested");
        let dims = nested.dims().to_vec();
        let regular = ParamSpace::regular(dims, [12, 7]).expect("regular");
        for space in [nested, regular] {
            let mut memo = CellMemo::default();
            // Rows of pixels: inverse depth and eccentricity changing slowly, across cell
            // boundaries and the space's ends, then jumps.
            let mut points = Vec::new();
            for row in 0..40 {
                for x in 0..300 {
                    let t = x as f32 / 300.0;
                    let s0 = -0.2 + 3.4 * t + 0.3 * (row as f32 * 0.37).sin();
                    let s1 = (row as f32 * 0.55 + 8.0 * (t - 0.5) * (t - 0.5)) - 0.5;
                    points.push([s0, s1]);
                }
            }
            for i in 0..2000 {
                let k = (i * 7919 % 2003) as f32 / 2003.0;
                points.push([3.5 * k - 0.2, 22.0 * ((k * 13.0).fract()) - 0.5]);
            }
            points.push([f32::NAN, 3.0]);
            points.push([1.0, f32::INFINITY]);
            for s in points {
                let fresh = space.lookup_and_blend(s, 0);
                assert_eq!(space.lookup_and_blend_memo(s, &mut memo), fresh, "{s:?}");
            }
        }
    }

    #[test]
    fn one_lookup_and_blend_is_the_two_calls() {
        for model in [
            PsfModel::ThinLens,
            PsfModel::LensMotion,
            PsfModel::PhysicalLens,
        ] {
            let ranges: Vec<[f64; 2]> = model.default_beta().iter().map(|_| [0.0, 30.0]).collect();
            let space = ParamSpace::for_model(model, &ranges, 16).expect("a valid space");
            for i in 0..400 {
                let s = [i as f32 * 0.083 - 1.0, (i * 7 % 400) as f32 * 0.081 - 0.5];
                for dim in 0..2 {
                    let (index, clamped) = space.lookup(s);
                    let blend = space.neighbour_blend(s, dim);
                    assert_eq!(
                        space.lookup_and_blend(s, dim),
                        (index, clamped, blend),
                        "{s:?}"
                    );
                }
            }
        }
    }

    fn lens_motion() -> ParamSpace {
        ParamSpace::for_model(PsfModel::LensMotion, &[[0.0, 64.0], [0.0, 192.0]], 20).unwrap()
    }

    /// The centre, in grid units along `dim`, of the cell holding physical `s`.
    fn centre_along(space: &ParamSpace, s: [f32; 2], dim: usize) -> f64 {
        let i = space.lookup(s).0;
        space.grid.cell_box(i).unwrap().center()[dim]
    }

    #[test]
    fn the_neighbour_blend_interpolates_linearly_between_cell_centres() {
        let space = lens_motion();
        let n = space.n() as f64;
        // A CoC in the first band, so that the motion axis holds cells of one edge.
        let coc = space.from_grid([0.3, 0.0])[0] as f32;
        let mut u1 = 0.6;
        while u1 < n - 0.6 {
            let motion = space.from_grid([0.0, u1])[1] as f32;
            let s = [coc, motion];
            let own = centre_along(&space, s, 1);
            // The shares' mean cell centre is the point itself: the tent between centres.
            let mean = match space.neighbour_blend(s, 1) {
                Some((other, share)) => {
                    assert!(share > 0.0 && share <= 0.5, "share {share}");
                    let other = space.grid.cell_box(other).unwrap().center()[1];
                    assert!((other - own).abs() > 0.5, "a different cell");
                    (1.0 - f64::from(share)) * own + f64::from(share) * other
                }
                None => own,
            };
            let u = space.to_grid([f64::from(coc), f64::from(motion)])[1];
            assert!((mean - u).abs() < 1e-3, "u1 {u}: blend centre {mean}");
            u1 += 0.037;
        }
        assert!(
            space.neighbour_blend([coc, 0.0], 1).is_none(),
            "first half cell"
        );
        assert!(
            space.neighbour_blend([coc, 1.0], 2).is_none(),
            "no third dimension"
        );
    }

    /// A regular space survives its serialised form, looks up every box's centre as that
    /// box, and refuses a resolution that does not match its boxes.
    #[test]
    fn a_regular_space_round_trips_and_looks_up_its_centres() {
        let dims = vec![
            Dimension {
                min: 0.001,
                max: 3.3,
                beta: 1.0,
            },
            Dimension {
                min: 0.0,
                max: 21.4,
                beta: 0.6,
            },
        ];
        let space = ParamSpace::regular(dims.clone(), [16, 10]).unwrap();
        assert_eq!(space.psf_count(), 160);
        let spec = ParamSpaceSpec::from(space.clone());
        assert_eq!(spec.regular, Some([16, 10]));
        assert_eq!(ParamSpace::try_from(spec.clone()).unwrap(), space);
        for i in 0..space.psf_count() {
            let c = space.cell_center(i).unwrap();
            assert_eq!(
                space.lookup([c[0] as f32, c[1] as f32]),
                (i, false),
                "box {i}"
            );
        }
        // Boxes narrow towards the largest eccentricity.
        let width = |i: u32| {
            let b = space.cell_box(i).unwrap();
            b.max[1] - b.min[1]
        };
        assert!(width(9) < 0.5 * width(0), "{} vs {}", width(9), width(0));
        let bad = ParamSpaceSpec { n: 7, ..spec };
        assert!(ParamSpace::try_from(bad).is_err());
        assert!(ParamSpace::regular(dims[..1].to_vec(), [4, 1]).is_err());
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

    /// The memoised one-dimensional lookup finds what the plain lookup and neighbour blend
    /// find, whatever order the values come in: rising, falling, scattered, out of range, NaN.
    #[test]
    fn the_memoised_1d_lookup_equals_the_plain_one() {
        let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 48.0]], 30).unwrap();
        let rising: Vec<f32> = (-20..=5200).map(|k| k as f32 * 0.01).collect();
        let falling: Vec<f32> = rising.iter().rev().copied().collect();
        // A fixed scatter (a multiplicative hash of the index) over and past the range.
        let scattered: Vec<f32> = (0u32..4000)
            .map(|k| (k.wrapping_mul(2_654_435_761) >> 8) as f32 / (1u32 << 24) as f32 * 60.0 - 6.0)
            .chain([f32::NAN, f32::INFINITY, -f32::INFINITY, 0.0, 48.0])
            .collect();
        for values in [rising, falling, scattered] {
            let mut memo = CellMemo::default();
            for s in values {
                for blend in [true, false] {
                    let (index, clamped) = space.lookup([s, 0.0]);
                    let expected = blend.then(|| space.neighbour_blend([s, 0.0], 0)).flatten();
                    assert_eq!(
                        space.lookup_blended_1d(s, blend, &mut memo),
                        (index, clamped, expected),
                        "s {s}, blend {blend}"
                    );
                }
            }
        }
    }

    #[test]
    fn rejects_bad_dimensions() {
        assert!(ParamSpace::for_model(PsfModel::ThinLens, &[[1.0, 1.0]], 10).is_err());
        assert!(ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, f64::NAN]], 10).is_err());
        assert!(ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 1.0], [0.0, 1.0]], 10).is_err());
        assert!(ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 1.0]], 0).is_err());
    }
}
