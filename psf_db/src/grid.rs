//! The nested grid (paper sec. 5.2): cells whose edge grows linearly with the grid coordinate.
//!
//! Resolution `n` grid units per dimension, coordinates `u` in `[0, n)^d` (d = 1 or 2).
//! Level `l` holds the points whose minimum coordinate lies in `[T(l), T(l+1))`,
//! `T(l) = l (l + 1) / 2`. Its cells have edge `l + 1` grid units (clipped at `n`) and form a
//! regular grid over `[T(l), n)^d` with spacing `l + 1`, of which only the multi-indices with a
//! zero component are kept (the L-shaped band of the level). With `m(l) = ceil((n - T(l)) / (l + 1))`
//! cells per axis, level `l` has `m^d - (m - 1)^d` cells: 1 in 1D, `2 m - 1` in 2D.
//!
//! Cell numbering: levels in increasing order (a start table gives each level's first index);
//! inside a level the kept multi-indices `(k0, k1)` in row-major order, i.e. `(0, 0), (0, 1), ...,
//! (0, m-1), (1, 0), (2, 0), ..., (m-1, 0)`: intra-level index `k1` when `k0 == 0`, else
//! `m + k0 - 1`. In 1D there is one cell per level and the cell index is the level.
//!
//! The forward map [`NestedGrid::index_of`] is O(1): level = the triangular root of the minimum
//! coordinate, `floor((sqrt(8 min(u) + 1) - 1) / 2)`, then the intra-level index as above.
//! The paper's 9x9 example (`n = 9`, 2D) has 28 cells instead of 81.

use serde::{Deserialize, Serialize};

use crate::error::SpaceError;

/// Largest accepted grid resolution (grid units per dimension); keeps tables and counts small.
pub const MAX_GRID_RESOLUTION: u32 = 1 << 16;

/// An axis-aligned box. In grid units for [`NestedGrid`], in physical units for
/// [`crate::ParamSpace::cell_box`]. Unused dimensions (1D spaces) are `0..0`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellBox {
    /// Lower corner (inclusive).
    pub min: [f64; 2],
    /// Upper corner (exclusive, except at the end of the space).
    pub max: [f64; 2],
}

impl CellBox {
    /// The box centre (midpoint of each side).
    pub fn center(&self) -> [f64; 2] {
        [
            0.5 * (self.min[0] + self.max[0]),
            0.5 * (self.min[1] + self.max[1]),
        ]
    }

    /// True when `p` lies in the box (closed on both sides), checking the first `dims` dimensions.
    pub fn contains(&self, p: [f64; 2], dims: usize) -> bool {
        (0..dims).all(|d| p[d] >= self.min[d] && p[d] <= self.max[d])
    }
}

/// What a grid is built from; the serialised form of [`NestedGrid`] (tables are rebuilt on load).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct GridSpec {
    /// Number of dimensions, 1 or 2.
    pub dims: u32,
    /// Resolution in grid units per dimension.
    pub n: u32,
}

/// The nested grid over `[0, n)^dims`; see the module documentation for the exact scheme.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "GridSpec", into = "GridSpec")]
pub struct NestedGrid {
    dims: u32,
    n: u32,
    /// First cell index of each level, plus the total cell count at the end (`levels + 1` entries).
    level_start: Vec<u32>,
}

/// `T(l) = l (l + 1) / 2`, the first grid coordinate of level `l`.
#[inline]
pub fn triangular(l: u32) -> u32 {
    l * (l + 1) / 2
}

impl TryFrom<GridSpec> for NestedGrid {
    type Error = SpaceError;
    fn try_from(spec: GridSpec) -> Result<Self, SpaceError> {
        NestedGrid::new(spec.dims as usize, spec.n)
    }
}

impl From<NestedGrid> for GridSpec {
    fn from(g: NestedGrid) -> GridSpec {
        GridSpec {
            dims: g.dims,
            n: g.n,
        }
    }
}

impl NestedGrid {
    /// A grid of `dims` (1 or 2) dimensions and `n` (1..=[`MAX_GRID_RESOLUTION`]) grid units per dimension.
    pub fn new(dims: usize, n: u32) -> Result<Self, SpaceError> {
        if !(1..=2).contains(&dims) {
            return Err(SpaceError::Dims(dims));
        }
        if n == 0 || n > MAX_GRID_RESOLUTION {
            return Err(SpaceError::Resolution(n));
        }
        let mut level_start = vec![0u32];
        let mut total = 0u32;
        let mut l = 0u32;
        while triangular(l) < n {
            total += cells_in_level(dims as u32, n, l);
            level_start.push(total);
            l += 1;
        }
        Ok(NestedGrid {
            dims: dims as u32,
            n,
            level_start,
        })
    }

