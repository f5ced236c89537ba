//! Reconstruction from stochastic frames (paper sec. 6.2, "Stochastic Frame-buffers").
//!
//! Every sample already sits where its lens position and time put it. Splatting its PSF there
//! would apply the PSF twice, so each sample's PSF is centred on the sensor position the sample
//! would have had through the lens centre at the shutter centre:
//!
//! ```text
//! q0 = p - c(d) * (u, v) - m * t
//! ```
//!
//! with `p` the sample's sensor position (pixel centre plus jitter), `c(d)` the signed CoC
//! radius at its depth, `(u, v)` its unit lens position, `m` its motion (pixels per frame) and
//! `t` its time (frames from the frame time); see `docs/STOCHASTIC.md`. The samples of one
//! pixel share its weight (1 / spp). Each moved sample is spread over the pixels around `q0`
//! ([`SamplePlacement`]: at low sample counts a Gaussian footprint, so that neighbouring
//! samples overlap, stretched along the frame's edges by [`crate::edge_field`]), always with
//! its own PSF. The weights of a blurred surface's fragments are then evened out over its
//! pixels ([`crate::sample_density`]), so that where samples happened to clump counts no more
//! than where they are sparse. Layering, splatting, integration and compositing are the
//! synthesis stages, unchanged; [`normalize_density`] then divides by the coverage.

use formats::StochasticFrames;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::dbset::DbSet;
use crate::edge_field::EdgeField;
use crate::pipeline::classify::{
    classify_fragments, resolve_model, ClassifyError, DataWindow, Fragment,
};
use crate::pipeline::{Classified, ClassifyOptions, Effects, PathCounts};
use crate::prepare::{Input, Plan};
use crate::synth::{render_cpu, SynthOptions, SynthStats};
use formats::RgbaImage;

/// The effects a camera and stochastic frames call for.
pub fn effects_of(camera: &Camera, frames: &StochasticFrames) -> Effects {
    Effects {
        defocus: camera.has_lens(),
        motion: camera.has_shutter()
            && frames
                .samples
                .iter()
                .any(|s| s.motion[0] != 0.0 || s.motion[1] != 0.0),
    }
}

/// How a sample, once moved back to the lens and shutter centre, is put on the pixel grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SamplePlacement {
    /// The pixel the moved sample falls in (up to a pixel of position error).
    Nearest,
    /// Split over the four nearest pixel centres with bilinear weights, so the sample keeps its
    /// sub-pixel position; the split is steeper for a light's samples, and for every sample
    /// from [`SHARPEN_EVERY_SAMPLE_SPP`] ([`sharpened_share`]).
    Bilinear,
    /// A normalised Gaussian of standard deviation `sigma_px` (pixels) over the pixel centres
    /// around the moved sample, for samples whose own PSF is narrower than that (CoC radius
    /// below `2 sigma_px`, a disk of the same variance); [`SamplePlacement::Bilinear`] for the
    /// rest, whose PSF already spreads them. Sparse samples need a footprint that overlaps
    /// their neighbours'; giving it here rather than by widening the PSF keeps each sample's
    /// PSF lookup at its true CoC (a wider CoC moves in-focus moving samples into coarser cells
    /// of the nested grid, whose motion streaks are pre-filtered over a much wider range).
    Footprint {
        /// Standard deviation of the footprint, pixels.
        sigma_px: f32,
    },
}

/// The footprint for one sample per pixel, pixels (the best of 0.4 to 0.8 on the built-in
/// scenes at 256x256; `cargo run --release -p runtime --example recon_lab SCENE`).
pub const FOOTPRINT_SIGMA_1SPP_PX: f32 = 0.6;

/// A sample brighter than this in a channel (linear) is a light's: it gets the sharpened
/// split ([`sharpened_share`]) where others get a footprint (stretched along the image's
/// edges, [`EdgeField`]) or a bilinear split.
const BRIGHT_SAMPLE: f32 = 1.0;

/// Slope of the sharpened split ([`sharpened_share`]): 1 is bilinear, infinite the nearest
/// pixel. 2 did best of 1.5, 2, 2.5 and 3 on the built-in scenes at 4, 8 and 16 spp and on the
/// shared comets frames; 3 widened a defocused highlight's rim at 4 spp.
pub const SHARPENED_SPLIT_SLOPE: f32 = 2.0;

/// From this many samples per pixel every sample's split is sharpened, not only a light's: at
/// 4 and 8 spp the per-sample position error shows as grain on textured surfaces (SSIM
/// -0.0002 to -0.0008 on the built-in scenes), at 16 spp it averages out and every score gains.
pub const SHARPEN_EVERY_SAMPLE_SPP: usize = 16;

/// A bilinear share `t` (the sample's offset from the lower pixel centre, in `[0, 1]`)
/// sharpened: `clamp(SHARPENED_SPLIT_SLOPE (t - 1/2) + 1/2, 0, 1)`. The PSFs a sample is drawn
/// with are images of a whole pixel already; a bilinear split widens every splat again by a
/// tent (variance 1/6 px^2 per axis over a pixel's jittered samples), which softens a light's
/// rim, where FLIP's worst pixels lie. At slope 2 a sample within a quarter pixel of a centre
/// goes to that pixel alone and the rest blend linearly: the variance halves (1/12 px^2), the
/// shares still sum to one and, averaged over a pixel's uniformly jittered samples, keep
/// their mean position (the map is odd about a half); one sample's position is off by at most
/// a quarter pixel.
pub fn sharpened_share(t: f32) -> f32 {
    ((t - 0.5) * SHARPENED_SPLIT_SLOPE + 0.5).clamp(0.0, 1.0)
}

/// Standard deviation of the footprint an in-focus sample of point-sampled frames gets from 3
/// spp, pixels. Frames whose samples all lie at their pixel centres (every jitter zero, as
/// Blender's pinhole sub-renders write them) carry no pixel filter: an in-focus edge or a
/// texture comes out as the point samples' staircase, where a renderer's own frame is
/// filtered over its pixel (Cycles: a 1.5 px Blackman-Harris). 0.5 did best of 0.4 to 0.6
/// on a Cycles street at 4 and 16 spp.
pub const POINT_SAMPLE_FILTER_SIGMA_PX: f32 = 0.5;

/// Standard deviation of the bilinear (tent) footprint, pixels: sqrt(1/6).
const BILINEAR_SIGMA_PX: f32 = 0.408;

/// Widest footprint [`SamplePlacement::Footprint`] applies, pixels.
pub const MAX_FOOTPRINT_SIGMA_PX: f32 = 4.0;

/// Most footprint taps along one axis (the widest footprint needs 2 x 3.03 x 4 + 1 = 25).
const MAX_FOOTPRINT_TAPS_PER_AXIS: usize = 32;

/// Footprint taps below this fraction of the centre tap are dropped (each tap is a splat).
const FOOTPRINT_TAP_CUTOFF: f32 = 1e-2;

impl SamplePlacement {
    /// The placement for `spp` samples per pixel: a Gaussian footprint whose area shrinks as
    /// 1 / spp (sigma `FOOTPRINT_SIGMA_1SPP_PX / sqrt(spp)`), bilinear once that is no wider
    /// than bilinear's own tent.
    pub fn for_spp(spp: usize) -> Self {
        let sigma_px = FOOTPRINT_SIGMA_1SPP_PX / (spp.max(1) as f32).sqrt();
        if sigma_px <= BILINEAR_SIGMA_PX {
            SamplePlacement::Bilinear
        } else {
            SamplePlacement::Footprint { sigma_px }
        }
    }
}

/// A sample moved back to the lens centre and the shutter centre.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MovedSample {
    /// Continuous sensor position there, pixels (pixel centres at +0.5).
    pub q: [f32; 2],
    /// Signed CoC radius at the sample's depth, pixels.
    pub coc: f32,
    /// Its motion at the shutter centre, pixels per frame (zero when the frame calls for no
    /// motion blur).
    pub motion: [f32; 2],
    /// How far its path bends across the motion, px per frame squared ([`Fragment::bend`] in
    /// frame units): a spinning surface's points travel arcs.
    pub bend: f32,
    /// Planar depth at the shutter centre, scene units: the sample's own, less its surface's
    /// speed in depth times its time where that speed is known ([`crate::depth_motion`]).
    pub depth: f32,
}

impl MovedSample {
    /// The pixel of a `width x height` frame (row-major index) its position `q` falls in;
    /// `None` outside the frame.
    pub fn pixel(&self, width: usize, height: usize) -> Option<usize> {
        let (x, y) = (self.q[0].floor(), self.q[1].floor());
        (x >= 0.0 && y >= 0.0 && (x as usize) < width && (y as usize) < height)
            .then(|| y as usize * width + x as usize)
    }
}

/// Sample indices `0..keys.len()` in the order of their pixel, by a counting sort: `keys[k]`
/// is sample `k`'s pixel, or `pixels` for one that has none (it sorts last).
pub(crate) struct SamplesByPixel {
    /// Where each pixel's samples start in `order` (`pixels + 2` entries: the samples
    /// without a pixel from `starts[pixels]`).
    pub starts: Vec<usize>,
    /// The sample indices, pixel by pixel, each pixel's in the samples' order.
    pub order: Vec<u32>,
    /// Each sample's place in `order`.
    pub place: Vec<u32>,
}

impl SamplesByPixel {
    /// Sorts the samples by `keys` (each at most `pixels`). Only 4 bytes a sample move
    /// serially; what is gathered in this order can be built in parallel in its final place.
    pub(crate) fn new(keys: &[u32], pixels: usize) -> Self {
        let mut starts = vec![0usize; pixels + 2];
        for &key in keys {
            starts[key as usize + 1] += 1;
        }
        for c in 0..=pixels {
            starts[c + 1] += starts[c];
        }
        let mut fill = starts.clone();
        let mut order = vec![0u32; keys.len()];
        let mut place = vec![0u32; keys.len()];
        for (k, &key) in keys.iter().enumerate() {
            let slot = &mut fill[key as usize];
            order[*slot] = k as u32;
            place[k] = *slot as u32;
            *slot += 1;
        }
        SamplesByPixel {
            starts,
            order,
            place,
        }
    }
}

