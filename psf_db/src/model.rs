//! PSF models: which parameter space a database samples and how many colour channels it has.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// The PSF model a database was built for (see `docs/DESIGN.md`, "PSF parameter spaces").
///
/// | model | dims | s0 | s1 | channels |
/// | --- | --- | --- | --- | --- |
/// | `thin-lens` | 1 | CoC radius (px) | - | 1 |
/// | `lens-motion` | 2 | CoC radius (px) | motion length over the shutter (px), along +x | 1 |
/// | `physical-lens` | 2 | depth (scene units) | eccentricity on the sensor (mm) | 3 (RGB) |
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PsfModel {
    /// Thin lens, circular or polygonal aperture; s = CoC radius in pixels.
    ThinLens,
    /// Thin lens plus linear motion along +x with a box shutter; s = (CoC radius px, motion length px).
    LensMotion,
    /// One biconvex spherical lens with a stop, chromatic; s = (depth, eccentricity mm).
    PhysicalLens,
}

/// The name given to [`PsfModel::from_str`] is none of the known models.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown PSF model '{0}' (expected thin-lens, lens-motion or physical-lens)")]
pub struct ParseModelError(pub String);

impl PsfModel {
    /// All models, in a fixed order.
    pub const ALL: [PsfModel; 3] = [
        PsfModel::ThinLens,
        PsfModel::LensMotion,
        PsfModel::PhysicalLens,
    ];

    /// The command-line / file name of the model: "thin-lens", "lens-motion", "physical-lens".
    pub fn name(self) -> &'static str {
        match self {
            PsfModel::ThinLens => "thin-lens",
            PsfModel::LensMotion => "lens-motion",
            PsfModel::PhysicalLens => "physical-lens",
        }
    }

    /// Number of dimensions of the parameter space (1 or 2).
    pub fn dims(self) -> usize {
        match self {
            PsfModel::ThinLens => 1,
            PsfModel::LensMotion | PsfModel::PhysicalLens => 2,
        }
    }

    /// Number of colour channels per spreadlet value: 1 (grey PSF) or 3 (RGB, chromatic).
    pub fn channels(self) -> usize {
        match self {
            PsfModel::ThinLens | PsfModel::LensMotion => 1,
            PsfModel::PhysicalLens => 3,
        }
    }

    /// The power-remapping exponents, one per dimension (length [`Self::dims`]): the paper's
    /// for the thin lens and lens motion; for the physical lens, inverse depth uniform (the
    /// blur grows linearly in it) and eccentricity 0.6, so that boxes narrow towards the
    /// corners, where vignetting changes the PSF fastest.
    pub fn default_beta(self) -> &'static [f64] {
        match self {
            PsfModel::ThinLens => &[2.0],
            PsfModel::LensMotion => &[2.0, 1.0],
            PsfModel::PhysicalLens => &[1.0, 0.6],
        }
    }
}

impl fmt::Display for PsfModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for PsfModel {
    type Err = ParseModelError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        PsfModel::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| ParseModelError(s.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for m in PsfModel::ALL {
            assert_eq!(m.name().parse::<PsfModel>(), Ok(m));
            assert_eq!(m.to_string(), m.name());
            assert_eq!(m.default_beta().len(), m.dims());
        }
        assert!("thin_lens".parse::<PsfModel>().is_err());
    }

    #[test]
    fn table_values() {
        assert_eq!(PsfModel::ThinLens.dims(), 1);
        assert_eq!(PsfModel::LensMotion.channels(), 1);
        assert_eq!(PsfModel::PhysicalLens.channels(), 3);
        assert_eq!(PsfModel::PhysicalLens.default_beta(), &[1.0, 0.6]);
    }
}
