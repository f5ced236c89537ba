//! Building a whole database: for every cell of the nested grid, trace the pre-filtered PSF,
//! sparsify it, score it, and store it as spreadlets or (fast track) dense.
//!
//! PSFs are processed in parallel (rayon), each with random streams derived from the seed and
//! its index only, and pushed in index order: the same config gives the same bytes whatever the
//! thread count.

use std::time::Instant;

use psf_db::{
    Aperture, BuildInfo, DatabaseBuilder, DbHeader, LensPrescription, ParamSpace, PsfDatabase,
    PsfModel, PsfStats,
};
use rayon::prelude::*;

use crate::aperture::{ApertureShape, LensAperture};
use crate::config::BuildConfig;
use crate::image::PsfImage;
use crate::prefilter::ParamBox;
use crate::quality::{integrate_spreadlets, l1, similarity};
use crate::report::{BuildReport, PsfReport};
use crate::sampler::psf_rng;
use crate::sparsify::{ablation, sparsify, SparsifyOptions, Spreadlets, Target};
use crate::trace::lens_motion::LensMotionTracer;
use crate::trace::physical_lens::PhysicalLensTracer;
use crate::trace::thin_lens::ThinLensTracer;
use crate::trace::{trace_psf, LightTracer, RayCount};
use crate::PrecomputeError;

/// Everything fixed for a build: the space, the tracer, the settings.
pub struct BuildPlan {
    /// The settings.
    pub config: BuildConfig,
    /// The sampled parameter space.
    pub space: ParamSpace,
    /// The model's light tracer.
    pub tracer: Box<dyn LightTracer>,
    /// Rays per PSF.
    pub rays: RayCount,
    /// The lens prescription (physical-lens).
    pub lens: Option<LensPrescription>,
    /// Extra notes for the header.
    pub notes: Vec<(String, String)>,
}

impl BuildPlan {
    /// Validates `cfg` and sets up the space and tracer.
    pub fn new(cfg: &BuildConfig) -> Result<Self, PrecomputeError> {
        cfg.validate()?;
        let spec = cfg.profile.spec(cfg.model);
        let count = cfg.psf_count.unwrap_or(spec.psf_count);
        let n = ParamSpace::resolution_for_count(cfg.model.dims(), count).ok_or_else(|| {
            PrecomputeError::InvalidConfig(format!(
                "no nested grid of {} dimension(s) has {count} PSFs",
                cfg.model.dims()
            ))
        })?;
        let aperture = LensAperture {
            shape: ApertureShape::from_blades(cfg.blades, f64::from(cfg.blade_rotation_rad)),
            ratio: f64::from(cfg.aperture_ratio),
            mask: cfg
                .aperture_mask
                .clone()
                .map(|m| std::sync::Arc::new(formats::MaskSampler::new(m))),
        };
        let mut notes = vec![("procedure".to_string(), cfg.procedure.name().to_string())];
        if cfg.model == PsfModel::LensMotion {
            let shutter = if cfg.analytic_shutter {
                "analytic"
            } else {
                "sampled"
            };
            notes.push(("shutter".to_string(), shutter.to_string()));
        }
        let (space, tracer, lens): (ParamSpace, Box<dyn LightTracer>, _) = match cfg.model {
            PsfModel::ThinLens | PsfModel::LensMotion => {
                let ranges = cfg.ranges.clone().unwrap_or(spec.ranges.clone());
                let space = match &spec.betas {
                    Some(betas) => ParamSpace::new(
                        ranges
                            .iter()
                            .zip(betas)
                            .map(|(r, &beta)| psf_db::Dimension {
                                min: r[0],
                                max: r[1],
                                beta,
                            })
                            .collect(),
                        n,
                    )?,
                    None => ParamSpace::for_model(cfg.model, &ranges, n)?,
                };
                let tracer: Box<dyn LightTracer> = if cfg.model == PsfModel::ThinLens {
                    Box::new(ThinLensTracer {
                        aperture: aperture.clone(),
                    })
                } else {
                    Box::new(LensMotionTracer {
                        aperture,
                        analytic_shutter: cfg.analytic_shutter,
                    })
                };
                (space, tracer, None)
            }
            PsfModel::PhysicalLens => {
                let opts = cfg.lens.clone().unwrap_or_default();
                opts.validate()?;
                let width_px = opts.image_width_px.unwrap_or(spec.physical_image_width_px);
                let system = opts.focused_system()?;
                let mm = opts.scene_unit_mm;
                let tracer = PhysicalLensTracer::new(
                    system.clone(),
                    mm,
                    opts.sensor_width_mm / f64::from(width_px),
                    opts.focus_distance * mm,
                    [opts.depth_range[0] * mm, opts.depth_range[1] * mm],
                    opts.max_eccentricity_mm,
                )
                .map_err(|e| PrecomputeError::InvalidLens(e.to_string()))?;
                if !(tracer.pinhole_distance_mm.is_finite() && tracer.pinhole_distance_mm > 0.0) {
                    return Err(PrecomputeError::InvalidLens(
                        "the chief ray does not reach the sensor".into(),
                    ));
                }
                notes.push((
                    "pinhole_distance_mm".into(),
                    format!("{:.6}", tracer.pinhole_distance_mm),
                ));
                notes.push(("lens".into(), system.prescription.name.clone()));
                let [near, far] = opts.depth_range;
                let ranges = [[1.0 / far, 1.0 / near], [0.0, opts.max_eccentricity_mm]];
                let space = physical_lens_space(ranges, count, opts.eccentricity_boxes)?;
                let presc = opts.prescription(&system, tracer.pinhole_distance_mm, width_px);
                (space, Box::new(tracer), Some(presc))
            }
        };
        let rays = match cfg.rays_per_psf {
            Some(r) => RayCount::Fixed(r),
            None => RayCount::PerPixel {
                per_px: spec.rays_per_px,
                min: spec.min_rays,
                max: spec.max_rays,
            },
        };
        Ok(BuildPlan {
            config: cfg.clone(),
            space,
            tracer,
            rays,
            lens,
            notes,
        })
    }

