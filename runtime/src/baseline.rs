//! Baselines for the study, on the same inputs and with the same PSFs as spreadlet:
//!
//! - **dense splat** (`--method dense`): every pixel's full pre-filtered PSF drawn directly,
//!   no Laplacian. It is the spreadlet pipeline itself run on a database whose every PSF is
//!   stored dense (the precompute's fast-track threshold `dense_ratio` set to 0, see
//!   [`dense_build_config`]): the precompute then stores the traced, pre-filtered PSF image
//!   instead of its spreadlets, and the pipeline's fast track draws it into each layer's direct
//!   image. Layering, soft layering, edge split, compositing and both backends stay as they are,
//!   so the only difference to spreadlet is the PSF representation: the quality upper bound of
//!   the method (the paper's SPLATTING).
//! - **filter** (`--method filter`): gathering instead of scattering (the paper's FILTERING):
//!   each output pixel looks up its own PSF (from its own depth and motion) and takes the
//!   PSF-weighted sum of the input around it, `out(x) = sum_o k_x(o) in(x - o)`. Where the PSF
//!   is the same everywhere this equals splatting exactly; at occlusion boundaries it does not
//!   (a blurred foreground does not spread over a sharp background). One layer, no compositing.
//!
//! The filter needs a dense image of every PSF: [`DenseKernels`] takes stored dense PSFs as
//! they are, and integrates sparse ones exactly (`poisson`'s lattice inverse of their
//! spreadlets); with a dense database ([`dense_build_config`]) every kernel is the pre-filtered
//! PSF itself.

use crate::synth::ms_since;
use std::time::Instant;

use poisson::{ExactIntegrator, Plane};
use precompute::BuildConfig;
use psf_db::{DatabaseBuilder, DbError, PsfDatabase};
use rayon::prelude::*;

use crate::camera::Camera;
use crate::dbcache;
use crate::dbset::DbSet;
use crate::gbuffer::GBuffer;
use crate::pipeline::classify::{classify, ClassifyError};
use crate::pipeline::{ClassifyOptions, Effects, RotationSampling, SplatPath};
use formats::RgbaImage;

/// The methods `spreadlet synth --method` and `spreadlet study` know besides the peers.
pub const METHODS: [&str; 3] = ["spreadlet", "dense", "filter"];

/// Errors of the baselines.
#[derive(Debug, thiserror::Error)]
pub enum BaselineError {
    /// Classification failed (sizes, passes, databases).
    #[error(transparent)]
    Classify(#[from] ClassifyError),
    /// A database could not be read, built or changed.
    #[error(transparent)]
    Db(#[from] DbError),
    /// The database cache failed.
    #[error(transparent)]
    Cache(#[from] dbcache::CacheError),
    /// The effects need a database and the set has none.
    #[error("the filter baseline needs a database for these effects, and none was given")]
    NoDatabase,
    /// The frame moves through a real lens, whose motion PSFs the splat builds per frame.
    #[error(
        "the filter baseline draws a real lens on still frames only; motion through it is \
         drawn by the splat (spreadlet synth)"
    )]
    MotionThroughLens,
}

/// `cfg` with every PSF stored dense: the fast-track threshold (`dense_ratio`, spreadlets per
/// support pixel above which a PSF is stored dense) set to 0. Everything else, seed included,
/// stays, so the dense PSFs are exactly the pre-filtered images the spreadlets of `cfg` are
/// fitted to.
pub fn dense_build_config(cfg: &BuildConfig) -> BuildConfig {
    let mut dense = cfg.clone();
    dense.dense_ratio = 0.0;
    dense
}

/// `cfg` with every PSF stored sparse: no fast track (the size, spreadlet ratio, similarity and
/// L1 rules of the precompute all disabled).
pub fn sparse_build_config(cfg: &BuildConfig) -> BuildConfig {
    let mut sparse = cfg.clone();
    sparse.dense_ratio = 1e6;
    sparse.dense_below_similarity = 0.0;
    sparse.dense_above_l1 = 1e9;
    sparse.dense_up_to_support = 0;
    sparse
}

/// A copy of `db` whose per-PSF statistics record no error (L1 0, similarity 1). Conditioning
/// (`condition::condition`) replaces sparse PSFs of large recorded L1 by dense analytic ones;
/// for a study of the sparse path alone that swap is unwanted.
pub fn without_recorded_error(db: &PsfDatabase) -> Result<PsfDatabase, DbError> {
    let mut header = db.header().clone();
    for s in &mut header.stats {
        s.l1 = 0.0;
        s.ssim = 1.0;
    }
    let mut builder = DatabaseBuilder::new(header);
    for i in 0..db.psf_count() {
        builder.push_copy(db, i)?;
    }
    builder.finish()
}

/// How many PSFs of `db` are stored sparse (0 for a database fit for the dense baseline).
pub fn sparse_psf_count(db: &PsfDatabase) -> usize {
    (0..db.psf_count())
        .filter(|&i| db.dense(i).is_none() && !db.spreadlets(i).0.is_empty())
        .count()
}

/// A dense image of one PSF: `width x height` pixels, `channels` values per pixel
/// (interleaved), its top-left at `origin` (pixels, relative to the PSF centre).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DenseKernel {
    /// Offset of the top-left pixel from the PSF centre, pixels (x right, y down).
    pub origin: [i32; 2],
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Values per pixel (1 grey, 3 RGB).
    pub channels: usize,
    /// Values, row-major, channel-interleaved.
    pub data: Vec<f32>,
}

