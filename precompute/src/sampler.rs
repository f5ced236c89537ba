//! Deterministic, stratified sample sequences for the light tracers.
//!
//! Each PSF gets its own random stream, derived from the build seed and the PSF index only, so
//! a build is byte-identical whatever the thread count. The ray samples are a Kronecker
//! (additive recurrence, "R_d") sequence: sample `i`, dimension `k` is
//! `frac(shift_k + i * alpha_k)` with `alpha_k = phi_d^-(k+1)`, `phi_d` the positive root of
//! `x^(d+1) = x + 1`. It is low-discrepancy in every projection (a stratified sample of the
//! lens, the shutter, the wavelengths and the pre-filter box at once), and the random shift
//! (Cranley-Patterson rotation) makes it an unbiased estimator. Low variance matters because
//! the Laplacian amplifies noise.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The random stream of PSF `index` in a build with `seed`; `stream` separates uses
/// (0 = tracing, 1 = sparsification, ...).
pub fn psf_rng(seed: u64, index: u32, stream: u32) -> ChaCha8Rng {
    // SplitMix64 of the three numbers: well-mixed, distinct streams per (seed, index, stream).
    let mut z = seed
        ^ (u64::from(index)).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (u64::from(stream)).wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    ChaCha8Rng::seed_from_u64(z)
}

/// A randomly shifted Kronecker sequence in `[0, 1)^dims`.
#[derive(Clone, Debug)]
pub struct KroneckerSequence {
    alpha: Vec<f64>,
    shift: Vec<f64>,
}

impl KroneckerSequence {
    /// A sequence of `dims` dimensions whose shift is drawn from `rng`.
    pub fn new(dims: usize, rng: &mut impl Rng) -> Self {
        let shift = (0..dims).map(|_| rng.random::<f64>()).collect();
        Self::with_shift(dims, shift)
    }

    /// A sequence with a given shift (one entry per dimension, in `[0, 1)`).
    pub fn with_shift(dims: usize, shift: Vec<f64>) -> Self {
        // phi_d: fixed point of x = (1 + x)^(1 / (d + 1)).
        let mut phi = 2.0f64;
        for _ in 0..64 {
            phi = (1.0 + phi).powf(1.0 / (dims as f64 + 1.0));
        }
        let alpha = (0..dims)
            .map(|k| (1.0 / phi).powi(k as i32 + 1).fract())
            .collect();
        KroneckerSequence { alpha, shift }
    }

    /// Number of dimensions.
    pub fn dims(&self) -> usize {
        self.alpha.len()
    }

    /// Writes sample `i` into `out` (`out.len() == dims()`).
    #[inline]
    pub fn sample(&self, i: u64, out: &mut [f64]) {
        // i * alpha exactly enough: split i so that the products stay well inside f64 precision.
        let hi = (i >> 24) as f64 * 16_777_216.0;
        let lo = (i & 0xFF_FFFF) as f64;
        for ((o, &a), &s) in out.iter_mut().zip(&self.alpha).zip(&self.shift) {
            let v = (hi * a).fract() + (lo * a).fract() + s;
            *o = v - v.floor();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_differ_and_repeat() {
        let a: u64 = psf_rng(7, 3, 0).random();
        let b: u64 = psf_rng(7, 3, 0).random();
        let c: u64 = psf_rng(7, 4, 0).random();
        let d: u64 = psf_rng(7, 3, 1).random();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_ne!(a, d);
    }

    #[test]
    fn kronecker_is_stratified() {
        // Every one of 16 x 16 strata of the first two dimensions gets 1024/256 = 4 +- 3
        // samples and none is empty (a random sequence leaves ~5 of them empty).
        let seq = KroneckerSequence::with_shift(4, vec![0.1, 0.2, 0.3, 0.4]);
        let mut counts = [0u32; 256];
        let mut u = [0.0; 4];
        for i in 0..1024 {
            seq.sample(i, &mut u);
            assert!(u.iter().all(|&x| (0.0..1.0).contains(&x)));
            counts[(u[0] * 16.0) as usize * 16 + (u[1] * 16.0) as usize] += 1;
        }
        assert!(counts.iter().all(|&c| (1..=7).contains(&c)), "{counts:?}");
    }
}
