//! Light tracing of PSF images: Monte Carlo over the lens (and time, and wavelength), with the
//! PSF parameters themselves jittered over the PSF's cell (pre-filtering, paper sec. 5.4).
//!
//! A tracer maps one ray sample (uniform numbers in `[0, 1)`) and the PSF parameters `s` to the
//! point where the light lands, in pixels from the PSF origin (the pinhole image of the point),
//! with a weight per colour channel. [`trace_psf`] integrates many rays into a [`PsfImage`]
//! whose channels each sum to 1: a PSF moves light, it does not create it.

pub mod lens_motion;
pub mod physical_lens;
pub mod thin_lens;

use rand::Rng;

use crate::image::PsfImage;
use crate::prefilter::ParamBox;
use crate::sampler::KroneckerSequence;
use crate::PrecomputeError;

/// Zero pixels kept around the traced support on every side (the Laplacian needs one ring, the
/// exact integrator wants the outer ring zero).
pub const BORDER_PX: i64 = 3;

/// Largest PSF image edge accepted, pixels (offsets must fit i16 in the database).
pub const MAX_PSF_EDGE_PX: usize = 8192;

/// Where one ray lands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Offset from the PSF origin, pixels (x right, y down).
    pub offset: [f64; 2],
    /// Light carried per channel (only the first `channels()` entries are used).
    pub weight: [f64; 3],
}

/// Bounds of a PSF's support: `[x_min, x_max, y_min, y_max]`, pixels from the origin.
pub type Bounds = [f64; 4];

/// A PSF model's light tracer.
pub trait LightTracer: Sync {
    /// Colour channels (1 or 3).
    fn channels(&self) -> usize;
    /// Uniform numbers one ray needs (lens, time, wavelength).
    fn ray_dims(&self) -> usize;
    /// Bounds of the support of every PSF with parameters in `params`, pixels.
    fn bounds(&self, params: &ParamBox) -> Bounds;
    /// Traces one ray for parameters `s` (physical units) and uniform numbers `u`
    /// (`u.len() == ray_dims()`); `None` when the ray is blocked.
    fn trace(&self, s: [f64; 2], u: &[f64]) -> Option<Hit>;
    /// Length, pixels, of a uniform sweep along +x that each hit stands for (centred on the
    /// hit), integrated exactly by [`trace_psf`] instead of sampled; 0 (the default): a point.
    fn sweep_px(&self, _s: [f64; 2]) -> f64 {
        0.0
    }
}

/// What tracing one PSF gave besides the image.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TraceStats {
    /// Rays launched.
    pub rays: u64,
    /// Rays blocked inside the lens (vignetting, total internal reflection).
    pub blocked: u64,
    /// Rays that landed outside the PSF image (dropped; should be ~0).
    pub outside: u64,
}

/// How many rays a PSF gets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RayCount {
    /// Exactly this many.
    Fixed(u64),
    /// `per_px` rays per pixel of the PSF image, clamped to `[min, max]`.
    PerPixel {
        /// Rays per image pixel.
        per_px: f64,
        /// Fewest rays.
        min: u64,
        /// Most rays.
        max: u64,
    },
}

impl RayCount {
    /// The ray count for an image of `pixels` pixels.
    pub fn resolve(&self, pixels: usize) -> u64 {
        match *self {
            RayCount::Fixed(n) => n,
            RayCount::PerPixel { per_px, min, max } => {
                ((per_px * pixels as f64).ceil() as u64).clamp(min, max.max(min))
            }
        }
    }
}

/// Traces rays of `tracer` with parameters from `params` into a normalised PSF image sized
/// from the tracer's bounds. `rng` draws the sequence's random shift; `index` names the PSF
/// in errors.
pub fn trace_psf(
    tracer: &dyn LightTracer,
    params: &ParamBox,
    rays: RayCount,
    rng: &mut impl Rng,
    index: u32,
) -> Result<(PsfImage, TraceStats), PrecomputeError> {
    let bounds = tracer.bounds(params);
    let mut image = blank_image(bounds, tracer.channels())?;
    let rays = rays.resolve(image.width * image.height);
    let pd = params.jitter_dims();
    let seq = KroneckerSequence::new(pd + tracer.ray_dims(), rng);
    let mut u = vec![0.0; seq.dims()];
    let mut acc: Vec<Vec<f64>> = vec![vec![0.0; image.width * image.height]; image.channels()];
    let mut stats = TraceStats {
        rays,
        ..TraceStats::default()
    };
    let (cx, cy) = (image.centre[0] as f64, image.centre[1] as f64);
    let (w, h) = (image.width as f64, image.height as f64);
    // Per channel, `width + 1` marks per row: +density where a sweep's interior starts, -density
    // where it ends (allocated at the first sweep).
    let mut ramps: Option<Vec<Vec<f64>>> = None;
    for i in 0..rays {
        seq.sample(i, &mut u);
        let s = params.sample(&u[..pd]);
        let Some(hit) = tracer.trace(s, &u[pd..]) else {
            stats.blocked += 1;
            continue;
        };
        let sweep = tracer.sweep_px(s);
        let x = cx + hit.offset[0] + 0.5;
        let py = (cy + hit.offset[1] + 0.5).floor();
        if sweep > 0.0 && py >= 0.0 && py < h {
            let row = py as usize;
            if !deposit_segment(
                &mut acc,
                &mut ramps,
                image.width,
                row,
                x,
                sweep,
                &hit.weight,
            ) {
                stats.outside += 1;
            }
            continue;
        }
        let px = x.floor();
        if !(px >= 0.0 && py >= 0.0 && px < w && py < h) {
            stats.outside += 1;
            continue;
        }
        let k = py as usize * image.width + px as usize;
        for (c, plane) in acc.iter_mut().enumerate() {
            plane[k] += hit.weight[c];
        }
    }
    // The interiors of the swept segments: a running sum of their start and end marks.
    if let Some(ramps) = &ramps {
        let wd = image.width;
        for (plane, marks) in acc.iter_mut().zip(ramps) {
            for y in 0..image.height {
                let mut run = 0.0;
                for x in 0..wd {
                    run += marks[y * (wd + 1) + x];
                    plane[y * wd + x] += run;
                }
            }
        }
    }
    for (c, plane) in acc.iter().enumerate() {
        let sum: f64 = plane.iter().sum();
        if sum.is_nan() || sum <= 0.0 {
            return Err(PrecomputeError::EmptyPsf { index });
        }
        for (o, &v) in image.planes[c].iter_mut().zip(plane) {
            *o = (v / sum) as f32;
        }
    }
    Ok((image, stats))
}