/// A dense image of every PSF of a database, indexed like the database.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DenseKernels {
    /// One kernel per PSF.
    pub kernels: Vec<DenseKernel>,
    /// How many were integrated from spreadlets (the rest were stored dense).
    pub integrated: usize,
}

impl DenseKernels {
    /// The kernels of `db`: stored dense PSFs as they are; sparse PSFs integrated exactly from
    /// their spreadlets (so they carry the sparse approximation's error) and cropped where the
    /// integrated image falls below 1e-5 of its peak.
    pub fn from_db(db: &PsfDatabase) -> Self {
        let ch = db.channels();
        let mut integrated = 0;
        let kernels = (0..db.psf_count())
            .map(|i| match db.dense(i) {
                Some(d) => DenseKernel {
                    origin: d.origin,
                    width: d.width,
                    height: d.height,
                    channels: d.channels,
                    data: d.data.to_vec(),
                },
                None => {
                    let (p, v) = db.spreadlets(i);
                    if p.is_empty() {
                        DenseKernel {
                            channels: ch,
                            ..DenseKernel::default()
                        }
                    } else {
                        integrated += 1;
                        integrate_spreadlets(p, v, ch)
                    }
                }
            })
            .collect();
        Self {
            kernels,
            integrated,
        }
    }
}

/// The image whose 5-point Laplacian the spreadlets `(positions, values)` are, by the exact
/// lattice inverse, cropped to where it exceeds 1e-5 of its peak.
pub fn integrate_spreadlets(
    positions: &[[i16; 2]],
    values: &[f32],
    channels: usize,
) -> DenseKernel {
    let r = positions
        .iter()
        .map(|p| i32::from(p[0]).abs().max(i32::from(p[1]).abs()))
        .max()
        .unwrap_or(0)
        + 3;
    let n = (2 * r + 1) as usize;
    let integrator = ExactIntegrator::new(n, n);
    let planes: Vec<Plane> = (0..channels)
        .map(|c| {
            let mut lap = Plane::new(n, n);
            for (k, p) in positions.iter().enumerate() {
                let x = (i32::from(p[0]) + r) as usize;
                let y = (i32::from(p[1]) + r) as usize;
                lap.add(x, y, values[k * channels + c]);
            }
            integrator.integrate(&lap)
        })
        .collect();
    let peak = planes
        .iter()
        .flat_map(|p| p.data.iter())
        .fold(0.0f32, |m, v| m.max(v.abs()));
    let keep = |x: usize, y: usize| planes.iter().any(|p| p.get(x, y).abs() > 1e-5 * peak);
    let (mut x0, mut y0, mut x1, mut y1) = (n, n, 0, 0);
    for y in 0..n {
        for x in 0..n {
            if keep(x, y) {
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x);
                y1 = y1.max(y);
            }
        }
    }
    if x0 > x1 {
        return DenseKernel {
            channels,
            ..DenseKernel::default()
        };
    }
    let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
    let mut data = Vec::with_capacity(w * h * channels);
    for y in y0..=y1 {
        for x in x0..=x1 {
            data.extend(planes.iter().map(|p| p.get(x, y)));
        }
    }
    DenseKernel {
        origin: [x0 as i32 - r, y0 as i32 - r],
        width: w,
        height: h,
        channels,
        data,
    }
}

