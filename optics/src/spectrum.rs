//! From wavelength to linear RGB: simple CIE-like channel sensitivities over 400-700 nm.
//!
//! Each channel is a Gaussian bump (R 605 nm, G 545 nm, B 450 nm), scaled so that its mean over
//! the sampled range is 1: a flat spectrum, sampled uniformly in wavelength, gives R = G = B
//! (white balance).

/// Shortest sampled wavelength, nm.
pub const LAMBDA_MIN_NM: f64 = 400.0;
/// Longest sampled wavelength, nm.
pub const LAMBDA_MAX_NM: f64 = 700.0;
/// Design wavelength (helium d line) the lens is focused for, nm.
pub const LAMBDA_DESIGN_NM: f64 = 587.56;

const PEAKS_NM: [f64; 3] = [605.0, 545.0, 450.0];
const WIDTHS_NM: [f64; 3] = [35.0, 35.0, 28.0];

/// White-balanced channel sensitivities.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spectrum {
    scale: [f64; 3],
}

impl Default for Spectrum {
    fn default() -> Self {
        Self::new()
    }
}

impl Spectrum {
    /// The sensitivities, normalised to mean 1 over [`LAMBDA_MIN_NM`, `LAMBDA_MAX_NM`].
    pub fn new() -> Self {
        let steps = 6000;
        let mut mean = [0.0; 3];
        for i in 0..steps {
            let l =
                LAMBDA_MIN_NM + (i as f64 + 0.5) / steps as f64 * (LAMBDA_MAX_NM - LAMBDA_MIN_NM);
            for (c, m) in mean.iter_mut().enumerate() {
                *m += raw(c, l) / steps as f64;
            }
        }
        Spectrum {
            scale: [1.0 / mean[0], 1.0 / mean[1], 1.0 / mean[2]],
        }
    }

    /// Wavelength (nm) for a uniform number `u` in `[0, 1)`.
    #[inline]
    pub fn wavelength_nm(u: f64) -> f64 {
        LAMBDA_MIN_NM + u * (LAMBDA_MAX_NM - LAMBDA_MIN_NM)
    }

    /// RGB weights of light at `lambda_nm`.
    #[inline]
    pub fn rgb(&self, lambda_nm: f64) -> [f64; 3] {
        [
            raw(0, lambda_nm) * self.scale[0],
            raw(1, lambda_nm) * self.scale[1],
            raw(2, lambda_nm) * self.scale[2],
        ]
    }
}

#[inline]
fn raw(c: usize, l: f64) -> f64 {
    let d = (l - PEAKS_NM[c]) / WIDTHS_NM[c];
    (-0.5 * d * d).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_spectrum_is_white() {
        let s = Spectrum::new();
        let mut sum = [0.0; 3];
        let n = 30_000;
        for i in 0..n {
            let rgb = s.rgb(Spectrum::wavelength_nm((i as f64 + 0.5) / n as f64));
            for c in 0..3 {
                sum[c] += rgb[c] / n as f64;
            }
        }
        for c in 0..3 {
            assert!((sum[c] - 1.0).abs() < 1e-3, "{sum:?}");
        }
        // Red light is red, blue light is blue.
        let r = s.rgb(620.0);
        let b = s.rgb(440.0);
        assert!(r[0] > 10.0 * r[2] && b[2] > 10.0 * b[0]);
    }
}
