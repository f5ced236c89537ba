//! Radical-inverse (Halton) numbers, the deterministic jitter of Guertin 2014, Sec. 3.4.5.

/// The radical inverse of `index` in `base` (>= 2): a number in [0, 1).
pub fn radical_inverse(mut index: u64, base: u64) -> f32 {
    let base = base.max(2);
    let inv_base = 1.0 / base as f64;
    let mut scale = inv_base;
    let mut value = 0.0f64;
    while index > 0 {
        value += (index % base) as f64 * scale;
        index /= base;
        scale *= inv_base;
    }
    value as f32
}

/// Halton number of `index` mapped to [lo, hi).
pub fn halton(index: u64, base: u64, lo: f32, hi: f32) -> f32 {
    lo + (hi - lo) * radical_inverse(index, base)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base_two_first_values() {
        let got: Vec<f32> = (1..=4).map(|i| radical_inverse(i, 2)).collect();
        assert_eq!(got, vec![0.5, 0.25, 0.75, 0.125]);
        assert!((radical_inverse(1, 3) - 1.0 / 3.0).abs() < 1e-7);
    }
}
