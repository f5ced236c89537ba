//! Integrating spreadlets cheaply while optimising them.
//!
//! The reconstruction of spreadlets `v_j` at pixels `x_j` is linear: `U = sum_j v_j P(. - x_j)`,
//! where `P` is the Green's function of the 5-point Laplacian. Here `P` is the *periodic*
//! one on a torus that is the PSF image padded by [`PAD_PX`] pixels on every side:
//! `P = IDFT(1 / lambda(k))`, `lambda(k) = 2 cos(2 pi kx / W) + 2 cos(2 pi ky / H) - 4`, with
//! the zero frequency set to 0. As in `poisson::integrate_exact`, the constant left free by
//! the Laplacian is fixed by subtracting the mean of the padding ring (where the true PSF is 0).
//! For the Laplacian of any image that is zero on the padding this is exact; for spreadlets it
//! is the cheap proxy the optimiser works on (the final figures use `poisson::integrate_exact`).
//!
//! [`Reconstruction`] keeps `U` and updates it by one shifted copy of `P` per changed
//! spreadlet, so an annealing step costs O(changed spreadlets x pixels), not an FFT.
//! [`Operator`] applies the same map and its adjoint by FFT, for the least-squares re-fit.

use std::f64::consts::PI;
use std::sync::Arc;

use poisson::fft::Fft2;
use rustfft::num_complex::Complex64;

/// Padding of the torus around the PSF image, pixels on each side.
pub const PAD_PX: usize = 8;

/// `1 / lambda(k)` of the 5-point stencil on a `w x h` torus, 0 at k = 0.
fn inverse_symbol(w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for ky in 0..h {
        let cy = 2.0 * (2.0 * PI * ky as f64 / h as f64).cos();
        for kx in 0..w {
            let l = 2.0 * (2.0 * PI * kx as f64 / w as f64).cos() + cy - 4.0;
            out[ky * w + kx] = if kx == 0 && ky == 0 { 0.0 } else { 1.0 / l };
        }
    }
    out
}

/// The geometry shared by the reconstruction and the operator: the PSF image (`width x height`)
/// inside a torus padded by [`PAD_PX`].
#[derive(Clone, Debug)]
pub struct Torus {
    /// PSF image width, pixels.
    pub width: usize,
    /// PSF image height, pixels.
    pub height: usize,
    /// Torus width, pixels.
    pub tw: usize,
    /// Torus height, pixels.
    pub th: usize,
    /// Periodic Green's function, `tw x th`, `kernel[0]` at offset (0, 0).
    pub kernel: Arc<Vec<f64>>,
    /// Number of padding pixels (torus minus image).
    pub margin_count: usize,
}

impl Torus {
    /// The torus around a `width x height` image.
    pub fn new(width: usize, height: usize) -> Self {
        let (tw, th) = (width + 2 * PAD_PX, height + 2 * PAD_PX);
        let sym = inverse_symbol(tw, th);
        let mut data: Vec<Complex64> = sym.iter().map(|&s| Complex64::new(s, 0.0)).collect();
        Fft2::new(tw, th).run(&mut data, true);
        Torus {
            width,
            height,
            tw,
            th,
            kernel: Arc::new(data.iter().map(|c| c.re).collect()),
            margin_count: tw * th - width * height,
        }
    }

    #[inline]
    fn in_image(&self, tx: usize, ty: usize) -> bool {
        tx >= PAD_PX && ty >= PAD_PX && tx < PAD_PX + self.width && ty < PAD_PX + self.height
    }
}

/// The running reconstruction `U` of a set of spreadlets, one torus plane per channel.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    torus: Torus,
    planes: Vec<Vec<f64>>,
}

impl Reconstruction {
    /// An empty reconstruction (no spreadlets) with `channels` planes.
    pub fn new(torus: Torus, channels: usize) -> Self {
        let n = torus.tw * torus.th;
        Reconstruction {
            torus,
            planes: vec![vec![0.0; n]; channels],
        }
    }