/// Every sample moved back to the lens and shutter centre (`docs/STOCHASTIC.md`), in the order
/// of `frames.samples`; `None` for a sample that carries nothing (all zero) or has a label
/// that is not finite.
pub fn moved_samples(
    frames: &StochasticFrames,
    camera: &Camera,
    effects: Effects,
) -> Vec<Option<MovedSample>> {
    moved_samples_of(frames, camera, effects, from_pinhole_sub_renders(frames))
}

/// [`moved_samples`], told whether the frames come from pinhole sub-renders
/// ([`from_pinhole_sub_renders`], a pass over every sample that [`PlacedSamples`] makes once).
fn moved_samples_of(
    frames: &StochasticFrames,
    camera: &Camera,
    effects: Effects,
    pinhole_sub_renders: bool,
) -> Vec<Option<MovedSample>> {
    let lens = camera.thin_lens();
    let field = effects.motion.then(|| PixelMotionField::of(frames));
    let bends = field.as_ref().map(PixelMotionField::bends);
    let central_differences = field.is_some() && pinhole_sub_renders;
    let depth_motion = field.as_ref().map(|field| {
        crate::depth_motion::DepthMotion::of(
            frames,
            |z| lens.map_or(0.0, |l| l.signed_coc_px(f64::from(z)) as f32),
            |pixel| field.speed(pixel),
        )
    });
    let shutter = camera.shutter_frames as f32;
    frames
        .samples
        .par_iter()
        .enumerate()
        .map(|(k, s)| {
            let pixel = k / frames.spp.max(1);
            let (px, py) = ((pixel % frames.width) as f32, (pixel / frames.width) as f32);
            if s.color == [0.0; 4] {
                return None; // carries nothing, whatever its labels
            }
            let finite = s.color.iter().all(|v| v.is_finite())
                && s.depth.is_finite()
                && s.depth > 0.0
                && s.lens
                    .iter()
                    .chain(&s.motion)
                    .chain(&s.jitter)
                    .all(|v| v.is_finite())
                && s.time.is_finite();
            if !finite {
                return None;
            }
            let coc = lens.map_or(0.0, |l| l.signed_coc_px(f64::from(s.depth)) as f32);
            let mut motion = if effects.motion { s.motion } else { [0.0; 2] };
            // A surface nearing or leaving the camera speeds up or slows down on screen.
            let nearing = depth_motion
                .as_ref()
                .and_then(|d| d.nearing(pixel, s.depth, motion));
            // Blender's labels are central differences over a frame each side: along a
            // nearing path, longer than the derivative.
            if let (Some(v), true) = (nearing, central_differences) {
                motion = crate::depth_motion::derivative_of_central_difference(motion, s.depth, v);
            }
            let along = nearing.map(|v| crate::depth_motion::path_acceleration(motion, s.depth, v));
            // The depth at the shutter centre: a nearing surface's samples then lie at one
            // depth whatever their time, so that one PSF draws them and they merge as one
            // surface (a car's samples at a quarter's difference in depth did not). A light's
            // samples keep their own, each the streak's width at its time: at the centre's,
            // a lamp's light drew faint scratches across the body beside it (why is not
            // understood; docs/BENCHMARKS.md, "A surface nearing the camera").
            let light = s.color[..3].iter().any(|&c| c > BRIGHT_SAMPLE);
            let depth = match nearing {
                Some(v) if !light => (s.depth - v * s.time).max(0.5 * s.depth),
                _ => s.depth,
            };
            // The pixel's bend is its nearest surface's: a sample of a farther one (the wall
            // seen past a spinning disc's rim) keeps its straight path.
            let mut bend = match (&field, &bends) {
                (Some(field), Some(bends)) if field.holds(pixel, s.depth) => bends[pixel],
                _ => 0.0,
            };
            if bend != 0.0 && central_differences {
                // The bend was read from the pixel's mean motion: so is its ratio.
                let speed = field.as_ref().map_or(0.0, |f| f.speed(pixel));
                let f = central_difference_speedup(bend, speed);
                motion = [motion[0] * f, motion[1] * f];
                bend *= f * f;
            }
            // Continuous sensor position (pixel centres at +0.5), moved back to the lens centre
            // and the shutter centre.
            let mut q = [
                px + 0.5 + s.jitter[0] - coc * s.lens[0] - motion[0] * s.time,
                py + 0.5 + s.jitter[1] - coc * s.lens[1] - motion[1] * s.time,
            ];
            // Along a path that speeds up, `p(t) = p0 + t m0 + t^2 a / 2`, as for a bend
            // below; then on to the middle of its stretch over the shutter, `p0 + a S^2 / 8`,
            // where the straight and even streak it is drawn with is centred.
            if let Some(a) = along {
                let t = s.time;
                let shift = 0.5 * t * t + 0.125 * shutter * shutter;
                q = [q[0] + shift * a[0], q[1] + shift * a[1]];
                motion = [motion[0] - t * a[0], motion[1] - t * a[1]];
            }
            // A light nearing or leaving the camera widens or narrows along its streak, its
            // CoC following its depth: drawn over the whole path at its own time's CoC, a
            // lamp driving at the camera came out one width, where the reference's streak
            // doubles. Such a sample draws the stratum of the path its time falls in instead,
            // along the straight path its nearing gives (a bend read from the motion field
            // there is the lamp's expansion seen across the road's and the body's motions).
            if let (Some(v), Some(a), true) = (nearing, along, light) {
                let coc_at = |z: f32| lens.map_or(0.0, |l| l.signed_coc_px(f64::from(z)) as f32);
                let stratum = LightStratum::of(s.time, s.depth, v, shutter, coc_at);
                if stratum.count > 1 {
                    (q, motion) = stratum.segment(q, motion, a, shutter);
                    bend = 0.0;
                }
            }
            // Along a bent path `p(t) = p0 + t m0 + t^2 a / 2` the label holds the motion at
            // the sample's own time, `m(t) = m0 + t a`: so `p0 = p(t) - t m(t) + t^2 a / 2`,
            // and the motion at the shutter centre is `m(t) - t a`.
            if bend != 0.0 {
                if let Some(across) = field.as_ref().and_then(|f| f.across(pixel)) {
                    let a = [bend * across[0], bend * across[1]];
                    let t = s.time;
                    q[0] += 0.5 * t * t * a[0];
                    q[1] += 0.5 * t * t * a[1];
                    motion = [motion[0] - t * a[0], motion[1] - t * a[1]];
                }
            }
            Some(MovedSample {
                q,
                coc,
                motion,
                bend,
                depth,
            })
        })
        .collect()
}

/// Largest change of a light's CoC radius (px) along the part of its streak one of its samples
/// draws ([`LightStratum`]).
pub const LIGHT_STRATUM_COC_PX: f32 = 0.5;

/// Most parts a light's streak is cut into ([`LightStratum`]).
pub const MAX_LIGHT_STRATA: u32 = 8;

/// The part of a nearing light's path over the shutter that one of its samples draws: the
/// shutter cut into `count` equal strata, so that the light's CoC changes by at most
/// [`LIGHT_STRATUM_COC_PX`] along each, and the one the sample's time falls in. Over a
/// stratum's samples (their times uniform within it) each part of the path is drawn by the
/// samples of its own time, at their own depth, so the streak widens as the light nears; its
/// light stays where it was (each sample's over its part, the parts covering the path once).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightStratum {
    /// Number of strata, at least 1 (1: the whole path).
    pub count: u32,
    /// The sample's stratum, `0..count`.
    pub index: u32,
}

impl LightStratum {
    /// The stratum of a light's sample at time `t` (frames from the shutter centre) and depth
    /// `depth`, nearing at `v` scene units per frame (its depth at time `tau` is `depth + v
    /// (tau - t)`), over a shutter of `shutter` frames, where `coc_at` gives the signed CoC
    /// radius (px) at a depth.
    pub fn of(t: f32, depth: f32, v: f32, shutter: f32, coc_at: impl Fn(f32) -> f32) -> Self {
        let at = |tau: f32| depth + v * (tau - t);
        let (start, end) = (at(-0.5 * shutter), at(0.5 * shutter));
        let whole = LightStratum { count: 1, index: 0 };
        if !(start > 0.0 && end > 0.0 && shutter > 0.0 && t.is_finite()) {
            return whole;
        }
        let change = (coc_at(end) - coc_at(start)).abs();
        if !change.is_finite() {
            return whole;
        }
        let count = ((change / LIGHT_STRATUM_COC_PX).ceil() as u32).clamp(1, MAX_LIGHT_STRATA);
        let index = (((t / shutter + 0.5) * count as f32).floor().max(0.0) as u32).min(count - 1);
        LightStratum { count, index }
    }

    /// The sample's part of the path `p(tau) = p0 + tau m0 + tau^2 a / 2` over the shutter
    /// (`tau` in frames from its centre), given the path's middle `q` (`p0 + a S^2 / 8`, the
    /// midpoint of its ends) and `m0`, px and px per frame: the part's midpoint, and the motion
    /// (px per frame) that draws it over the shutter.
    pub fn segment(
        &self,
        q: [f32; 2],
        m0: [f32; 2],
        a: [f32; 2],
        shutter: f32,
    ) -> ([f32; 2], [f32; 2]) {
        if self.count <= 1 {
            return (q, m0);
        }
        let s = shutter;
        let p0 = [q[0] - 0.125 * s * s * a[0], q[1] - 0.125 * s * s * a[1]];
        let p = |tau: f32| {
            let h = 0.5 * tau * tau;
            [
                p0[0] + tau * m0[0] + h * a[0],
                p0[1] + tau * m0[1] + h * a[1],
            ]
        };
        let width = s / self.count as f32;
        let tau0 = -0.5 * s + self.index as f32 * width;
        let (from, to) = (p(tau0), p(tau0 + width));
        (
            [0.5 * (from[0] + to[0]), 0.5 * (from[1] + to[1])],
            [(to[0] - from[0]) / s, (to[1] - from[1]) / s],
        )
    }
}

