//! Pre-filtering (paper sec. 5.4): a PSF stands for every parameter in its nested-grid cell, so
//! its light is integrated over the cell as well: each ray draws its PSF parameters uniformly
//! in the cell's box in grid coordinates `u` (the remapped space in which the runtime picks the
//! nearest PSF), mapped back to physical units. Without pre-filtering every ray uses the cell's
//! representative parameters.

use psf_db::ParamSpace;

/// The PSF parameters one PSF is traced with.
#[derive(Clone, Debug)]
pub struct ParamBox {
    space: ParamSpace,
    u_min: [f64; 2],
    u_max: [f64; 2],
    centre: [f64; 2],
    prefilter: bool,
}

impl ParamBox {
    /// The box of PSF `index` of `space`; `prefilter = false` gives the cell centre only.
    /// `None` when `index` is out of range.
    pub fn for_cell(space: &ParamSpace, index: u32, prefilter: bool) -> Option<Self> {
        Self::for_cell_along(space, index, [prefilter; 2])
    }

    /// [`ParamBox::for_cell`], pre-filtered only along the dimensions `prefilter` marks: along
    /// the others every ray takes the middle of the box (in grid coordinates). A ray still draws
    /// a uniform number per dimension, so the marked dimensions sample as they would with all
    /// marked.
    pub fn for_cell_along(space: &ParamSpace, index: u32, prefilter: [bool; 2]) -> Option<Self> {
        let b = space.grid().cell_box(index)?;
        let centre = space.cell_center(index)?;
        let (mut u_min, mut u_max) = (b.min, b.max);
        for k in 0..2 {
            if !prefilter[k] {
                let mid = 0.5 * (u_min[k] + u_max[k]);
                (u_min[k], u_max[k]) = (mid, mid);
            }
        }
        Some(ParamBox {
            space: space.clone(),
            u_min,
            u_max,
            centre,
            prefilter: prefilter.iter().any(|&p| p),
        })
    }

    /// Fixed parameters `s` (physical units) in a space of `dims` dimensions: no pre-filtering.
    pub fn fixed(space: &ParamSpace, s: [f64; 2]) -> Self {
        ParamBox {
            space: space.clone(),
            u_min: [0.0; 2],
            u_max: [0.0; 2],
            centre: s,
            prefilter: false,
        }
    }

    /// Number of uniform numbers [`Self::sample`] takes (the space's dimensions, or 0 without
    /// pre-filtering).
    pub fn jitter_dims(&self) -> usize {
        if self.prefilter {
            self.space.dim_count()
        } else {
            0
        }
    }

    /// The representative parameters (physical units).
    pub fn centre(&self) -> [f64; 2] {
        self.centre
    }

    /// Parameters (physical units) for uniform numbers `xi` (`xi.len() == jitter_dims()`).
    #[inline]
    pub fn sample(&self, xi: &[f64]) -> [f64; 2] {
        if !self.prefilter {
            return self.centre;
        }
        let mut u = [0.0; 2];
        for (k, &x) in xi.iter().enumerate() {
            u[k] = self.u_min[k] + x * (self.u_max[k] - self.u_min[k]);
        }
        let mut s = self.space.from_grid(u);
        if self.space.dim_count() == 1 {
            s[1] = 0.0;
        }
        s
    }

    /// Smallest and largest parameters the box can give, per dimension (physical units).
    pub fn range(&self) -> [[f64; 2]; 2] {
        if !self.prefilter {
            return [[self.centre[0]; 2], [self.centre[1]; 2]];
        }
        let lo = self.space.from_grid(self.u_min);
        let hi = self.space.from_grid(self.u_max);
        let mut r = [[lo[0], hi[0]], [lo[1], hi[1]]];
        if self.space.dim_count() == 1 {
            r[1] = [0.0, 0.0];
        }
        r
    }
}
