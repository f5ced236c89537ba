//! The exact inverse of the 5-point stencil (its lattice Green's function) by FFT.
//!
//! Input: the Laplacian `L f` of an image `f` that is zero on the plane's outer ring (so
//! `L f` is zero outside the plane and sums to zero). The plane is placed in the top-left
//! corner of a periodic domain at least `margin` pixels larger on each axis (rounded up to a
//! size of the form 2^a 3^b 5^c), the periodic problem is solved in f64 with the eigenvalues
//! of the stencil, `lambda(kx, ky) = 2 cos(2 pi kx / W) + 2 cos(2 pi ky / H) - 4`, and the zero
//! frequency set to 0. The periodic solution is then `f + c` exactly; `c` is the mean over the
//! margin (where `f = 0`), which follows from the zero mean of the whole periodic solution:
//! `c = -(sum over the plane) / (pixels in the margin)`. Subtracting it returns `f` to rounding
//! error (measured ~1e-14 in f64 on random compact images).
//!
//! An input that does not sum to zero (not the Laplacian of a compact image) loses its mean:
//! dropping the zero frequency solves for `lap - mean(lap)` over the padded domain, so a wider
//! margin brings such results closer to the free-space solution.

use std::sync::Arc;

use rayon::prelude::*;
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};

use crate::plane::Plane;

/// Default margin (px) added on each axis before rounding up to an FFT-friendly size.
pub const DEFAULT_MARGIN: usize = 8;

/// Values per chunk of the deterministic parallel sum of the solution (see `solve`, step 4).
const SUM_CHUNK: usize = 1 << 14;

/// Smallest `m >= n` of the form 2^a 3^b 5^c (`n >= 1`).
pub fn fft_friendly(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut r = m;
        for p in [2, 3, 5] {
            while r.is_multiple_of(p) {
                r /= p;
            }
        }
        if r == 1 {
            return m;
        }
        m += 1;
    }
}

/// A reusable exact integrator for one plane size (FFT plans and eigenvalue tables cached).
pub struct ExactIntegrator {
    width: usize,
    height: usize,
    pw: usize,
    ph: usize,
    row_fwd: Arc<dyn Fft<f64>>,
    row_inv: Arc<dyn Fft<f64>>,
    col_fwd: Arc<dyn Fft<f64>>,
    col_inv: Arc<dyn Fft<f64>>,
    /// `2 cos(2 pi k / pw) - 2`, per column frequency.
    eig_x: Vec<f64>,
    /// `2 cos(2 pi k / ph) - 2`, per row frequency.
    eig_y: Vec<f64>,
}

impl std::fmt::Debug for ExactIntegrator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExactIntegrator")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("padded", &(self.pw, self.ph))
            .finish()
    }
}

impl ExactIntegrator {
    /// An integrator for `width x height` planes with [`DEFAULT_MARGIN`].
    pub fn new(width: usize, height: usize) -> Self {
        Self::with_margin(width, height, DEFAULT_MARGIN)
    }

    /// An integrator for `width x height` planes padded by at least `margin` px per axis
    /// (at least 1).
    pub fn with_margin(width: usize, height: usize, margin: usize) -> Self {
        let margin = margin.max(1);
        let pw = fft_friendly(width + margin);
        let ph = fft_friendly(height + margin);
        let mut planner = FftPlanner::<f64>::new();
        let eig = |n: usize| {
            (0..n)
                .map(|k| 2.0 * (2.0 * std::f64::consts::PI * k as f64 / n as f64).cos() - 2.0)
                .collect::<Vec<f64>>()
        };
        ExactIntegrator {
            width,
            height,
            pw,
            ph,
            row_fwd: planner.plan_fft_forward(pw),
            row_inv: planner.plan_fft_inverse(pw),
            col_fwd: planner.plan_fft_forward(ph),
            col_inv: planner.plan_fft_inverse(ph),
            eig_x: eig(pw),
            eig_y: eig(ph),
        }
    }

    /// Plane size this integrator accepts, px.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Size of the periodic domain, px.
    pub fn padded_size(&self) -> (usize, usize) {
        (self.pw, self.ph)
    }

    /// Integrates one f64 plane (row-major `width x height`); panics on a size mismatch.
    pub fn integrate_f64(&self, lap: &[f64]) -> Vec<f64> {
        self.solve(lap)
    }

    /// Integrates one f32 plane (f64 inside); panics on a size mismatch.
    pub fn integrate(&self, lap: &Plane) -> Plane {
        self.check(lap);
        Plane {
            width: self.width,
            height: self.height,
            data: self.solve(&lap.data).iter().map(|&v| v as f32).collect(),
        }
    }

    /// Integrates two f32 planes (e.g. two colour channels); panics on a size mismatch.
    pub fn integrate_pair(&self, a: &Plane, b: &Plane) -> (Plane, Plane) {
        rayon::join(|| self.integrate(a), || self.integrate(b))
    }

    fn check(&self, p: &Plane) {
        assert!(
            p.width == self.width && p.height == self.height && p.data.len() == p.width * p.height,
            "ExactIntegrator for {}x{} given a {}x{} plane",
            self.width,
            self.height,
            p.width,
            p.height
        );
    }