    /// The pre-filter box of PSF `index`. A physical-lens PSF is traced at the middle of its
    /// eccentricities, and at the middle of its inverse depths where the runtime scales it
    /// onto each pixel's defocus ([`psf_db::ParamSpace::blend_scales_cell`]); nearer the
    /// focus plane it is pre-filtered over them
    /// ([`LensOptions::prefilter_inverse_depth`](crate::LensOptions::prefilter_inverse_depth),
    /// [`LensOptions::prefilter_eccentricity`](crate::LensOptions::prefilter_eccentricity)).
    pub fn param_box(&self, index: u32) -> Result<ParamBox, PrecomputeError> {
        let prefilter = self.config.prefilter;
        let along = match (&self.config.model, &self.config.lens) {
            (PsfModel::PhysicalLens, lens) => {
                // A physical-lens build without lens options traces the default lens.
                let default = crate::LensOptions::default();
                let lens = lens.as_ref().unwrap_or(&default);
                let scaled = lens.focus_distance > 0.0
                    && self
                        .space
                        .blend_scales_cell(index, 1.0 / lens.focus_distance);
                [
                    lens.prefilter_inverse_depth || !scaled,
                    lens.prefilter_eccentricity,
                ]
            }
            _ => [true, true],
        };
        ParamBox::for_cell_along(&self.space, index, along.map(|a| prefilter && a)).ok_or_else(
            || {
                PrecomputeError::InvalidConfig(format!(
                    "PSF {index} out of range (the space has {})",
                    self.space.psf_count()
                ))
            },
        )
    }

    /// Traces PSF `index` (deterministic for the seed).
    pub fn trace(
        &self,
        index: u32,
    ) -> Result<(PsfImage, crate::trace::TraceStats), PrecomputeError> {
        let params = self.param_box(index)?;
        let mut rng = psf_rng(self.config.seed, index, 0);
        trace_psf(self.tracer.as_ref(), &params, self.rays, &mut rng, index)
    }