/// Adds a uniform segment of light along row `row`: `[x - len/2, x + len/2]` in coordinates where
/// pixel `k` covers `[k, k + 1)`, carrying `weight` per channel in all. The two end pixels get
/// their exact covered fraction directly; the pixels in between through `ramps` (start and end
/// marks, summed later), so a sweep costs O(1) whatever its length. Returns false when part of
/// the segment fell outside the image (that part is dropped).
fn deposit_segment(
    acc: &mut [Vec<f64>],
    ramps: &mut Option<Vec<Vec<f64>>>,
    width: usize,
    row: usize,
    x: f64,
    len: f64,
    weight: &[f64; 3],
) -> bool {
    let (a, b) = (x - 0.5 * len, x + 0.5 * len);
    let wd = width as f64;
    let inside = a >= 0.0 && b <= wd;
    let (a, b) = (a.max(0.0), b.min(wd));
    if a.is_nan() || b.is_nan() || b <= a {
        return false;
    }
    let (ka, kb) = (a.floor() as usize, (b.floor() as usize).min(width - 1));
    let base = row * width;
    let channels = acc.len();
    let height = acc.first().map_or(0, |p| p.len() / width.max(1));
    if ka >= kb {
        for (c, plane) in acc.iter_mut().enumerate() {
            plane[base + ka] += weight[c] * (b - a) / len;
        }
        return inside;
    }
    let (fa, fb) = ((ka + 1) as f64 - a, b - kb as f64);
    for (c, plane) in acc.iter_mut().enumerate() {
        let d = weight[c] / len;
        plane[base + ka] += d * fa;
        plane[base + kb] += d * fb;
        if kb > ka + 1 {
            let m = &mut ramps
                .get_or_insert_with(|| vec![vec![0.0; (width + 1) * height]; channels])[c];
            let mrow = row * (width + 1);
            m[mrow + ka + 1] += d;
            m[mrow + kb] -= d;
        }
    }
    inside
}

/// A black image covering `bounds` plus [`BORDER_PX`] on each side.
pub fn blank_image(bounds: Bounds, channels: usize) -> Result<PsfImage, PrecomputeError> {
    if !bounds.iter().all(|b| b.is_finite()) {
        return Err(PrecomputeError::InvalidConfig(format!(
            "PSF bounds are not finite: {bounds:?}"
        )));
    }
    // Offset x falls into pixel round(x) = floor(x + 0.5) relative to the centre.
    let x_lo = (bounds[0] + 0.5).floor() as i64 - BORDER_PX;
    let x_hi = (bounds[1] + 0.5).floor() as i64 + BORDER_PX;
    let y_lo = (bounds[2] + 0.5).floor() as i64 - BORDER_PX;
    let y_hi = (bounds[3] + 0.5).floor() as i64 + BORDER_PX;
    let (x_lo, y_lo) = (x_lo.min(-BORDER_PX), y_lo.min(-BORDER_PX));
    let (x_hi, y_hi) = (x_hi.max(BORDER_PX), y_hi.max(BORDER_PX));
    let width = (x_hi - x_lo + 1) as usize;
    let height = (y_hi - y_lo + 1) as usize;
    if width > MAX_PSF_EDGE_PX || height > MAX_PSF_EDGE_PX {
        return Err(PrecomputeError::InvalidConfig(format!(
            "a PSF would be {width}x{height} px, more than {MAX_PSF_EDGE_PX} px per edge: \
             reduce the parameter ranges"
        )));
    }
    Ok(PsfImage::zeros(
        width,
        height,
        [(-x_lo) as usize, (-y_lo) as usize],
        channels,
    ))
}

/// Bounds found by tracing `n` rays (deterministic sequence) and widening the box by
/// `grow` (fraction of its size) plus `pad_px` pixels; for tracers without closed-form bounds.
pub fn pilot_bounds(
    tracer: &dyn LightTracer,
    params: &ParamBox,
    n: u64,
    grow: f64,
    pad_px: f64,
) -> Bounds {
    let pd = params.jitter_dims();
    let dims = pd + tracer.ray_dims();
    let seq = KroneckerSequence::with_shift(dims, vec![0.5; dims]);
    let mut u = vec![0.0; dims];
    let mut b = [0.0f64, 0.0, 0.0, 0.0];
    for i in 0..n {
        seq.sample(i, &mut u);
        let s = params.sample(&u[..pd]);
        if let Some(hit) = tracer.trace(s, &u[pd..]) {
            b[0] = b[0].min(hit.offset[0]);
            b[1] = b[1].max(hit.offset[0]);
            b[2] = b[2].min(hit.offset[1]);
            b[3] = b[3].max(hit.offset[1]);
        }
    }
    let gx = grow * (b[1] - b[0]) + pad_px;
    let gy = grow * (b[3] - b[2]) + pad_px;
    [b[0] - gx, b[1] + gx, b[2] - gy, b[3] + gy]
}
