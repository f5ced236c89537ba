//! Refractive index of optical glass as a function of wavelength.

use psf_db::Dispersion;

/// Schott N-BK7 Sellmeier coefficients (B dimensionless, C in um^2).
pub const BK7: Dispersion = Dispersion::Sellmeier {
    b: [1.039_612_12, 0.231_792_344, 1.010_469_45],
    c_um2: [0.006_000_698_67, 0.020_017_914_4, 103.560_653],
};

/// Refractive index of `glass` at wavelength `lambda_um` micrometres.
#[inline]
pub fn refractive_index(glass: &Dispersion, lambda_um: f64) -> f64 {
    let l2 = lambda_um * lambda_um;
    match glass {
        Dispersion::Cauchy { a, b_um2 } => a + b_um2 / l2,
        Dispersion::Sellmeier { b, c_um2 } => {
            let n2 = 1.0
                + b[0] * l2 / (l2 - c_um2[0])
                + b[1] * l2 / (l2 - c_um2[1])
                + b[2] * l2 / (l2 - c_um2[2]);
            n2.max(0.0).sqrt()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bk7_catalogue_values() {
        // Schott catalogue: n_d (587.56 nm) = 1.5168, n_F (486.13 nm) = 1.5224, n_C (656.27 nm) = 1.5143.
        assert!((refractive_index(&BK7, 0.58756) - 1.5168).abs() < 1e-4);
        assert!((refractive_index(&BK7, 0.48613) - 1.5224).abs() < 1e-4);
        assert!((refractive_index(&BK7, 0.65627) - 1.5143).abs() < 1e-4);
    }
}