    /// The sparsification settings of this build.
    pub fn sparsify_options(&self) -> SparsifyOptions {
        SparsifyOptions {
            budget: f64::from(self.config.spreadlet_budget),
            procedure: self.config.procedure,
            refit_iterations: self.config.refit_iterations,
            ..SparsifyOptions::default()
        }
    }

    /// Traces, sparsifies and scores PSF `index`.
    pub fn process(&self, index: u32) -> Result<ProcessedPsf, PrecomputeError> {
        let params = self.param_box(index)?;
        let (image, tstats) = self.trace(index)?;
        let target = Target::new(&image, self.config.procedure.split_signs());
        let opts = self.sparsify_options();
        let support = image.support();
        let candidate = match self.config.budget_tradeoff {
            None => self.candidate(&image, &target, &opts, index, 0),
            Some(lambda) => {
                // Hill-climb the density ladder from the configured budget on
                // `similarity - lambda * sparsity` (unimodal in practice).
                let score = |c: &Candidate| {
                    c.similarity
                        - f64::from(lambda) * c.spreadlets.len() as f64 / support.max(1) as f64
                };
                let mut best = self.candidate(&image, &target, &opts, index, 0);
                let mut best_score = score(&best);
                for dir in [1i32, -1] {
                    let mut k = dir;
                    let mut moved = false;
                    while (LADDER_MIN..=LADDER_MAX).contains(&k) {
                        let c = self.candidate(&image, &target, &opts, index, k);
                        let sc = score(&c);
                        if sc > best_score {
                            (best, best_score, moved) = (c, sc, true);
                            k += dir;
                        } else {
                            break;
                        }
                    }
                    if moved {
                        break;
                    }
                }
                best
            }
        };
        // A PSF only a few pixels across gets one or two Voronoi cells at any dart spacing, and
        // a cell's collapsed value is the Laplacian's sum there, about zero: it sparsifies to
        // (almost) nothing. When that leaves it poor, its exact Laplacian (small, and exact)
        // takes its place. The ladder's score cannot decide this: its sparsity term exceeds 1
        // for such PSFs and would always prefer nothing.
        let poor = candidate.similarity < EXACT_FALLBACK_BELOW_SIMILARITY
            || candidate.l1 > EXACT_FALLBACK_ABOVE_L1;
        let candidate = if poor && target.active.len() <= EXACT_FALLBACK_MAX_SPREADLETS {
            let exact = exact_candidate(&image, &target, candidate.budget);
            if exact.similarity > candidate.similarity {
                exact
            } else {
                candidate
            }
        } else {
            candidate
        };
        let Candidate {
            spreadlets: sparse,
            similarity: sim,
            l1: err,
            budget,
        } = candidate;
        let abl = if self.config.ablation {
            let mut rng = psf_rng(self.config.seed, index, 2);
            Some(ablation(&target, &opts, &mut rng))
        } else {
            None
        };
        let cfg = &self.config;
        let dense = support <= cfg.dense_up_to_support as usize
            || sparse.len() as f64 > f64::from(cfg.dense_ratio) * support as f64
            || ((sim < f64::from(cfg.dense_below_similarity)
                || err > f64::from(cfg.dense_above_l1))
                && support <= cfg.dense_max_support as usize);
        let range = params.range();
        let report = PsfReport {
            index,
            coords: params.centre(),
            box_min: [range[0][0], range[1][0]],
            box_max: [range[0][1], range[1][1]],
            image_size: [image.width, image.height],
            rays: tstats.rays,
            spreadlets: sparse.len(),
            budget,
            dense_support: support,
            sparsity: sparse.len() as f64 / support.max(1) as f64,
            similarity: sim,
            l1: err,
            dense,
            extent_px: image.extent(),
            blocked_fraction: tstats.blocked as f64 / tstats.rays.max(1) as f64,
            ablation: abl,
        };
        Ok(ProcessedPsf {
            image,
            spreadlets: sparse,
            report,
        })
    }
}

/// Largest exact Laplacian (non-zero pixels) that [`BuildPlan::process`] puts in place of a
/// poor sparsification: PSFs up to about 5 px in radius, where darts and collapse leave
/// too few cells.
const EXACT_FALLBACK_MAX_SPREADLETS: usize = 256;