    /// Adds spreadlet `value` (one per channel) at image pixel `(x, y)`.
    pub fn add(&mut self, pos: [i32; 2], value: &[f64]) {
        let t = &self.torus;
        let (tw, th) = (t.tw, t.th);
        let px = (pos[0] + PAD_PX as i32).rem_euclid(tw as i32) as usize;
        let py = (pos[1] + PAD_PX as i32).rem_euclid(th as i32) as usize;
        let k = &t.kernel;
        for (plane, &v) in self.planes.iter_mut().zip(value) {
            if v == 0.0 {
                continue;
            }
            for ty in 0..th {
                let ky = (ty + th - py) % th;
                let krow = &k[ky * tw..(ky + 1) * tw];
                let row = &mut plane[ty * tw..(ty + 1) * tw];
                // Kernel index kx = (tx - px) mod tw: two contiguous runs.
                let split = px;
                let (left, right) = row.split_at_mut(split);
                for (o, &kv) in right.iter_mut().zip(&krow[..tw - split]) {
                    *o += v * kv;
                }
                for (o, &kv) in left.iter_mut().zip(&krow[tw - split..]) {
                    *o += v * kv;
                }
            }
        }
    }

    /// The constant fixed by the padding: mean of `U` over the padding ring, per channel.
    fn margin_means(&self) -> Vec<f64> {
        let t = &self.torus;
        self.planes
            .iter()
            .map(|p| {
                let total: f64 = p.iter().sum();
                let mut inner = 0.0;
                for y in 0..t.height {
                    let row = (y + PAD_PX) * t.tw + PAD_PX;
                    inner += p[row..row + t.width].iter().sum::<f64>();
                }
                (total - inner) / t.margin_count.max(1) as f64
            })
            .collect()
    }

    /// L1 distance `sum_c sum_px |U_c - mean_c - psf_c|` to the PSF (planar, image-sized).
    pub fn l1(&self, psf: &[Vec<f32>]) -> f64 {
        let t = &self.torus;
        let means = self.margin_means();
        let mut cost = 0.0;
        for ((p, f), m) in self.planes.iter().zip(psf).zip(means) {
            for y in 0..t.height {
                let row = (y + PAD_PX) * t.tw + PAD_PX;
                let frow = &f[y * t.width..(y + 1) * t.width];
                for (u, &fv) in p[row..row + t.width].iter().zip(frow) {
                    cost += (u - m - f64::from(fv)).abs();
                }
            }
        }
        cost
    }

    /// Squared L2 distance `sum_c sum_px (U_c - mean_c - psf_c)^2` to the PSF.
    pub fn l2(&self, psf: &[Vec<f32>]) -> f64 {
        self.image()
            .iter()
            .zip(psf)
            .map(|(u, f)| {
                u.iter()
                    .zip(f)
                    .map(|(&a, &b)| (f64::from(a) - f64::from(b)).powi(2))
                    .sum::<f64>()
            })
            .sum()
    }

    /// The reconstruction on the image, planar per channel.
    pub fn image(&self) -> Vec<Vec<f32>> {
        let t = &self.torus;
        let means = self.margin_means();
        self.planes
            .iter()
            .zip(means)
            .map(|(p, m)| {
                let mut out = Vec::with_capacity(t.width * t.height);
                for y in 0..t.height {
                    let row = (y + PAD_PX) * t.tw + PAD_PX;
                    out.extend(p[row..row + t.width].iter().map(|&u| (u - m) as f32));
                }
                out
            })
            .collect()
    }
}

/// The linear map from spreadlet values at fixed positions to the reconstructed image (and
/// its adjoint), by FFT; one channel at a time.
pub struct Operator {
    torus: Torus,
    fft: Fft2,
    symbol: Vec<f64>,
    sites: Vec<usize>,
}

impl Operator {
    /// The operator for spreadlets at image pixels `positions` (all inside the image).
    pub fn new(torus: Torus, positions: &[[i32; 2]]) -> Self {
        let fft = Fft2::new(torus.tw, torus.th);
        let symbol = inverse_symbol(torus.tw, torus.th);
        let sites = positions
            .iter()
            .map(|p| (p[1] as usize + PAD_PX) * torus.tw + p[0] as usize + PAD_PX)
            .collect();
        Operator {
            torus,
            fft,
            symbol,
            sites,
        }
    }