/// A copy of `db` with every sparse PSF replaced by [`integrate_spreadlets`] of it (for
/// `--method dense` with a database given by file that stores some PSFs sparse: the dense
/// images then carry the spreadlets' error, not the pre-filtered PSF). Returns the database and
/// how many PSFs were integrated.
pub fn densify(db: &PsfDatabase) -> Result<(PsfDatabase, usize), DbError> {
    let kernels = DenseKernels::from_db(db);
    let mut builder = DatabaseBuilder::new(db.header().clone());
    for (i, k) in kernels.kernels.iter().enumerate() {
        if db.dense(i).is_none() && k.data.is_empty() {
            builder.push_sparse(&[], &[])?;
            continue;
        }
        let clamp16 = |v: i32| v.clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16;
        builder.push_dense(
            [clamp16(k.origin[0]), clamp16(k.origin[1])],
            k.width.min(usize::from(u16::MAX)) as u16,
            k.height.min(usize::from(u16::MAX)) as u16,
            &k.data,
        )?;
    }
    Ok((builder.finish()?, kernels.integrated))
}

/// Knobs of the filter baseline.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilterOptions {
    /// A pixel whose CoC radius and motion length are both below this (pixels) keeps its own
    /// colour (as the splat path copies it).
    pub copy_threshold_px: f32,
    /// How rotated kernel offsets read the input: bilinear (the adjoint of the splat's
    /// bilinear split) or nearest.
    pub rotation: RotationSampling,
}

impl Default for FilterOptions {
    fn default() -> Self {
        Self {
            copy_threshold_px: ClassifyOptions::default().copy_threshold_px,
            rotation: RotationSampling::Bilinear,
        }
    }
}

/// What a filter run did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FilterStats {
    /// Pixels that gathered with a PSF.
    pub filtered: usize,
    /// Pixels that kept their own colour (PSF under a pixel, or empty input).
    pub copied: usize,
    /// PSF lookups clamped to the database's range.
    pub clamped: usize,
    /// Time to find every pixel's PSF, ms.
    pub classify_ms: f64,
    /// Time of the gathering, ms.
    pub filter_ms: f64,
    /// Both, ms.
    pub total_ms: f64,
}

/// The PSF a pixel gathers with in the filter baseline.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelPsf {
    /// Index of its kernel (PSF) in the database and in [`DenseKernels::kernels`].
    pub psf: u32,
    /// Cosine of the kernel's rotation (motion direction).
    pub rot_cos: f32,
    /// Sine of the kernel's rotation.
    pub rot_sin: f32,
}

/// Every pixel's kernel for the filter baseline, row-major (`None`: the pixel keeps its
/// colour), with the lookup's counts and time in the stats. The CPU ([`filter`]) and GPU
/// (`gpu::filter_gpu`) gathers share it.
pub fn filter_plan(
    gbuffer: &GBuffer,
    camera: &Camera,
    dbs: &DbSet,
    options: &FilterOptions,
) -> Result<(Vec<Option<PixelPsf>>, FilterStats), BaselineError> {
    let (w, h) = (gbuffer.width, gbuffer.height);
    let mut stats = FilterStats::default();
    let t = Instant::now();
    let effects = Effects::of(camera, gbuffer);
    // One record per non-empty pixel: one layer, no soft layering, no edge split, no blend
    // of neighbouring cells.
    let classify_options = ClassifyOptions {
        layers: 1,
        soft_layers: None,
        edge_split: false,
        continuous_lookup: false,
        // The filter gathers each pixel's PSF from the set's databases: no PSFs of the frame's own.
        smear_motion: false,
        // Each pixel gathers its own PSF, at the frame's resolution.
        reduced_resolution: false,
        few_sparse_images: false,
        copy_threshold_px: options.copy_threshold_px,
        ..ClassifyOptions::default()
    };
    let mut per_pixel: Vec<Option<PixelPsf>> = vec![None; w * h];
    if effects.cheapest_model().is_some() {
        if dbs.combined.is_none() {
            return Err(BaselineError::NoDatabase);
        }
        let classified = classify(gbuffer, camera, dbs, &classify_options)?;
        if classified.database.is_some() {
            return Err(BaselineError::MotionThroughLens);
        }
        stats.clamped = classified.counts.clamped;
        let pad = classified.frame.pad as i32;
        for r in &classified.records {
            if r.path == SplatPath::Copy as u32 {
                continue;
            }
            let (x, y) = (r.center_x - pad, r.center_y - pad);
            if x < 0 || y < 0 || x >= w as i32 || y >= h as i32 {
                continue;
            }
            per_pixel[y as usize * w + x as usize] = Some(PixelPsf {
                psf: r.psf_index,
                rot_cos: r.rot_cos,
                rot_sin: r.rot_sin,
            });
        }
    } else {
        crate::pipeline::classify::classify_sizes(gbuffer, camera)?;
    }
    stats.filtered = per_pixel.iter().filter(|p| p.is_some()).count();
    stats.copied = w * h - stats.filtered;
    stats.classify_ms = ms_since(t);
    Ok((per_pixel, stats))
}