/// Similarity below which [`BuildPlan::process`] tries a small PSF's exact Laplacian (the
/// default `dense_below_similarity`).
const EXACT_FALLBACK_BELOW_SIMILARITY: f64 = 0.9;

/// L1 (fraction of the PSF's light) above which [`BuildPlan::process`] tries a small PSF's
/// exact Laplacian (the default `dense_above_l1`). Similarity alone is lenient on PSFs of a
/// few pixels: a 1.5 px disk drawn by 10 spreadlets scored 0.98 at L1 0.52.
const EXACT_FALLBACK_ABOVE_L1: f64 = 0.15;

/// Every non-zero Laplacian pixel of `target` as a spreadlet: integrates back to the PSF
/// exactly (to rounding).
fn exact_candidate(image: &PsfImage, target: &Target, budget: f64) -> Candidate {
    let ch = target.channels();
    let mut spreadlets = Spreadlets {
        positions: Vec::with_capacity(target.active.len()),
        values: Vec::with_capacity(target.active.len() * ch),
        channels: ch,
    };
    for k in 0..target.active.len() {
        let [x, y] = target.active_xy(k);
        spreadlets.positions.push([x as i32, y as i32]);
        for c in 0..ch {
            spreadlets.values.push(target.active_lap(k, c));
        }
    }
    Candidate::scored(spreadlets, image, budget)
}

/// Rungs of the density ladder: budget `spreadlet_budget * 2^(k / 2)`, `k` in
/// `LADDER_MIN..=LADDER_MAX` (0.35x to 4x).
const LADDER_MIN: i32 = -3;
const LADDER_MAX: i32 = 4;

/// One sparsification of a PSF and its exact figures.
struct Candidate {
    spreadlets: Spreadlets,
    similarity: f64,
    l1: f64,
    budget: f64,
}

impl Candidate {
    /// `spreadlets` of `image`, scored by integrating them exactly.
    fn scored(spreadlets: Spreadlets, image: &PsfImage, budget: f64) -> Self {
        let recon = integrate_spreadlets(&spreadlets, image.width, image.height);
        Candidate {
            similarity: similarity(&recon, &image.planes, image.width, image.height),
            l1: l1(&recon, &image.planes),
            spreadlets,
            budget,
        }
    }
}

impl BuildPlan {
    /// Sparsifies `target` at rung `rung` of the density ladder (0 = the configured budget),
    /// with the PSF's own random stream (the same for every rung), and scores it exactly.
    fn candidate(
        &self,
        image: &PsfImage,
        target: &Target,
        opts: &SparsifyOptions,
        index: u32,
        rung: i32,
    ) -> Candidate {
        let budget = opts.budget * 2f64.powf(0.5 * f64::from(rung));
        let opts = SparsifyOptions { budget, ..*opts };
        let mut rng = psf_rng(self.config.seed, index, 1);
        Candidate::scored(sparsify(target, &opts, &mut rng).spreadlets, image, budget)
    }
}

/// The progress a build shows on stderr when asked to: an indicatif bar with the
/// `progress-bar` feature (the `precompute` binary's) on a terminal; else (a library build, or
/// stderr going to a farm job's log, where a bar draws nothing) one plain line per tenth of the
/// PSFs with the time so far, so that a build of many minutes is never silent.
struct StderrProgress {
    #[cfg(feature = "progress-bar")]
    bar: Option<indicatif::ProgressBar>,
    /// Label and PSF count of the plain lines, when they are shown.
    lines: Option<(String, u32)>,
    start: std::time::Instant,
}

impl StderrProgress {
    fn new(show: bool, total: u32, label: String) -> Self {
        let start = std::time::Instant::now();
        #[cfg(feature = "progress-bar")]
        if show && std::io::IsTerminal::is_terminal(&std::io::stderr()) {
            let bar = indicatif::ProgressBar::new(u64::from(total));
            if let Ok(style) = indicatif::ProgressStyle::with_template(
                "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} PSFs (eta {eta})",
            ) {
                bar.set_style(style);
            }
            bar.set_message(label);
            return Self {
                bar: Some(bar),
                lines: None,
                start,
            };
        }
        Self {
            #[cfg(feature = "progress-bar")]
            bar: None,
            lines: show.then_some((label, total)),
            start,
        }
    }

