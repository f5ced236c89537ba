//! Geometric optics for spreadlet's physical lenses.
//!
//! - [`glass`]: refractive index against wavelength (Sellmeier, Cauchy, or a catalogue glass's
//!   `n_d` and Abbe number).
//! - [`prescription`]: a lens as optical designers write it (per surface: radius of curvature,
//!   thickness to the next surface, the medium behind it, clear aperture; the stop marked), read
//!   from JSON or from the plain table of pbrt's realistic camera; built-in lenses.
//! - [`system`]: sequential tracing through the surfaces in both directions, the paraxial
//!   properties (focal length, entrance pupil, the equivalent pinhole), focusing by moving the
//!   lens against the sensor, and the pupil bounds that keep ray sampling efficient.
//! - [`spectrum`]: wavelength to linear RGB.
//!
//! Units: millimetres on the lens side; wavelengths in micrometres unless a name says nm.

pub mod glass;
pub mod prescription;
pub mod spectrum;
pub mod system;

pub use glass::{refractive_index, Dispersion, BK7};
pub use prescription::{Medium, Prescription, PrescriptionError, Surface, BUILTIN_LENSES};
pub use spectrum::{Spectrum, LAMBDA_DESIGN_NM, LAMBDA_MAX_NM, LAMBDA_MIN_NM};
pub use system::{LensRay, LensSystem, PupilBounds};
