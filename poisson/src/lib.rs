//! poisson: the one discrete Laplacian stencil of the project, its exact lattice inverse (FFT),
//! and convolution pyramids (Farbman et al. 2011) that approximate it quickly.
//!
//! Planes are linear f32 (or f64) channels, row-major, (0,0) top-left, y down.
//!
//! ```
//! use poisson::{integrate_exact, laplacian, Plane};
//! let mut f = Plane::new(16, 16);
//! f.set(8, 8, 1.0);
//! let back = integrate_exact(&laplacian(&f));
//! assert!((back.get(8, 8) - 1.0).abs() < 1e-5 && back.get(3, 3).abs() < 1e-5);
//! ```

pub mod error;
pub mod exact;
pub mod fft;
pub mod plane;
pub mod pyramid;
pub mod stencil;

pub use error::PoissonError;
pub use exact::{integrate_exact, integrate_exact_f64, ExactIntegrator};
pub use plane::{Plane, PlaneF64, PlaneOf};
pub use pyramid::{integrate_pyramid, PyramidWorkspace, PYRAMID_SCALE};
pub use stencil::{laplacian, laplacian_f64, laplacian_into, laplacian_of};