/// Whether the frames come from Blender's pinhole sub-renders
/// (`../shared/examples/comets/stochastic/README.md`), recognised by every sample lying at its
/// pixel centre (jitter zero). Such frames carry no pixel filter, and their motion labels are
/// central differences of the Vector pass over a frame on each side, `(p(t + 1) - p(t - 1)) /
/// 2`, rather than the derivative the format asks for: along a straight path the two agree,
/// along an arc the label is a chord, shorter than the path.
pub fn from_pinhole_sub_renders(frames: &StochasticFrames) -> bool {
    frames.samples.par_iter().all(|s| s.jitter == [0.0; 2])
}

/// Largest `x = |bend| / |label|` (the sine of the turn per frame) a central difference is read
/// with: towards a quarter turn a frame `asin` grows without bound, and so would the speed.
const MAX_CENTRAL_DIFFERENCE_SINE: f32 = 0.99;

/// What a central-difference motion label of a path bending by `bend` (px per frame squared,
/// read from the labels) is scaled by to give the speed along the path, for labels `speed` px
/// per frame long: over a circle of radius `R` turning `w` radians a frame the label is
/// `R sin w` long and the bend `R sin^2 w`, so `x = |bend| / speed = sin w` and the speed
/// `R w` is the label times `asin(x) / x` (the bend, `R w^2`, that squared). 1 for a straight
/// path or a still one.
pub fn central_difference_speedup(bend: f32, speed: f32) -> f32 {
    let x = bend.abs() / speed;
    if !(x > 0.0 && x.is_finite()) {
        return 1.0;
    }
    let x = x.min(MAX_CENTRAL_DIFFERENCE_SINE);
    x.asin() / x
}

/// Each pixel's motion as its nearest surface's samples hold it (their mean, and their mean
/// depth), the field whose turning bends the paths ([`crate::pipeline::classify::path_bends`]):
/// a spinning disc's samples carry the tangent at their own time, and moved back or smeared
/// along it their light leaves the disc's outline.
struct PixelMotionField {
    width: usize,
    height: usize,
    motion: Vec<[f32; 2]>,
    depth: Vec<f32>,
    coverage: Vec<[f32; 4]>,
}

/// Samples of a pixel within this relative depth of its nearest are of its nearest surface.
pub(crate) const FIELD_SAME_SURFACE_DEPTH: f32 = 0.03;

impl PixelMotionField {
    fn of(frames: &StochasticFrames) -> Self {
        let spp = frames.spp.max(1);
        let usable = |s: &&formats::Sample| {
            s.color[3] > 0.0
                && s.depth.is_finite()
                && s.depth > 0.0
                && s.motion.iter().chain([&s.time]).all(|v| v.is_finite())
        };
        let per_pixel: Vec<([f32; 2], f32, f32)> = frames
            .samples
            .par_chunks(spp)
            .map(|pixel| {
                let nearest = pixel
                    .iter()
                    .filter(usable)
                    .map(|s| s.depth)
                    .fold(f32::INFINITY, f32::min);
                if !nearest.is_finite() {
                    return ([0.0; 2], f32::INFINITY, 0.0);
                }
                let limit = nearest * (1.0 + FIELD_SAME_SURFACE_DEPTH);
                let (mut m, mut d, mut n) = ([0.0f32; 2], 0.0f32, 0.0f32);
                for s in pixel.iter().filter(usable).filter(|s| s.depth <= limit) {
                    m[0] += s.motion[0];
                    m[1] += s.motion[1];
                    d += s.depth;
                    n += 1.0;
                }
                ([m[0] / n, m[1] / n], d / n, 1.0)
            })
            .collect();
        PixelMotionField {
            width: frames.width,
            height: frames.height,
            motion: per_pixel.iter().map(|p| p.0).collect(),
            depth: per_pixel.iter().map(|p| p.1).collect(),
            coverage: per_pixel.iter().map(|p| [0.0, 0.0, 0.0, p.2]).collect(),
        }
    }

    /// Every pixel's path bend, px per frame squared.
    fn bends(&self) -> Vec<f32> {
        crate::pipeline::classify::path_bends(
            self.width,
            self.height,
            &self.motion,
            Some(&self.depth),
            &self.coverage,
        )
    }

    /// Whether a sample at `depth` in `pixel` is of the surface whose motion the field holds
    /// there.
    fn holds(&self, pixel: usize, depth: f32) -> bool {
        self.depth.get(pixel).is_some_and(|&d| {
            d.is_finite() && (depth - d).abs() <= 2.0 * FIELD_SAME_SURFACE_DEPTH * d
        })
    }

    /// The length of the pixel's motion, px per frame (0 outside the frame).
    fn speed(&self, pixel: usize) -> f32 {
        self.motion.get(pixel).map_or(0.0, |m| m[0].hypot(m[1]))
    }

    /// The unit vector a positive bend points along at `pixel`: its motion turned a quarter
    /// turn, `(-m_y, m_x) / |m|`.
    fn across(&self, pixel: usize) -> Option<[f32; 2]> {
        let m = self.motion.get(pixel)?;
        let len = m[0].hypot(m[1]);
        (len > 0.0 && len.is_finite()).then(|| [-m[1] / len, m[0] / len])
    }
}

/// The samples of stochastic frames as reconstruction places them: moved back to the lens and
/// shutter centre, with the colour they are drawn with (denoised where the frames carry
/// guides), and the pixels each is put on.
pub(crate) struct PlacedSamples<'a> {
    frames: &'a StochasticFrames,
    moved: Vec<Option<MovedSample>>,
    denoised: Option<Vec<[f32; 4]>>,
    placement: SamplePlacement,
    /// Where samples get a footprint: the image's edges, along which it is stretched.
    edges: Option<EdgeField>,
    /// Each sample's share of its pixel: 1 / spp.
    weight: f32,
    /// The shutter, frames.
    shutter: f32,
    /// Samples dropped for non-finite labels.
    pub dropped: usize,
    /// Whether every sample lies at its pixel centre (jitter zero): such frames carry no
    /// pixel filter, and their in-focus samples get one ([`POINT_SAMPLE_FILTER_SIGMA_PX`]).
    point_sampled: bool,
}

impl<'a> PlacedSamples<'a> {
    /// Moves every sample of `frames` back and denoises them where the frames carry guides.
    pub fn new(
        frames: &'a StochasticFrames,
        camera: &Camera,
        effects: Effects,
        placement: SamplePlacement,
    ) -> Self {
        let point_sampled = from_pinhole_sub_renders(frames);
        let moved = moved_samples_of(frames, camera, effects, point_sampled);
        let dropped = moved
            .par_iter()
            .zip(&frames.samples)
            .filter(|(m, s)| m.is_none() && s.color != [0.0; 4])
            .count();
        let denoised = frames
            .guides
            .as_ref()
            .map(|guides| crate::denoise::denoise_samples(frames, guides, &moved));
        let edges = match placement {
            SamplePlacement::Footprint { sigma_px } => {
                let positions: Vec<Option<[f32; 2]>> =
                    moved.iter().map(|m| m.map(|m| m.q)).collect();
                let original: Vec<[f32; 4]>;
                let colors: &[[f32; 4]] = match &denoised {
                    Some(denoised) => denoised,
                    None => {
                        original = frames.samples.iter().map(|s| s.color).collect();
                        &original
                    }
                };
                Some(EdgeField::from_samples(
                    frames.width,
                    frames.height,
                    &positions,
                    colors,
                    bounded_sigma(sigma_px),
                ))
            }
            _ => None,
        };
        PlacedSamples {
            frames,
            moved,
            denoised,
            placement,
            edges,
            weight: 1.0 / frames.spp.max(1) as f32,
            shutter: camera.shutter_frames as f32,
            dropped,
            point_sampled,
        }
    }

    /// Number of samples (placed or not).
    pub fn len(&self) -> usize {
        self.frames.samples.len()
    }

    /// Calls `tap(x, y, share)` for each pixel (column, row) sample `k` is put on, with its
    /// share of the sample; nothing for a sample that carries nothing or was dropped.
    pub fn for_each_tap(&self, k: usize, mut tap: impl FnMut(i32, i32, f32)) {
        let Some(MovedSample {
            q: [qx, qy], coc, ..
        }) = self.moved[k]
        else {
            return;
        };
        let footprint = match self.placement {
            SamplePlacement::Footprint { sigma_px } if coc.abs() < 2.0 * sigma_px => Some(sigma_px),
            SamplePlacement::Bilinear
                if self.point_sampled
                    && coc.abs() < 2.0 * POINT_SAMPLE_FILTER_SIGMA_PX
                    && !self.is_bright(k) =>
            {
                return push_footprint(qx, qy, POINT_SAMPLE_FILTER_SIGMA_PX, |x, y, share| {
                    tap(x as i32, y as i32, share)
                });
            }
            _ => None,
        };
        match (self.placement, footprint) {
            // A light's sample is split over its four pixels steeply instead (below): a
            // footprint, round or stretched along an edge, widened its rim (and stretched, its
            // light ran past the ends of its own streak).
            (_, Some(sigma_px)) if !self.is_bright(k) => match self.edges.as_ref() {
                Some(edges) => {
                    edges.push_steered(qx, qy, bounded_sigma(sigma_px), |x, y, share| {
                        tap(x as i32, y as i32, share)
                    })
                }
                None => push_footprint(qx, qy, sigma_px, |x, y, share| {
                    tap(x as i32, y as i32, share)
                }),
            },
            (SamplePlacement::Nearest, _) => tap(qx.floor() as i32, qy.floor() as i32, 1.0),
            (_, _) => {
                // Pixel (x, y) has its centre at (x + 0.5, y + 0.5).
                let (fx, fy) = (qx - 0.5, qy - 0.5);
                let (x0, y0) = (fx.floor(), fy.floor());
                let (mut tx, mut ty) = (fx - x0, fy - y0);
                if footprint.is_some() || self.sharpens_split(k) {
                    (tx, ty) = (sharpened_share(tx), sharpened_share(ty));
                }
                for (dx, dy, share) in [
                    (0.0, 0.0, (1.0 - tx) * (1.0 - ty)),
                    (1.0, 0.0, tx * (1.0 - ty)),
                    (0.0, 1.0, (1.0 - tx) * ty),
                    (1.0, 1.0, tx * ty),
                ] {
                    // Shares this small change nothing visible and cost a whole splat.
                    if share > 1e-4 {
                        tap((x0 + dx) as i32, (y0 + dy) as i32, share);
                    }
                }
            }
        }
    }

