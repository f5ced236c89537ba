//! The database cache: a user with only a G-buffer and a camera gets a result from one command.
//! A missing database is built with `precompute` (the `quick` profile by default) into the
//! cache folder ([`cache_dir`]: `$SPREADLET_CACHE`, else the platform's cache folder), named by
//! model, profile and a hash of the build settings, and reused on later runs.

use std::path::{Path, PathBuf};

use precompute::{build_database_reporting, BuildConfig, Profile};
use psf_db::{PsfDatabase, PsfModel};

/// Environment variable naming the cache folder.
pub const CACHE_ENV: &str = "SPREADLET_CACHE";

/// Errors of the cache.
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    /// The cache folder could not be created.
    #[error("cannot create the database cache folder {path}: {source}")]
    Folder {
        /// The folder.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// Building the database failed.
    #[error("building the {model} database failed: {source}")]
    Build {
        /// The model.
        model: &'static str,
        /// The cause.
        source: precompute::PrecomputeError,
    },
    /// Reading or writing a database failed.
    #[error(transparent)]
    Db(#[from] psf_db::DbError),
    /// A database file given explicitly could not be read (missing, truncated, corrupt).
    #[error("database {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// The cause.
        source: psf_db::DbError,
    },
    /// A database file given explicitly is of another model than the scene needs.
    #[error("database {path} is a {found} database, but this input needs {needed}")]
    WrongModel {
        /// The file.
        path: String,
        /// Its model.
        found: &'static str,
        /// The model needed.
        needed: &'static str,
    },
}

/// The cache folder, whatever the working directory: `$SPREADLET_CACHE` when set and
/// non-empty, else the platform's cache folder (`$XDG_CACHE_HOME/spreadlet`, else
/// `~/.cache/spreadlet`; `~/Library/Caches/spreadlet` on macOS; `%LOCALAPPDATA%\spreadlet` on
/// Windows), else `.spreadlet-cache` in the working directory when no home is known.
pub fn cache_dir() -> PathBuf {
    cache_dir_from(&|name| std::env::var_os(name))
}

/// [`cache_dir`] with the environment given as a lookup.
fn cache_dir_from(env: &dyn Fn(&str) -> Option<std::ffi::OsString>) -> PathBuf {
    let var = |name: &str| env(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some(dir) = var(CACHE_ENV) {
        return dir;
    }
    let platform = if cfg!(target_os = "windows") {
        var("LOCALAPPDATA")
    } else if cfg!(target_os = "macos") {
        var("HOME").map(|h| h.join("Library/Caches"))
    } else {
        var("XDG_CACHE_HOME")
            .filter(|p| p.is_absolute())
            .or_else(|| var("HOME").map(|h| h.join(".cache")))
    };
    match platform {
        Some(dir) => dir.join("spreadlet"),
        None => PathBuf::from(".spreadlet-cache"),
    }
}

/// What the cache tells its caller while it works.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CacheEvent {
    /// A cached file was unreadable or of another model; it is rebuilt.
    Unusable {
        /// The file.
        path: PathBuf,
    },
    /// A database is being built (minutes with the paper profile).
    Building {
        /// The model's name.
        model: &'static str,
        /// The profile's name.
        profile: &'static str,
        /// The file it goes to.
        path: PathBuf,
    },
    /// A database being built has `done` of its `total` PSFs traced and sparsified (sent at
    /// every percent; from the builder's worker threads, so two may arrive out of order).
    Progress {
        /// The model's name.
        model: &'static str,
        /// PSFs done.
        done: u32,
        /// PSFs in the database.
        total: u32,
    },
}

impl CacheEvent {
    /// How far a build is, in [0, 1], for a progress event; `None` for the others.
    pub fn fraction(&self) -> Option<f64> {
        match self {
            CacheEvent::Progress { done, total, .. } => {
                Some(f64::from(*done) / f64::from((*total).max(1)))
            }
            _ => None,
        }
    }
}

impl std::fmt::Display for CacheEvent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CacheEvent::Unusable { path } => {
                write!(
                    f,
                    "cached database {} is unusable; rebuilding",
                    path.display()
                )
            }
            CacheEvent::Building {
                model,
                profile,
                path,
            } => write!(
                f,
                "building the {model} database ({profile} profile) into {}",
                path.display()
            ),
            CacheEvent::Progress { model, done, total } => {
                write!(f, "building the {model} database: {done} of {total} PSFs")
            }
        }
    }
}

