//! psf_db: PSF models and parameter spaces, power remapping, the nested grid, and the spreadlet
//! database file format shared by `precompute` (writer) and `runtime` (reader).
//!
//! See `docs/DESIGN.md` for the contracts. Typical use:
//!
//! ```
//! use psf_db::{DatabaseBuilder, DbHeader, ParamSpace, PsfDatabase, PsfModel};
//! let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 10).unwrap();
//! let mut b = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space, 32));
//! for _ in 0..4 {
//!     b.push_sparse(&[[0, 0], [1, 0]], &[1.0, -1.0]).unwrap();
//! }
//! let db = b.finish().unwrap();
//! let back = PsfDatabase::from_bytes(&db.to_bytes().unwrap()).unwrap();
//! assert_eq!(back, db);
//! let (psf, clamped) = back.lookup([3.0, 0.0]);
//! assert!(!clamped && (psf as usize) < back.psf_count());
//! ```

pub mod builder;
pub mod error;
pub mod extension;
pub mod format;
pub mod grid;
pub mod header;
pub mod model;
pub mod shard;
pub mod space;

pub use error::{DbError, SpaceError};
pub use extension::{DenseExtension, DenseShape};
pub use format::{
    Aperture, BuildInfo, DatabaseBuilder, DbHeader, DenseEntry, DenseView, Dispersion,
    LensPrescription, PsfDatabase, PsfStats, FORMAT_VERSION, MAGIC, SPARSE_SLOT,
};
pub use grid::{CellBox, Grid, GridSpec, NestedGrid, RegularGrid};
pub use model::{ParseModelError, PsfModel};
pub use shard::{merge_shards, ShardRange};
pub use space::{CellMemo, Dimension, ParamSpace, ParamSpaceSpec};
