//! The one database loader, and the one rule for which PSF model serves which effect.
//!
//! - Still pixels are drawn with the thin-lens database; pixels that move with the lens-motion
//!   database; a frame that moves loads both ([`crate::dbset::DbSet`] looks each pixel up in the
//!   one it needs). A pinhole, still frame needs none.
//! - A set loaded for lens-motion also serves a frame with defocus alone, so a sequence whose
//!   motion stops keeps its databases ([`serves`]).
//! - Databases come from the cache folder, built there with `precompute` when missing or
//!   unreadable ([`crate::dbcache`]), or from one file the caller names (then that file serves
//!   every pixel; it must be of a model the input can use).

use std::path::{Path, PathBuf};

use precompute::{BuildConfig, Profile};
use psf_db::{PsfDatabase, PsfModel};

use crate::condition::{condition, ConditionReport};
use crate::dbcache;
use crate::dbset::DbSet;
use crate::error::Error;

/// A database the loader used: its model, its file and whether this call built it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DbUsed {
    /// The model's name (`thin-lens`, `lens-motion`, `physical-lens`).
    pub model: &'static str,
    /// The file.
    pub path: PathBuf,
    /// True when it was built by this call.
    pub built_now: bool,
    /// The lens prescription a physical-lens database was traced through (its name).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lens: Option<String>,
}

/// How a database was conditioned before use (the `condition` stage).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Conditioned {
    /// The model's name.
    pub model: &'static str,
    /// What conditioning changed.
    pub report: ConditionReport,
}

/// Where the loader finds databases.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Source<'a> {
    /// The cache folder (built on demand with the given profile).
    Cache {
        /// The folder.
        dir: &'a Path,
        /// The profile of databases built on demand.
        profile: Profile,
    },
    /// One file for every pixel.
    File(&'a Path),
}

/// The aperture `camera`'s databases are traced with: its blades and their rotation (radians,
/// counter-clockwise on the image, reduced to one blade's turn, so that rotations a blade
/// apart share a database; 0 for a circle) and its anamorphic squeeze.
pub fn aperture_of(camera: &crate::Camera) -> psf_db::Aperture {
    psf_db::Aperture {
        blades: camera.aperture_blades,
        rotation_rad: camera.aperture_rotation_rad() as f32,
        ratio: camera.aperture_ratio as f32,
        // Filled in by `with_mask` once the camera's aperture image is read.
        image_hash: 0,
    }
}

/// `aperture` for a user-drawn aperture image: its content hash keys the databases.
pub fn with_mask(
    aperture: psf_db::Aperture,
    mask: Option<&formats::ApertureMask>,
) -> psf_db::Aperture {
    psf_db::Aperture {
        image_hash: mask.map_or(0, |m| m.content_hash()),
        ..aperture
    }
}

/// The physical lens `camera` names (`camera.json` `lens`), as the `physical-lens` build
/// options: its prescription stopped down to the camera's f-number and focused at its focus
/// distance, for the camera's sensor and image width. The database covers depths from a quarter
/// of the focus distance (at least twice the focal length) to a thousand times it, and the
/// whole sensor out to its corners; lookups beyond clamp. `None` for the thin lens.
pub fn lens_of(camera: &crate::Camera) -> Result<Option<precompute::LensOptions>, Error> {
    let Some(prescription) = camera.prescription()? else {
        return Ok(None);
    };
    let focus = camera.focus_distance.unwrap_or(1.0);
    let near = (0.25 * focus).max(2.0 * camera.focal_length_scene());
    let mm_per_px = camera.sensor_width_mm / f64::from(camera.width);
    let half_diagonal_px = 0.5 * f64::from(camera.width).hypot(f64::from(camera.height));
    Ok(Some(precompute::LensOptions {
        prescription: Some(prescription),
        f_stop: camera.f_stop,
        focus_distance: focus,
        scene_unit_mm: camera.scene_unit_mm,
        sensor_width_mm: camera.sensor_width_mm,
        image_width_px: Some(camera.width),
        depth_range: [near.min(0.5 * focus), 1000.0 * focus],
        max_eccentricity_mm: half_diagonal_px * mm_per_px,
        ..precompute::LensOptions::default()
    }))
}