    /// What each pixel's samples that are drawn blurred (their CoC radius or half their motion
    /// over the shutter at least [`crate::sample_density::MIN_BLUR_PX`]) took from it, in pixel
    /// order ([`crate::behind_blur`]): they are moved away and drawn spread, and the pixel's
    /// other samples are all that stays on it.
    pub fn blurred_samples(&self) -> Vec<crate::behind_blur::BlurredSamples> {
        let spp = self.frames.spp.max(1);
        (0..self.frames.width * self.frames.height)
            .into_par_iter()
            .map(|p| {
                let mut out = crate::behind_blur::BlurredSamples::default();
                for k in p * spp..(p + 1) * spp {
                    let (Some(s), Some(m)) = (
                        self.frames.samples.get(k),
                        self.moved.get(k).copied().flatten(),
                    ) else {
                        continue;
                    };
                    let motion = m.motion.map(|v| v * self.shutter);
                    let blur = m.coc.abs().max(0.5 * motion[0].hypot(motion[1]));
                    if s.color[3] > 0.0 && blur >= crate::sample_density::MIN_BLUR_PX {
                        out.share += self.weight;
                        out.farthest_depth = out.farthest_depth.max(m.depth);
                        out.motion_sum =
                            [out.motion_sum[0] + motion[0], out.motion_sum[1] + motion[1]];
                        out.blur_sum += blur;
                        out.count += 1;
                    }
                }
                out
            })
            .collect()
    }

    /// Whether sample `k`'s bilinear split is sharpened ([`sharpened_share`]) with the
    /// bilinear placement (3 spp and more): for a light's sample, and for every sample from
    /// [`SHARPEN_EVERY_SAMPLE_SPP`]. (At 1 and 2 spp a light's sample that would get a
    /// footprint is split sharpened too; one drawn with its own PSF keeps the plain split,
    /// which did better on the `bokeh` scene's highlights.)
    fn sharpens_split(&self, k: usize) -> bool {
        self.placement == SamplePlacement::Bilinear
            && (self.frames.spp >= SHARPEN_EVERY_SAMPLE_SPP || self.is_bright(k))
    }

    /// Whether sample `k`'s colour (denoised where it was) exceeds [`BRIGHT_SAMPLE`] in a
    /// channel.
    fn is_bright(&self, k: usize) -> bool {
        let color = self
            .denoised
            .as_ref()
            .map_or(self.frames.samples[k].color, |d| d[k]);
        color[..3].iter().any(|&c| c > BRIGHT_SAMPLE)
    }

    /// The fragment of sample `k`'s `share` on pixel `(x, y)`.
    pub fn fragment(&self, k: usize, x: i32, y: i32, share: f32) -> Fragment {
        self.fragment_seed(k).at(x, y, share)
    }

    /// What every fragment of sample `k` shares.
    fn fragment_seed(&self, k: usize) -> FragmentSeed {
        let s = &self.frames.samples[k];
        let (motion, depth, bend) =
            self.moved[k].map_or(([0.0; 2], s.depth, 0.0), |m| (m.motion, m.depth, m.bend));
        // A blurred surface near the frame's edge is seen through the part of the lens (and
        // of the shutter) whose rays start inside the frame: fewer of its samples come back to
        // it than in the middle, and each stands for the rest.
        let inside = self.moved[k].map_or(1.0, |m| {
            inside_fraction(
                m.q,
                m.coc,
                [motion[0] * self.shutter, motion[1] * self.shutter],
                (self.frames.width, self.frames.height),
            )
        });
        FragmentSeed {
            color: self.denoised.as_ref().map_or(s.color, |d| d[k]),
            weight: self.weight / inside,
            parallax: 1.0 / depth,
            depth,
            motion: [motion[0] * self.shutter, motion[1] * self.shutter],
            // Over the shutter a path's bend scales with the shutter's square.
            bend: bend * self.shutter * self.shutter,
        }
    }

    /// [`Self::fragment_seed`] of every sample, ordered by the pixel its moved position falls
    /// in (row by row; samples that carry nothing, or land outside the frame, last, in their
    /// order), and each sample's place in that list. The merge reads a pixel's fragments
    /// together, and they come from samples moved to that pixel and its neighbours: in this
    /// order their seeds lie together, where in the samples' order a defocused frame's are a
    /// CoC apart, a cache miss each. One compact record a sample costs the merge far fewer
    /// misses again than the sample, its move and its denoised colour.
    fn fragment_seeds_by_pixel(
        &self,
        width: usize,
        height: usize,
    ) -> (Vec<FragmentSeed>, Vec<u32>) {
        let cells = width * height;
        let cell_of = |k: usize| {
            self.moved[k]
                .and_then(|m| m.pixel(width, height))
                .unwrap_or(cells)
        };
        let keys: Vec<u32> = (0..self.len())
            .into_par_iter()
            .map(|k| cell_of(k) as u32)
            .collect();
        let SamplesByPixel {
            order,
            place: slot_of,
            ..
        } = SamplesByPixel::new(&keys, cells);
        drop(keys);
        // Made in the samples' order (each sample, its move and its colour read in order), then
        // gathered: one random read a sample rather than three.
        let in_sample_order: Vec<FragmentSeed> = (0..self.len())
            .into_par_iter()
            .map(|k| self.fragment_seed(k))
            .collect();
        let seeds = order
            .par_iter()
            .map(|&k| in_sample_order[k as usize])
            .collect();
        (seeds, slot_of)
    }
}

/// The least share of a sample's lens and shutter that [`inside_fraction`] returns: a sample
/// at the frame's very edge stands for at most four.
pub const MIN_INSIDE_FRACTION: f32 = 0.25;

/// Points of the unit disc where [`inside_fraction`] places the lens: a golden-angle spiral,
/// each point the centre of an equal area.
const INSIDE_LENS_POINTS: usize = 24;

/// Times over the shutter where [`inside_fraction`] places a moving sample.
const INSIDE_TIMES: usize = 3;

/// The share of the lens and shutter whose rays, meeting a surface point that lies at
/// lens-centre and shutter-centre position `q` (pixels) with signed CoC radius `coc` (pixels)
/// and motion `path` over the shutter (pixels), start inside a `width x height` frame. A
/// sample lands at `q` from pixel `q + coc u + path t`, for lens point `u` in the unit disc and
/// time `t` in `[-1/2, 1/2]`; near the frame's edge only part of those pixels were rendered,
/// and the surface's samples there are that much sparser. 1 where the disc and path stay
/// inside; at least [`MIN_INSIDE_FRACTION`].
pub fn inside_fraction(
    q: [f32; 2],
    coc: f32,
    path: [f32; 2],
    (width, height): (usize, usize),
) -> f32 {
    let (w, h) = (width as f32, height as f32);
    let reach = [
        coc.abs() + 0.5 * path[0].abs(),
        coc.abs() + 0.5 * path[1].abs(),
    ];
    let finite = q.iter().chain(&reach).all(|v| v.is_finite());
    let clear = q[0] - reach[0] >= 0.0
        && q[0] + reach[0] <= w
        && q[1] - reach[1] >= 0.0
        && q[1] + reach[1] <= h;
    if clear || !finite {
        return 1.0;
    }
    let times = if path == [0.0; 2] { 1 } else { INSIDE_TIMES };
    let mut inside = 0usize;
    for u in inside_lens_points() {
        for j in 0..times {
            let t = (j as f32 + 0.5) / times as f32 - 0.5;
            let x = q[0] + coc * u[0] + path[0] * t;
            let y = q[1] + coc * u[1] + path[1] * t;
            inside += usize::from(x >= 0.0 && y >= 0.0 && x < w && y < h);
        }
    }
    (inside as f32 / (INSIDE_LENS_POINTS * times) as f32).max(MIN_INSIDE_FRACTION)
}

/// `pi (3 - sqrt 5)`, radians.
const GOLDEN_ANGLE: f32 = 2.399_963;

/// The lens points of [`inside_fraction`], made once: every sample near the frame's edge reads
/// them.
fn inside_lens_points() -> &'static [[f32; 2]; INSIDE_LENS_POINTS] {
    static POINTS: std::sync::OnceLock<[[f32; 2]; INSIDE_LENS_POINTS]> = std::sync::OnceLock::new();
    POINTS.get_or_init(|| {
        std::array::from_fn(|i| {
            let radius = ((i as f32 + 0.5) / INSIDE_LENS_POINTS as f32).sqrt();
            let angle = i as f32 * GOLDEN_ANGLE;
            [radius * angle.cos(), radius * angle.sin()]
        })
    })
}

/// The part of a sample's fragments that does not depend on the pixel: colour, the sample's
/// weight in the frame (`1 / spp`, over its [`inside_fraction`]), parallax and depth, motion
/// and bend over the shutter.
#[derive(Clone, Copy)]
struct FragmentSeed {
    color: [f32; 4],
    weight: f32,
    parallax: f32,
    depth: f32,
    motion: [f32; 2],
    bend: f32,
}

impl FragmentSeed {
    /// The fragment of this sample's `share` on pixel `(x, y)`.
    fn at(&self, x: i32, y: i32, share: f32) -> Fragment {
        Fragment {
            x,
            y,
            color: self.color,
            weight: self.weight * share,
            parallax: self.parallax,
            depth: self.depth,
            motion: self.motion,
            bend: self.bend,
            source: 0,
        }
    }
}

/// One fragment per finite sample (four with [`SamplePlacement::Bilinear`]), centred where the
/// lens centre at the shutter centre would have put it. Returns the fragments and the number of
/// samples dropped (non-finite labels).
pub fn sample_fragments(
    frames: &StochasticFrames,
    camera: &Camera,
    effects: Effects,
    placement: SamplePlacement,
) -> (Vec<Fragment>, usize) {
    let placed = PlacedSamples::new(frames, camera, effects, placement);
    let mut fragments = Vec::new();
    for k in 0..placed.len() {
        placed.for_each_tap(k, |x, y, share| {
            fragments.push(placed.fragment(k, x, y, share))
        });
    }
    (fragments, placed.dropped)
}