/// The build settings for `model` at `profile` with an aperture of `blades` blades (0 =
/// circular).
///
/// The runtime samples the one-dimensional thin-lens space more finely than the profile's
/// default for `quick` (64 PSFs instead of 24: a still surface otherwise takes a CoC up to ~15%
/// off); it costs seconds to build. The physical-lens space too (160 instead of 40).
pub fn build_config(model: PsfModel, profile: Profile, blades: u32) -> BuildConfig {
    let mut cfg = BuildConfig::new(model, profile);
    cfg.blades = blades;
    if model == PsfModel::ThinLens && profile == Profile::Quick {
        cfg.psf_count = Some(THIN_LENS_QUICK_PSFS);
    }
    if model == PsfModel::PhysicalLens && profile == Profile::Quick {
        // The profile's 40 leave cells so wide in inverse depth that a drop 0.45 m from a
        // lens focused at 1.2 m took a PSF pre-filtered over blurs 30 % larger (the rain
        // scene: SSIM 0.918 with 40, 0.940 with 160); a double Gauss builds in about two
        // minutes on 2 cores.
        cfg.psf_count = Some(PHYSICAL_LENS_QUICK_PSFS);
    }
    cfg
}

/// Eccentricity of the PSFs a physical-lens database's rotational averages on the axis are
/// drawn from ([`axis_config`]), mm: a micrometre, on the axis to the pixel.
pub const AXIS_ECCENTRICITY_MM: f64 = 1e-3;

/// The build settings of the lens's PSFs on the optical axis that go with the physical-lens
/// database `main` built from `cfg`: one per inverse-depth box of `main` (its cells that start
/// at eccentricity 0), over the same depths, in one eccentricity box
/// [`AXIS_ECCENTRICITY_MM`] wide, each stored dense (the runtime averages their images over
/// turns: spreadlets would only approximate them). `None` for any other model. The runtime
/// draws their rotational averages near the axis ([`crate::dbset::DbSet::physical`]).
pub fn axis_config(cfg: &BuildConfig, main: &PsfDatabase) -> Option<BuildConfig> {
    if cfg.model != PsfModel::PhysicalLens {
        return None;
    }
    let boxes = crate::dbset::on_axis_cells(main) as u32;
    let mut lens = cfg.lens.clone().unwrap_or_default();
    lens.max_eccentricity_mm = AXIS_ECCENTRICITY_MM;
    lens.eccentricity_boxes = Some(1);
    let mut axis = cfg.clone();
    axis.psf_count = Some(boxes.max(1));
    axis.dense_up_to_support = u32::MAX;
    axis.lens = Some(lens);
    Some(axis)
}

/// PSFs of the thin-lens database the runtime builds with the quick profile.
pub const THIN_LENS_QUICK_PSFS: u32 = 64;

/// PSFs of the physical-lens database the runtime builds with the quick profile.
pub const PHYSICAL_LENS_QUICK_PSFS: u32 = 160;

/// The file name a configuration is cached under: model, profile, and a hash (FNV-1a 64) of
/// every build setting, the profile's numbers and the database format version (and for a
/// physical lens, which of its cells are traced at the middle of their inverse depths).
pub fn cache_file_name(cfg: &BuildConfig) -> String {
    let mut key = format!(
        "{cfg:?} spec={:?} format={}",
        cfg.profile.spec(cfg.model),
        psf_db::FORMAT_VERSION
    );
    if cfg.model == PsfModel::PhysicalLens {
        key += &format!(
            " scaled_blend={}",
            psf_db::space::SCALED_BLEND_MIN_CELLS_FROM_FOCUS
        );
    }
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in key.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    format!(
        "{}-{}-{h:016x}.sprdlt",
        cfg.model.name(),
        cfg.profile.name()
    )
}

/// Where a cached database came from.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct DbSource {
    /// The file.
    pub path: PathBuf,
    /// True when it was built by this call.
    pub built: bool,
}

/// The database for `cfg` from the cache folder `dir`, built (and stored) when missing or
/// unreadable (a corrupt cache file is rebuilt, not trusted). `progress` shows the builder's
/// progress bars; `on_event` hears of rebuilds and builds.
pub fn cached_database(
    cfg: &BuildConfig,
    dir: &Path,
    progress: bool,
    on_event: &(dyn Fn(CacheEvent) + Sync),
) -> Result<(PsfDatabase, DbSource), CacheError> {
    cached_database_at(cfg, &dir.join(cache_file_name(cfg)), progress, on_event)
}

/// Where the lens's PSFs on the axis ([`axis_config`]) are kept beside the physical-lens
/// database at `main`: `NAME.axis.sprdlt` for `NAME.sprdlt`. A database named by hand
/// (`--db`) finds them there too, so it draws what the cache draws.
pub fn axis_path(main: &Path) -> PathBuf {
    main.with_extension("axis.sprdlt")
}

