//! Build settings: the profiles (test, quick, paper), the lens options and [`BuildConfig`].

use std::fmt;
use std::str::FromStr;

use psf_db::{LensPrescription, PsfModel};
use serde::{Deserialize, Serialize};

use crate::sparsify::Procedure;
use crate::PrecomputeError;
use optics::{LensSystem, Prescription};

/// How thoroughly a database is built.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Profile {
    /// Seconds: few small PSFs (CoC <= 12 px, motion <= 24 px), few rays; for test suites.
    Test,
    /// Minutes on 2 cores: CoC up to 64 px, motion up to 192 px.
    Quick,
    /// The paper's sample counts (100 / 400 / 4,000 PSFs) at up to 512 px PSFs; slow.
    Paper,
}

impl Profile {
    /// Name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Profile::Test => "test",
            Profile::Quick => "quick",
            Profile::Paper => "paper",
        }
    }

    /// The profile's numbers for `model`.
    pub fn spec(self, model: PsfModel) -> ProfileSpec {
        use Profile::*;
        use PsfModel::*;
        let (psf_count, ranges): (u32, Vec<[f64; 2]>) = match (self, model) {
            (Test, ThinLens) => (6, vec![[0.0, 12.0]]),
            (Test, LensMotion) => (10, vec![[0.0, 12.0], [0.0, 24.0]]),
            (Test, PhysicalLens) => (6, vec![]),
            (Quick, ThinLens) => (24, vec![[0.0, 64.0]]),
            (Quick, LensMotion) => (48, vec![[0.0, 64.0], [0.0, 192.0]]),
            (Quick, PhysicalLens) => (40, vec![]),
            (Paper, ThinLens) => (100, vec![[0.0, 255.0]]),
            (Paper, LensMotion) => (400, vec![[0.0, 127.0], [0.0, 256.0]]),
            (Paper, PhysicalLens) => (4000, vec![]),
        };
        let (rays_per_px, min_rays, max_rays, image_width_px) = match self {
            Test => (48.0, 20_000, 400_000, 480),
            Quick => (2048.0, 1_000_000, 200_000_000, 1920),
            Paper => (4096.0, 4_000_000, 1_200_000_000, 3840),
        };
        ProfileSpec {
            psf_count,
            ranges,
            rays_per_px,
            min_rays,
            max_rays,
            physical_image_width_px: image_width_px,
            betas: match (self, model) {
                // 48 PSFs instead of the paper's 400: with the paper's linear motion axis
                // (beta 1) the first motion cell would span 0-13.7 px, so every slightly moving
                // pixel got a ~7 px streak (visible on spinning objects). beta 2 makes the
                // first cells 0-1 px and 1-3.9 px; the last stays 165-192 px.
                (Quick, LensMotion) => Some(vec![2.0, 2.0]),
                _ => None,
            },
        }
    }
}

impl fmt::Display for Profile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Profile {
    type Err = PrecomputeError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "test" => Ok(Profile::Test),
            "quick" => Ok(Profile::Quick),
            "paper" => Ok(Profile::Paper),
            _ => Err(PrecomputeError::InvalidConfig(format!(
                "unknown profile '{s}' (expected test, quick or paper)"
            ))),
        }
    }
}

/// The numbers behind a [`Profile`] for one model.
#[derive(Clone, Debug, PartialEq)]
pub struct ProfileSpec {
    /// Target number of PSFs (the grid resolution is the smallest giving at least this many).
    pub psf_count: u32,
    /// Parameter ranges `[min, max]` per dimension (physical units); empty for
    /// `physical-lens`, whose ranges come from [`LensOptions`].
    pub ranges: Vec<[f64; 2]>,
    /// Rays per pixel of the PSF image (the ray count scales with the PSF's area).
    pub rays_per_px: f64,
    /// Fewest rays per PSF.
    pub min_rays: u64,
    /// Most rays per PSF.
    pub max_rays: u64,
    /// Image width of the `physical-lens` sensor, pixels.
    pub physical_image_width_px: u32,
    /// Power-remapping exponents per dimension, when the profile departs from the model's
    /// paper values ([`PsfModel::default_beta`]); recorded in the database header either way.
    pub betas: Option<Vec<f64>>,
}

