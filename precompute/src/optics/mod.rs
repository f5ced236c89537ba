//! Geometric optics for the `physical-lens` model: glass dispersion, the spectral response
//! that turns wavelengths into linear RGB, and a biconvex spherical singlet with a stop.

pub mod glass;
pub mod singlet;
pub mod spectrum;