/// The filter baseline on the CPU: every output pixel gathers the input (premultiplied RGBA)
/// with its own PSF from `kernels` (built from `dbs.combined`, see [`DenseKernels::from_db`]).
/// Colour values of RGB kernels weight R, G, B separately and alpha by their mean (as the splat
/// does). Pixels whose PSF lies under a pixel keep their colour. Where the gathered alpha
/// exceeds one, the pixel is divided by it; negative values are clamped to zero.
pub fn filter(
    gbuffer: &GBuffer,
    camera: &Camera,
    dbs: &DbSet,
    kernels: &DenseKernels,
    options: &FilterOptions,
) -> Result<(RgbaImage, FilterStats), BaselineError> {
    let total = Instant::now();
    let (w, h) = (gbuffer.width, gbuffer.height);
    let (per_pixel, mut stats) = filter_plan(gbuffer, camera, dbs, options)?;

    let t = Instant::now();
    let input = &gbuffer.color;
    let mut out = RgbaImage::new(w, h);
    out.pixels
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, px) in row.iter_mut().enumerate() {
                let i = y * w + x;
                *px = match per_pixel[i]
                    .and_then(|p| kernels.kernels.get(p.psf as usize).map(|k| (p, k)))
                {
                    Some((p, k)) if !k.data.is_empty() => {
                        gather(input, w, h, x as i32, y as i32, k, p, options.rotation)
                    }
                    _ => input[i],
                };
                if px[3] > 1.0 {
                    let inv = 1.0 / px[3];
                    *px = px.map(|v| v * inv);
                }
                *px = px.map(|v| v.max(0.0));
            }
        });
    stats.filter_ms = ms_since(t);
    stats.total_ms = ms_since(total);
    Ok((out, stats))
}

/// `sum_o k(o) in(x - R o)` for one output pixel.
#[allow(clippy::too_many_arguments)]
fn gather(
    input: &[[f32; 4]],
    w: usize,
    h: usize,
    x: i32,
    y: i32,
    k: &DenseKernel,
    p: PixelPsf,
    sampling: RotationSampling,
) -> [f32; 4] {
    let ch = k.channels;
    let identity = p.rot_cos == 1.0 && p.rot_sin == 0.0;
    let fetch = |sx: i32, sy: i32| -> [f32; 4] {
        if sx < 0 || sy < 0 || sx >= w as i32 || sy >= h as i32 {
            [0.0; 4]
        } else {
            input[sy as usize * w + sx as usize]
        }
    };
    let mut acc = [0.0f32; 4];
    for v in 0..k.height {
        let oy = k.origin[1] + v as i32;
        for u in 0..k.width {
            let at = (v * k.width + u) * ch;
            let vals = &k.data[at..at + ch];
            if vals.iter().all(|&a| a == 0.0) {
                continue;
            }
            let ox = k.origin[0] + u as i32;
            let weight = |c: [f32; 4]| -> [f32; 4] {
                match vals {
                    [g] => c.map(|a| a * g),
                    [r, gr, b] => [c[0] * r, c[1] * gr, c[2] * b, c[3] * (r + gr + b) / 3.0],
                    _ => [0.0; 4],
                }
            };
            let sample = if identity {
                fetch(x - ox, y - oy)
            } else {
                let rx = p.rot_cos * ox as f32 - p.rot_sin * oy as f32;
                let ry = p.rot_sin * ox as f32 + p.rot_cos * oy as f32;
                match sampling.for_image_space() {
                    RotationSampling::Nearest => {
                        fetch(x - rx.round() as i32, y - ry.round() as i32)
                    }
                    RotationSampling::Bilinear | RotationSampling::Bspline => {
                        // The splat puts the value at centre + r split over the four pixels
                        // around it; its adjoint reads x - r from the same four weights.
                        let (fx, fy) = (rx.floor(), ry.floor());
                        let (tx, ty) = (rx - fx, ry - fy);
                        let (bx, by) = (x - fx as i32, y - fy as i32);
                        let mut s = [0.0f32; 4];
                        for (dx, dy, wgt) in [
                            (0, 0, (1.0 - tx) * (1.0 - ty)),
                            (1, 0, tx * (1.0 - ty)),
                            (0, 1, (1.0 - tx) * ty),
                            (1, 1, tx * ty),
                        ] {
                            if wgt != 0.0 {
                                let c = fetch(bx - dx, by - dy);
                                for j in 0..4 {
                                    s[j] += wgt * c[j];
                                }
                            }
                        }
                        s
                    }
                }
            };
            let add = weight(sample);
            for j in 0..4 {
                acc[j] += add[j];
            }
        }
    }
    acc
}
