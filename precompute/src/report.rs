//! The build report: per-PSF figures and their means (serialised to JSON by the binary).

use serde::{Deserialize, Serialize};

use crate::sparsify::AblationL1;

/// Figures of one PSF.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PsfReport {
    /// Index in the database.
    pub index: u32,
    /// Representative parameters (physical units; second 0 in 1D spaces).
    pub coords: [f64; 2],
    /// The pre-filter box, lower corner (physical units).
    pub box_min: [f64; 2],
    /// The pre-filter box, upper corner (physical units).
    pub box_max: [f64; 2],
    /// PSF image size `[width, height]`, pixels.
    pub image_size: [usize; 2],
    /// Rays traced.
    pub rays: u64,
    /// Spreadlets of the sparse representation.
    pub spreadlets: usize,
    /// Spreadlet budget (density) they were thrown with (the configured one, or the rung of
    /// the density ladder chosen, see `BuildConfig::budget_tradeoff`).
    #[serde(default)]
    pub budget: f64,
    /// Pixels of the PSF's support (non-zero pixels).
    pub dense_support: usize,
    /// `spreadlets / dense_support`.
    pub sparsity: f64,
    /// SSIM of the exactly integrated spreadlets against the pre-filtered PSF (both scaled
    /// by the PSF's maximum), mean over channels.
    pub similarity: f64,
    /// `sum_px |integrated - PSF|` (the PSF sums to 1 per channel), mean over channels.
    pub l1: f64,
    /// Stored dense (fast track) instead of as spreadlets.
    pub dense: bool,
    /// Largest distance of the support from the centre, pixels.
    pub extent_px: f32,
    /// Fraction of rays blocked in the lens (physical-lens vignetting).
    pub blocked_fraction: f64,
    /// Ablation L1 figures (optimiser's integrator), when asked for.
    pub ablation: Option<AblationL1>,
}

/// Mean ablation figures over the database, absolute and relative to darts only.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AblationReport {
    /// Mean L1 of each variant.
    pub mean_l1: AblationL1,
    /// The same, in percent of darts only (the paper: 100, 96.7, 87.1, 86.5).
    pub percent_of_darts: AblationL1,
}

/// The report of one database build.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BuildReport {
    /// Model name.
    pub model: String,
    /// Profile name.
    pub profile: String,
    /// Seed.
    pub seed: u64,
    /// Spreadlet budget.
    pub spreadlet_budget: f32,
    /// Pre-filtering on.
    pub prefilter: bool,
    /// Sparsification procedure.
    pub procedure: String,
    /// Nested-grid resolution n.
    pub grid_resolution: u32,
    /// Per PSF, in database order.
    pub psfs: Vec<PsfReport>,
    /// Mean sparsity (spreadlets / dense support) over all PSFs' sparse representations.
    pub mean_sparsity: f64,
    /// Mean similarity (SSIM) over all PSFs' sparse representations.
    pub mean_similarity: f64,
    /// Mean L1 over all PSFs' sparse representations.
    pub mean_l1: f64,
    /// Mean sparsity over the PSFs stored as spreadlets.
    pub sparse_stored_mean_sparsity: f64,
    /// Mean similarity over the PSFs stored as spreadlets.
    pub sparse_stored_mean_similarity: f64,
    /// Sum of spreadlets over the sum of dense supports, all PSFs (dense ones count their
    /// support): the splatting work relative to dense splatting, each PSF used equally often.
    pub aggregate_cost_ratio: f64,
    /// PSFs stored dense (fast track).
    pub dense_count: usize,
    /// Spreadlets stored in the database.
    pub stored_spreadlets: usize,
    /// Wall-clock build time, seconds.
    pub build_seconds: f64,
    /// Ablation, when asked for.
    pub ablation: Option<AblationReport>,
}

impl BuildReport {
    /// Fills the means from `psfs`.
    pub fn summarise(&mut self) {
        let n = self.psfs.len().max(1) as f64;
        self.mean_sparsity = self.psfs.iter().map(|p| p.sparsity).sum::<f64>() / n;
        self.mean_similarity = self.psfs.iter().map(|p| p.similarity).sum::<f64>() / n;
        self.mean_l1 = self.psfs.iter().map(|p| p.l1).sum::<f64>() / n;
        self.dense_count = self.psfs.iter().filter(|p| p.dense).count();
        let sparse: Vec<&PsfReport> = self.psfs.iter().filter(|p| !p.dense).collect();
        let k = sparse.len().max(1) as f64;
        self.sparse_stored_mean_sparsity = sparse.iter().map(|p| p.sparsity).sum::<f64>() / k;
        self.sparse_stored_mean_similarity = sparse.iter().map(|p| p.similarity).sum::<f64>() / k;
        let cost: f64 = self
            .psfs
            .iter()
            .map(|p| if p.dense { p.dense_support } else { p.spreadlets } as f64)
            .sum();
        let support: f64 = self.psfs.iter().map(|p| p.dense_support as f64).sum();
        self.aggregate_cost_ratio = cost / support.max(1.0);
        self.stored_spreadlets = self
            .psfs
            .iter()
            .filter(|p| !p.dense)
            .map(|p| p.spreadlets)
            .sum();
        let abl: Vec<AblationL1> = self.psfs.iter().filter_map(|p| p.ablation).collect();
        self.ablation = if abl.is_empty() {
            None
        } else {
            let k = abl.len() as f64;
            let mean = AblationL1 {
                darts: abl.iter().map(|a| a.darts).sum::<f64>() / k,
                darts_lloyd: abl.iter().map(|a| a.darts_lloyd).sum::<f64>() / k,
                darts_annealing: abl.iter().map(|a| a.darts_annealing).sum::<f64>() / k,
                full: abl.iter().map(|a| a.full).sum::<f64>() / k,
                refit: abl.iter().map(|a| a.refit).sum::<f64>() / k,
            };
            let pct = |v: f64| 100.0 * v / mean.darts.max(1e-300);
            Some(AblationReport {
                percent_of_darts: AblationL1 {
                    darts: 100.0,
                    darts_lloyd: pct(mean.darts_lloyd),
                    darts_annealing: pct(mean.darts_annealing),
                    full: pct(mean.full),
                    refit: pct(mean.refit),
                },
                mean_l1: mean,
            })
        };
    }
}