/// The `physical-lens` model's lens, focus, sensor and parameter ranges.
///
/// The lens is `prescription` when given (a built-in lens or a prescription file,
/// [`optics::Prescription`]), else the biconvex singlet the `*_mm` lens fields describe.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LensOptions {
    /// A lens prescription; `None`: the singlet of the fields below.
    pub prescription: Option<Prescription>,
    /// Stops the lens down to this f-number (paraxial, focal length over entrance pupil
    /// diameter); `None`: wide open.
    pub f_stop: Option<f64>,
    /// Singlet: signed radius of the front surface, mm (> 0).
    pub radius_front_mm: f64,
    /// Singlet: signed radius of the back surface, mm (< 0).
    pub radius_back_mm: f64,
    /// Singlet: centre thickness, mm.
    pub thickness_mm: f64,
    /// Singlet: clear diameter of the lens (rim), mm.
    pub lens_diameter_mm: f64,
    /// Singlet: diameter of the aperture stop, mm.
    pub stop_diameter_mm: f64,
    /// Singlet: stop position relative to the front vertex, mm (<= 0: in front of the lens).
    pub stop_position_mm: f64,
    /// Distance in focus (from the entrance pupil), scene units.
    pub focus_distance: f64,
    /// Millimetres per scene unit.
    pub scene_unit_mm: f64,
    /// Sensor width, mm.
    pub sensor_width_mm: f64,
    /// Image width, pixels; `None` takes the profile's.
    pub image_width_px: Option<u32>,
    /// Depth range `[near, far]` sampled, scene units (from the entrance pupil).
    pub depth_range: [f64; 2],
    /// Largest eccentricity sampled, mm on the sensor.
    pub max_eccentricity_mm: f64,
    /// Pre-filter each PSF over its box's eccentricities as well as its inverse depths. Off:
    /// each is traced at the middle of its eccentricities. The runtime takes an eccentricity
    /// box's PSF for every pixel in it, turned onto the pixel's radial direction, with no blend
    /// across boxes, so a box's average stands for its ends too; a corner pixel lies at the
    /// last box's outer end, where the average over the box drew a far drop's bokeh 4-6 %
    /// wider than the lens does (traced at the middle: 2-5 %).
    #[serde(default)]
    pub prefilter_eccentricity: bool,
    /// Pre-filter every PSF over its box's inverse depths. Off: a PSF the runtime scales onto
    /// each pixel's own defocus when it blends it with the next box's
    /// ([`psf_db::ParamSpace::blend_scales_cell`]: all but those within a few boxes of the
    /// focus plane) is traced at the middle of its inverse depths, as at the middle of its
    /// eccentricities: the scaled blend gives every depth its size already, and a PSF
    /// averaged over its box as well drew a drop's rim softer than the lens does (0.6-1.3 px
    /// of blur radius per box through the double Gauss at 512 px).
    #[serde(default)]
    pub prefilter_inverse_depth: bool,
    /// Eccentricity boxes of the grid; `None` takes them from the PSF count (about `sqrt(count
    /// / 1.6)`). One box with a tiny `max_eccentricity_mm` traces a PSF on the optical axis per
    /// inverse-depth box: the runtime's rotational averages near the axis
    /// (`spreadlet::dbcache::axis_config`).
    #[serde(default)]
    pub eccentricity_boxes: Option<u32>,
}

impl Default for LensOptions {
    /// An f = 51 mm BK7 biconvex singlet at f/4.3 with its stop 15 mm in front, focused at
    /// 1 m, on a 36 mm wide sensor; depths 0.4-10 m, eccentricities up to 18 mm.
    fn default() -> Self {
        LensOptions {
            prescription: None,
            f_stop: None,
            radius_front_mm: 51.68,
            radius_back_mm: -51.68,
            thickness_mm: 6.0,
            lens_diameter_mm: 16.0,
            stop_diameter_mm: 12.0,
            stop_position_mm: -15.0,
            focus_distance: 1.0,
            scene_unit_mm: 1000.0,
            sensor_width_mm: 36.0,
            image_width_px: None,
            depth_range: [0.4, 10.0],
            max_eccentricity_mm: 18.0,
            prefilter_eccentricity: false,
            prefilter_inverse_depth: false,
            eccentricity_boxes: None,
        }
    }
}

impl LensOptions {
    /// The lens as given (wide open).
    pub fn wide_open(&self) -> Prescription {
        match &self.prescription {
            Some(p) => p.clone(),
            None => Prescription::singlet(
                self.radius_front_mm,
                self.radius_back_mm,
                self.thickness_mm,
                self.lens_diameter_mm,
                self.stop_diameter_mm,
                -self.stop_position_mm,
            ),
        }
    }