    /// Number of cells a `dims`-dimensional grid of resolution `n` has (0 when invalid).
    pub fn cell_count_for(dims: usize, n: u32) -> u32 {
        NestedGrid::new(dims, n).map_or(0, |g| g.cell_count())
    }

    /// The smallest resolution `n` whose grid has at least `target` cells; `None` when even
    /// [`MAX_GRID_RESOLUTION`] has fewer (1D: at most 361 cells) or `dims` is not 1 or 2.
    pub fn resolution_for_count(dims: usize, target: u32) -> Option<u32> {
        if Self::cell_count_for(dims, MAX_GRID_RESOLUTION) < target {
            return None;
        }
        // Cell counts grow monotonically with n: bisect.
        let (mut lo, mut hi) = (1u32, MAX_GRID_RESOLUTION);
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if Self::cell_count_for(dims, mid) >= target {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        Some(lo)
    }

    /// Number of dimensions (1 or 2).
    pub fn dims(&self) -> usize {
        self.dims as usize
    }

    /// Resolution in grid units per dimension.
    pub fn n(&self) -> u32 {
        self.n
    }

    /// Total number of cells (= PSFs in a database).
    pub fn cell_count(&self) -> u32 {
        self.level_start[self.level_start.len() - 1]
    }

    /// Number of levels.
    pub fn levels(&self) -> u32 {
        (self.level_start.len() - 1) as u32
    }

    /// First cell index of each level followed by the total cell count (`levels() + 1` entries);
    /// the table a GPU mirror of [`Self::index_of`] needs.
    pub fn level_starts(&self) -> &[u32] {
        &self.level_start
    }

    /// Cells per axis of level `l`'s regular grid: `ceil((n - T(l)) / (l + 1))`.
    pub fn cells_per_axis(&self, l: u32) -> u32 {
        cells_per_axis(self.n, l)
    }

    /// The cell containing grid point `u` (grid units). Coordinates are clamped to `[0, n)`;
    /// NaN counts as 0. O(1).
    #[inline]
    pub fn index_of(&self, u: [f64; 2]) -> u32 {
        let n = self.n as f64;
        let clamp = |x: f64| if x >= 0.0 { x.min(n) } else { 0.0 }; // NaN -> 0
        let u0 = clamp(u[0]);
        let u1 = if self.dims == 2 { clamp(u[1]) } else { u0 };
        let (min_u, min_dim) = if u1 < u0 { (u1, 1) } else { (u0, 0) };
        let last_level = self.levels() - 1;
        let mut l = (((8.0 * min_u + 1.0).sqrt() - 1.0) * 0.5).floor() as u32;
        // Guard the float root against rounding at level boundaries.
        if l > 0 && (triangular(l) as f64) > min_u {
            l -= 1;
        }
        if (triangular(l + 1) as f64) <= min_u {
            l += 1;
        }
        let l = l.min(last_level);
        let start = self.level_start[l as usize];
        if self.dims == 1 {
            return start;
        }
        let origin = triangular(l) as f64;
        let edge = (l + 1) as f64;
        let m = cells_per_axis(self.n, l);
        let k = |x: f64| (((x - origin) / edge).floor().max(0.0) as u32).min(m - 1);
        let (k0, k1) = if min_dim == 0 { (0, k(u1)) } else { (k(u0), 0) };
        start + if k0 == 0 { k1 } else { m + k0 - 1 }
    }

    /// The level of cell `i` (`i < cell_count()`).
    pub fn level_of(&self, i: u32) -> u32 {
        (self.level_start.partition_point(|&s| s <= i) - 1) as u32
    }

    /// The box (grid units) of cell `i`; `None` when `i >= cell_count()`.
    pub fn cell_box(&self, i: u32) -> Option<CellBox> {
        if i >= self.cell_count() {
            return None;
        }
        let l = self.level_of(i);
        let j = i - self.level_start[l as usize];
        let m = cells_per_axis(self.n, l);
        let (k0, k1) = if j < m { (0, j) } else { (j - m + 1, 0) };
        let origin = triangular(l) as f64;
        let edge = (l + 1) as f64;
        let n = self.n as f64;
        let side = |k: u32| {
            (
                origin + k as f64 * edge,
                (origin + (k + 1) as f64 * edge).min(n),
            )
        };
        let (a0, b0) = side(k0);
        let mut b = CellBox {
            min: [a0, 0.0],
            max: [b0, 0.0],
        };
        if self.dims == 2 {
            let (a1, b1) = side(k1);
            b.min[1] = a1;
            b.max[1] = b1;
        }
        Some(b)
    }

    /// All cell boxes in index order (the inverse map g^-1).
    pub fn boxes(&self) -> Vec<CellBox> {
        (0..self.cell_count())
            .filter_map(|i| self.cell_box(i))
            .collect()
    }
}

/// A regular grid over `[0, n)^2` of `cells[0] x cells[1]` equal boxes, numbered with
/// dimension 0 major: cell `i0 cells[1] + i1`. `n = cells[0] cells[1]`, so every box edge is a
/// whole number of grid units. The physical-lens model samples on it: its PSF changes as fast
/// for a near object in the frame's corner as anywhere, where a nested grid's cells are widest.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RegularGrid {
    cells: [u32; 2],
}

