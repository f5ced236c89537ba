//! Sparsification of one PSF into spreadlets (paper sec. 5.5), in the paper's order:
//!
//! 1. the 5-point Laplacian of the pre-filtered PSF ([`target`]);
//! 2. Poisson-disk dart throwing with |Laplacian| importance ([`darts`]);
//! 3. Lloyd relaxation weighted by |Laplacian| on `spade` Voronoi cells ([`lloyd`]);
//! 4. collapsing each cell into its site ([`collapse`]);
//! 5. simulated annealing of the positions on the L1 cost ([`anneal`]).
//!
//! [`Procedure::Refit`] adds a least-squares re-fit of the values ([`refit`]), kept only when it
//! lowers the L1 cost. [`ablation`] measures the L1 of the procedure's partial variants.

pub mod anneal;
pub mod collapse;
pub mod darts;
pub mod green;
pub mod lloyd;
pub mod refit;
pub mod target;
pub mod voronoi;

use rand::Rng;
use serde::{Deserialize, Serialize};

pub use collapse::Spreadlets;
pub use target::Target;

use anneal::{anneal, reconstruct, AnnealOptions};
use collapse::{collapse, round_sites};
use darts::throw_darts;
use green::Torus;
use lloyd::lloyd;

/// Which sparsification procedure to run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Procedure {
    /// The paper's: darts, Lloyd, collapse, annealing.
    Paper,
    /// The paper's steps with separate Voronoi cells for positive and negative Laplacian
    /// pixels (a cell never straddles an edge, whose two signed sides would cancel), then a
    /// least-squares re-fit of the values (kept when it lowers the L1).
    #[default]
    Improved,
}

impl Procedure {
    /// Name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Procedure::Paper => "paper",
            Procedure::Improved => "improved",
        }
    }

    /// Whether positive and negative Laplacian pixels get separate cells.
    pub fn split_signs(self) -> bool {
        self == Procedure::Improved
    }
}

impl std::str::FromStr for Procedure {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "paper" => Ok(Procedure::Paper),
            "improved" => Ok(Procedure::Improved),
            _ => Err(format!("unknown procedure '{s}' (expected paper or improved)")),
        }
    }
}

/// Settings of the sparsification.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SparsifyOptions {
    /// Spreadlet density (1 = default); dart spacing scales with `1 / sqrt(budget)`.
    pub budget: f64,
    /// Dart radius at the reference importance for budget 1, pixels.
    pub dart_spacing_px: f64,
    /// Consecutive failed darts before stopping (paper: 10,000).
    pub dart_failures: u32,
    /// Lloyd iterations (paper: 50).
    pub lloyd_iterations: u32,
    /// Annealing settings (paper: 400 steps of 1 %).
    pub anneal: AnnealOptions,
    /// Procedure.
    pub procedure: Procedure,
    /// CGLS iterations of the re-fit.
    pub refit_iterations: u32,
}

impl Default for SparsifyOptions {
    fn default() -> Self {
        SparsifyOptions {
            budget: 1.0,
            dart_spacing_px: darts::DART_SPACING_PX,
            dart_failures: 10_000,
            lloyd_iterations: 50,
            anneal: AnnealOptions::default(),
            procedure: Procedure::default(),
            refit_iterations: 40,
        }
    }
}

/// Spreadlets and their L1 error on the optimiser's integrator.
#[derive(Clone, Debug)]
pub struct Sparsified {
    /// The spreadlets (image pixel positions).
    pub spreadlets: Spreadlets,
    /// `sum_c sum_px |integrated - PSF|`.
    pub l1: f64,
}

/// L1 of the partial procedures (same darts for all), on the optimiser's integrator.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AblationL1 {
    /// Darts, collapsed.
    pub darts: f64,
    /// Darts and Lloyd, collapsed.
    pub darts_lloyd: f64,
    /// Darts, collapsed, annealed.
    pub darts_annealing: f64,
    /// Darts, Lloyd, collapsed, annealed (the paper's full procedure).
    pub full: f64,
}

/// Runs the procedure on `t`.
pub fn sparsify(t: &Target, opts: &SparsifyOptions, rng: &mut impl Rng) -> Sparsified {
    let torus = Torus::new(t.width, t.height);
    let mut sites = throw_darts(t, opts.budget, opts.dart_spacing_px, opts.dart_failures, rng);
    lloyd(t, &mut sites, opts.lloyd_iterations);
    let c = collapse(t, round_sites(&sites, t.width, t.height));
    let (s, l1) = anneal(t, &torus, c, &opts.anneal, rng);
    if opts.procedure == Procedure::Improved && !s.is_empty() {
        let r = refit::refit(t, &torus, &s, opts.refit_iterations);
        let l1r = reconstruct(&torus, &r).l1(&t.psf);
        if l1r < l1 {
            return Sparsified {
                spreadlets: r,
                l1: l1r,
            };
        }
    }
    Sparsified { spreadlets: s, l1 }
}

/// The ablation of the paper's procedure on `t`: L1 of darts only, darts + Lloyd,
/// darts + annealing and the full procedure, all from the same darts.
pub fn ablation(t: &Target, opts: &SparsifyOptions, rng: &mut impl Rng) -> AblationL1 {
    let torus = Torus::new(t.width, t.height);
    let darts = throw_darts(t, opts.budget, opts.dart_spacing_px, opts.dart_failures, rng);
    let d = collapse(t, round_sites(&darts, t.width, t.height));
    let l1_darts = reconstruct(&torus, &d.spreadlets).l1(&t.psf);
    let mut relaxed = darts.clone();
    lloyd(t, &mut relaxed, opts.lloyd_iterations);
    let l = collapse(t, round_sites(&relaxed, t.width, t.height));
    let l1_lloyd = reconstruct(&torus, &l.spreadlets).l1(&t.psf);
    let (_, l1_da) = anneal(t, &torus, d, &opts.anneal, rng);
    let (_, l1_full) = anneal(t, &torus, l, &opts.anneal, rng);
    AblationL1 {
        darts: l1_darts,
        darts_lloyd: l1_lloyd,
        darts_annealing: l1_da,
        full: l1_full,
    }
}
