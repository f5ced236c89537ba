//! The database header: what a database is (model, parameter space, aperture, lens), how it
//! was built, per-PSF statistics, and for a part of a sharded build the range of PSFs it holds.
//! Stored with bincode by [`crate::format`].

use serde::{Deserialize, Serialize};

use crate::error::DbError;
use crate::model::PsfModel;
use crate::space::ParamSpace;

/// Aperture shape of the lens models.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Aperture {
    /// Number of diaphragm blades; 0 = circular aperture.
    pub blades: u32,
    /// Rotation of the polygon, radians (counter-clockwise on the image, y down).
    pub rotation_rad: f32,
    /// Anamorphic squeeze: the aperture's width divided by it after the rotation (1 = round).
    pub ratio: f32,
    /// Content hash of a user-drawn aperture image (`formats::ApertureMask::content_hash`);
    /// 0 for the blade polygon or the disk.
    pub image_hash: u64,
}

impl Default for Aperture {
    fn default() -> Self {
        Aperture {
            blades: 0,
            rotation_rad: 0.0,
            ratio: 1.0,
            image_hash: 0,
        }
    }
}

/// Wavelength dependence of a glass's refractive index (defined by the optics crate).
pub use optics::Dispersion;

/// The physical lens a `physical-lens` database was traced through (filled by the precompute).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LensPrescription {
    /// The lens's surfaces, as traced (stopped down to the f-number the database was built
    /// for).
    pub lens: optics::Prescription,
    /// Distance in focus, scene units from the entrance pupil.
    pub focus_distance: f64,
    /// Millimetres per scene unit.
    pub scene_unit_mm: f64,
    /// Paraxial focal length at the design wavelength, mm.
    pub focal_length_mm: f64,
    /// Paraxial f-number at the design wavelength (focal length over entrance pupil
    /// diameter).
    pub f_number: f64,
    /// Distance from the last surface's vertex to the sensor, mm (set by focusing).
    pub sensor_distance_mm: f64,
    /// Image distance of the equivalent pinhole camera at the entrance pupil, mm: a pinhole
    /// G-buffer for this lens projects with it (it grows as the lens focuses closer).
    pub pinhole_distance_mm: f64,
    /// Sensor width, mm.
    pub sensor_width_mm: f64,
    /// Image width, pixels (pixels per mm = image_width_px / sensor_width_mm).
    pub image_width_px: u32,
}

/// Per-PSF statistics recorded by the precompute.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PsfStats {
    /// The PSF's representative parameters (physical units; second entry 0 in 1D spaces).
    pub coords: [f32; 2],
    /// Number of spreadlets (0 for a dense PSF).
    pub spreadlets: u32,
    /// Number of pixels of the dense PSF's support.
    pub dense_support: u32,
    /// L1 error of the integrated spreadlets against the pre-filtered PSF.
    pub l1: f32,
    /// SSIM of the integrated spreadlets against the pre-filtered PSF (`metrics::ssim_plane`).
    pub ssim: f32,
    /// Largest distance of the PSF's support from its centre, pixels.
    pub extent_px: f32,
}

/// How a database was built (informational).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BuildInfo {
    /// Profile name ("quick", "paper", ...).
    pub profile: String,
    /// Wall-clock build time, seconds. Leave `None` for byte-reproducible files.
    pub build_seconds: Option<f64>,
    /// Tool and version that wrote the file.
    pub tool: String,
    /// Free-form key/value notes.
    pub notes: Vec<(String, String)>,
}

