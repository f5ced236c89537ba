//! Textures: a checkerboard in the shape's texture coordinates (view-independent albedo).

use glam::DVec2;
use serde::{Deserialize, Serialize};

use crate::error::{invalid, Result};

/// A checkerboard: squares of the material's albedo alternate with squares of `color`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Checker {
    /// Linear RGB albedo of the second colour of squares.
    pub color: [f32; 3],
    /// Squares per unit of texture coordinate (per metre on planes and boxes, per quad edge
    /// on quads, per full turn / half turn on spheres).
    pub scale: f64,
}

impl Checker {
    /// Checks the scale.
    pub fn validate(&self, context: &str) -> Result<()> {
        if !(self.scale.is_finite() && self.scale > 0.0) {
            return Err(invalid(context, "checker scale must be a positive number"));
        }
        if self.color.iter().any(|c| !c.is_finite() || *c < 0.0) {
            return Err(invalid(
                context,
                "checker color must be finite and non-negative",
            ));
        }
        Ok(())
    }

    /// True where the second colour shows at texture coordinates `uv`.
    pub fn is_odd(&self, uv: DVec2) -> bool {
        // A tiny offset keeps squares stable where a coordinate is exactly an integer (e.g. a
        // plane through the origin).
        let a = (uv.x * self.scale + 1e-7).floor() as i64;
        let b = (uv.y * self.scale + 1e-7).floor() as i64;
        (a + b).rem_euclid(2) == 1
    }

    /// The albedo at `uv` given the base albedo.
    pub fn eval(&self, base: [f32; 3], uv: DVec2) -> [f32; 3] {
        if self.is_odd(uv) {
            self.color
        } else {
            base
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checker_alternates() {
        let c = Checker {
            color: [1.0, 0.0, 0.0],
            scale: 2.0,
        };
        let base = [0.0, 0.0, 1.0];
        assert_eq!(c.eval(base, DVec2::new(0.1, 0.1)), base);
        assert_eq!(c.eval(base, DVec2::new(0.6, 0.1)), [1.0, 0.0, 0.0]);
        assert_eq!(c.eval(base, DVec2::new(0.6, 0.6)), base);
        assert_eq!(c.eval(base, DVec2::new(-0.1, 0.1)), [1.0, 0.0, 0.0]);
    }
}
