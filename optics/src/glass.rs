//! Refractive index of optical glass as a function of wavelength.

use serde::{Deserialize, Serialize};

/// Wavelength dependence of a glass's refractive index, wavelength in micrometres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Dispersion {
    /// `n(l) = a + b / l^2`, `b` in um^2.
    Cauchy {
        /// Constant term.
        a: f64,
        /// Coefficient of `1 / l^2`, um^2.
        b_um2: f64,
    },
    /// `n^2(l) = 1 + sum_i b_i l^2 / (l^2 - c_i)`, `c_i` in um^2 (BK7: b = 1.0396, 0.2318, 1.0105;
    /// c = 0.0060, 0.0200, 103.56).
    Sellmeier {
        /// The three `B` coefficients.
        b: [f64; 3],
        /// The three `C` coefficients, um^2.
        c_um2: [f64; 3],
    },
}

/// Schott N-BK7 Sellmeier coefficients (B dimensionless, C in um^2).
pub const BK7: Dispersion = Dispersion::Sellmeier {
    b: [1.039_612_12, 0.231_792_344, 1.010_469_45],
    c_um2: [0.006_000_698_67, 0.020_017_914_4, 103.560_653],
};

/// Helium d line, um: where a catalogue's `n_d` is measured.
pub const LAMBDA_D_UM: f64 = 0.587_56;
/// Hydrogen F line, um.
pub const LAMBDA_F_UM: f64 = 0.486_13;
/// Hydrogen C line, um.
pub const LAMBDA_C_UM: f64 = 0.656_27;

impl Dispersion {
    /// The two-term Cauchy glass with index `n_d` at the d line and Abbe number
    /// `v_d = (n_d - 1) / (n_F - n_C)`, as a catalogue lists a glass; `v_d = inf` (or 0) gives a
    /// glass without dispersion.
    pub fn from_abbe(n_d: f64, v_d: f64) -> Dispersion {
        if !(v_d.is_finite() && v_d > 0.0) {
            return Dispersion::Cauchy { a: n_d, b_um2: 0.0 };
        }
        let spread = (n_d - 1.0) / v_d;
        let b_um2 = spread / (LAMBDA_F_UM.powi(-2) - LAMBDA_C_UM.powi(-2));
        Dispersion::Cauchy {
            a: n_d - b_um2 / (LAMBDA_D_UM * LAMBDA_D_UM),
            b_um2,
        }
    }

    /// Refractive index at `lambda_um`.
    #[inline]
    pub fn index(&self, lambda_um: f64) -> f64 {
        refractive_index(self, lambda_um)
    }
}

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

    #[test]
    fn abbe_glass_has_its_catalogue_index_and_abbe_number() {
        // N-BK7: n_d 1.5168, v_d 64.17.
        let g = Dispersion::from_abbe(1.5168, 64.17);
        let (nd, nf, nc) = (
            g.index(LAMBDA_D_UM),
            g.index(LAMBDA_F_UM),
            g.index(LAMBDA_C_UM),
        );
        assert!((nd - 1.5168).abs() < 1e-12);
        assert!(((nd - 1.0) / (nf - nc) - 64.17).abs() < 1e-9);
        // And it follows the Sellmeier BK7 within 2e-3 over the visible range.
        for l in [0.40, 0.45, 0.55, 0.65, 0.70] {
            assert!((g.index(l) - BK7.index(l)).abs() < 2e-3, "{l}");
        }
        let flat = Dispersion::from_abbe(1.6, f64::INFINITY);
        assert_eq!(flat.index(0.4), flat.index(0.7));
    }
}
