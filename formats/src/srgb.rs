//! The sRGB transfer function, the one every preview, metric and crop uses.

/// sRGB encoding (IEC 61966-2-1) of a linear value clamped to [0, 1] first; NaN maps to 0.
pub fn srgb_encode(linear: f32) -> f32 {
    let v = if linear > 0.0 { linear.min(1.0) } else { 0.0 }; // NaN -> 0
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// [`srgb_encode`] quantised to 8 bits (round to nearest).
pub fn srgb8(linear: f32) -> u8 {
    (srgb_encode(linear) * 255.0 + 0.5) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    // The curve itself is tested where the metrics use it (metrics/tests/ssim.rs).
    #[test]
    fn eight_bits_round_to_nearest_and_clamp() {
        assert_eq!(srgb8(0.0), 0);
        assert_eq!(srgb8(1.0), 255);
        assert_eq!(srgb8(f32::INFINITY), 255);
        assert_eq!(srgb8(f32::NAN), 0);
        assert_eq!(srgb8(0.18), (srgb_encode(0.18) * 255.0 + 0.5) as u8);
    }
}
