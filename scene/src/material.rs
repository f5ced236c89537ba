//! Materials and lights: diffuse albedo (optionally checkered) plus emission, lit by point and
//! directional lights with hard shadows and a constant ambient term. Shading never depends on
//! the viewing direction, as image-based DoF/MB methods assume.

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::error::{invalid, Result};
use crate::texture::Checker;

/// A view-independent surface: outgoing radiance = emission + albedo * irradiance-like term.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Linear RGB diffuse albedo (default mid grey).
    #[serde(default = "default_albedo")]
    pub albedo: [f32; 3],
    /// Optional checkerboard replacing the albedo on alternate squares.
    #[serde(default)]
    pub checker: Option<Checker>,
    /// Linear RGB emitted radiance (added unshaded; emissive highlights).
    #[serde(default)]
    pub emission: [f32; 3],
}

fn default_albedo() -> [f32; 3] {
    [0.5, 0.5, 0.5]
}

impl Default for Material {
    fn default() -> Self {
        Self {
            albedo: default_albedo(),
            checker: None,
            emission: [0.0; 3],
        }
    }
}

impl Material {
    /// Checks colours and the checker.
    pub fn validate(&self, context: &str) -> Result<()> {
        let ok = |c: &[f32; 3]| c.iter().all(|v| v.is_finite() && *v >= 0.0);
        if !ok(&self.albedo) || !ok(&self.emission) {
            return Err(invalid(
                context,
                "albedo and emission must be finite and >= 0",
            ));
        }
        if let Some(checker) = &self.checker {
            checker.validate(context)?;
        }
        Ok(())
    }

    /// Albedo at texture coordinates `uv`.
    pub fn albedo_at(&self, uv: DVec2) -> [f32; 3] {
        match &self.checker {
            Some(checker) => checker.eval(self.albedo, uv),
            None => self.albedo,
        }
    }
}

/// A light source (lights are not visible themselves: use an emissive sphere for that).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Light {
    /// A point light: contributes `intensity * max(0, n.l) / distance^2`, shadowed.
    Point {
        /// Position, metres.
        position: DVec3,
        /// Linear RGB intensity.
        intensity: [f32; 3],
    },
    /// A directional light: contributes `intensity * max(0, n.l)`, shadowed.
    Directional {
        /// Direction the light travels (towards the scene), any length but zero.
        direction: DVec3,
        /// Linear RGB irradiance scale.
        intensity: [f32; 3],
    },
    /// A rectangle `corner + a edge_u + b edge_v` (a, b in [0, 1]) that emits `radiance`
    /// uniformly from its front side, the side `edge_u x edge_v` points to (a Blender area
    /// light). Soft shadows: each shading point sees it through one random point of the
    /// rectangle, so a penumbra is noisy in one sample and converges over many. Contributes
    /// `radiance cos_surface cos_light area / (pi distance^2)` per sample (the irradiance over
    /// pi, as the other lights' terms are), shadowed.
    Area {
        /// One corner, metres.
        corner: DVec3,
        /// First edge from the corner, metres.
        edge_u: DVec3,
        /// Second edge from the corner, metres.
        edge_v: DVec3,
        /// Linear RGB radiance of the front side.
        radiance: [f32; 3],
    },
}

impl Light {
    /// Checks positions, directions and intensities.
    pub fn validate(&self, context: &str) -> Result<()> {
        let (v, i) = match self {
            Light::Point {
                position,
                intensity,
            } => (*position, intensity),
            Light::Directional {
                direction,
                intensity,
            } => {
                if direction.length_squared() == 0.0 {
                    return Err(invalid(
                        context,
                        "directional light needs a non-zero direction",
                    ));
                }
                (*direction, intensity)
            }
            Light::Area {
                corner,
                edge_u,
                edge_v,
                radiance,
            } => {
                if !(edge_u.is_finite() && edge_v.is_finite())
                    || edge_u.cross(*edge_v).length_squared() == 0.0
                {
                    return Err(invalid(
                        context,
                        "area light needs two finite, non-parallel, non-zero edges",
                    ));
                }
                (*corner, radiance)
            }
        };
        if !v.is_finite() || i.iter().any(|c| !c.is_finite() || *c < 0.0) {
            return Err(invalid(
                context,
                "light values must be finite (intensity >= 0)",
            ));
        }
        Ok(())
    }
}