    fn convolve(&self, data: &mut [Complex64]) {
        self.fft.run(data, false);
        for (d, &s) in data.iter_mut().zip(&self.symbol) {
            *d *= s;
        }
        self.fft.run(data, true);
    }

    /// `A v`: the image (`width x height`) the values `v` reconstruct.
    pub fn apply(&self, v: &[f64]) -> Vec<f64> {
        let t = &self.torus;
        let mut data = vec![Complex64::new(0.0, 0.0); t.tw * t.th];
        for (&s, &x) in self.sites.iter().zip(v) {
            data[s].re += x;
        }
        self.convolve(&mut data);
        let (mut total, mut inner) = (0.0, 0.0);
        for (i, d) in data.iter().enumerate() {
            total += d.re;
            if t.in_image(i % t.tw, i / t.tw) {
                inner += d.re;
            }
        }
        let mean = (total - inner) / t.margin_count.max(1) as f64;
        let mut out = Vec::with_capacity(t.width * t.height);
        for y in 0..t.height {
            let row = (y + PAD_PX) * t.tw + PAD_PX;
            out.extend(data[row..row + t.width].iter().map(|d| d.re - mean));
        }
        out
    }

    /// `A^T r` for an image-sized residual `r`.
    pub fn adjoint(&self, r: &[f64]) -> Vec<f64> {
        let t = &self.torus;
        let sum: f64 = r.iter().sum();
        let m = -sum / t.margin_count.max(1) as f64;
        let mut data = vec![Complex64::new(0.0, 0.0); t.tw * t.th];
        for (i, d) in data.iter_mut().enumerate() {
            let (x, y) = (i % t.tw, i / t.tw);
            d.re = if t.in_image(x, y) {
                r[(y - PAD_PX) * t.width + x - PAD_PX]
            } else {
                m
            };
        }
        // P is symmetric, so correlation = convolution.
        self.convolve(&mut data);
        self.sites.iter().map(|&s| data[s].re).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn laplacian(img: &[f64], w: usize, h: usize) -> Vec<f64> {
        let at = |x: i64, y: i64| {
            if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                0.0
            } else {
                img[y as usize * w + x as usize]
            }
        };
        let mut out = vec![0.0; w * h];
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                out[y as usize * w + x as usize] =
                    at(x - 1, y) + at(x + 1, y) + at(x, y - 1) + at(x, y + 1) - 4.0 * at(x, y);
            }
        }
        out
    }

    #[test]
    fn unsparsified_laplacian_integrates_back_exactly() {
        // A blob that is zero on the image border: splatting every Laplacian pixel returns it.
        let (w, h) = (13usize, 9usize);
        let mut img = vec![0.0; w * h];
        for y in 2..7 {
            for x in 2..11 {
                img[y * w + x] = ((x * 7 + y * 3) % 5) as f64 + 1.0;
            }
        }
        let lap = laplacian(&img, w, h);
        let torus = Torus::new(w, h);
        let mut rec = Reconstruction::new(torus.clone(), 1);
        let mut positions = Vec::new();
        let mut values = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let v = lap[y * w + x];
                if v != 0.0 {
                    rec.add([x as i32, y as i32], &[v]);
                    positions.push([x as i32, y as i32]);
                    values.push(v);
                }
            }
        }
        let f32img: Vec<f32> = img.iter().map(|&v| v as f32).collect();
        assert!(rec.l1(&[f32img]) < 1e-4);
        // The FFT operator agrees with the incremental one, and its adjoint is its transpose.
        let op = Operator::new(torus, &positions);
        let a = op.apply(&values);
        let r = rec.image();
        for (x, y) in a.iter().zip(&r[0]) {
            assert!((x - f64::from(*y)).abs() < 1e-5);
        }
        let probe: Vec<f64> = (0..w * h).map(|i| ((i * 37) % 11) as f64 - 5.0).collect();
        let lhs: f64 = a.iter().zip(&probe).map(|(x, y)| x * y).sum();
        let at = op.adjoint(&probe);
        let rhs: f64 = at.iter().zip(&values).map(|(x, y)| x * y).sum();
        assert!(
            (lhs - rhs).abs() < 1e-8 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
    }
}
