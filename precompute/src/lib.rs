//! precompute: the offline half of Laplacian kernel splatting (Leimkühler et al. 2018).
//!
//! For every PSF of a model's nested-grid parameter space: light-trace it, pre-filtered over its
//! cell ([`trace`], [`prefilter`]); sparsify its Laplacian into spreadlets ([`sparsify`]); score
//! it ([`quality`]); store it as spreadlets or, when that does not pay, dense (fast track).
//! [`build_database`] does it all and is what the runtime calls to build a missing database:
//!
//! ```no_run
//! use precompute::{build_database, BuildConfig, Profile};
//! use psf_db::PsfModel;
//! let cfg = BuildConfig::new(PsfModel::LensMotion, Profile::Test);
//! let (db, report) = build_database(&cfg, false).unwrap();
//! println!("{} PSFs, mean sparsity {:.3}", db.psf_count(), report.mean_sparsity);
//! ```

pub mod aperture;
pub mod build;
pub mod config;
pub mod error;
pub mod image;
pub use optics;
pub mod prefilter;
pub mod quality;
pub mod report;
pub mod sampler;
pub mod sparsify;
pub mod trace;

pub use build::{build_database, build_database_reporting, BuildPlan, ProcessedPsf, PsfProgress};
pub use config::{BuildConfig, LensOptions, Profile, ProfileSpec};
pub use error::PrecomputeError;
pub use image::PsfImage;
pub use report::{BuildReport, PsfReport};
pub use sparsify::{AblationL1, Procedure, SparsifyOptions, Spreadlets};