    /// `finished` PSFs are done (from any worker thread; each count is reported once).
    fn tick(&self, finished: u32) {
        #[cfg(feature = "progress-bar")]
        if let Some(bar) = &self.bar {
            bar.inc(1);
            return;
        }
        if let Some((label, total)) = &self.lines {
            if let Some(line) = progress_line(label, finished, *total, self.start.elapsed()) {
                eprintln!("{line}");
            }
        }
    }

    fn finish(self) {
        #[cfg(feature = "progress-bar")]
        if let Some(bar) = self.bar {
            bar.finish_and_clear();
        }
    }
}

/// The plain progress line for `finished` of `total` PSFs after `elapsed`, at every tenth of
/// them and at the last; `None` in between.
fn progress_line(
    label: &str,
    finished: u32,
    total: u32,
    elapsed: std::time::Duration,
) -> Option<String> {
    let tenth = (total / 10).max(1);
    (finished.is_multiple_of(tenth) || finished == total).then(|| {
        let s = elapsed.as_secs();
        format!(
            "{label}: {finished}/{total} PSFs, {}:{:02} min",
            s / 60,
            s % 60
        )
    })
}

/// Eccentricity boxes per inverse-depth box of the physical-lens grid: the PSF's size moves
/// with inverse depth over the whole range, its shape with eccentricity mostly towards the
/// corners, where the eccentricity axis's remapping puts its boxes.
const PHYSICAL_DEPTH_PER_ECCENTRICITY: f64 = 1.6;

/// The physical-lens space over `ranges` (inverse depth, 1 / scene units; eccentricity, mm):
/// a regular grid of about `count` boxes. Inverse depth is uniform, as the blur grows linearly
/// in it, so each box spans the same blur in pixels, near or far; eccentricity is remapped with
/// the model's beta (below 1), so boxes narrow towards the corners, where vignetting cuts the
/// cat's eye fastest. A nested grid's boxes are widest where both coordinates are large, a near
/// object in a corner: there a PSF stood for blurs 47 % apart and eccentricities 3 mm apart.
/// `eccentricity_boxes` sets the boxes across eccentricity instead.
pub fn physical_lens_space(
    ranges: [[f64; 2]; 2],
    count: u32,
    eccentricity_boxes: Option<u32>,
) -> Result<ParamSpace, psf_db::SpaceError> {
    let across = eccentricity_boxes.unwrap_or_else(|| {
        (f64::from(count) / PHYSICAL_DEPTH_PER_ECCENTRICITY)
            .sqrt()
            .round()
            .max(1.0) as u32
    });
    let across = across.clamp(1, count.max(1));
    let along = count.div_ceil(across).max(1);
    let dims = ranges
        .iter()
        .zip(PsfModel::PhysicalLens.default_beta())
        .map(|(r, &beta)| psf_db::Dimension {
            min: r[0],
            max: r[1],
            beta,
        })
        .collect();
    ParamSpace::regular(dims, [along, across])
}

/// One processed PSF.
#[derive(Clone, Debug)]
pub struct ProcessedPsf {
    /// The traced, pre-filtered PSF.
    pub image: PsfImage,
    /// Its spreadlets (image pixel positions).
    pub spreadlets: Spreadlets,
    /// Its figures.
    pub report: PsfReport,
}

/// Builds the database `cfg` describes. `progress` shows the progress over PSFs on stderr (a
/// bar with the `progress-bar` feature, else a line per tenth).
pub fn build_database(
    cfg: &BuildConfig,
    progress: bool,
) -> Result<(PsfDatabase, BuildReport), PrecomputeError> {
    build_database_part(cfg, None, progress)
}