/// What one load needs.
pub struct Request<'a> {
    /// Where the databases come from.
    pub source: Source<'a>,
    /// The cheapest model that reproduces the input's effects (`None`: nothing to simulate).
    pub needed: Option<PsfModel>,
    /// The aperture's blades (0 = circular) and their rotation ([`aperture_of`] a camera).
    pub aperture: psf_db::Aperture,
    /// A user-drawn aperture the databases are traced with (its hash is in `aperture`:
    /// [`with_mask`]).
    pub mask: Option<&'a formats::ApertureMask>,
    /// The camera's physical lens ([`lens_of`]): every pixel is then drawn with a
    /// `physical-lens` database built for it.
    pub lens: Option<&'a precompute::LensOptions>,
    /// Conditioning (monopole removal, energy normalisation) before use.
    pub condition: bool,
    /// Changes the runtime's build settings before the cache is asked (the baselines store
    /// every PSF dense); `None` keeps them.
    pub adjust: Option<&'a dyn Fn(BuildConfig) -> BuildConfig>,
    /// Applied to each database as read, before conditioning (the dense baseline densifies a
    /// file whose PSFs are stored sparse).
    pub transform: Option<&'a dyn Fn(PsfDatabase) -> Result<PsfDatabase, Error>>,
    /// Prints the builder's progress bars (database builds take minutes).
    pub progress: bool,
    /// Moving pixels are drawn with the thin-lens PSF smeared along their motion
    /// ([`crate::pipeline::ClassifyOptions::smear_motion`]): a cache load then reads no
    /// lens-motion database.
    pub smear_motion: bool,
}

/// What a load returned.
pub struct Loaded {
    /// The databases, ready for classification.
    pub set: DbSet,
    /// Which files were used.
    pub used: Vec<DbUsed>,
    /// What conditioning changed, per database (empty without conditioning).
    pub conditioning: Vec<Conditioned>,
}

/// True when a set loaded for `loaded` can serve an input that needs `needed`: the same model,
/// or a lens-motion set for defocus alone.
pub fn serves(loaded: Option<PsfModel>, needed: Option<PsfModel>) -> bool {
    loaded == needed || (loaded == Some(PsfModel::LensMotion) && needed == Some(PsfModel::ThinLens))
}

/// The models a cache load reads for `needed`: thin-lens for still pixels, plus lens-motion
/// when something moves and moving pixels are not drawn by smearing the thin-lens PSF.
pub fn models_for(needed: PsfModel, smear_motion: bool) -> Vec<PsfModel> {
    let mut models = vec![PsfModel::ThinLens];
    if needed == PsfModel::LensMotion && !smear_motion {
        models.push(PsfModel::LensMotion);
    }
    models
}

