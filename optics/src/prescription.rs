//! A lens prescription: the surfaces of a lens from the object side to the image side, as
//! optical designers publish them and as pbrt's realistic camera reads them.
//!
//! Per surface: the signed radius of curvature (positive: centre of curvature behind the
//! surface, towards the image; 0: flat), the axial thickness to the next surface, the medium
//! behind the surface (air, or a glass with its dispersion), and the clear aperture diameter.
//! One surface is the aperture stop (flat, air behind it). The last thickness is the nominal
//! distance to the image plane; focusing replaces it.
//!
//! Two file forms:
//! - JSON: `{"name", "description", "surfaces": [{"radius_mm", "thickness_mm",
//!   "aperture_diameter_mm", "stop", "glass": {"name", "n_d", "abbe_number"} |
//!   {"name", "sellmeier_b", "sellmeier_c_um2"}}]}`, `glass` absent for air;
//! - the plain table of pbrt-v4's realistic camera: one surface per line, `radius thickness
//!   index aperture`, `#` comments, radius 0 and index 0 for the stop, index 1 for air; an
//!   optional fifth column gives the glass's Abbe number (without it the glass has no
//!   dispersion, as in pbrt).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::glass::{Dispersion, BK7};

/// Most surfaces a prescription may have.
pub const MAX_SURFACES: usize = 64;
/// Largest prescription file read, bytes.
pub const MAX_PRESCRIPTION_BYTES: u64 = 1 << 20;

/// What is wrong with a prescription.
#[derive(Debug, thiserror::Error)]
pub enum PrescriptionError {
    /// The file could not be read.
    #[error("lens prescription {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The JSON did not parse.
    #[error("lens prescription {path}: {source}")]
    Json {
        /// The file.
        path: String,
        /// Why.
        source: serde_json::Error,
    },
    /// A line of the table did not parse.
    #[error("lens prescription {path}, line {line}: {message}")]
    Table {
        /// The file.
        path: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// The lens cannot exist.
    #[error("lens prescription {name}: {message}")]
    Invalid {
        /// The lens.
        name: String,
        /// What is wrong.
        message: String,
    },
    /// Neither a built-in lens nor a readable file.
    #[error(
        "lens {0:?} is neither a built-in lens ({list}) nor a prescription file",
        list = BUILTIN_LENSES.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", ")
    )]
    Unknown(String),
}

/// The medium behind a surface.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Medium {
    /// Air (index 1 at every wavelength).
    Air,
    /// A glass.
    Glass {
        /// Catalogue name, for people ("" when not given).
        name: String,
        /// Its index against wavelength.
        dispersion: Dispersion,
    },
}

impl Medium {
    /// Refractive index at `lambda_um`.
    #[inline]
    pub fn index(&self, lambda_um: f64) -> f64 {
        match self {
            Medium::Air => 1.0,
            Medium::Glass { dispersion, .. } => dispersion.index(lambda_um),
        }
    }
}

/// One refracting surface (or the stop).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Surface {
    /// Signed radius of curvature, mm (> 0: centre towards the image; 0: flat).
    pub radius_mm: f64,
    /// Axial distance to the next surface, mm (of the last: to the nominal image plane).
    pub thickness_mm: f64,
    /// Clear aperture diameter, mm (rays outside it are blocked: vignetting).
    pub aperture_diameter_mm: f64,
    /// True for the aperture stop.
    pub stop: bool,
    /// The medium behind the surface.
    pub medium: Medium,
}

/// A lens: its surfaces from the object side to the image side.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Prescription {
    /// Name, for people and for the database cache.
    pub name: String,
    /// Where it comes from.
    pub description: String,
    /// The surfaces.
    pub surfaces: Vec<Surface>,
}