    /// The lens stopped down to [`LensOptions::f_stop`] and focused at
    /// [`LensOptions::focus_distance`] for the design wavelength.
    pub fn focused_system(&self) -> Result<LensSystem, PrecomputeError> {
        LensSystem::focused(
            self.wide_open(),
            self.f_stop,
            self.focus_distance * self.scene_unit_mm,
        )
        .map_err(|e| PrecomputeError::InvalidLens(e.to_string()))
    }

    /// Checks ranges and units.
    pub fn validate(&self) -> Result<(), PrecomputeError> {
        let bad = |m: String| Err(PrecomputeError::InvalidLens(m));
        if !(self.scene_unit_mm.is_finite() && self.scene_unit_mm > 0.0) {
            return bad(format!(
                "scene_unit_mm must be > 0, got {}",
                self.scene_unit_mm
            ));
        }
        if !(self.sensor_width_mm.is_finite() && self.sensor_width_mm > 0.0) {
            return bad(format!(
                "sensor width must be > 0 mm, got {}",
                self.sensor_width_mm
            ));
        }
        let [near, far] = self.depth_range;
        if !(near.is_finite() && far.is_finite() && near > 0.0 && near < far) {
            return bad(format!(
                "depth range must satisfy 0 < near < far, got {near}..{far}"
            ));
        }
        if !(self.focus_distance.is_finite() && self.focus_distance > 0.0) {
            return bad(format!(
                "focus distance must be > 0, got {}",
                self.focus_distance
            ));
        }
        if !(self.max_eccentricity_mm.is_finite() && self.max_eccentricity_mm > 0.0) {
            return bad(format!(
                "max eccentricity must be > 0 mm, got {}",
                self.max_eccentricity_mm
            ));
        }
        if self.image_width_px == Some(0) {
            return bad("image width must be > 0 px".into());
        }
        if self.prescription.is_none() {
            singlet_checks(self)?;
        }
        self.focused_system().map(|_| ())
    }

    /// The prescription recorded in the database header, for the focused `system`, its
    /// pinhole distance and the image width used.
    pub fn prescription(
        &self,
        system: &LensSystem,
        pinhole_distance_mm: f64,
        image_width_px: u32,
    ) -> LensPrescription {
        let design = optics::system::LAMBDA_DESIGN_UM;
        LensPrescription {
            lens: system.prescription.clone(),
            focus_distance: self.focus_distance,
            scene_unit_mm: self.scene_unit_mm,
            focal_length_mm: system.focal_length(design),
            f_number: system.f_number(design).unwrap_or(f64::NAN),
            sensor_distance_mm: system.sensor_z_mm - system.rear_vertex_z(),
            pinhole_distance_mm,
            sensor_width_mm: self.sensor_width_mm,
            image_width_px,
        }
    }
}

/// The singlet's own limits, with messages in its terms: biconvex, edge thickness > 0.
fn singlet_checks(o: &LensOptions) -> Result<(), PrecomputeError> {
    let bad = |m: &str| Err(PrecomputeError::InvalidLens(m.to_string()));
    let vals = [
        o.radius_front_mm,
        o.radius_back_mm,
        o.thickness_mm,
        o.lens_diameter_mm,
        o.stop_diameter_mm,
        o.stop_position_mm,
    ];
    if !vals.iter().all(|v| v.is_finite()) {
        return bad("non-finite singlet value");
    }
    if !(o.radius_front_mm > 0.0 && o.radius_back_mm < 0.0) {
        return bad("a biconvex lens needs radius_front > 0 and radius_back < 0");
    }
    if !(o.thickness_mm > 0.0 && o.lens_diameter_mm > 0.0 && o.stop_diameter_mm > 0.0) {
        return bad("thickness, lens diameter and stop diameter must be positive");
    }
    if o.stop_position_mm > 0.0 {
        return bad("the stop must lie in front of the lens (stop position <= 0)");
    }
    let rim = 0.5 * o.lens_diameter_mm;
    if rim >= o.radius_front_mm.min(-o.radius_back_mm) {
        return bad("the lens diameter exceeds a surface's sphere");
    }
    let sag = |r: f64| r.abs() - (r * r - rim * rim).sqrt();
    if sag(o.radius_front_mm) + sag(o.radius_back_mm) >= o.thickness_mm {
        return bad("the surfaces cross inside the lens diameter (edge thickness <= 0)");
    }
    Ok(())
}

/// The default `lambda` of [`BuildConfig::budget_tradeoff`]: 0.3, i.e. 3.3 % more spreadlets
/// (per support pixel) must buy at least 0.01 of similarity.
pub const DEFAULT_BUDGET_TRADEOFF: f32 = 0.3;