/// [`cached_database`] at the file `path`: read when it holds a database of `cfg`'s model,
/// else built from `cfg` and written there.
pub fn cached_database_at(
    cfg: &BuildConfig,
    path: &Path,
    progress: bool,
    on_event: &(dyn Fn(CacheEvent) + Sync),
) -> Result<(PsfDatabase, DbSource), CacheError> {
    let path = path.to_path_buf();
    let dir = path.parent().unwrap_or(Path::new("."));
    if path.exists() {
        match PsfDatabase::read(&path) {
            Ok(db) if db.model() == cfg.model => {
                return Ok((db, DbSource { path, built: false }));
            }
            Ok(_) | Err(_) => on_event(CacheEvent::Unusable { path: path.clone() }),
        }
    }
    std::fs::create_dir_all(dir).map_err(|source| CacheError::Folder {
        path: dir.display().to_string(),
        source,
    })?;
    on_event(CacheEvent::Building {
        model: cfg.model.name(),
        profile: cfg.profile.name(),
        path: path.clone(),
    });
    let model = cfg.model.name();
    let on_psf = |done, total| on_event(CacheEvent::Progress { model, done, total });
    let (db, _report) =
        build_database_reporting(cfg, None, progress, Some(&on_psf)).map_err(|source| {
            CacheError::Build {
                model: cfg.model.name(),
                source,
            }
        })?;
    db.write_atomic(&path)?;
    Ok((db, DbSource { path, built: true }))
}

/// Reads a database given explicitly and checks that it is of a model usable for `needed`
/// (a lens-motion database also serves defocus alone).
pub fn explicit_database(path: &Path, needed: PsfModel) -> Result<PsfDatabase, CacheError> {
    let db = PsfDatabase::read(path).map_err(|source| CacheError::Read {
        path: path.display().to_string(),
        source,
    })?;
    // A physical-lens database serves every pixel, moving ones by smearing its PSFs.
    let found = db.model();
    let ok = found == needed
        || (needed == PsfModel::ThinLens && found == PsfModel::LensMotion)
        || found == PsfModel::PhysicalLens;
    if !ok {
        return Err(CacheError::WrongModel {
            path: path.display().to_string(),
            found: found.name(),
            needed: needed.name(),
        });
    }
    Ok(db)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_follows_the_platform_not_the_working_directory() {
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |name: &str| {
                pairs
                    .iter()
                    .find(|(k, _)| *k == name)
                    .map(|(_, v)| std::ffi::OsString::from(v))
            }
        };
        let all = env(&[
            ("SPREADLET_CACHE", "/c/spreadlet"),
            ("XDG_CACHE_HOME", "/x"),
            ("HOME", "/h"),
            ("LOCALAPPDATA", "/l"),
        ]);
        assert_eq!(cache_dir_from(&all), PathBuf::from("/c/spreadlet"));
        let empty_override = env(&[
            ("SPREADLET_CACHE", ""),
            ("XDG_CACHE_HOME", "/x"),
            ("HOME", "/h"),
            ("LOCALAPPDATA", "/l"),
        ]);
        let home_only = env(&[("HOME", "/h"), ("LOCALAPPDATA", "/l")]);
        if cfg!(target_os = "linux") {
            assert_eq!(
                cache_dir_from(&empty_override),
                PathBuf::from("/x/spreadlet")
            );
            assert_eq!(
                cache_dir_from(&home_only),
                PathBuf::from("/h/.cache/spreadlet")
            );
            // A relative XDG_CACHE_HOME is invalid by the specification and ignored.
            let relative = env(&[("XDG_CACHE_HOME", "rel"), ("HOME", "/h")]);
            assert_eq!(
                cache_dir_from(&relative),
                PathBuf::from("/h/.cache/spreadlet")
            );
        }
        assert_eq!(cache_dir_from(&env(&[])), PathBuf::from(".spreadlet-cache"));
    }

    #[test]
    fn cache_names_differ_by_model_profile_and_settings() {
        let a = cache_file_name(&build_config(PsfModel::ThinLens, Profile::Quick, 0));
        let b = cache_file_name(&build_config(PsfModel::ThinLens, Profile::Quick, 6));
        let c = cache_file_name(&build_config(PsfModel::LensMotion, Profile::Quick, 0));
        let d = cache_file_name(&build_config(PsfModel::ThinLens, Profile::Test, 0));
        assert!(a.starts_with("thin-lens-quick-"));
        assert_ne!(a, b);
        assert_ne!(a, c);
        assert_ne!(a, d);
        assert_eq!(
            a,
            cache_file_name(&build_config(PsfModel::ThinLens, Profile::Quick, 0))
        );
    }
}