/// Loads the databases `request` asks for; `on_event` hears of every database built.
pub fn load(
    request: &Request,
    on_event: &(dyn Fn(dbcache::CacheEvent) + Sync),
) -> Result<Loaded, Error> {
    let Some(needed) = request.needed else {
        return Ok(Loaded {
            set: DbSet::none(),
            used: Vec::new(),
            conditioning: Vec::new(),
        });
    };
    let mut used = Vec::new();
    let mut conditioning = Vec::new();
    let mut prepare = |db: PsfDatabase| -> Result<PsfDatabase, Error> {
        let db = match request.transform {
            Some(t) => t(db)?,
            None => db,
        };
        if !request.condition {
            return Ok(db);
        }
        let (db, report) = condition(&db)?;
        conditioning.push(Conditioned {
            model: db.model().name(),
            report,
        });
        Ok(db)
    };
    let set = match request.source {
        Source::File(path) => {
            let db = dbcache::explicit_database(path, needed)?;
            used.push(DbUsed {
                model: db.model().name(),
                path: path.to_path_buf(),
                built_now: false,
                lens: db.header().lens.as_ref().map(|l| l.lens.name.clone()),
            });
            // A physical-lens database's PSFs on the axis, where the cache keeps them beside it.
            let at = dbcache::axis_path(path);
            if db.model() == PsfModel::PhysicalLens && at.is_file() {
                let axis = dbcache::explicit_database(&at, PsfModel::PhysicalLens)?;
                let main = prepare(db)?;
                DbSet::physical(main, Some(prepare(axis)?)).map_err(|e| {
                    let why = match e {
                        psf_db::DbError::Invalid(why) => why,
                        other => other.to_string(),
                    };
                    let at = at.display();
                    psf_db::DbError::Invalid(format!(
                        "{at}: {why} (move it away to draw without it)"
                    ))
                })?
            } else {
                DbSet::single(prepare(db)?)?
            }
        }
        Source::Cache { dir, profile } if request.lens.is_some() => {
            // One physical-lens database serves still and moving pixels: a moving pixel's PSF
            // is its lens PSF smeared along its motion, per frame (`motion_smear`).
            let mut cfg = dbcache::build_config(PsfModel::PhysicalLens, profile, 0);
            cfg.lens = request.lens.cloned();
            if let Some(adjust) = request.adjust {
                cfg = adjust(cfg);
            }
            let (db, source) = dbcache::cached_database(&cfg, dir, request.progress, on_event)?;
            let axis_at = dbcache::axis_path(&source.path);
            used.push(DbUsed {
                model: PsfModel::PhysicalLens.name(),
                path: source.path,
                built_now: source.built,
                lens: db.header().lens.as_ref().map(|l| l.lens.name.clone()),
            });
            // The lens's PSFs on the axis, for the rotational averages drawn near it.
            let axis_cfg = dbcache::axis_config(&cfg, &db);
            let main = prepare(db)?;
            let axis = match axis_cfg {
                Some(axis_cfg) => {
                    let (axis, _) = dbcache::cached_database_at(
                        &axis_cfg,
                        &axis_at,
                        request.progress,
                        on_event,
                    )?;
                    Some(prepare(axis)?)
                }
                None => None,
            };
            DbSet::physical(main, axis)?
        }
        Source::Cache { dir, profile } => {
            let mut loaded = Vec::new();
            for model in models_for(needed, request.smear_motion) {
                let mut cfg = dbcache::build_config(model, profile, request.aperture.blades);
                cfg.blade_rotation_rad = request.aperture.rotation_rad;
                cfg.aperture_ratio = request.aperture.ratio;
                cfg.aperture_mask = request.mask.cloned();
                if let Some(adjust) = request.adjust {
                    cfg = adjust(cfg);
                }
                let (db, source) = dbcache::cached_database(&cfg, dir, request.progress, on_event)?;
                used.push(DbUsed {
                    model: model.name(),
                    path: source.path,
                    built_now: source.built,
                    lens: None,
                });
                loaded.push(prepare(db)?);
            }
            let main = (loaded.len() > 1).then(|| loaded.remove(1));
            DbSet::new(loaded.pop(), main)?
        }
    };
    Ok(Loaded {
        set,
        used,
        conditioning,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(blades: u32, rotation_deg: f64) -> crate::Camera {
        let mut c = crate::Camera::from_json_str(
            r#"{"width":64,"height":64,"focal_length_mm":50.0,"sensor_width_mm":36.0,
                "f_stop":2.0,"focus_distance":1.0}"#,
        )
        .expect("camera");
        c.aperture_blades = blades;
        c.aperture_rotation_deg = rotation_deg;
        c
    }

    #[test]
    fn databases_key_on_the_blade_rotation_up_to_one_blade() {
        let turned = aperture_of(&camera(5, 20.0));
        assert!((f64::from(turned.rotation_rad) - 20f64.to_radians()).abs() < 1e-6);
        // A blade further (72 degrees for five) or back is the same aperture.
        assert_eq!(aperture_of(&camera(5, 92.0)), turned);
        assert_eq!(aperture_of(&camera(5, -52.0)), turned);
        assert_ne!(aperture_of(&camera(5, 0.0)), turned);
        // A circle has no rotation.
        assert_eq!(aperture_of(&camera(0, 33.0)), aperture_of(&camera(0, 0.0)));
        // The cache file differs with the rotation.
        let file = |a: psf_db::Aperture| {
            let mut cfg = dbcache::build_config(PsfModel::ThinLens, Profile::Quick, a.blades);
            cfg.blade_rotation_rad = a.rotation_rad;
            dbcache::cache_file_name(&cfg)
        };
        assert_ne!(file(turned), file(aperture_of(&camera(5, 0.0))));
        // And with the anamorphic squeeze.
        let mut squeezed = camera(0, 0.0);
        squeezed.aperture_ratio = 2.0;
        let squeezed = aperture_of(&squeezed);
        assert_eq!(squeezed.ratio, 2.0);
        let file = |a: psf_db::Aperture| {
            let mut cfg = dbcache::build_config(PsfModel::ThinLens, Profile::Quick, a.blades);
            cfg.aperture_ratio = a.ratio;
            dbcache::cache_file_name(&cfg)
        };
        assert_ne!(file(squeezed), file(aperture_of(&camera(0, 0.0))));
    }
}