/// Everything a database build needs. Start from [`BuildConfig::new`] and change fields.
#[derive(Clone, Debug, PartialEq)]
pub struct BuildConfig {
    /// The PSF model.
    pub model: PsfModel,
    /// The profile (sample counts, ranges, rays).
    pub profile: Profile,
    /// Random seed; the same config and seed give the same bytes.
    pub seed: u64,
    /// Rays per PSF; `None` scales with the PSF's area per the profile.
    pub rays_per_psf: Option<u64>,
    /// Spreadlet density (1.0 default; 0.5 and 2.0 the paper's other operating points); the
    /// dart spacing scales with `1 / sqrt(budget)`.
    pub spreadlet_budget: f32,
    /// Pre-filter each PSF over its cell (default on).
    pub prefilter: bool,
    /// Aperture blades (0 = circular) for thin-lens and lens-motion.
    pub blades: u32,
    /// Rotation of the bladed aperture, radians.
    pub blade_rotation_rad: f32,
    /// Anamorphic squeeze of the thin-lens and lens-motion aperture: its width divided by it
    /// after the rotation (1 = round; at least 1, so the PSF stays within its CoC radius).
    pub aperture_ratio: f32,
    /// A user-drawn aperture for thin-lens and lens-motion (the blades are then ignored).
    pub aperture_mask: Option<formats::ApertureMask>,
    /// Lens for physical-lens (`None` = [`LensOptions::default`]).
    pub lens: Option<LensOptions>,
    /// Sparsification procedure (default: [`Procedure::Refit`]; [`Procedure::Paper`] for the
    /// paper's).
    pub procedure: Procedure,
    /// lens-motion: integrate the box shutter exactly per lens sample (each ray deposits its
    /// whole motion segment) instead of sampling the time like the paper (default on: the
    /// same PSFs in expectation with far less Monte Carlo noise).
    pub analytic_shutter: bool,
    /// Per-PSF density (beyond the paper): `Some(lambda)` sparsifies at budgets
    /// `spreadlet_budget * 2^(k/2)`, `k` from -3 to 4, hill-climbing from `k = 0`, and keeps
    /// the spreadlets maximising `similarity - lambda * sparsity` (so `lambda` is the
    /// similarity one spreadlet per support pixel must buy: spreadlets go where they help
    /// most, the mean similarity for a mean sparsity is maximised); `None` (the paper):
    /// one run at `spreadlet_budget`.
    pub budget_tradeoff: Option<f32>,
    /// CGLS iterations of the least-squares re-fit ([`Procedure::Refit`], `Improved`); the fit
    /// keeps each channel's sum and light and is kept only when it lowers the squared error.
    pub refit_iterations: u32,
    /// Also measure the ablation (darts / +Lloyd / +annealing / full) per PSF; slower.
    pub ablation: bool,
    /// Override the profile's PSF count target.
    pub psf_count: Option<u32>,
    /// Override the profile's parameter ranges (thin-lens, lens-motion).
    pub ranges: Option<Vec<[f64; 2]>>,
    /// A PSF is stored dense when its spreadlets exceed this fraction of its dense support.
    pub dense_ratio: f32,
    /// A PSF of at most [`Self::dense_max_support`] pixels is also stored dense when its
    /// spreadlets' similarity falls below this (small PSFs are cheap to draw directly).
    pub dense_below_similarity: f32,
    /// A PSF of at most [`Self::dense_max_support`] pixels is also stored dense when its
    /// spreadlets' L1 error (fraction of its light misplaced) exceeds this.
    pub dense_above_l1: f32,
    /// Largest dense support (pixels) the similarity and L1 rules apply to.
    pub dense_max_support: u32,
    /// A PSF whose dense support is at most this many pixels is stored dense whatever its
    /// spreadlets: up to about this size (a disc of radius 18 px) drawing its pixels on the
    /// CPU costs about what drawing its spreadlets and integrating their layer costs, and the
    /// image is the pre-filtered PSF itself, where the spreadlets approximate it. 0 leaves the
    /// choice to the other rules ([`DEFAULT_DENSE_UP_TO_SUPPORT`]; the test profile uses 0, so
    /// that its small PSFs exercise the sparse path).
    pub dense_up_to_support: u32,
}

/// [`BuildConfig::dense_up_to_support`] of the quick and paper profiles, pixels. Measured at
/// 512 x 512 against the same databases with 0 (docs/BENCHMARKS.md, "Small PSFs stored
/// dense"): the frames whose PSFs all fall under it skip integration and score as well or
/// better; larger PSFs stay sparse, where the spreadlets pay.
pub const DEFAULT_DENSE_UP_TO_SUPPORT: u32 = 1024;