/// A footprint's standard deviation as it is drawn, pixels: a fraction of a pixel to a few
/// pixels (the clamp bounds the taps), [`FOOTPRINT_SIGMA_1SPP_PX`] for one that is not finite.
fn bounded_sigma(sigma_px: f32) -> f32 {
    if sigma_px.is_finite() {
        sigma_px.clamp(0.1, MAX_FOOTPRINT_SIGMA_PX)
    } else {
        FOOTPRINT_SIGMA_1SPP_PX
    }
}

/// Calls `push(x, y, share)` for each pixel `(x, y)` (column and row, as floats) under a
/// normalised Gaussian footprint of `sigma_px` centred at continuous sensor position
/// `(qx, qy)` (pixel centres at +0.5); the shares sum to 1. Taps under
/// [`FOOTPRINT_TAP_CUTOFF`] of the peak are left out.
fn push_footprint(qx: f32, qy: f32, sigma_px: f32, push: impl FnMut(f32, f32, f32)) {
    let sigma_px = bounded_sigma(sigma_px);
    let inv_two_var = 1.0 / (2.0 * sigma_px * sigma_px);
    let reach = sigma_px * (2.0 * (1.0 / FOOTPRINT_TAP_CUTOFF).ln()).sqrt();
    let span = |q: f32| tap_span(q, reach, MAX_FOOTPRINT_TAPS_PER_AXIS);
    let ((x0, nx), (y0, ny)) = (span(qx), span(qy));
    // The Gaussian is separable: one exponential per column and per row, not per tap.
    let axis_weights = |first: f32, count: usize, q: f32| {
        let mut weights = [0.0f32; MAX_FOOTPRINT_TAPS_PER_AXIS];
        for (i, w) in weights.iter_mut().take(count).enumerate() {
            let e = first + i as f32 + 0.5 - q;
            *w = (-e * e * inv_two_var).exp();
        }
        weights
    };
    let (wx, wy) = (axis_weights(x0, nx, qx), axis_weights(y0, ny, qy));
    let tap = |i: usize, j: usize| -> f32 {
        let w = wx[i] * wy[j];
        if w >= FOOTPRINT_TAP_CUTOFF {
            w
        } else {
            0.0
        }
    };
    push_normalized((x0, nx), (y0, ny), tap, push);
}

/// The first pixel (column or row, as a float) and the number of pixels whose centres lie
/// within `reach` of continuous position `q` (pixel centres at +0.5), at most `most`. Integer
/// counts: far from the origin (a huge but finite motion label) `x + 1.0 == x` in f32, and a
/// float loop would never end.
pub(crate) fn tap_span(q: f32, reach: f32, most: usize) -> (f32, usize) {
    let first = (q - 0.5 - reach).ceil();
    let last = (q - 0.5 + reach).floor();
    let count = if last >= first {
        ((last - first) as usize + 1).min(most)
    } else {
        0
    };
    (first, count)
}

/// Calls `push(x, y, share)` for each tap `(i, j)` of the box of columns `x0 .. x0 + nx` and
/// rows `y0 .. y0 + ny` whose weight `tap(i, j)` is positive, with the weights normalised to
/// sum to 1; nothing where they sum to zero or NaN.
pub(crate) fn push_normalized(
    (x0, nx): (f32, usize),
    (y0, ny): (f32, usize),
    tap: impl Fn(usize, usize) -> f32,
    mut push: impl FnMut(f32, f32, f32),
) {
    let total: f32 = (0..ny)
        .flat_map(|j| (0..nx).map(move |i| (i, j)))
        .map(|(i, j)| tap(i, j))
        .sum();
    if total.is_nan() || total <= 0.0 {
        return;
    }
    for j in 0..ny {
        for i in 0..nx {
            let w = tap(i, j);
            if w > 0.0 {
                push(x0 + i as f32, y0 + j as f32, w / total);
            }
        }
    }
}

/// Reconstructs depth of field and motion blur from stochastic frames with the synthesis
/// pipeline, on the CPU: [`crate::prepare::Plan`] with [`crate::prepare::Input::samples`],
/// drawn by [`crate::synth::render_cpu`]. `dbs` must hold a database of the model the camera
/// and samples call for.
///
/// ```no_run
/// use spreadlet::{Camera, Renderer, StochasticFrames, SynthOptions};
/// # fn main() -> Result<(), spreadlet::Error> {
/// let frames = StochasticFrames::read_exr("stochastic_4spp.exr".as_ref())?;
/// let camera = Camera::from_json_file("camera.json".as_ref())?;
/// let mut renderer = Renderer::new(Default::default())?;
/// renderer.reconstruct(&frames, &camera, &SynthOptions::default())?; // loads the databases
/// let dbs = renderer.databases().expect("loaded by the first frame");
/// let (image, _) = spreadlet::reconstruct(&frames, &camera, dbs, &SynthOptions::default())?;
/// image.write_exr("out.exr".as_ref())?;
/// # Ok(()) }
/// ```
pub fn reconstruct(
    frames: &StochasticFrames,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats), crate::Error> {
    let prepared = Plan::new(Input::samples(frames), camera, options)?.prepare(dbs)?;
    Ok(render_cpu(prepared, dbs))
}

/// `options` as reconstruction applies them: the coverage that "over" leaves missing is made up
/// with the colour it hid of the farther layers
/// ([`crate::pipeline::composite::CompositeOptions::restore_occluded`]), because the samples
/// already hold their visibility; and nothing is repeated beyond the frame's edge
/// ([`crate::pipeline::FrameEdges::Black`]), whose light the samples' weights make up.
pub fn for_samples(options: &SynthOptions) -> SynthOptions {
    let mut options = options.clone();
    options.composite.restore_occluded = true;
    // Samples near the frame's edge are weighted for the share of the lens and shutter that
    // reached them from inside it ([`inside_fraction`]); repeating the border's records
    // outwards as well counted that light twice (the Cycles fence's top rows 25 % too bright).
    options.classify.frame_edges = crate::pipeline::FrameEdges::Black;
    options
}

/// Reconstruction's classification: the samples moved back and classified with `effects`
/// ([`effects_of`]), and the statistics started (effects, size, options). The caller renders the
/// records and then applies [`normalize_density`].
pub(crate) fn classify_samples(
    frames: &StochasticFrames,
    camera: &Camera,
    effects: Effects,
    dbs: &DbSet,
    options: &SynthOptions,
    placement: SamplePlacement,
) -> Result<(Classified, SynthStats), ClassifyError> {
    if camera.width as usize != frames.width || camera.height as usize != frames.height {
        return Err(ClassifyError::SizeMismatch {
            cam_w: camera.width,
            cam_h: camera.height,
            img_w: frames.width,
            img_h: frames.height,
        });
    }
    let stats = SynthStats::starting(
        effects,
        (frames.width, frames.height),
        crate::gbuffer::Overscan::NONE,
        options,
    );
    let model = resolve_model(effects, dbs, options.classify.smear_motion)?;
    // Each sample's fragments merged with those of its surface on each pixel as they are
    // placed: the frame's millions of unmerged fragments are never held at once.
    let placed = PlacedSamples::new(frames, camera, effects, placement);
    // The merge names each fragment by its seed's place, not its sample: the same fragments in
    // the same order, their seeds read from memory in order.
    let (seeds, slot_of) = placed.fragment_seeds_by_pixel(frames.width, frames.height);
    let mut fragments = crate::sample_merge::merge_placed(
        frames.width,
        frames.height,
        camera,
        options.classify.hdr_dense_threshold,
        placed.len(),
        |samples, emit| {
            for k in samples {
                let slot = slot_of[k];
                placed.for_each_tap(k, |x, y, share| emit(x, y, slot, share));
            }
        },
        |x, y, slot, share| seeds[slot as usize].at(x, y, share),
    );
    // The samples' moves, colours and seeds (about 90 bytes a sample) are not needed past the
    // merge: freed before the fragments are evened out and classified, when the frame's
    // memory peaks.
    let blurred = placed.blurred_samples();
    let dropped = placed.dropped;
    drop((seeds, slot_of, placed));
    let reach = crate::sample_density::reach_px(frames.spp);
    crate::sample_density::even_out(
        &mut fragments,
        frames.width,
        frames.height,
        reach,
        crate::sample_merge::signed_coc_of(camera),
    );
    crate::behind_blur::fill_behind_blur(
        &mut fragments,
        frames.width,
        frames.height,
        reach,
        &blurred,
        crate::sample_merge::signed_coc_of(camera),
    );
    drop(blurred);
    let counts = PathCounts {
        dropped,
        ..PathCounts::default()
    };
    // Samples are not one surface per pixel: nothing to continue across the layers.
    let classify = ClassifyOptions {
        continue_layers: false,
        ..options.classify.clone()
    };
    let classified = classify_fragments(
        fragments,
        frames.width,
        frames.height,
        DataWindow::frame(frames.width, frames.height),
        camera,
        dbs,
        model,
        &classify,
        counts,
    )?;
    Ok((classified, stats))
}