/// Told how many of a build's PSFs are done: `(done, total)`, called from the worker threads
/// whenever `done` reaches another percent of `total` (and at `total`). Calls may come from
/// several threads at once, so two may arrive out of order.
pub type PsfProgress<'a> = &'a (dyn Fn(u32, u32) + Sync);

/// [`build_database_part`] that also reports its progress to `on_psf` (for callers that show
/// progress their own way: a GUI, a Python callback).
pub fn build_database_reporting(
    cfg: &BuildConfig,
    shard: Option<(u32, u32)>,
    progress: bool,
    on_psf: Option<PsfProgress<'_>>,
) -> Result<(PsfDatabase, BuildReport), PrecomputeError> {
    build_database_impl(cfg, shard, progress, on_psf)
}

/// Builds part `k` of `n` of the database `cfg` describes (`shard = Some((k, n))`), or the
/// whole database (`None`). A part holds the contiguous PSF range of [`psf_db::ShardRange`],
/// each PSF traced with the seed it has in a whole build, so [`psf_db::merge_shards`] of all
/// parts gives the bytes of the whole build.
pub fn build_database_part(
    cfg: &BuildConfig,
    shard: Option<(u32, u32)>,
    progress: bool,
) -> Result<(PsfDatabase, BuildReport), PrecomputeError> {
    build_database_impl(cfg, shard, progress, None)
}

fn build_database_impl(
    cfg: &BuildConfig,
    shard: Option<(u32, u32)>,
    progress: bool,
    on_psf: Option<PsfProgress<'_>>,
) -> Result<(PsfDatabase, BuildReport), PrecomputeError> {
    let start = Instant::now();
    let plan = BuildPlan::new(cfg)?;
    let range = match shard {
        Some((k, n)) => Some(psf_db::ShardRange::of(k, n, plan.space.psf_count())?),
        None => None,
    };
    let indices = range.map_or(0..plan.space.psf_count(), |r| r.indices());
    let n = indices.len() as u32;
    let bar = StderrProgress::new(progress, n, format!("{} {}", cfg.model, cfg.profile));
    let done = std::sync::atomic::AtomicU32::new(0);
    // Report at every percent, not every PSF: a callback may cost a lock or an interpreter.
    let step = (n / 100).max(1);
    let results: Vec<Result<ProcessedPsf, PrecomputeError>> = indices
        .into_par_iter()
        .map(|i| {
            let r = plan.process(i);
            let finished = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            bar.tick(finished);
            if let Some(report) = on_psf {
                if finished.is_multiple_of(step) || finished == n {
                    report(finished, n);
                }
            }
            r
        })
        .collect();
    bar.finish();

    let mut header = DbHeader::new(cfg.model, plan.space.clone(), 0);
    header.rays_per_psf = match plan.rays {
        RayCount::Fixed(r) => r,
        RayCount::PerPixel { max, .. } => max,
    };
    header.seed = cfg.seed;
    header.spreadlet_budget = cfg.spreadlet_budget;
    header.prefilter = cfg.prefilter;
    header.aperture = Aperture {
        blades: cfg.blades,
        rotation_rad: cfg.blade_rotation_rad,
        ratio: cfg.aperture_ratio,
        image_hash: cfg.aperture_mask.as_ref().map_or(0, |m| m.content_hash()),
    };
    header.lens = plan.lens.clone();
    header.shard = range;
    header.build = BuildInfo {
        profile: cfg.profile.name().into(),
        build_seconds: None,
        tool: format!("precompute {}", env!("CARGO_PKG_VERSION")),
        notes: plan.notes.clone(),
    };
    let mut builder = DatabaseBuilder::new(header);
    let mut reports = Vec::with_capacity(n as usize);
    let mut stats = Vec::with_capacity(n as usize);
    let mut resolution = 0u32;
    for r in results {
        let p = r?;
        let img = &p.image;
        resolution = resolution.max(img.width.max(img.height) as u32);
        if p.report.dense {
            push_dense(&mut builder, img)?;
        } else {
            let (cx, cy) = (img.centre[0] as i32, img.centre[1] as i32);
            let positions: Vec<[i16; 2]> = p
                .spreadlets
                .positions
                .iter()
                .map(|q| [(q[0] - cx) as i16, (q[1] - cy) as i16])
                .collect();
            let values: Vec<f32> = p.spreadlets.values.iter().map(|&v| v as f32).collect();
            builder.push_sparse(&positions, &values)?;
        }
        stats.push(PsfStats {
            coords: [p.report.coords[0] as f32, p.report.coords[1] as f32],
            spreadlets: if p.report.dense {
                0
            } else {
                p.report.spreadlets as u32
            },
            dense_support: p.report.dense_support as u32,
            l1: p.report.l1 as f32,
            ssim: p.report.similarity as f32,
            extent_px: p.report.extent_px,
        });
        reports.push(p.report);
    }
    builder.header_mut().stats = stats;
    builder.header_mut().psf_resolution = resolution;
    let db = builder.finish()?;
    let mut report = BuildReport {
        model: cfg.model.name().into(),
        profile: cfg.profile.name().into(),
        seed: cfg.seed,
        spreadlet_budget: cfg.spreadlet_budget,
        prefilter: cfg.prefilter,
        procedure: cfg.procedure.name().into(),
        grid_resolution: plan.space.n(),
        psfs: reports,
        mean_sparsity: 0.0,
        mean_similarity: 0.0,
        mean_l1: 0.0,
        sparse_stored_mean_sparsity: 0.0,
        sparse_stored_mean_similarity: 0.0,
        aggregate_cost_ratio: 0.0,
        dense_count: 0,
        stored_spreadlets: 0,
        build_seconds: 0.0,
        ablation: None,
    };
    report.summarise();
    report.build_seconds = start.elapsed().as_secs_f64();
    Ok((db, report))
}