impl RegularGrid {
    /// A grid of `cells[0] x cells[1]` boxes (each at least 1, the product at most
    /// [`MAX_GRID_RESOLUTION`]).
    pub fn new(cells: [u32; 2]) -> Result<Self, SpaceError> {
        let n = u64::from(cells[0]) * u64::from(cells[1]);
        if cells.contains(&0) || n > u64::from(MAX_GRID_RESOLUTION) {
            return Err(SpaceError::RegularCells(cells));
        }
        Ok(RegularGrid { cells })
    }

    /// Boxes per dimension.
    pub fn cells(&self) -> [u32; 2] {
        self.cells
    }

    /// Grid units per dimension, `cells[0] cells[1]`.
    pub fn n(&self) -> u32 {
        self.cells[0] * self.cells[1]
    }

    /// Number of boxes.
    pub fn cell_count(&self) -> u32 {
        self.n()
    }

    /// Edge of a box along dimension `k`, grid units.
    fn edge(&self, k: usize) -> u32 {
        self.n() / self.cells[k]
    }

    /// The box containing grid point `u`, clamped to `[0, n)`; NaN counts as 0. O(1).
    #[inline]
    pub fn index_of(&self, u: [f64; 2]) -> u32 {
        let n = f64::from(self.n());
        let along = |k: usize| {
            let x = if u[k] >= 0.0 { u[k].min(n) } else { 0.0 }; // NaN -> 0
            ((x / f64::from(self.edge(k))).floor() as u32).min(self.cells[k] - 1)
        };
        along(0) * self.cells[1] + along(1)
    }

    /// The box (grid units) of cell `i`; `None` when `i >= cell_count()`.
    pub fn cell_box(&self, i: u32) -> Option<CellBox> {
        if i >= self.cell_count() {
            return None;
        }
        let k = [i / self.cells[1], i % self.cells[1]];
        let side = |d: usize| {
            let e = f64::from(self.edge(d));
            (f64::from(k[d]) * e, f64::from(k[d] + 1) * e)
        };
        let ((a0, b0), (a1, b1)) = (side(0), side(1));
        Some(CellBox {
            min: [a0, a1],
            max: [b0, b1],
        })
    }
}

/// The cells a parameter space's PSFs sample: the paper's nested grid, or a regular one.
#[derive(Clone, Debug, PartialEq)]
pub enum Grid {
    /// Cells whose edge grows with the smaller grid coordinate (thin lens, lens motion).
    Nested(NestedGrid),
    /// Equal boxes (physical lens).
    Regular(RegularGrid),
}

impl Grid {
    /// Grid units per dimension.
    pub fn n(&self) -> u32 {
        match self {
            Grid::Nested(g) => g.n(),
            Grid::Regular(g) => g.n(),
        }
    }

    /// Number of cells.
    pub fn cell_count(&self) -> u32 {
        match self {
            Grid::Nested(g) => g.cell_count(),
            Grid::Regular(g) => g.cell_count(),
        }
    }

    /// The cell containing grid point `u` (grid units), clamped to the grid; NaN counts as 0.
    #[inline]
    pub fn index_of(&self, u: [f64; 2]) -> u32 {
        match self {
            Grid::Nested(g) => g.index_of(u),
            Grid::Regular(g) => g.index_of(u),
        }
    }