impl BuildConfig {
    /// Defaults for `model` and `profile`: seed 1, rays from the profile, budget 1,
    /// pre-filtering on, circular aperture, default lens, the analytic shutter, the paper's
    /// procedure plus a least-squares re-fit ([`Procedure::Refit`]) on a per-PSF density ladder
    /// ([`DEFAULT_BUDGET_TRADEOFF`]); [`BuildConfig::paper`] gives the paper's. Stored dense
    /// up to [`DEFAULT_DENSE_UP_TO_SUPPORT`] support pixels (but in the test profile), above
    /// 0.5 spreadlets per support pixel, or, when at most 4096 px, below similarity 0.9 or
    /// above L1 0.15.
    pub fn new(model: PsfModel, profile: Profile) -> Self {
        BuildConfig {
            model,
            profile,
            seed: 1,
            rays_per_psf: None,
            spreadlet_budget: 1.0,
            prefilter: true,
            blades: 0,
            blade_rotation_rad: 0.0,
            aperture_ratio: 1.0,
            aperture_mask: None,
            lens: None,
            procedure: Procedure::default(),
            analytic_shutter: true,
            budget_tradeoff: Some(DEFAULT_BUDGET_TRADEOFF),
            refit_iterations: 40,
            ablation: false,
            psf_count: None,
            ranges: None,
            dense_ratio: 0.5,
            dense_below_similarity: 0.9,
            dense_above_l1: 0.15,
            dense_max_support: 4096,
            dense_up_to_support: match profile {
                Profile::Test => 0,
                Profile::Quick | Profile::Paper => DEFAULT_DENSE_UP_TO_SUPPORT,
            },
        }
    }

    /// [`BuildConfig::new`] with the paper's method wherever this project goes beyond it:
    /// sampled shutter time, the paper's procedure, one spreadlet budget for every PSF.
    pub fn paper(model: PsfModel, profile: Profile) -> Self {
        BuildConfig {
            analytic_shutter: false,
            procedure: Procedure::Paper,
            budget_tradeoff: None,
            ..BuildConfig::new(model, profile)
        }
    }

    /// Checks every setting; the message says which and why.
    pub fn validate(&self) -> Result<(), PrecomputeError> {
        let bad = |m: String| Err(PrecomputeError::InvalidConfig(m));
        if !(self.spreadlet_budget.is_finite()
            && self.spreadlet_budget >= 0.01
            && self.spreadlet_budget <= 100.0)
        {
            return bad(format!(
                "spreadlet budget must be in [0.01, 100], got {}",
                self.spreadlet_budget
            ));
        }
        if self.rays_per_psf == Some(0) {
            return bad("rays per PSF must be > 0".into());
        }
        if self.blades == 1 || self.blades == 2 || self.blades > 64 {
            return bad(format!(
                "blades must be 0 (circle) or 3..=64, got {}",
                self.blades
            ));
        }
        if !self.blade_rotation_rad.is_finite() {
            return bad("blade rotation must be finite".into());
        }
        if !(self.aperture_ratio.is_finite() && (1.0..=16.0).contains(&self.aperture_ratio)) {
            return bad(format!(
                "aperture ratio must lie in [1, 16], got {}",
                self.aperture_ratio
            ));
        }
        if let Some(l) = self.budget_tradeoff {
            if !(l.is_finite() && l >= 0.0) {
                return bad(format!("budget trade-off must be >= 0, got {l}"));
            }
        }
        if let Some(n) = self.psf_count {
            if n == 0 || n > 1_000_000 {
                return bad(format!("PSF count must be in 1..=1000000, got {n}"));
            }
        }
        if !(self.dense_ratio.is_finite() && self.dense_ratio >= 0.0) {
            return bad(format!(
                "dense ratio must be >= 0, got {}",
                self.dense_ratio
            ));
        }
        if let Some(r) = &self.ranges {
            if r.len() != self.model.dims() {
                return bad(format!(
                    "{} needs {} ranges, got {}",
                    self.model,
                    self.model.dims(),
                    r.len()
                ));
            }
            for &[lo, hi] in r {
                if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && lo < hi) {
                    return bad(format!("range {lo}..{hi} must satisfy 0 <= min < max"));
                }
            }
        }
        if let Some(l) = &self.lens {
            l.validate()?;
        }
        Ok(())
    }
}