/// Stores `img` dense, cropped to its support's bounding box.
fn push_dense(builder: &mut DatabaseBuilder, img: &PsfImage) -> Result<(), PrecomputeError> {
    let (w, h) = (img.width, img.height);
    let (mut x0, mut y0, mut x1, mut y1) = (w, h, 0, 0);
    for y in 0..h {
        for x in 0..w {
            if img.planes.iter().any(|p| p[y * w + x] != 0.0) {
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x);
                y1 = y1.max(y);
            }
        }
    }
    if x0 > x1 {
        (x0, y0, x1, y1) = (img.centre[0], img.centre[1], img.centre[0], img.centre[1]);
    }
    let (cw, chh) = (x1 - x0 + 1, y1 - y0 + 1);
    let ch = img.channels();
    let mut data = Vec::with_capacity(cw * chh * ch);
    for y in y0..=y1 {
        for x in x0..=x1 {
            for p in &img.planes {
                data.push(p[y * w + x]);
            }
        }
    }
    let origin = [
        (x0 as i64 - img.centre[0] as i64) as i16,
        (y0 as i64 - img.centre[1] as i64) as i16,
    ];
    builder.push_dense(origin, cw as u16, chh as u16, &data)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// Without a terminal a build says how far it is at every tenth of its PSFs and at its
    /// last, with the time so far, and nothing in between.
    #[test]
    fn a_plain_progress_line_comes_at_every_tenth_and_the_last() {
        let lines: Vec<(u32, String)> = (1..=45)
            .filter_map(|n| {
                progress_line(
                    "thin-lens quick",
                    n,
                    45,
                    Duration::from_secs(u64::from(n) * 7),
                )
                .map(|l| (n, l))
            })
            .collect();
        let at: Vec<u32> = lines.iter().map(|(n, _)| *n).collect();
        assert_eq!(at, [4, 8, 12, 16, 20, 24, 28, 32, 36, 40, 44, 45]);
        assert_eq!(lines[0].1, "thin-lens quick: 4/45 PSFs, 0:28 min");
        assert_eq!(lines[11].1, "thin-lens quick: 45/45 PSFs, 5:15 min");
        assert_eq!(
            progress_line("x", 1, 3, Duration::ZERO).as_deref(),
            Some("x: 1/3 PSFs, 0:00 min")
        );
    }
}
