//! A 2-D complex FFT of a fixed size, planned once (rows, then columns), for the periodic
//! problems of the project: the sparsifier's Green's function on a torus. The exact integrator
//! ([`crate::ExactIntegrator`]) uses real-input transforms of its own on top of the same
//! planner.

use std::sync::Arc;

use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};

/// A 2D FFT of a fixed size (row-major, `w x h`).
pub struct Fft2 {
    w: usize,
    h: usize,
    row_fwd: Arc<dyn Fft<f64>>,
    row_inv: Arc<dyn Fft<f64>>,
    col_fwd: Arc<dyn Fft<f64>>,
    col_inv: Arc<dyn Fft<f64>>,
}

impl Fft2 {
    /// Plans for `w x h`.
    pub fn new(w: usize, h: usize) -> Self {
        let mut p = FftPlanner::new();
        Fft2 {
            w,
            h,
            row_fwd: p.plan_fft_forward(w),
            row_inv: p.plan_fft_inverse(w),
            col_fwd: p.plan_fft_forward(h),
            col_inv: p.plan_fft_inverse(h),
        }
    }

    /// In-place transform; the inverse is scaled by 1 / (w h).
    pub fn run(&self, data: &mut [Complex64], inverse: bool) {
        let (w, h) = (self.w, self.h);
        let (row, col) = if inverse {
            (&self.row_inv, &self.col_inv)
        } else {
            (&self.row_fwd, &self.col_fwd)
        };
        row.process(data);
        let mut column = vec![Complex64::new(0.0, 0.0); h];
        for x in 0..w {
            for y in 0..h {
                column[y] = data[y * w + x];
            }
            col.process(&mut column);
            for y in 0..h {
                data[y * w + x] = column[y];
            }
        }
        if inverse {
            let s = 1.0 / (w * h) as f64;
            for v in data.iter_mut() {
                *v *= s;
            }
        }
    }
}