/// Divides every pixel by its accumulated coverage. Samples moved back to their lens-centre
/// positions land unevenly (two in one pixel, none in its neighbour); with opaque samples the
/// coverage is the local sample density, and dividing by it is the normalisation of a
/// reconstruction filter (sum of weighted samples over sum of weights). Pixels no sample
/// reached stay as they are. Assumes the frame is opaque where samples hit something (misses
/// carry alpha 0 and do not count).
pub fn normalize_density(image: &mut RgbaImage) {
    for p in &mut image.pixels {
        let a = p[3];
        if a > 1e-3 {
            let inv = 1.0 / a;
            for v in p.iter_mut() {
                *v *= inv;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    /// The share of the lens inside the frame: all of it in the middle and for an in-focus
    /// point, half on an edge, a quarter in a corner, less beyond, never under the floor.
    #[test]
    fn the_share_of_the_lens_inside_the_frame_falls_to_half_on_its_edge() {
        let frame = (100, 80);
        let f = |q: [f32; 2], coc: f32| inside_fraction(q, coc, [0.0; 2], frame);
        assert_eq!(f([50.0, 40.0], 20.0), 1.0);
        assert_eq!(f([0.5, 0.5], 0.0), 1.0);
        let edge = f([50.0, 0.0], 10.0);
        assert!((edge - 0.5).abs() < 0.1, "{edge}");
        let inner = f([50.0, 5.0], 10.0);
        assert!(inner > edge && inner < 1.0, "{inner}");
        assert!(f([50.0, -5.0], 10.0) < edge);
        assert_eq!(f([0.0, 0.0], 10.0), MIN_INSIDE_FRACTION);
        assert_eq!(f([-50.0, 40.0], 10.0), MIN_INSIDE_FRACTION);
        // A path along the edge changes nothing; across it, its far half leaves the frame.
        let along = inside_fraction([50.0, 40.0], 0.0, [30.0, 0.0], frame);
        assert_eq!(along, 1.0);
        let across = inside_fraction([50.0, 1.0], 0.0, [0.0, 30.0], frame);
        assert!((across - 2.0 / 3.0).abs() < 0.01, "{across}");
        // Labels far beyond f32's pixel grid leave the weight alone.
        assert_eq!(f([f32::NAN, 0.0], 10.0), 1.0);
        assert_eq!(f([50.0, 40.0], f32::INFINITY), 1.0);
    }

    use super::*;
    use formats::Sample;

    /// The counting sort keeps each pixel's samples in their order, puts samples without a
    /// pixel last, and each sample's place is where `order` holds it.
    #[test]
    fn samples_sort_by_pixel_stably_with_the_pixelless_last() {
        let pixels = 4;
        let keys = [2u32, 4, 0, 2, 1, 4, 2, 0];
        let sorted = SamplesByPixel::new(&keys, pixels);
        assert_eq!(sorted.order, [2, 7, 4, 0, 3, 6, 1, 5]);
        assert_eq!(sorted.starts, [0, 2, 3, 6, 6, 8]);
        for (k, &place) in sorted.place.iter().enumerate() {
            assert_eq!(sorted.order[place as usize], k as u32);
        }
    }

    fn camera() -> Camera {
        Camera::from_json_str(
            r#"{"width":16,"height":16,"focal_length_mm":50,"sensor_width_mm":36,
            "f_stop":2.0,"focus_distance":1.0,"aperture_blades":0,"shutter_frames":1.0}"#,
        )
        .expect("camera")
    }

    /// A nearing light's strata: as many as its CoC's change over the shutter asks for, each
    /// sample in the one its time falls in, and the strata's segments laid end to end along
    /// the path from where it starts to where it ends.
    #[test]
    fn a_nearing_lights_strata_cover_its_path_once() {
        // CoC radius 2 px per scene unit nearer than 3: from 4 px to 7 px over the shutter.
        let coc_at = |z: f32| 2.0 * (3.0 - z);
        // Nearing 1.5 scene units a frame: its depth from 1.755 to 0.255 over the shutter.
        let (v, shutter) = (-1.5f32, 1.0f32);
        let first = LightStratum::of(-0.5, 1.755, v, shutter, coc_at);
        assert_eq!(first, LightStratum { count: 6, index: 0 });
        let last = LightStratum::of(0.49, 0.27, v, shutter, coc_at);
        assert_eq!(last, LightStratum { count: 6, index: 5 });
        // No change of depth: the whole path.
        assert_eq!(
            LightStratum::of(0.2, 1.0, 0.0, shutter, coc_at),
            LightStratum { count: 1, index: 0 }
        );
        // A CoC that changes by 20 px: no more than the most strata.
        assert_eq!(
            LightStratum::of(0.0, 1.0, -1.0, shutter, |z: f32| 10.0 / z).count,
            MAX_LIGHT_STRATA
        );
        // A depth that would reach the camera within the shutter: the whole path.
        assert_eq!(LightStratum::of(0.0, 0.4, -1.0, shutter, coc_at).count, 1);
        let (m0, a) = ([12.0f32, -5.0], [3.0f32, 2.0]);
        let p = |tau: f32| {
            [
                tau * m0[0] + 0.5 * tau * tau * a[0],
                tau * m0[1] + 0.5 * tau * tau * a[1],
            ]
        };
        let middle = [0.125 * a[0], 0.125 * a[1]];
        let mut end = p(-0.5);
        for index in 0..6 {
            let (q, m) = LightStratum { count: 6, index }.segment(middle, m0, a, shutter);
            let (from, to) = (
                [q[0] - 0.5 * m[0], q[1] - 0.5 * m[1]],
                [q[0] + 0.5 * m[0], q[1] + 0.5 * m[1]],
            );
            for c in 0..2 {
                assert!(
                    (from[c] - end[c]).abs() < 1e-4,
                    "stratum {index} starts at {from:?}, not {end:?}"
                );
            }
            end = to;
        }
        for c in 0..2 {
            assert!(
                (end[c] - p(0.5)[c]).abs() < 1e-4,
                "the last stratum ends at {end:?}"
            );
        }
    }

    /// The sharpened split keeps the bilinear split's sum and, over a pixel's uniformly
    /// jittered samples, its mean position, with half its spread; a quarter pixel from a
    /// centre it is that pixel alone.
    #[test]
    fn the_sharpened_split_keeps_the_mean_position_and_halves_the_spread() {
        assert_eq!(sharpened_share(0.0), 0.0);
        assert_eq!(sharpened_share(0.2), 0.0);
        assert_eq!(sharpened_share(0.5), 0.5);
        assert_eq!(sharpened_share(0.8), 1.0);
        assert_eq!(sharpened_share(1.0), 1.0);
        let n = 100_000;
        let (mut mean, mut spread, mut bilinear_spread) = (0.0f64, 0.0f64, 0.0f64);
        for i in 0..n {
            let t = (i as f32 + 0.5) / n as f32;
            let share = f64::from(sharpened_share(t));
            // Weights (1 - share, share) on the pixels at 0 and 1: mean `share`, variance
            // share (1 - share).
            mean += share;
            spread += share * (1.0 - share);
            bilinear_spread += f64::from(t) * (1.0 - f64::from(t));
        }
        let (mean, spread, bilinear_spread) = (
            mean / n as f64,
            spread / n as f64,
            bilinear_spread / n as f64,
        );
        assert!((mean - 0.5).abs() < 1e-6, "mean {mean}");
        assert!((spread - 1.0 / 12.0).abs() < 1e-4, "spread {spread}");
        assert!(
            (bilinear_spread - 1.0 / 6.0).abs() < 1e-4,
            "bilinear {bilinear_spread}"
        );
    }

    /// The fragments of one still, in-focus sample 0.2 px right of and below its pixel's
    /// centre, with the bilinear placement: a light's goes to its pixel alone, a dim one's is
    /// split over four pixels below 16 spp and, sharpened, over that pixel alone from 16 spp.
    #[test]
    fn a_lights_samples_and_every_sample_from_16_spp_split_sharper() {
        let cam = camera();
        let taps = |spp: usize, color: f32| {
            let mut frames = StochasticFrames::new(16, 16, spp, vec![Sample::default(); 256 * spp]);
            frames.samples[(7 * 16 + 5) * spp] = Sample {
                color: [color, color, color, 1.0],
                depth: 1.0, // the focus distance: no blur
                jitter: [0.2, 0.2],
                ..Sample::default()
            };
            let effects = effects_of(&cam, &frames);
            let (fragments, _) =
                sample_fragments(&frames, &cam, effects, SamplePlacement::Bilinear);
            let total: f32 = fragments.iter().map(|f| f.weight).sum();
            assert!((total - 1.0 / spp as f32).abs() < 1e-6, "{total}");
            let mut pixels: Vec<(i32, i32)> = fragments.iter().map(|f| (f.x, f.y)).collect();
            pixels.sort_unstable();
            pixels
        };
        assert_eq!(taps(4, 5.0), vec![(5, 7)]);
        assert_eq!(taps(4, 0.5), vec![(5, 7), (5, 8), (6, 7), (6, 8)]);
        assert_eq!(taps(8, 0.5).len(), 4);
        assert_eq!(taps(16, 0.5), vec![(5, 7)]);
    }

    /// At 1 spp an in-focus sample gets a footprint over the pixels round it, but a light's
    /// gets the sharpened split: 0.2 px from its pixel's centre, that pixel alone.
    #[test]
    fn a_lights_in_focus_sample_at_1_spp_is_split_not_spread() {
        let cam = camera();
        let taps = |color: f32| {
            let mut frames = StochasticFrames::new(16, 16, 1, vec![Sample::default(); 256]);
            frames.samples[7 * 16 + 5] = Sample {
                color: [color, color, color, 1.0],
                depth: 1.0,
                jitter: [0.2, 0.2],
                ..Sample::default()
            };
            let effects = effects_of(&cam, &frames);
            let placement = SamplePlacement::for_spp(1);
            assert!(matches!(placement, SamplePlacement::Footprint { .. }));
            let (fragments, _) = sample_fragments(&frames, &cam, effects, placement);
            let total: f32 = fragments.iter().map(|f| f.weight).sum();
            assert!((total - 1.0).abs() < 1e-5, "{total}");
            fragments.len()
        };
        assert_eq!(taps(5.0), 1);
        assert!(taps(0.5) >= 4, "a dim sample keeps its footprint");
    }

    /// A sample displaced by its lens offset and motion lands back on its pinhole pixel.
    #[test]
    fn samples_are_moved_back_to_the_lens_and_shutter_centre() {
        let cam = camera();
        let lens = cam.thin_lens().expect("lens");
        let depth = 2.0f32;
        let coc = lens.signed_coc_px(f64::from(depth)) as f32;
        let (qx, qy) = (5.5f32, 7.5f32); // pinhole position at t = 0: pixel (5, 7)
        let (u, v, t, m) = (0.6f32, -0.3f32, 0.25f32, [8.0f32, -4.0f32]);
        let (sx, sy) = (qx + coc * u + m[0] * t, qy + coc * v + m[1] * t);
        let (x, y) = (sx.floor() as usize, sy.floor() as usize);
        let mut frames = StochasticFrames::new(16, 16, 1, vec![Sample::default(); 256]);
        frames.samples[y * 16 + x] = Sample {
            color: [1.0; 4],
            depth,
            lens: [u, v],
            time: t,
            motion: m,
            jitter: [sx - x as f32 - 0.5, sy - y as f32 - 0.5],
        };
        let effects = effects_of(&cam, &frames);
        assert!(effects.defocus && effects.motion);
        let (fragments, dropped) =
            sample_fragments(&frames, &cam, effects, SamplePlacement::Nearest);
        assert_eq!(dropped, 0);
        assert_eq!(fragments.len(), 1);
        assert_eq!((fragments[0].x, fragments[0].y), (5, 7));
        assert_eq!(fragments[0].motion, m); // shutter 1 frame
    }

    /// A defocused, moving wall at 4 spp: each pixel receives its neighbours' bilinear shares
    /// (about 16 fragments), and merging leaves one per pixel of the wall and the margin round
    /// it, with the light kept (the wall is dim enough that no pixel's merged fragment becomes
    /// bright where the samples pile up).
    #[test]
    fn samples_of_one_surface_merge_to_one_fragment_per_pixel() {
        let cam = camera();
        let spp = 4;
        let mut samples = Vec::new();
        for k in 0..16 * 16 * spp {
            let j = k as f32;
            samples.push(Sample {
                color: [0.2, 0.1, 0.4, 1.0],
                depth: 1.5,
                lens: [(j * 0.37).sin() * 0.7, (j * 0.53).cos() * 0.7],
                time: (j * 0.11).sin() * 0.5,
                motion: [3.0, 1.0],
                jitter: [(j * 0.71).sin() * 0.5, (j * 0.29).cos() * 0.5],
            });
        }
        let frames = StochasticFrames::new(16, 16, spp, samples);
        let effects = effects_of(&cam, &frames);
        let (fragments, _) = sample_fragments(&frames, &cam, effects, SamplePlacement::Bilinear);
        assert!(fragments.len() > 3 * 16 * 16 * spp, "{}", fragments.len());
        let merged = crate::sample_merge::merge_alike(&fragments, 16, 16, &cam, 2.0);
        let pixels: std::collections::HashSet<(i32, i32)> =
            fragments.iter().map(|f| (f.x, f.y)).collect();
        assert_eq!(merged.len(), pixels.len());
        let light =
            |fs: &[Fragment]| -> f64 { fs.iter().map(|f| f64::from(f.color[2] * f.weight)).sum() };
        assert!((light(&merged) / light(&fragments) - 1.0).abs() < 1e-5);
    }

    /// Bilinear placement keeps the sample's weight and its sub-pixel position: the shares sum
    /// to the sample's weight and their weighted mean of pixel centres is the moved position.
    #[test]
    fn bilinear_placement_keeps_weight_and_position() {
        let cam = camera();
        let mut frames = StochasticFrames::new(16, 16, 2, vec![Sample::default(); 512]);
        let (x, y) = (6usize, 9usize);
        frames.samples[(y * 16 + x) * 2] = Sample {
            color: [0.5, 0.25, 1.0, 1.0],
            depth: 1.0, // in focus: no lens offset
            lens: [0.3, 0.1],
            time: 0.0,
            motion: [0.0; 2],
            jitter: [0.2, -0.35],
        };
        let effects = effects_of(&cam, &frames);
        let (fragments, _) = sample_fragments(&frames, &cam, effects, SamplePlacement::Bilinear);
        assert_eq!(fragments.len(), 4);
        let total: f32 = fragments.iter().map(|f| f.weight).sum();
        assert!((total - 0.5).abs() < 1e-6, "weights sum to {total}");
        let mean = |axis: fn(&Fragment) -> i32| -> f32 {
            fragments
                .iter()
                .map(|f| f.weight * (axis(f) as f32 + 0.5))
                .sum::<f32>()
                / total
        };
        assert!((mean(|f| f.x) - (x as f32 + 0.5 + 0.2)).abs() < 1e-5);
        assert!((mean(|f| f.y) - (y as f32 + 0.5 - 0.35)).abs() < 1e-5);
    }

    /// Frames whose every sample lies at its pixel centre get a pixel filter on their in-focus
    /// samples from 3 spp: the footprint of [`POINT_SAMPLE_FILTER_SIGMA_PX`], keeping weight
    /// and position. A light's sample, a blurred one, and any sample of jittered frames keep
    /// the bilinear split.
    #[test]
    fn point_sampled_frames_filter_their_in_focus_samples() {
        let cam = camera();
        let lens = cam.thin_lens().expect("lens");
        let blurred_depth = (lens.focus_distance / (1.0 + 3.0 / lens.coc_scale_px)) as f32;
        let frame = |color: [f32; 4], depth: f32, jitter: [f32; 2]| {
            let mut frames = StochasticFrames::new(16, 16, 4, vec![Sample::default(); 1024]);
            frames.samples[(9 * 16 + 6) * 4] = Sample {
                color,
                depth,
                jitter,
                ..Sample::default()
            };
            frames
        };
        let fragments = |frames: &StochasticFrames| {
            let effects = effects_of(&cam, frames);
            sample_fragments(frames, &cam, effects, SamplePlacement::Bilinear).0
        };
        let dim = [0.5, 0.25, 0.8, 1.0];
        let filtered = fragments(&frame(dim, 1.0, [0.0; 2]));
        assert!(filtered.len() > 4, "{} taps", filtered.len());
        let total: f32 = filtered.iter().map(|f| f.weight).sum();
        assert!((total - 0.25).abs() < 1e-6, "weights sum to {total}");
        let moment = |power: i32| -> f32 {
            filtered
                .iter()
                .map(|f| f.weight * (f.x as f32 + 0.5 - 6.5).powi(power))
                .sum::<f32>()
                / total
        };
        assert!(moment(1).abs() < 1e-5, "mean offset {}", moment(1));
        let sigma = moment(2).sqrt();
        assert!(
            (sigma - POINT_SAMPLE_FILTER_SIGMA_PX).abs() < 0.06,
            "filter sigma {sigma}"
        );
        assert!(fragments(&frame(dim, 1.0, [0.1, 0.0])).len() <= 4);
        assert!(fragments(&frame([4.0, 3.0, 2.0, 1.0], 1.0, [0.0; 2])).len() <= 4);
        assert!(fragments(&frame(dim, blurred_depth, [0.0; 2])).len() <= 4);
    }

    /// Samples of a disc turning `theta` per frame about the frame's centre, each labelled with
    /// the motion at its own time (the tangent there, as a renderer's vector pass gives it),
    /// are moved back along their arcs: each lands where its point was at the shutter centre
    /// (along the tangent it would land up to `r (1 - cos(theta t))` outside), carries the
    /// motion at the shutter centre, and bends towards the centre by `theta |m|`.
    #[test]
    fn a_turning_surfaces_samples_move_back_along_their_arcs() {
        let cam = camera();
        let (w, spp) = (48usize, 4usize);
        let theta = 0.4f32;
        let centre = [24.0f32, 24.0];
        let turn = |v: [f32; 2], a: f32| {
            let (sin, cos) = a.sin_cos();
            [cos * v[0] - sin * v[1], sin * v[0] + cos * v[1]]
        };
        let mut samples = vec![Sample::default(); w * w * spp];
        for (k, s) in samples.iter_mut().enumerate() {
            let pixel = k / spp;
            let jitter = [0.1 + 0.2 * (k % 4) as f32, 0.7 - 0.2 * (k % 4) as f32];
            let p = [
                (pixel % w) as f32 + 0.5 + jitter[0] - 0.5,
                (pixel / w) as f32 + 0.5 + jitter[1] - 0.5,
            ];
            let r = [p[0] - centre[0], p[1] - centre[1]];
            *s = Sample {
                color: [0.5, 0.5, 0.5, 1.0],
                depth: 1.0, // in focus: no lens offset
                lens: [0.0; 2],
                time: ((k * 7 + pixel * 3) % 9) as f32 / 9.0 - 0.45,
                // y down: a positive turn is clockwise on screen, m = theta (-r_y, r_x).
                motion: [-theta * r[1], theta * r[0]],
                jitter: [jitter[0] - 0.5, jitter[1] - 0.5],
            };
        }
        let frames = StochasticFrames::new(w, w, spp, samples);
        let effects = effects_of(&cam, &frames);
        let moved = moved_samples(&frames, &cam, effects);
        let (mut worst, mut checked) = (0.0f32, 0);
        for (k, m) in moved.iter().enumerate() {
            let s = &frames.samples[k];
            let pixel = k / spp;
            let p = [
                (pixel % w) as f32 + 0.5 + s.jitter[0],
                (pixel / w) as f32 + 0.5 + s.jitter[1],
            ];
            let r = [p[0] - centre[0], p[1] - centre[1]];
            let radius = r[0].hypot(r[1]);
            // The field's fit needs a window of the surface round the pixel.
            let (x, y) = (pixel % w, pixel / w);
            if !(4..w - 4).contains(&x) || !(4..w - 4).contains(&y) || radius < 4.0 {
                continue;
            }
            let m = m.expect("a finite sample moves back");
            let r0 = turn(r, -theta * s.time);
            let p0 = [centre[0] + r0[0], centre[1] + r0[1]];
            worst = worst.max((m.q[0] - p0[0]).hypot(m.q[1] - p0[1]));
            let m0 = [-theta * r0[1], theta * r0[0]];
            let speed = m0[0].hypot(m0[1]);
            assert!(
                (m.motion[0] - m0[0]).hypot(m.motion[1] - m0[1]) < 0.02 * speed + 0.05,
                "motion {:?} against {m0:?}",
                m.motion
            );
            assert!(
                (m.bend - theta * speed).abs() < 0.05 * theta * speed + 0.05,
                "bend {} against {}",
                m.bend,
                theta * speed
            );
            checked += 1;
        }
        assert!(checked > 1000, "{checked} samples checked");
        assert!(
            worst < 0.05,
            "a moved sample lies {worst} px from its arc's centre point"
        );

        // A still wall behind, seen in one sample of a turning pixel, is not bent with it.
        let mut frames = frames;
        let (x, y) = (34usize, 20usize);
        let wall = (y * w + x) * spp + 1;
        frames.samples[wall].depth = 3.0;
        frames.samples[wall].motion = [0.0; 2];
        frames.samples[wall].time = 0.4;
        let moved = moved_samples(&frames, &cam, effects);
        let m = moved[wall].expect("the wall sample moves back");
        assert_eq!(m.motion, [0.0; 2]);
        assert_eq!(m.bend, 0.0);
    }

    /// Blender's pinhole sub-renders label a turning point with the central difference of its
    /// path, a chord `sin w / w` of its speed: such frames (every sample at its pixel centre)
    /// have the label scaled back to the speed along the arc, so their samples still move back
    /// to the arc's centre point.
    #[test]
    fn central_difference_labels_of_a_turning_surface_are_read_as_its_speed() {
        assert_eq!(central_difference_speedup(0.0, 30.0), 1.0);
        assert_eq!(central_difference_speedup(3.0, 0.0), 1.0, "a still path");
        let w = 0.5f32;
        let f = central_difference_speedup(20.0 * w.sin().powi(2), 20.0 * w.sin());
        assert!((f - w / w.sin()).abs() < 1e-5, "{f}");

        let cam = camera();
        let (size, spp) = (48usize, 4usize);
        let theta = 0.6f32;
        let centre = [24.0f32, 24.0];
        let turn = |v: [f32; 2], a: f32| {
            let (sin, cos) = a.sin_cos();
            [cos * v[0] - sin * v[1], sin * v[0] + cos * v[1]]
        };
        let mut samples = vec![Sample::default(); size * size * spp];
        for (k, s) in samples.iter_mut().enumerate() {
            let pixel = k / spp;
            let p = [(pixel % size) as f32 + 0.5, (pixel / size) as f32 + 0.5];
            let r = [p[0] - centre[0], p[1] - centre[1]];
            *s = Sample {
                color: [0.5, 0.5, 0.5, 1.0],
                depth: 1.0,
                lens: [0.0; 2],
                time: ((k * 7 + pixel * 3) % 9) as f32 / 9.0 - 0.45,
                // (p(t + 1) - p(t - 1)) / 2 on the circle: the tangent, sin(theta) r long.
                motion: [-theta.sin() * r[1], theta.sin() * r[0]],
                jitter: [0.0; 2],
            };
        }
        let frames = StochasticFrames::new(size, size, spp, samples);
        assert!(from_pinhole_sub_renders(&frames));
        let moved = moved_samples(&frames, &cam, effects_of(&cam, &frames));
        let (mut worst, mut checked) = (0.0f32, 0);
        for (k, m) in moved.iter().enumerate() {
            let s = &frames.samples[k];
            let pixel = k / spp;
            let (x, y) = (pixel % size, pixel / size);
            let r = [x as f32 + 0.5 - centre[0], y as f32 + 0.5 - centre[1]];
            if !(4..size - 4).contains(&x) || !(4..size - 4).contains(&y) || r[0].hypot(r[1]) < 4.0
            {
                continue;
            }
            let m = m.expect("a finite sample moves back");
            let r0 = turn(r, -theta * s.time);
            let err = (m.q[0] - centre[0] - r0[0]).hypot(m.q[1] - centre[1] - r0[1]);
            worst = worst.max(err);
            let m0 = [-theta * r0[1], theta * r0[0]];
            let speed = m0[0].hypot(m0[1]);
            // The shutter centre's motion is `m(t) - t a`, the arc taken as a parabola: 3.6 %
            // long where the sample's time is 0.27 radians of turn from the centre.
            assert!(
                (m.motion[0] - m0[0]).hypot(m.motion[1] - m0[1]) < 0.05 * speed + 0.05,
                "motion {:?} against {m0:?}",
                m.motion
            );
            checked += 1;
        }
        assert!(checked > 1000, "{checked} samples checked");
        // Read as the speed, the chords left samples up to 0.5 px short of their arc's centre.
        assert!(
            worst < 0.15,
            "a moved sample lies {worst} px from its arc's centre point"
        );
    }

    /// One opaque sample at depth `depth` with jitter `jitter`, in pixel (6, 9) of a 16x16 frame.
    fn lone_sample(depth: f32, jitter: [f32; 2], motion: [f32; 2]) -> StochasticFrames {
        let mut frames = StochasticFrames::new(16, 16, 1, vec![Sample::default(); 256]);
        frames.samples[9 * 16 + 6] = Sample {
            color: [0.5, 0.25, 1.0, 1.0],
            depth,
            lens: [0.0, 0.0],
            time: 0.0,
            motion,
            jitter,
        };
        frames
    }

    /// The Gaussian footprint keeps the sample's weight and, to 0.02 px (the cut-off tail is
    /// not symmetric), its sub-pixel position, and spreads it with the variance it was given.
    #[test]
    fn footprint_keeps_weight_and_position_and_has_its_variance() {
        let cam = camera();
        let sigma = FOOTPRINT_SIGMA_1SPP_PX;
        for jitter in [[0.0, 0.0], [0.2, -0.35], [0.49, 0.49], [-0.5, 0.1]] {
            let frames = lone_sample(1.0, jitter, [6.0, 0.0]);
            let effects = effects_of(&cam, &frames);
            let (fragments, _) = sample_fragments(
                &frames,
                &cam,
                effects,
                SamplePlacement::Footprint { sigma_px: sigma },
            );
            assert!(fragments.len() > 4, "{} taps", fragments.len());
            let total: f32 = fragments.iter().map(|f| f.weight).sum();
            assert!((total - 1.0).abs() < 1e-5, "weights sum to {total}");
            let centre = |f: &Fragment| [f.x as f32 + 0.5, f.y as f32 + 0.5];
            let (qx, qy) = (6.5 + jitter[0], 9.5 + jitter[1]);
            let mean_x: f32 = fragments.iter().map(|f| f.weight * centre(f)[0]).sum();
            let mean_y: f32 = fragments.iter().map(|f| f.weight * centre(f)[1]).sum();
            assert!((mean_x - qx).abs() < 0.02, "x {mean_x} vs {qx}");
            assert!((mean_y - qy).abs() < 0.02, "y {mean_y} vs {qy}");
            let var_x: f32 = fragments
                .iter()
                .map(|f| f.weight * (centre(f)[0] - qx).powi(2))
                .sum();
            // The 1 % cut-off trims the tails a little.
            assert!(
                (var_x.sqrt() - sigma).abs() < 0.06,
                "footprint sigma {} vs {sigma}",
                var_x.sqrt()
            );
            // Every tap keeps the sample's own motion: the footprint is not a PSF change.
            assert!(fragments.iter().all(|f| f.motion == [6.0, 0.0]));
        }
    }

    /// A sample whose own CoC already spreads it wider than the footprint is placed
    /// bilinearly; one in focus gets the footprint.
    #[test]
    fn footprint_only_for_samples_narrower_than_it() {
        let cam = camera();
        let lens = cam.thin_lens().expect("lens");
        let sigma = FOOTPRINT_SIGMA_1SPP_PX;
        // In front of the focus plane, signed CoC = k (1 - s / d) reaches any radius.
        let wide = f64::from(2.5 * sigma);
        let blurred_depth = (lens.focus_distance / (1.0 + wide / lens.coc_scale_px)) as f32;
        assert!(lens.signed_coc_px(f64::from(blurred_depth)).abs() > f64::from(2.0 * sigma));
        let placement = SamplePlacement::Footprint { sigma_px: sigma };
        let count = |depth| {
            let frames = lone_sample(depth, [0.1, 0.2], [0.0; 2]);
            sample_fragments(&frames, &cam, effects_of(&cam, &frames), placement)
                .0
                .len()
        };
        assert!(count(blurred_depth) <= 4);
        assert!(count(1.0) > 4);
    }

    /// The placement follows the sample count: a footprint at 1 spp, narrower at 2, bilinear
    /// from 4 on, and a non-finite footprint does not loop or lose the sample.
    #[test]
    fn placement_for_spp_narrows_with_more_samples() {
        assert_eq!(
            SamplePlacement::for_spp(1),
            SamplePlacement::Footprint {
                sigma_px: FOOTPRINT_SIGMA_1SPP_PX
            }
        );
        match SamplePlacement::for_spp(2) {
            SamplePlacement::Footprint { sigma_px } => {
                assert!((sigma_px - FOOTPRINT_SIGMA_1SPP_PX / 2f32.sqrt()).abs() < 1e-6)
            }
            other => panic!("2 spp gave {other:?}"),
        }
        assert_eq!(SamplePlacement::for_spp(4), SamplePlacement::Bilinear);
        // A huge but finite motion puts the moved sample where f32 has no unit steps; the
        // footprint must still end (bounded taps) and keep the weight.
        let cam_moving = camera();
        let mut far = lone_sample(1.0, [0.0; 2], [3e30, -3e30]);
        far.samples[9 * 16 + 6].time = 0.5;
        let (fragments, _) = sample_fragments(
            &far,
            &cam_moving,
            effects_of(&cam_moving, &far),
            SamplePlacement::for_spp(1),
        );
        assert!(fragments.len() <= MAX_FOOTPRINT_TAPS_PER_AXIS.pow(2));
        assert_eq!(SamplePlacement::for_spp(0), SamplePlacement::for_spp(1));
        let cam = camera();
        let frames = lone_sample(1.0, [0.0; 2], [0.0; 2]);
        for sigma_px in [f32::NAN, f32::INFINITY, 1e9, 0.0] {
            let (fragments, _) = sample_fragments(
                &frames,
                &cam,
                effects_of(&cam, &frames),
                SamplePlacement::Footprint { sigma_px },
            );
            let total: f32 = fragments.iter().map(|f| f.weight).sum();
            assert!(
                (total - 1.0).abs() < 1e-5,
                "sigma {sigma_px}: weight {total}"
            );
            assert!(
                fragments.len() <= 1000,
                "sigma {sigma_px}: {} taps",
                fragments.len()
            );
        }
    }

    #[test]
    fn non_finite_samples_are_dropped_and_counted() {
        let cam = camera();
        let mut frames = StochasticFrames::new(
            16,
            16,
            1,
            vec![
                Sample {
                    color: [1.0; 4],
                    depth: 1.0,
                    ..Sample::default()
                };
                256
            ],
        );
        frames.samples[3].depth = f32::NAN;
        frames.samples[4].color[0] = f32::INFINITY;
        let (fragments, dropped) = sample_fragments(
            &frames,
            &cam,
            effects_of(&cam, &frames),
            SamplePlacement::Nearest,
        );
        assert_eq!(dropped, 2);
        assert_eq!(fragments.len(), 254);
    }
}