    /// Solves the periodic problem for a real plane and returns the offset-corrected solution
    /// on the plane. Real-input FFTs: two rows share one complex FFT, and only the `pw/2 + 1`
    /// non-negative x frequencies are transformed along y.
    fn solve<T: Copy + Into<f64> + Sync>(&self, lap: &[T]) -> Vec<f64> {
        let (w, h, pw, ph) = (self.width, self.height, self.pw, self.ph);
        assert_eq!(
            lap.len(),
            w * h,
            "exact integration of {w}x{h} given {} values",
            lap.len()
        );
        if w == 0 || h == 0 {
            return Vec::new();
        }
        let nk = pw / 2 + 1;
        let zero = Complex64::default();
        // 1. Half spectra of the plane's rows (margin rows are zero), two rows per FFT.
        let mut spec = vec![zero; h * nk];
        spec.par_chunks_mut(2 * nk).enumerate().for_each_init(
            || {
                (
                    vec![zero; pw],
                    vec![zero; self.row_fwd.get_inplace_scratch_len()],
                )
            },
            |(buf, scratch), (pair, out)| {
                let y0 = 2 * pair;
                let has_second = out.len() == 2 * nk;
                for x in 0..w {
                    let a = lap[y0 * w + x].into();
                    let b = if has_second {
                        lap[(y0 + 1) * w + x].into()
                    } else {
                        0.0
                    };
                    buf[x] = Complex64::new(a, b);
                }
                buf[w..].fill(zero);
                self.row_fwd.process_with_scratch(buf, scratch);
                for k in 0..nk {
                    let z = buf[k];
                    let zc = buf[(pw - k) % pw].conj();
                    out[k] = (z + zc) * 0.5;
                    if has_second {
                        // (z - zc) / 2i
                        let d = (z - zc) * 0.5;
                        out[nk + k] = Complex64::new(d.im, -d.re);
                    }
                }
            },
        );
        // 2. Columns (blocks of COLS x frequencies): gather, FFT, divide by the eigenvalue, inverse FFT.
        const COLS: usize = 8;
        let norm = 1.0 / (pw as f64 * ph as f64);
        let mut cols = vec![zero; nk * ph];
        let scratch_len = self
            .col_fwd
            .get_inplace_scratch_len()
            .max(self.col_inv.get_inplace_scratch_len());
        cols.par_chunks_mut(COLS * ph).enumerate().for_each_init(
            || vec![zero; scratch_len],
            |scratch, (block, out)| {
                let k0 = block * COLS;
                let nb = out.len() / ph;
                for y in 0..h {
                    let src = &spec[y * nk + k0..y * nk + k0 + nb];
                    for (j, v) in src.iter().enumerate() {
                        out[j * ph + y] = *v;
                    }
                }
                for (j, col) in out.chunks_exact_mut(ph).enumerate() {
                    let kx = k0 + j;
                    self.col_fwd.process_with_scratch(col, scratch);
                    let ex = self.eig_x[kx];
                    for (v, ey) in col.iter_mut().zip(&self.eig_y) {
                        *v *= norm / (ex + ey);
                    }
                    if kx == 0 {
                        col[0] = zero;
                    }
                    self.col_inv.process_with_scratch(col, scratch);
                }
            },
        );
        // 3. Inverse row FFTs of the plane's rows, two real rows per complex FFT.
        let mut out = vec![0.0f64; w * h];
        out.par_chunks_mut(2 * w).enumerate().for_each_init(
            || {
                (
                    vec![zero; pw],
                    vec![zero; self.row_inv.get_inplace_scratch_len()],
                )
            },
            |(buf, scratch), (pair, rows)| {
                let y0 = 2 * pair;
                let has_second = rows.len() == 2 * w;
                for k in 0..nk {
                    let a = cols[k * ph + y0];
                    let b = if has_second {
                        cols[k * ph + y0 + 1]
                    } else {
                        zero
                    };
                    // a + i b, and its mirror conj(a) + i conj(b) at pw - k.
                    buf[k] = Complex64::new(a.re - b.im, a.im + b.re);
                    if k > 0 && k < pw - k {
                        buf[pw - k] = Complex64::new(a.re + b.im, b.re - a.im);
                    }
                }
                self.row_inv.process_with_scratch(buf, scratch);
                for x in 0..w {
                    rows[x] = buf[x].re;
                    if has_second {
                        rows[w + x] = buf[x].im;
                    }
                }
            },
        );
        // 4. The periodic solution has zero mean, so the margin's mean is
        //    -(sum over the plane) / (pixels in the margin).
        //    Summed in fixed chunks, then the chunk sums in order: a plain parallel `sum` splits
        //    the work where threads steal it, so its rounding (and the output's bits) would
        //    depend on the thread count and timing.
        let margin_pixels = (pw * ph - w * h) as f64;
        let chunk_sums: Vec<f64> = out
            .par_chunks(SUM_CHUNK)
            .map(|c| c.iter().sum::<f64>())
            .collect();
        let c = -chunk_sums.iter().sum::<f64>() / margin_pixels;
        out.par_iter_mut().for_each(|v| *v -= c);
        out
    }
}

/// Exact integration of one f32 plane (see the module docs). For repeated use at one size,
/// keep an [`ExactIntegrator`].
pub fn integrate_exact(lap: &Plane) -> Plane {
    ExactIntegrator::new(lap.width, lap.height).integrate(lap)
}

/// Exact integration of a row-major `w x h` f64 plane; panics when `lap.len() != w * h`.
pub fn integrate_exact_f64(lap: &[f64], w: usize, h: usize) -> Vec<f64> {
    assert_eq!(
        lap.len(),
        w * h,
        "integrate_exact_f64: {w}x{h} given {} values",
        lap.len()
    );
    ExactIntegrator::new(w, h).integrate_f64(lap)
}