/// The lenses built into spreadlet: name and JSON text.
pub const BUILTIN_LENSES: &[(&str, &str)] = &[
    ("singlet-51mm", include_str!("../lenses/singlet-51mm.json")),
    (
        "double-gauss-50mm",
        include_str!("../lenses/double-gauss-50mm.json"),
    ),
    (
        "wide-angle-22mm",
        include_str!("../lenses/wide-angle-22mm.json"),
    ),
];

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FilePrescription {
    name: String,
    #[serde(default)]
    description: String,
    surfaces: Vec<FileSurface>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileSurface {
    #[serde(default)]
    radius_mm: f64,
    thickness_mm: f64,
    aperture_diameter_mm: f64,
    #[serde(default)]
    stop: bool,
    #[serde(default)]
    glass: Option<FileGlass>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileGlass {
    #[serde(default)]
    name: String,
    n_d: Option<f64>,
    abbe_number: Option<f64>,
    sellmeier_b: Option<[f64; 3]>,
    sellmeier_c_um2: Option<[f64; 3]>,
}

impl FileGlass {
    fn medium(self, lens: &str, index: usize) -> Result<Medium, PrescriptionError> {
        let dispersion = match (
            self.n_d,
            self.abbe_number,
            self.sellmeier_b,
            self.sellmeier_c_um2,
        ) {
            (Some(n_d), v, None, None) => Dispersion::from_abbe(n_d, v.unwrap_or(f64::INFINITY)),
            (None, None, Some(b), Some(c_um2)) => Dispersion::Sellmeier { b, c_um2 },
            _ if self.name.eq_ignore_ascii_case("N-BK7") => BK7,
            _ => {
                return Err(invalid(
                    lens,
                    format!(
                        "surface {}: a glass needs n_d (and optionally abbe_number), or \
                         sellmeier_b and sellmeier_c_um2",
                        index + 1
                    ),
                ))
            }
        };
        Ok(Medium::Glass {
            name: self.name,
            dispersion,
        })
    }
}

fn invalid(name: &str, message: impl Into<String>) -> PrescriptionError {
    PrescriptionError::Invalid {
        name: name.to_string(),
        message: message.into(),
    }
}

impl Prescription {
    /// The built-in lens `name`, if there is one.
    pub fn builtin(name: &str) -> Option<Prescription> {
        let (_, text) = BUILTIN_LENSES.iter().find(|(n, _)| *n == name)?;
        Prescription::from_json_str(text, name).ok()
    }

    /// A built-in lens by name, or else a prescription file (`.json`, otherwise the table);
    /// a relative path is taken from `base_dir` when given.
    pub fn resolve(
        name_or_path: &str,
        base_dir: Option<&Path>,
    ) -> Result<Prescription, PrescriptionError> {
        if let Some(p) = Prescription::builtin(name_or_path) {
            return Ok(p);
        }
        let path = PathBuf::from(name_or_path);
        let path = match base_dir {
            Some(dir) if path.is_relative() => dir.join(path),
            _ => path,
        };
        if !path.is_file() {
            return Err(PrescriptionError::Unknown(name_or_path.to_string()));
        }
        Prescription::read(&path)
    }

    /// Reads a prescription file: JSON when it ends in `.json`, the pbrt table otherwise.
    pub fn read(path: &Path) -> Result<Prescription, PrescriptionError> {
        let shown = path.display().to_string();
        let io = |source| PrescriptionError::Io {
            path: shown.clone(),
            source,
        };
        let len = std::fs::metadata(path).map_err(io)?.len();
        if len > MAX_PRESCRIPTION_BYTES {
            return Err(invalid(
                &shown,
                format!(
                    "the file is {len} bytes; a prescription is at most {MAX_PRESCRIPTION_BYTES}"
                ),
            ));
        }
        let text = std::fs::read_to_string(path).map_err(io)?;
        let is_json = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"));
        if is_json {
            Prescription::from_json_str(&text, &shown)
        } else {
            let name = path
                .file_stem()
                .map_or_else(|| shown.clone(), |s| s.to_string_lossy().into_owned());
            Prescription::from_table_str(&text, &name, &shown)
        }
    }

    /// Parses the JSON form; `source` names it in errors.
    pub fn from_json_str(text: &str, source: &str) -> Result<Prescription, PrescriptionError> {
        let file: FilePrescription =
            serde_json::from_str(text).map_err(|e| PrescriptionError::Json {
                path: source.to_string(),
                source: e,
            })?;
        let mut surfaces = Vec::with_capacity(file.surfaces.len());
        for (i, s) in file.surfaces.into_iter().enumerate() {
            let medium = match s.glass {
                Some(g) => g.medium(&file.name, i)?,
                None => Medium::Air,
            };
            surfaces.push(Surface {
                radius_mm: s.radius_mm,
                thickness_mm: s.thickness_mm,
                aperture_diameter_mm: s.aperture_diameter_mm,
                stop: s.stop,
                medium,
            });
        }
        let p = Prescription {
            name: file.name,
            description: file.description,
            surfaces,
        };
        p.validate()?;
        Ok(p)
    }

    /// Parses pbrt's table (`radius thickness index aperture [abbe]` per line); `name` names
    /// the lens, `source` the file in errors.
    pub fn from_table_str(
        text: &str,
        name: &str,
        source: &str,
    ) -> Result<Prescription, PrescriptionError> {
        let mut surfaces = Vec::new();
        let mut description = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line = raw.trim();
            if let Some(comment) = line.strip_prefix('#') {
                if surfaces.is_empty() {
                    description.push(comment.trim().to_string());
                }
                continue;
            }
            if line.is_empty() {
                continue;
            }
            let bad = |message: String| PrescriptionError::Table {
                path: source.to_string(),
                line: i + 1,
                message,
            };
            let numbers: Vec<f64> = line
                .split_whitespace()
                .map(|t| {
                    t.parse::<f64>()
                        .map_err(|_| bad(format!("{t:?} is not a number")))
                })
                .collect::<Result<_, _>>()?;
            if !(4..=5).contains(&numbers.len()) {
                return Err(bad(format!(
                    "expected `radius thickness index aperture [abbe]`, got {} numbers",
                    numbers.len()
                )));
            }
            if surfaces.len() == MAX_SURFACES {
                return Err(bad(format!("more than {MAX_SURFACES} surfaces")));
            }
            let (radius, thickness, index, aperture) =
                (numbers[0], numbers[1], numbers[2], numbers[3]);
            let stop = index == 0.0;
            let medium = if stop || index == 1.0 {
                Medium::Air
            } else {
                Medium::Glass {
                    name: String::new(),
                    dispersion: Dispersion::from_abbe(
                        index,
                        numbers.get(4).copied().unwrap_or(f64::INFINITY),
                    ),
                }
            };
            surfaces.push(Surface {
                radius_mm: radius,
                thickness_mm: thickness,
                aperture_diameter_mm: aperture,
                stop,
                medium,
            });
        }
        let p = Prescription {
            name: name.to_string(),
            description: description.join(" "),
            surfaces,
        };
        p.validate()?;
        Ok(p)
    }

    /// Checks that the lens can exist: finite numbers, one flat stop with air behind it,
    /// positive apertures and thicknesses, spheres larger than their apertures, indices >= 1.
    pub fn validate(&self) -> Result<(), PrescriptionError> {
        let bad = |m: String| Err(invalid(&self.name, m));
        if self.surfaces.is_empty() {
            return bad("it has no surfaces".into());
        }
        if self.surfaces.len() > MAX_SURFACES {
            return bad(format!("more than {MAX_SURFACES} surfaces"));
        }
        let stops = self.surfaces.iter().filter(|s| s.stop).count();
        if stops != 1 {
            return bad(format!("it needs exactly one aperture stop, has {stops}"));
        }
        for (i, s) in self.surfaces.iter().enumerate() {
            let k = i + 1;
            let vals = [s.radius_mm, s.thickness_mm, s.aperture_diameter_mm];
            if !vals.iter().all(|v| v.is_finite()) {
                return bad(format!("surface {k}: non-finite value in {vals:?}"));
            }
            if s.thickness_mm < 0.0 {
                return bad(format!("surface {k}: thickness {} mm < 0", s.thickness_mm));
            }
            if s.aperture_diameter_mm.is_nan() || s.aperture_diameter_mm <= 0.0 {
                return bad(format!(
                    "surface {k}: aperture diameter {} mm must be > 0",
                    s.aperture_diameter_mm
                ));
            }
            if s.radius_mm != 0.0 && s.radius_mm.abs() < 0.5 * s.aperture_diameter_mm {
                return bad(format!(
                    "surface {k}: the aperture ({} mm) is wider than the sphere of radius {} mm",
                    s.aperture_diameter_mm, s.radius_mm
                ));
            }
            if s.stop && (s.radius_mm != 0.0 || s.medium != Medium::Air) {
                return bad(format!(
                    "surface {k}: the stop must be flat with air behind it"
                ));
            }
            for l in [0.4, 0.5876, 0.7] {
                let n = s.medium.index(l);
                if !(n.is_finite() && (1.0..4.0).contains(&n)) {
                    return bad(format!(
                        "surface {k}: the index at {} nm is {n}; glass lies in [1, 4)",
                        l * 1e3
                    ));
                }
            }
        }
        Ok(())
    }

    /// Index of the stop surface.
    pub fn stop_index(&self) -> usize {
        self.surfaces.iter().position(|s| s.stop).unwrap_or(0)
    }

    /// The biconvex singlet with a stop in front: radii, centre thickness and clear diameter
    /// of the lens, stop diameter and its distance in front of the lens, mm; N-BK7 glass.
    pub fn singlet(
        radius_front_mm: f64,
        radius_back_mm: f64,
        thickness_mm: f64,
        lens_diameter_mm: f64,
        stop_diameter_mm: f64,
        stop_gap_mm: f64,
    ) -> Prescription {
        Prescription {
            name: "singlet".into(),
            description: "biconvex N-BK7 singlet behind its stop".into(),
            surfaces: vec![
                Surface {
                    radius_mm: 0.0,
                    thickness_mm: stop_gap_mm,
                    aperture_diameter_mm: stop_diameter_mm,
                    stop: true,
                    medium: Medium::Air,
                },
                Surface {
                    radius_mm: radius_front_mm,
                    thickness_mm,
                    aperture_diameter_mm: lens_diameter_mm,
                    stop: false,
                    medium: Medium::Glass {
                        name: "N-BK7".into(),
                        dispersion: BK7,
                    },
                },
                Surface {
                    radius_mm: radius_back_mm,
                    thickness_mm: 0.0,
                    aperture_diameter_mm: lens_diameter_mm,
                    stop: false,
                    medium: Medium::Air,
                },
            ],
        }
    }

    /// A copy stopped down: the stop's diameter times `scale` (in (0, 1]).
    pub fn with_stop_scaled(&self, scale: f64) -> Prescription {
        let mut p = self.clone();
        let i = p.stop_index();
        p.surfaces[i].aperture_diameter_mm *= scale;
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtins_parse_and_validate() {
        for (name, _) in BUILTIN_LENSES {
            let p = Prescription::builtin(name).expect(name);
            assert_eq!(&p.name, name);
            assert!(p.surfaces.len() >= 3);
        }
    }

    #[test]
    fn the_pbrt_table_reads_like_the_json() {
        let table = "# D-GAUSS F/2 22deg HFOV\n# radius thickness N aperture\n\
                     29.475 3.76 1.67 25.2 47.1\n84.83 0.12 1 25.2\n0 4.5 0 17.1\n\
                     -14.495 1.18 1.603 17\n-39.73 0 1 20\n";
        let p = Prescription::from_table_str(table, "dg", "mem").expect("table");
        assert_eq!(p.surfaces.len(), 5);
        assert!(p.surfaces[2].stop);
        assert_eq!(p.surfaces[1].medium, Medium::Air);
        let n = p.surfaces[0].medium.index(crate::glass::LAMBDA_D_UM);
        assert!((n - 1.67).abs() < 1e-12);
        // Without an Abbe number the glass does not disperse.
        let m = &p.surfaces[3].medium;
        assert_eq!(m.index(0.4), m.index(0.7));
        assert!(p.description.starts_with("D-GAUSS"));
    }

    #[test]
    fn bad_prescriptions_are_named() {
        let two_stops = "0 1 0 10\n0 1 0 10\n";
        let e = Prescription::from_table_str(two_stops, "x", "mem").unwrap_err();
        assert!(e.to_string().contains("exactly one aperture stop"), "{e}");
        let text = "10 1 1.5 30\n0 1 0 5\n";
        let e = Prescription::from_table_str(text, "x", "mem").unwrap_err();
        assert!(e.to_string().contains("wider than the sphere"), "{e}");
        let e = Prescription::from_table_str("1 2 three 4\n", "x", "mem").unwrap_err();
        assert!(e.to_string().contains("line 1"), "{e}");
        let e = Prescription::from_table_str("0 1 0 nan\n", "x", "mem").unwrap_err();
        assert!(e.to_string().contains("non-finite"), "{e}");
        let e = Prescription::resolve("no-such-lens", None).unwrap_err();
        assert!(e.to_string().contains("double-gauss-50mm"), "{e}");
        let e =
            Prescription::from_json_str("{\"name\": \"x\", \"surfaces\": [], \"zoom\": 1}", "m")
                .unwrap_err();
        assert!(e.to_string().contains("zoom"), "{e}");
    }
}
