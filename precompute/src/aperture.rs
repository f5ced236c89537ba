//! Sampling the lens aperture: a unit disk, or a regular polygon of N blades inscribed in it.

use std::f64::consts::PI;

/// The shape of the aperture, in units of its radius (circumradius for a polygon).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ApertureShape {
    /// The unit disk.
    Circle,
    /// A regular polygon with `blades >= 3` vertices on the unit circle, the first at angle
    /// `rotation_rad` (counter-clockwise from +x on the image, y down).
    Polygon {
        /// Number of blades (vertices).
        blades: u32,
        /// Rotation, radians.
        rotation_rad: f64,
    },
}

impl ApertureShape {
    /// The shape for `blades` (0 = circle; 3 or more = polygon).
    pub fn from_blades(blades: u32, rotation_rad: f64) -> Self {
        if blades < 3 {
            ApertureShape::Circle
        } else {
            ApertureShape::Polygon {
                blades,
                rotation_rad,
            }
        }
    }

    /// Area of the shape (the unit disk: pi).
    pub fn area(&self) -> f64 {
        match *self {
            ApertureShape::Circle => PI,
            ApertureShape::Polygon { blades, .. } => {
                let n = f64::from(blades);
                0.5 * n * (2.0 * PI / n).sin()
            }
        }
    }

    /// Maps `(u0, u1)` uniform in `[0, 1)^2` to a point uniform over the shape, keeping
    /// stratification (nearby `u` give nearby points).
    #[inline]
    pub fn sample(&self, u0: f64, u1: f64) -> [f64; 2] {
        match *self {
            ApertureShape::Circle => concentric_disk(u0, u1),
            ApertureShape::Polygon {
                blades,
                rotation_rad,
            } => {
                // Pick one of the N equal triangles (centre, v_k, v_k+1) with u0, re-use the
                // fraction, and map uniformly into it: p = sqrt(a) ((1 - b) v_k + b v_k+1).
                let n = f64::from(blades);
                let t = u0 * n;
                let k = t.floor().min(n - 1.0);
                let a = (t - k).sqrt();
                let step = 2.0 * PI / n;
                let (s0, c0) = (rotation_rad + k * step).sin_cos();
                let (s1, c1) = (rotation_rad + (k + 1.0) * step).sin_cos();
                // y down on the image: counter-clockwise means negative y for positive angles.
                [
                    a * ((1.0 - u1) * c0 + u1 * c1),
                    -a * ((1.0 - u1) * s0 + u1 * s1),
                ]
            }
        }
    }

    /// True when `p` (in units of the radius) lies inside the shape.
    pub fn contains(&self, p: [f64; 2]) -> bool {
        match *self {
            ApertureShape::Circle => p[0] * p[0] + p[1] * p[1] <= 1.0,
            ApertureShape::Polygon {
                blades,
                rotation_rad,
            } => {
                let n = f64::from(blades);
                let step = 2.0 * PI / n;
                // Inside every edge's half-plane: the apothem is cos(step / 2).
                (0..blades).all(|k| {
                    let mid = rotation_rad + (f64::from(k) + 0.5) * step;
                    let (s, c) = mid.sin_cos();
                    p[0] * c - p[1] * s <= (0.5 * step).cos() + 1e-12
                })
            }
        }
    }
}

/// The aperture the thin-lens tracers sample: an outline (or a user-drawn image, which
/// replaces it) squeezed horizontally by an anamorphic ratio after its rotation, as Cycles
/// does (`bokeh.x /= aperture_ratio`).
#[derive(Clone, Debug, PartialEq)]
pub struct LensAperture {
    /// The outline, in units of the aperture radius.
    pub shape: ApertureShape,
    /// The squeeze: x is divided by it (1 = none).
    pub ratio: f64,
    /// A user-drawn aperture, sampled instead of `shape`.
    pub mask: Option<std::sync::Arc<formats::MaskSampler>>,
}

impl LensAperture {
    /// The disk, unsqueezed.
    pub fn round() -> Self {
        LensAperture {
            shape: ApertureShape::Circle,
            ratio: 1.0,
            mask: None,
        }
    }

    /// A point over the squeezed outline or image, in units of the aperture radius (see
    /// [`ApertureShape::sample`]), uniform over the outline, with the image's density over
    /// an image.
    #[inline]
    pub fn sample(&self, u0: f64, u1: f64) -> [f64; 2] {
        let [x, y] = match &self.mask {
            Some(mask) => mask.sample(u0, u1),
            None => self.shape.sample(u0, u1),
        };
        [x / self.ratio, y]
    }

    /// True when `p` (in units of the radius) lets light through.
    pub fn contains(&self, p: [f64; 2]) -> bool {
        let q = [p[0] * self.ratio, p[1]];
        match &self.mask {
            Some(mask) => mask.transmission(q) > 0.0,
            None => self.shape.contains(q),
        }
    }
}

/// Shirley and Chiu's concentric map from the unit square to the unit disk (area-preserving).
#[inline]
pub fn concentric_disk(u0: f64, u1: f64) -> [f64; 2] {
    let a = 2.0 * u0 - 1.0;
    let b = 2.0 * u1 - 1.0;
    if a == 0.0 && b == 0.0 {
        return [0.0, 0.0];
    }
    let (r, phi) = if a.abs() > b.abs() {
        (a, PI / 4.0 * (b / a))
    } else {
        (b, PI / 2.0 - PI / 4.0 * (a / b))
    };
    [r * phi.cos(), r * phi.sin()]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_stay_inside_and_cover_evenly() {
        for shape in [
            ApertureShape::Circle,
            ApertureShape::from_blades(6, 0.3),
            ApertureShape::from_blades(5, 0.0),
        ] {
            let mut quadrants = [0u32; 4];
            for i in 0..64 {
                for j in 0..64 {
                    let p = shape.sample((i as f64 + 0.5) / 64.0, (j as f64 + 0.5) / 64.0);
                    assert!(shape.contains(p), "{shape:?} {p:?}");
                    quadrants[usize::from(p[0] > 0.0) * 2 + usize::from(p[1] > 0.0)] += 1;
                }
            }
            // Symmetric shapes (up to the pentagon's tilt): each quadrant near a quarter.
            assert!(
                quadrants.iter().all(|&q| (800..1250).contains(&q)),
                "{quadrants:?}"
            );
        }
        assert!((ApertureShape::from_blades(4, 0.0).area() - 2.0).abs() < 1e-12);
    }
}