    /// The box (grid units) of cell `i`; `None` when `i >= cell_count()`.
    pub fn cell_box(&self, i: u32) -> Option<CellBox> {
        match self {
            Grid::Nested(g) => g.cell_box(i),
            Grid::Regular(g) => g.cell_box(i),
        }
    }
}

fn cells_per_axis(n: u32, l: u32) -> u32 {
    (n - triangular(l)).div_ceil(l + 1)
}

fn cells_in_level(dims: u32, n: u32, l: u32) -> u32 {
    let m = cells_per_axis(n, l);
    if dims == 1 {
        1
    } else {
        2 * m - 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every box's centre maps back to it, the boxes tile the square exactly, and points
    /// outside (or NaN) clamp to the edge boxes.
    #[test]
    fn regular_boxes_tile_the_square_and_centres_map_back() {
        for cells in [[1, 1], [16, 10], [3, 2], [7, 13]] {
            let g = RegularGrid::new(cells).unwrap();
            let n = f64::from(g.n());
            assert_eq!(g.cell_count(), cells[0] * cells[1]);
            let mut area = 0.0;
            for i in 0..g.cell_count() {
                let b = g.cell_box(i).unwrap();
                assert_eq!(g.index_of(b.center()), i, "{cells:?} box {i}");
                assert_eq!(g.index_of(b.min), i, "{cells:?} box {i}: its lower corner");
                area += (b.max[0] - b.min[0]) * (b.max[1] - b.min[1]);
            }
            assert_eq!(area, n * n, "{cells:?}");
            assert!(g.cell_box(g.cell_count()).is_none());
            assert_eq!(g.index_of([-3.0, f64::NAN]), 0);
            assert_eq!(g.index_of([n, 2.0 * n]), g.cell_count() - 1);
            assert_eq!(g.index_of([0.0, n]), cells[1] - 1);
        }
        assert!(RegularGrid::new([0, 4]).is_err());
        assert!(RegularGrid::new([300, 300]).is_err());
    }

    #[test]
    fn paper_example_9x9_has_28_cells() {
        let g = NestedGrid::new(2, 9).unwrap();
        assert_eq!(g.cell_count(), 28);
        assert_eq!(g.level_starts(), &[0, 17, 24, 27, 28]);
    }

    #[test]
    fn one_dimensional_levels_are_cells() {
        let g = NestedGrid::new(1, 10).unwrap();
        // T = 0, 1, 3, 6, 10: four levels, edges 1, 2, 3, 4.
        assert_eq!(g.cell_count(), 4);
        let b = g.cell_box(3).unwrap();
        assert_eq!((b.min[0], b.max[0]), (6.0, 10.0));
        assert_eq!(g.index_of([5.99, 0.0]), 2);
        assert_eq!(g.index_of([6.0, 0.0]), 3);
        assert_eq!(g.index_of([100.0, 0.0]), 3);
        assert_eq!(g.index_of([-1.0, 0.0]), 0);
        assert_eq!(g.index_of([f64::NAN, 0.0]), 0);
    }

    #[test]
    fn centres_map_back_and_boxes_tile_the_square() {
        for dims in 1..=2 {
            for n in 1..=60 {
                let g = NestedGrid::new(dims, n).unwrap();
                let mut area = 0.0;
                for (i, b) in g.boxes().iter().enumerate() {
                    assert_eq!(
                        g.index_of(b.center()),
                        i as u32,
                        "dims {dims} n {n} cell {i}"
                    );
                    let mut a = b.max[0] - b.min[0];
                    if dims == 2 {
                        a *= b.max[1] - b.min[1];
                    }
                    assert!(a > 0.0);
                    area += a;
                }
                assert_eq!(area, (n as f64).powi(dims as i32), "dims {dims} n {n}");
            }
        }
    }

    #[test]
    fn resolution_for_count_is_minimal() {
        for dims in 1..=2 {
            for target in [1, 2, 28, 100, 361, 400, 4000] {
                let Some(n) = NestedGrid::resolution_for_count(dims, target) else {
                    assert!(dims == 1 && target > 361);
                    continue;
                };
                assert!(NestedGrid::cell_count_for(dims, n) >= target);
                if n > 1 {
                    assert!(NestedGrid::cell_count_for(dims, n - 1) < target);
                }
            }
        }
    }
}