/// The database header (bincode-encoded in the file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DbHeader {
    /// PSF model; callers check it against the model they expect.
    pub model: PsfModel,
    /// Parameter space (ranges, betas, nested grid: `space.grid()`).
    pub space: ParamSpace,
    /// Channels per spreadlet value and dense pixel (= `model.channels()`).
    pub channels: u32,
    /// PSF image resolution used for tracing, px (square); every offset lies within +-this.
    pub psf_resolution: u32,
    /// Light-tracing samples per PSF.
    pub rays_per_psf: u64,
    /// Random seed of the build.
    pub seed: u64,
    /// Spreadlet density knob (1.0 = default).
    pub spreadlet_budget: f32,
    /// Whether PSFs were pre-filtered over their cell's box.
    pub prefilter: bool,
    /// Aperture shape.
    pub aperture: Aperture,
    /// Lens prescription (`physical-lens` only).
    pub lens: Option<LensPrescription>,
    /// Per-PSF statistics, in PSF order (empty or `psf_count` entries).
    pub stats: Vec<PsfStats>,
    /// Build information.
    pub build: BuildInfo,
    /// `Some` for a partial file of a sharded build (`precompute --shard K/N`): it stores only
    /// the PSFs of its range, and [`crate::merge_shards`] joins the parts into the database.
    pub shard: Option<ShardRange>,
}

impl DbHeader {
    /// Number of PSFs the file stores: the shard's range, else every PSF of the space.
    pub fn stored_psf_count(&self) -> usize {
        match &self.shard {
            Some(r) => r.len as usize,
            None => self.space.psf_count() as usize,
        }
    }
}

impl DbHeader {
    /// A header with defaults for everything but model, space and PSF resolution: channels from
    /// the model, no rays, seed 0, budget 1.0, pre-filtering on, circular aperture, no lens,
    /// no stats.
    pub fn new(model: PsfModel, space: ParamSpace, psf_resolution: u32) -> Self {
        DbHeader {
            model,
            space,
            channels: model.channels() as u32,
            psf_resolution,
            rays_per_psf: 0,
            seed: 0,
            spreadlet_budget: 1.0,
            prefilter: true,
            aperture: Aperture::default(),
            lens: None,
            stats: Vec::new(),
            build: BuildInfo::default(),
            shard: None,
        }
    }
}

/// The range of PSFs one part of a sharded build holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardRange {
    /// This part's index, `0..count`.
    pub index: u32,
    /// Number of parts the build is split into.
    pub count: u32,
    /// Index of the first PSF of the part in the whole database.
    pub first_psf: u32,
    /// Number of PSFs in the part (may be 0 when there are more parts than PSFs).
    pub len: u32,
}

impl ShardRange {
    /// Part `index` of `count` of a database of `psf_total` PSFs.
    pub fn of(index: u32, count: u32, psf_total: u32) -> Result<Self, DbError> {
        if count == 0 || index >= count {
            return Err(DbError::Invalid(format!(
                "shard {index}/{count}: the index must be below the count, and the count at least 1"
            )));
        }
        let start = |k: u32| (u64::from(psf_total) * u64::from(k) / u64::from(count)) as u32;
        let first_psf = start(index);
        Ok(ShardRange {
            index,
            count,
            first_psf,
            len: start(index + 1) - first_psf,
        })
    }

    /// Parses `"K/N"` (0-based K) into `(K, N)`.
    pub fn parse_spec(spec: &str) -> Result<(u32, u32), DbError> {
        let bad = || {
            DbError::Invalid(format!(
                "shard {spec:?}: expected K/N with 0 <= K < N, e.g. 0/4"
            ))
        };
        let (k, n) = spec.split_once('/').ok_or_else(bad)?;
        let k: u32 = k.trim().parse().map_err(|_| bad())?;
        let n: u32 = n.trim().parse().map_err(|_| bad())?;
        if n == 0 || k >= n {
            return Err(bad());
        }
        Ok((k, n))
    }

    /// The PSF indices of the part.
    pub fn indices(&self) -> std::ops::Range<u32> {
        self.first_psf..self.first_psf + self.len
    }

    /// Checks the range against a space of `psf_total` PSFs: it must be exactly the range
    /// [`ShardRange::of`] gives, so that parts of one build always tile the same way.
    pub(crate) fn validate(&self, psf_total: u32) -> Result<(), DbError> {
        match ShardRange::of(self.index, self.count, psf_total) {
            Ok(expected) if expected == *self => Ok(()),
            _ => Err(DbError::OutOfBounds {
                what: format!(
                    "shard {}/{} claims PSFs {}..{} of {psf_total}, which is not that part's range",
                    self.index,
                    self.count,
                    self.first_psf,
                    u64::from(self.first_psf) + u64::from(self.len)
                ),
            }),
        }
    }
}
