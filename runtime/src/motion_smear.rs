//! The PSF of a moving point seen through a real lens: its physical-lens PSF smeared along its
//! motion over the shutter.
//!
//! A physical-lens PSF depends on the point's inverse depth and its eccentricity, and is stored
//! with the radial direction along +x ([`psf_db::PsfModel::PhysicalLens`]). Over one shutter a
//! moving point's pinhole image travels the segment `c + t m`, `t` in `[-1/2, 1/2]` (the
//! shutter is box-shaped and centred on the frame time; `m` is the motion over the shutter,
//! px). The factorisation used here takes the lens PSF of the segment's centre for every
//! instant, so the motion PSF is
//!
//! ```text
//! P_motion(x) = integral over t in [-1/2, 1/2] of P_lens(x - t m) dt,
//! ```
//!
//! the lens PSF convolved with a uniform segment of length `|m|`. It ignores that the depth and
//! the field position change along the segment; `tests/physical_lens.rs` measures that against
//! light tracing every instant through the lens.
//!
//! The smeared PSF is built in the image's frame: the lens PSF turned onto the pixel's radial
//! direction, then smeared along the motion, so the record draws it unrotated (a turned dense
//! draw costs four bilinear taps per pixel). A segment reversed is the same segment, so the
//! motion's angle is taken modulo pi.
//!
//! Where the pixel's path over the shutter bends (a point turning about a centre), the segment
//! is the arc of the same length and the path's curvature ([`smear`]; docs/DESIGN.md, "Curved
//! paths").
//!
//! The smeared PSFs are built per frame, for the (cell, turn, length, angle, bend) keys its
//! moving pixels use, and appended to the frame's database as dense PSFs. Keys are quantised so
//! that a streak's ends and a PSF's rim are off by at most about a quarter pixel, or, where a
//! quantity is dithered between the steps either side of it over neighbouring pixels, so that
//! the streaks average to the pixel's own: the length in steps of 1/4 px up to 8 px and of 2 %
//! beyond, the angle in steps of at most 1/length radians rounded or 2/length dithered (the tip
//! of a streak of length `L` moves `L/2 * dtheta` px a step; [`AngleResolution`]), the turn in
//! steps of at most 1/(2 reach) radians.

use psf_db::PsfDatabase;

use crate::pipeline::splat::floor_exact;
use crate::subpixel_psf::{SubpixelPsf, STEPS};

/// Lengths up to this (px) are quantised in steps of [`FINE_LENGTH_STEP_PX`].
const FINE_LENGTH_MAX_PX: f32 = 8.0;
/// Length step below [`FINE_LENGTH_MAX_PX`], px.
const FINE_LENGTH_STEP_PX: f32 = 0.25;
/// Relative length step beyond [`FINE_LENGTH_MAX_PX`].
const COARSE_LENGTH_RATIO: f32 = 1.02;
/// Relative length step beyond [`FINE_LENGTH_MAX_PX`] of a key whose angle is dithered
/// ([`AngleResolution::Dithered`]: a frame whose every pixel streaks its own way), twice
/// [`COARSE_LENGTH_RATIO`]'s step as its angle steps are twice the rounded ones. On a car driving
/// at the camera reconstructed from 4 spp, 11 % less time for the same scores
/// (docs/BENCHMARKS.md, "Dithered keys' lengths in steps of 4 %").
const DITHERED_LENGTH_RATIO: f32 = 1.04;
/// A lens PSF narrower than this (px, its trimmed image's smaller side) is smeared with taps a
/// quarter pixel apart rather than one.
pub const NARROW_PSF_PX: usize = 8;
/// Taps per pixel of path of a smear drawn from a PSF's images at sub-pixel shifts
/// ([`smear_within_subpixel`]).
const SUBPIXEL_TAPS_PER_PX: f32 = 2.0;
/// Bend quantisation step, px: a step moves the path's ends sideways by 1/4 px.
const BEND_STEP_PX: f32 = 2.0;
/// A bend smaller than this (px; its ends off the straight line by under 1/8 px) is drawn
/// straight: a path is then a key like any straight one.
const MIN_BEND_PX: f32 = 1.0;
/// Largest motion length smeared, px: a longer one is clamped (and counted as clamped).
pub const MAX_SMEAR_PX: f32 = 512.0;
/// Largest smeared PSF image, pixels: its width times height. Beyond it the smear's taps are
/// what costs, not the memory; a frame that needs more is an error rather than a slow crawl.
const MAX_SMEARED_PIXELS: usize = 4 << 20;
/// Most values (pixels times channels) of smeared PSF images one frame builds, summed (1 GiB
/// of f32: 64 Mi pixels of RGBA, four times as many of grey), by default
/// (`ClassifyOptions::smeared_values_budget`): a frame beyond it draws its longest streaks at a
/// reduced resolution, or is an error, never an unbounded allocation. A camera pan through the
/// double Gauss at 512 px runs in 0.24 GB in all; a Cycles disc spinning 30 degrees a frame,
/// reconstructed from 16 spp along its arcs, builds 202 M values (0.81 GB).
pub const MAX_FRAME_SMEARED_VALUES: usize = 4 * (64 << 20);

/// Which smeared PSF a moving fragment uses: its physical-lens cell (index in the set's
/// combined database), the turn of that PSF onto the fragment's radial direction, and its
/// motion's length and angle, quantised. The smeared PSF is built in the image's frame (turned,
/// then smeared), so a record draws it unrotated: a dense draw turned by the record costs four
/// bilinear taps per pixel, an unrotated one a single add.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SmearKey {
    /// Index of the lens PSF in the combined database.
    pub cell: u32,
    /// Quantised motion length (see [`SmearKey::length_px`]).
    pub length_step: u32,
    /// Quantised angle of the motion from +x (y down), in `[0, angle_steps)`, modulo pi.
    pub angle_step: u32,
    /// Quantised turn of the lens PSF's +x onto the radial direction, in `[0, turn_steps)`.
    pub turn_step: u32,
    /// Turn steps over a full turn: finer for a wider PSF (its rim moves `reach * dturn`).
    pub turn_steps: u32,
    /// How finely the angle is quantised ([`SmearKey::angle_steps`]).
    pub angle_resolution: AngleResolution,
    /// Quantised bend of the motion path (see [`SmearKey::bend_px`]), signed, relative to the
    /// key's angle: positive bends towards the angle turned a quarter turn clockwise on screen
    /// (`(-sin, cos)`, y down).
    pub bend_step: i32,
}

/// How finely a [`SmearKey`]'s motion angle is quantised: steps at most `1 / (per_px
/// length)` radians apart over `[0, pi)`, where the tip of a streak of length `L` moves `L/2`
/// times the step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum AngleResolution {
    /// Steps `2 / length` radians apart, the motion's angle dithered between the two steps either side of it
    /// ([`SmearKey::dithered`]): a tip is off by up to 1 px on a pixel of its own, and over
    /// neighbouring pixels the streaks average to the motion's angle. Half the keys of
    /// rounded steps on a frame whose every pixel moves its own way (a car driving at the
    /// camera).
    Dithered,
    /// Steps `1 / length` radians apart, rounded: a tip off by at most 1/4 px.
    Rounded,
    /// Steps `1 / (4 length)` radians apart, rounded: for a lens PSF reaching under
    /// [`NARROW_PSF_PX`] / 2 px, whose streak is a thin line: a tip a step moves shows between
    /// neighbouring pixels, dithered or not (a spinning disc's flat squares came out mottled).
    Fine,
}

impl AngleResolution {
    /// Angle steps per pixel of motion length, per radian.
    fn per_px(self) -> f32 {
        match self {
            AngleResolution::Dithered => 0.5,
            AngleResolution::Rounded => 1.0,
            AngleResolution::Fine => 4.0,
        }
    }

    /// The relative length step beyond [`FINE_LENGTH_MAX_PX`] of a key at this resolution.
    fn length_ratio(self) -> f32 {
        match self {
            AngleResolution::Dithered => DITHERED_LENGTH_RATIO,
            AngleResolution::Rounded | AngleResolution::Fine => COARSE_LENGTH_RATIO,
        }
    }
}

/// The quantised length of a motion `len` px long (clamped to [`MAX_SMEAR_PX`]): steps of
/// [`FINE_LENGTH_STEP_PX`] up to [`FINE_LENGTH_MAX_PX`], then of `ratio`, the step above
/// where `threshold` (in `[0, 1)`) is at least one minus the length's fraction of the way
/// between its two steps.
fn length_step(len: f32, threshold: f32, ratio: f32) -> u32 {
    let len = len.min(MAX_SMEAR_PX);
    let quantise = |steps: f32| (steps + threshold).floor() as u32;
    if len <= FINE_LENGTH_MAX_PX {
        quantise(len / FINE_LENGTH_STEP_PX)
    } else {
        let fine = (FINE_LENGTH_MAX_PX / FINE_LENGTH_STEP_PX) as u32;
        fine + quantise((len / FINE_LENGTH_MAX_PX).ln() / ratio.ln())
    }
}

impl SmearKey {
    /// The key of lens PSF `cell` (reaching `reach_px` from its centre) turned onto `radial`
    /// (unit vector, x right, y down) and smeared along `motion` (px over the shutter, x
    /// right, y down). Returns the key and whether the length was clamped.
    pub fn new(
        cell: u32,
        motion: [f32; 2],
        bend: f32,
        radial: [f32; 2],
        reach_px: f32,
    ) -> (Self, bool) {
        Self::quantised(
            cell,
            motion,
            bend,
            radial,
            reach_px,
            0.5,
            AngleResolution::Rounded,
        )
    }

    /// [`SmearKey::new`] with the length's quantisation dithered: the length step below or
    /// above the motion's length, the one above where `threshold` (in `[0, 1)`) is at least
    /// one minus the length's fraction of the way between them. Over pixels whose thresholds
    /// are spread evenly over `[0, 1)`, the smeared PSF is then the linear interpolation
    /// between the two steps, continuous in the length, where rounding (`threshold` 1/2)
    /// steps: a surface whose motion varies smoothly shows no line where the rounding turns.
    /// The angle is rounded as [`SmearKey::new`] rounds it. The path's `bend` (px, relative to
    /// the motion's own direction: see `Fragment::bend`) is rounded to its step.
    pub fn dithered(
        cell: u32,
        motion: [f32; 2],
        bend: f32,
        radial: [f32; 2],
        reach_px: f32,
        threshold: f32,
    ) -> (Self, bool) {
        Self::quantised(
            cell,
            motion,
            bend,
            radial,
            reach_px,
            threshold,
            AngleResolution::Rounded,
        )
    }

    /// [`SmearKey::dithered`] with the angle quantised as `angles` says for a lens PSF reaching
    /// at least [`NARROW_PSF_PX`] / 2 px (dithered by the same `threshold` where that is
    /// [`AngleResolution::Dithered`]); a narrower one's in fine steps, rounded.
    pub fn quantised(
        cell: u32,
        motion: [f32; 2],
        bend: f32,
        radial: [f32; 2],
        reach_px: f32,
        threshold: f32,
        angles: AngleResolution,
    ) -> (Self, bool) {
        let len = (motion[0] * motion[0] + motion[1] * motion[1]).sqrt();
        let clamped = len > MAX_SMEAR_PX;
        // The rim of a PSF reaching r px moves r * dturn when turned: at most 1/4 px off.
        let turn_steps = (std::f32::consts::TAU * reach_px.max(1.0) / 0.5)
            .ceil()
            .clamp(8.0, 4096.0) as u32;
        let turn = radial[1].atan2(radial[0]).rem_euclid(std::f32::consts::TAU);
        let turn_step =
            ((turn / std::f32::consts::TAU * turn_steps as f32).round() as u32) % turn_steps;
        let key = SmearKey {
            cell,
            // Quantised with the angle, at its resolution's step.
            length_step: 0,
            angle_step: 0,
            turn_step,
            turn_steps,
            angle_resolution: AngleResolution::Rounded,
            bend_step: 0,
        };
        (
            key.with_angles(motion, bend, reach_px, threshold, angles),
            clamped,
        )
    }

    /// This key with the angle and bend of `motion` and `bend` quantised as
    /// [`SmearKey::quantised`] quantises them for the same lens PSF (reaching `reach_px`),
    /// `threshold` and `angles`, and its length at the step that resolution calls for
    /// ([`DITHERED_LENGTH_RATIO`] for dithered angles); its cell and turn kept. A frame that
    /// first keyed its fragments at one angle resolution re-keys them at another without
    /// looking their PSFs up again.
    pub fn with_angles(
        self,
        motion: [f32; 2],
        bend: f32,
        reach_px: f32,
        threshold: f32,
        angles: AngleResolution,
    ) -> Self {
        let angle_resolution = if 2.0 * reach_px < NARROW_PSF_PX as f32 {
            AngleResolution::Fine
        } else {
            angles
        };
        let len = (motion[0] * motion[0] + motion[1] * motion[1]).sqrt();
        let key = SmearKey {
            angle_resolution,
            length_step: length_step(len, threshold, angle_resolution.length_ratio()),
            ..self
        };
        let n = key.angle_steps();
        let angle = motion[1].atan2(motion[0]).rem_euclid(std::f32::consts::PI);
        let steps = angle / std::f32::consts::PI * n as f32;
        let step = match key.angle_resolution {
            AngleResolution::Dithered => (steps + threshold).floor() as u32,
            AngleResolution::Rounded | AngleResolution::Fine => steps.round() as u32,
        } % n;
        let key = SmearKey {
            angle_step: step,
            ..key
        };
        // At most half a turn over the shutter (beyond, the quadratic estimate means little).
        let most = std::f32::consts::PI * key.length_px();
        // Rounded, not dithered: a step moves a streak's ends sideways by a quarter pixel and
        // leaves its light where it was, and dithering it too doubled a spinning disc's keys.
        // A bend under a step's threshold either way is none: which way the key faces (a sine
        // and cosine) matters only for one that is not.
        if !bend.is_finite() || bend.abs().min(most) < MIN_BEND_PX {
            return SmearKey {
                bend_step: 0,
                ..key
            };
        }
        // The key's direction may be the motion's reversed (angles are taken modulo pi): the
        // same arc is then bent the other way relative to it.
        let (sin, cos) = key.angle_rad().sin_cos();
        let facing = cos * motion[0] + sin * motion[1] >= 0.0;
        let bend = if facing { bend } else { -bend };
        let bend_step = (bend.clamp(-most, most) / BEND_STEP_PX).round() as i32;
        SmearKey { bend_step, ..key }
    }

    /// How far the motion path bends sideways, px: its sideways acceleration over the shutter,
    /// `8` times how far the path's ends lie off the straight line through its centre. The
    /// path is the arc of curvature `bend / length^2` (see [`smear`]).
    pub fn bend_px(&self) -> f32 {
        self.bend_step as f32 * BEND_STEP_PX
    }

    /// The motion length this key smears over, px.
    pub fn length_px(&self) -> f32 {
        let fine = (FINE_LENGTH_MAX_PX / FINE_LENGTH_STEP_PX) as u32;
        if self.length_step <= fine {
            self.length_step as f32 * FINE_LENGTH_STEP_PX
        } else {
            let ratio = self.angle_resolution.length_ratio();
            FINE_LENGTH_MAX_PX * ratio.powi((self.length_step - fine) as i32)
        }
    }

    /// How many angle steps cover pi at this key's length: at most `1 / (per_px length)`
    /// radians apart, `per_px` as [`SmearKey::angle_resolution`] says, and at least four, and
    /// even, so that a quarter turn is a
    /// whole number of steps ([`crate::smear_symmetry`]).
    pub fn angle_steps(&self) -> u32 {
        let len = self.length_px();
        let steps = (std::f32::consts::PI * len * self.angle_resolution.per_px())
            .ceil()
            .max(4.0) as u32;
        steps + steps % 2
    }

    /// The angle of the motion from +x, radians in `[0, pi)`.
    pub fn angle_rad(&self) -> f32 {
        self.angle_step as f32 * std::f32::consts::PI / self.angle_steps() as f32
    }

    /// An upper bound on the pixels of this key's smeared image, for a lens PSF reaching
    /// `reach_px` from its centre: its turned box, grown by the path on each axis.
    pub fn estimated_pixels(&self, reach_px: f32) -> usize {
        let side = 2.0 * reach_px.max(0.0) + 5.0;
        let (sin, cos) = self.angle_rad().sin_cos();
        let len = self.length_px();
        let sag = 2.0 * sagitta(len, self.bend_px());
        ((side + len * cos.abs() + sag + 2.0) * (side + len * sin.abs() + sag + 2.0)) as usize
    }

    /// The turn of the lens PSF's +x onto the radial direction, radians in `[0, 2 pi)`.
    pub fn turn_rad(&self) -> f32 {
        turn_rad(self.turn_step, self.turn_steps)
    }
}

/// A dense PSF image, channel-interleaved, `origin` its top-left pixel relative to the PSF
/// centre (px, x right, y down).
#[derive(Clone, Debug, PartialEq)]
pub struct PsfImage {
    /// Top-left pixel relative to the centre, px.
    pub origin: [i32; 2],
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Channels per pixel.
    pub channels: usize,
    /// `width * height * channels` values, row-major.
    pub data: Vec<f32>,
}

impl PsfImage {
    /// A single lit pixel of value 1, grey: the PSF of an in-focus point.
    #[cfg(test)]
    pub(crate) fn point() -> Self {
        Self {
            origin: [0, 0],
            width: 1,
            height: 1,
            channels: 1,
            data: vec![1.0],
        }
    }
}

/// Why a smeared PSF could not be built.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SmearError {
    /// The smeared image would be larger than the renderer draws.
    #[error(
        "a PSF smeared along {length_px:.0} px of motion would be {width} x {height} px, \
         more than the {MAX_SMEARED_PIXELS} pixels drawn per PSF: shorten the shutter"
    )]
    TooLarge {
        /// Motion length, px.
        length_px: f32,
        /// Width of the smeared image, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    /// The frame's smeared PSFs together would be larger than the renderer builds per frame.
    #[error(
        "the frame's moving pixels call for {keys} smeared PSFs of about {pixels} pixels of \
         {channels} channel(s) in all, more than the {budget_values} values built per frame: \
         shorten the shutter or render the frame in tiles"
    )]
    FrameTooLarge {
        /// Distinct smeared PSFs.
        keys: usize,
        /// Their estimated pixels, summed.
        pixels: usize,
        /// Values per pixel (1 grey, 3 RGB).
        channels: usize,
        /// The frame's budget of values (`ClassifyOptions::smeared_values_budget`).
        budget_values: usize,
    },
}

/// PSF `index` of `db` as a non-negative image: a dense PSF as stored, a sparse one integrated
/// from its spreadlets (the exact inverse of the one Laplacian stencil, on a plane two pixels
/// wider on every side than the spreadlets) with the sparse fit's negative residue clamped to
/// zero and each channel scaled back to its sum (a bright pixel times a negative residue
/// draws a dark speck). `None` for an empty PSF.
pub fn psf_image(db: &PsfDatabase, index: usize) -> Option<PsfImage> {
    let channels = db.channels();
    if let Some(d) = db.dense(index) {
        let image = PsfImage {
            origin: d.origin,
            width: d.width,
            height: d.height,
            channels: d.channels,
            data: d.data.to_vec(),
        };
        return Some(image.trimmed());
    }
    let (positions, values) = db.spreadlets(index);
    if positions.is_empty() {
        return None;
    }
    const MARGIN: i32 = 2;
    let (mut x0, mut y0, mut x1, mut y1) = (i32::MAX, i32::MAX, i32::MIN, i32::MIN);
    for p in positions {
        x0 = x0.min(i32::from(p[0]));
        y0 = y0.min(i32::from(p[1]));
        x1 = x1.max(i32::from(p[0]));
        y1 = y1.max(i32::from(p[1]));
    }
    let origin = [x0 - MARGIN, y0 - MARGIN];
    let width = (x1 - x0 + 1 + 2 * MARGIN) as usize;
    let height = (y1 - y0 + 1 + 2 * MARGIN) as usize;
    let mut integrated = vec![0f32; width * height * channels];
    for c in 0..channels {
        let mut lap = poisson::Plane::new(width, height);
        for (k, p) in positions.iter().enumerate() {
            let x = (i32::from(p[0]) - origin[0]) as usize;
            let y = (i32::from(p[1]) - origin[1]) as usize;
            lap.add(x, y, values[k * channels + c]);
        }
        let image = poisson::integrate_exact(&lap);
        for (i, &v) in image.data.iter().enumerate() {
            integrated[i * channels + c] = v;
        }
    }
    let mut data: Vec<f32> = integrated.iter().map(|&v| v.max(0.0)).collect();
    keep_channel_sums(&integrated, &mut data, channels);
    let image = PsfImage {
        origin,
        width,
        height,
        channels,
        data,
    };
    Some(image.trimmed())
}

/// Scales each channel of `after` (channel-interleaved, `ch` channels) to the sum it has in
/// `before`; a channel with nothing left stays as it is.
fn keep_channel_sums(before: &[f32], after: &mut [f32], ch: usize) {
    if ch == 3 {
        keep_rgb_sums(before, after);
    } else {
        keep_any_sums(before, after, ch);
    }
}

/// [`keep_channel_sums`] for any channel count.
fn keep_any_sums(before: &[f32], after: &mut [f32], ch: usize) {
    if ch == 0 {
        return;
    }
    // Each channel summed in pixel order, all channels in one pass.
    let sums = |data: &[f32]| -> Vec<f64> {
        let mut sums = vec![0f64; ch];
        for px in data.chunks_exact(ch) {
            for (s, &v) in sums.iter_mut().zip(px) {
                *s += f64::from(v);
            }
        }
        sums
    };
    let (was, is) = (sums(before), sums(after));
    let scale: Vec<Option<f32>> = was
        .iter()
        .zip(&is)
        .map(|(&was, &is)| (is > 0.0).then(|| (was / is) as f32))
        .collect();
    for px in after.chunks_exact_mut(ch) {
        for (v, s) in px.iter_mut().zip(&scale) {
            if let Some(s) = s {
                *v *= s;
            }
        }
    }
}

/// [`keep_channel_sums`] for three channels, with the sums in registers: the same sums in
/// the same order, so the same result to the bit.
fn keep_rgb_sums(before: &[f32], after: &mut [f32]) {
    let sums = |data: &[f32]| -> [f64; 3] {
        let mut sums = [0f64; 3];
        for px in data.chunks_exact(3) {
            sums[0] += f64::from(px[0]);
            sums[1] += f64::from(px[1]);
            sums[2] += f64::from(px[2]);
        }
        sums
    };
    let (was, is) = (sums(before), sums(after));
    let scale: [f32; 3] = std::array::from_fn(|k| {
        if is[k] > 0.0 {
            (was[k] / is[k]) as f32
        } else {
            1.0
        }
    });
    if scale == [1.0; 3] {
        return;
    }
    for px in after.chunks_exact_mut(3) {
        px[0] *= scale[0];
        px[1] *= scale[1];
        px[2] *= scale[2];
    }
}

/// Below this fraction of an image's largest value a border row or column counts as empty.
const TRIM_FRACTION: f32 = 1e-4;

impl PsfImage {
    /// The image without its border rows and columns whose every value is below
    /// [`TRIM_FRACTION`] of the largest, each channel scaled back to its sum. A stored PSF's
    /// box is often much wider than its light; a smear's cost and a dense draw's grow with it.
    pub fn trimmed(self) -> PsfImage {
        let ch = self.channels;
        let peak = self.data.iter().fold(0.0f32, |m, &v| m.max(v.abs()));
        let floor = peak * TRIM_FRACTION;
        let lit = |x: usize, y: usize| {
            let i = (y * self.width + x) * ch;
            self.data[i..i + ch].iter().any(|v| v.abs() > floor)
        };
        let rows: Vec<usize> = (0..self.height)
            .filter(|&y| (0..self.width).any(|x| lit(x, y)))
            .collect();
        let cols: Vec<usize> = (0..self.width)
            .filter(|&x| (0..self.height).any(|y| lit(x, y)))
            .collect();
        let (Some(&y0), Some(&y1), Some(&x0), Some(&x1)) =
            (rows.first(), rows.last(), cols.first(), cols.last())
        else {
            return self;
        };
        if (x0, y0, x1, y1) == (0, 0, self.width - 1, self.height - 1) {
            return self;
        }
        let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
        let mut data = Vec::with_capacity(w * h * ch);
        for y in y0..=y1 {
            let row = (y * self.width + x0) * ch;
            data.extend_from_slice(&self.data[row..row + w * ch]);
        }
        keep_channel_sums(&self.data, &mut data, ch);
        PsfImage {
            origin: [self.origin[0] + x0 as i32, self.origin[1] + y0 as i32],
            width: w,
            height: h,
            channels: ch,
            data,
        }
    }
}

/// How far an arc of `length` px bent by `bend` px ([`SmearKey::bend_px`]) lies off its
/// tangent at the centre at its ends, px: `(1 - cos(phi)) / kappa` with curvature
/// `kappa = bend / length^2` and `phi = kappa length / 2` the turn from the centre to an end.
pub fn sagitta(length: f32, bend: f32) -> f32 {
    if bend == 0.0 || length <= 0.0 {
        return 0.0;
    }
    let kappa = bend.abs() / (length * length);
    let phi = (0.5 * kappa * length).min(std::f32::consts::FRAC_PI_2);
    (1.0 - phi.cos()) / kappa
}

/// Where `psf` smeared along the path of `length` px at `angle` radians bent by `bend` px
/// lies: [`smear`]'s image without its values. Errors where it would be larger than the
/// renderer draws per PSF.
pub fn smear_extent(
    psf: &PsfImage,
    length: f32,
    angle: f32,
    bend: f32,
) -> Result<SmearExtent, SmearError> {
    let (dx, dy) = (angle.cos(), angle.sin());
    let half = 0.5 * length;
    let sag = sagitta(length, bend);
    // One pixel more on each side than the path reaches: the bilinear weights of a shift
    // spill one pixel beyond its integer part. Along the chord the arc reaches no further than
    // half its length, across it no further than its sagitta.
    let grow_x = (half * dx.abs() + sag * dy.abs()).ceil() as i32 + 1;
    let grow_y = (half * dy.abs() + sag * dx.abs()).ceil() as i32 + 1;
    let width = psf.width + 2 * grow_x as usize;
    let height = psf.height + 2 * grow_y as usize;
    if width * height > MAX_SMEARED_PIXELS {
        return Err(SmearError::TooLarge {
            length_px: length,
            width,
            height,
        });
    }
    Ok(SmearExtent {
        origin: [psf.origin[0] - grow_x, psf.origin[1] - grow_y],
        width,
        height,
        grow: [grow_x, grow_y],
    })
}

/// The box of a smeared PSF ([`smear_extent`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SmearExtent {
    /// Top-left pixel relative to the centre, px.
    pub origin: [i32; 2],
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// How far the box reaches beyond the unsmeared PSF's on each side, px per axis.
    grow: [i32; 2],
}

impl SmearExtent {
    /// The box that the pixel grid's symmetry `g` moves this one onto
    /// ([`crate::smear_symmetry`]).
    pub fn moved(self, g: crate::smear_symmetry::GridSymmetry) -> Self {
        let (origin, width, height) =
            crate::smear_symmetry::transform_box(self.origin, self.width, self.height, g);
        let grow = if g.swaps_axes() {
            [self.grow[1], self.grow[0]]
        } else {
            self.grow
        };
        Self {
            origin,
            width,
            height,
            grow,
        }
    }
}

/// `psf` convolved with a uniform path of `length` px centred on the PSF centre, leaving it
/// at `angle` radians from +x (y down) both ways: the mean of `psf` shifted to `taps` points
/// spaced at most one pixel apart along the path (the midpoints of equal parts), each shift
/// drawn with bilinear weights. Every channel keeps its sum.
///
/// The path is the segment when `bend` is 0, else the arc of the same length whose curvature
/// is `kappa = bend / length^2`, bent towards `(-sin, cos)` for a positive `bend`: the point
/// at arc length `s` from the centre lies at `sin(kappa s) / kappa` along the angle and
/// `(1 - cos(kappa s)) / kappa` across it. A point turning about a centre travels such an
/// arc; for small turns it is the quadratic path `t m + t^2 a / 2` of a motion `m` with
/// sideways acceleration `a = bend`.
pub fn smear(psf: &PsfImage, length: f32, angle: f32, bend: f32) -> Result<PsfImage, SmearError> {
    let extent = smear_extent(psf, length, angle, bend)?;
    let mut data = vec![0f32; extent.width * extent.height * psf.channels];
    smear_into(psf, length, angle, bend, extent, &mut data);
    Ok(PsfImage {
        origin: extent.origin,
        width: extent.width,
        height: extent.height,
        channels: psf.channels,
        data,
    })
}

/// [`smear`] into `out`, which it overwrites: `extent.width * extent.height * psf.channels`
/// values, for `extent` = [`smear_extent`]`(psf, length, angle, bend)`.
pub fn smear_into(
    psf: &PsfImage,
    length: f32,
    angle: f32,
    bend: f32,
    extent: SmearExtent,
    out: &mut [f32],
) {
    out.fill(0.0);
    let mut written = vec![[0u16; 2]; extent.height];
    smear_within(psf, length, angle, bend, extent, out, &mut written);
}

/// [`smear`] into `out`, which must hold zeros (`extent.width * extent.height *
/// psf.channels` values, for `extent` = [`smear_extent`]`(psf, length, angle, bend)`),
/// touching only the pixels the streak can reach: `written[row]` is set to the columns
/// `[first, end)` of each of the `extent.height` rows outside which the row keeps its zeros. A
/// thin streak turned across its box lights a few pixels of each row, and the box's other
/// pixels are then never read or written.
pub fn smear_within(
    psf: &PsfImage,
    length: f32,
    angle: f32,
    bend: f32,
    extent: SmearExtent,
    out: &mut [f32],
    written: &mut [[u16; 2]],
) {
    let [grow_x, grow_y] = extent.grow;
    let width = extent.width;
    let ch = psf.channels;
    debug_assert_eq!(out.len(), width * extent.height * ch);
    debug_assert_eq!(written.len(), extent.height);
    // A tap's bilinear weights widen a PSF by up to a pixel, most at half-pixel shifts: on a
    // PSF only a few pixels wide, taps a pixel apart draw a beaded streak whose beads move
    // with the angle, and neighbouring pixels' streaks no longer add up to a flat surface.
    // Narrow PSFs get taps a quarter pixel apart.
    let narrow = psf.width.min(psf.height) < NARROW_PSF_PX;
    let taps_per_px = if narrow { 4.0 } else { 1.0 };
    let (shifts, share) = tap_shifts(length, angle, bend, extent.grow, taps_per_px);
    // The taps' bilinear weights summed into one small kernel (a tap's shift lands in
    // `0..=2 grow` per axis), then the PSF drawn once per non-zero kernel pixel: a streak's
    // taps a quarter pixel apart share their pixels, so this is several times fewer passes
    // over the PSF than one per tap and weight.
    let (kw, kh) = (2 * grow_x as usize + 1, 2 * grow_y as usize + 1);
    // One row and one column of slack: a tap on a kernel pixel's far edge (a shift that is a
    // whole number) gives its next pixel a weight of exactly 0, added there without a check.
    let stride = kw + 1;
    let mut padded = vec![0f32; stride * (kh + 1)];
    // Per kernel row, the columns `[first, end)` its taps touched: outside them it is zero.
    let mut kernel_columns = vec![[usize::MAX, 0usize]; kh + 1];
    for [sx, sy] in shifts {
        // Shifts are at least 1 (the box grows a pixel beyond the path), so `as` floors; through
        // i32, a single conversion instruction where one to u64 takes a dozen.
        let (ix, iy) = (sx as i32 as usize, sy as i32 as usize);
        let (fx, fy) = (sx - ix as f32, sy - iy as f32);
        let at = iy * stride + ix;
        let Some(corner) = padded.get_mut(at..at + stride + 2) else {
            continue;
        };
        corner[0] += (1.0 - fx) * (1.0 - fy) * share;
        corner[1] += fx * (1.0 - fy) * share;
        corner[stride] += (1.0 - fx) * fy * share;
        corner[stride + 1] += fx * fy * share;
        for row in &mut kernel_columns[iy..iy + 2] {
            *row = [row[0].min(ix), row[1].max(ix + 2)];
        }
    }
    let kernel = padded;
    kernel_columns.truncate(kh);
    for row in &mut kernel_columns {
        *row = if row[0] < row[1] {
            [row[0], row[1].min(kw)]
        } else {
            [0, 0]
        };
    }
    // Each PSF row's span, and from them and the kernel's, the columns each output row can
    // reach; written with zeros first (a fresh page read before it is written is faulted
    // twice, each fault flushing the other threads' TLBs).
    let psf_spans: Vec<[usize; 2]> = psf
        .data
        .chunks_exact(psf.width * ch)
        .map(|row| {
            let lit = |px: &[f32]| px.iter().any(|&v| v != 0.0);
            match row.chunks_exact(ch).position(lit) {
                None => [0, 0],
                Some(first) => [
                    first,
                    psf.width - row.chunks_exact(ch).rev().position(lit).unwrap_or(0),
                ],
            }
        })
        .collect();
    let mut reach = vec![[usize::MAX, 0usize]; extent.height];
    for (ky, k) in kernel_columns.iter().enumerate() {
        if k[0] >= k[1] {
            continue;
        }
        for (y, s) in psf_spans.iter().enumerate() {
            if s[0] < s[1] {
                let r = &mut reach[y + ky];
                r[0] = r[0].min(k[0] + s[0]);
                r[1] = r[1].max(k[1] - 1 + s[1]);
            }
        }
    }
    // A single-pixel PSF reaches exactly its kernel's columns, each written once below.
    let single_pixel = psf.width == 1 && psf.height == 1;
    for ((row, r), w) in out
        .chunks_exact_mut(width * ch)
        .zip(&reach)
        .zip(written.iter_mut())
    {
        if r[0] < r[1] {
            if !single_pixel {
                row[r[0] * ch..r[1] * ch].fill(0.0);
            }
            // A box wider than the format's u16 widths cannot be stored: its columns saturate.
            let column = |c: usize| u16::try_from(c).unwrap_or(u16::MAX);
            *w = [column(r[0]), column(r[1])];
        } else {
            *w = [0, 0];
        }
    }
    // A single-pixel PSF (a sharp point's) is drawn as its kernel, row by row.
    if single_pixel {
        let value = &psf.data[..ch];
        for (ky, k) in kernel_columns.iter().enumerate() {
            let weights = &kernel[ky * stride + k[0]..ky * stride + k[1]];
            let dst = &mut out[(ky * width + k[0]) * ch..(ky * width + k[1]) * ch];
            for (d, &w) in dst.chunks_exact_mut(ch).zip(weights) {
                for (d, s) in d.iter_mut().zip(value) {
                    *d = w * s;
                }
            }
        }
        return;
    }
    // Each PSF row's span padded with zeros to whole groups of `LANES` values, added in
    // fixed-width steps that compile to vector instructions: a small PSF's rows (7 values of
    // a sharp pixel's disc) were added one value at a time. The padding adds `w * 0` to the
    // values just past a span, which leaves them as they were (every value is finite and
    // non-negative, so not even a zero's sign changes), and those past the row's reach are
    // never read.
    const LANES: usize = 8;
    let mut lanes: Vec<[f32; LANES]> = Vec::new();
    // Per lit PSF row: its index, first column, number of values and first group in `lanes`.
    let lane_rows: Vec<(usize, usize, usize, usize)> = psf_spans
        .iter()
        .enumerate()
        .filter(|(_, s)| s[0] < s[1])
        .map(|(y, s)| {
            let start = lanes.len();
            let src = &psf.data[(y * psf.width + s[0]) * ch..(y * psf.width + s[1]) * ch];
            lanes.extend(src.chunks(LANES).map(|c| {
                let mut group = [0.0; LANES];
                group[..c.len()].copy_from_slice(c);
                group
            }));
            (y, s[0], src.len(), start)
        })
        .collect();
    for (ky, k) in kernel_columns.iter().enumerate() {
        if k[0] >= k[1] {
            continue;
        }
        for kx in k[0]..k[1] {
            let w = kernel[ky * stride + kx];
            if w == 0.0 {
                continue;
            }
            for &(y, first, len, start) in &lane_rows {
                let at = ((y + ky) * width + kx + first) * ch;
                let src = &lanes[start..start + len.div_ceil(LANES)];
                match out.get_mut(at..at + src.len() * LANES) {
                    Some(dst) => {
                        let (dst, _) = dst.as_chunks_mut::<LANES>();
                        for (d, s) in dst.iter_mut().zip(src) {
                            *d = std::array::from_fn(|i| d[i] + w * s[i]);
                        }
                    }
                    // The box's last values: the span alone.
                    None => {
                        for (d, s) in out[at..at + len].iter_mut().zip(src.as_flattened()) {
                            *d += w * s;
                        }
                    }
                }
            }
        }
    }
}

/// The taps of a path of `length` px at `angle` radians bent by `bend` px (see [`smear`]):
/// each tap's shift in the smeared box's pixels (the box grown by `grow` px beyond the lens
/// PSF's on each side), and the share of the PSF's light each carries; `taps_per_px` along
/// the path.
fn tap_shifts(
    length: f32,
    angle: f32,
    bend: f32,
    grow: [i32; 2],
    taps_per_px: f32,
) -> (Vec<[f32; 2]>, f32) {
    let (dx, dy) = (angle.cos(), angle.sin());
    let [grow_x, grow_y] = grow;
    let taps = ((length * taps_per_px).ceil() as usize + 1).max(1);
    let share = 1.0 / taps as f32;
    let kappa = if length > 0.0 {
        bend / (length * length)
    } else {
        0.0
    };
    // The taps' shifts apart from their weights: neither loop waits on the other's chain
    // (the arc's rotation recurrence; the kernel's sums, a tap a quarter pixel on adding to
    // the pixels the last one did).
    let mut shifts: Vec<[f32; 2]> = Vec::with_capacity(taps);
    if kappa == 0.0 {
        for k in 0..taps {
            let t = ((k as f32 + 0.5) / taps as f32 - 0.5) * length;
            let (along, across) = (t, 0.0);
            // The shift of this tap, in output pixels relative to the input's placement.
            let sx = along * dx - across * dy + grow_x as f32;
            let sy = along * dy + across * dx + grow_y as f32;
            shifts.push([sx, sy]);
        }
    } else {
        // On an arc, the turn at each tap by rotating the first tap's by the taps' spacing
        // (one sine and cosine per image rather than per tap), in f64. Along the chord and
        // across it (towards `(-dy, dx)`).
        let spacing = f64::from(length) / taps as f64;
        let k64 = f64::from(kappa);
        let (step_sin, step_cos) = (k64 * spacing).sin_cos();
        let (mut sin, mut cos) = (k64 * (0.5 * spacing - 0.5 * f64::from(length))).sin_cos();
        // The radius, multiplied rather than divided by per tap: two divisions a tap were the
        // loop's critical path.
        let radius = 1.0 / k64;
        for _ in 0..taps {
            let (along, across) = ((sin * radius) as f32, ((1.0 - cos) * radius) as f32);
            (sin, cos) = (
                sin * step_cos + cos * step_sin,
                cos * step_cos - sin * step_sin,
            );
            let sx = along * dx - across * dy + grow_x as f32;
            let sy = along * dy + across * dx + grow_y as f32;
            shifts.push([sx, sy]);
        }
    }
    (shifts, share)
}

/// `psf` smeared along `key`'s path into `out` as [`smear_within`] does, from its images at
/// sub-pixel shifts where `sub` holds them ([`smear_within_subpixel`]).
pub fn smear_key_within(
    psf: &PsfImage,
    sub: Option<&SubpixelPsf>,
    key: SmearKey,
    extent: SmearExtent,
    out: &mut [f32],
    written: &mut [[u16; 2]],
) {
    let (length, angle, bend) = (key.length_px(), key.angle_rad(), key.bend_px());
    match sub {
        Some(sub) => smear_within_subpixel(sub, length, angle, bend, extent, out, written),
        None => smear_within(psf, length, angle, bend, extent, out, written),
    }
}

/// [`smear_within`] for a narrow PSF whose box-filtered images at sub-pixel shifts are known
/// (`sub`): each tap adds the image at its shift rounded to `1 / STEPS` px, where
/// bilinear weights would draw the PSF widened by a second pixel box
/// ([`crate::subpixel_psf`]). The same box and rows as [`smear_within`]; taps half a pixel
/// apart.
pub fn smear_within_subpixel(
    sub: &SubpixelPsf,
    length: f32,
    angle: f32,
    bend: f32,
    extent: SmearExtent,
    out: &mut [f32],
    written: &mut [[u16; 2]],
) {
    let width = extent.width;
    debug_assert_eq!(out.len(), width * extent.height);
    debug_assert_eq!(written.len(), extent.height);
    // Each tap is the PSF at its own shift, so no bilinear beads: taps half a pixel apart
    // stay within a sixth of the error of the bilinear smear (half that of a quarter pixel
    // apart), for half the adds.
    let (shifts, share) = tap_shifts(length, angle, bend, extent.grow, SUBPIXEL_TAPS_PER_PX);
    let steps = STEPS as f32;
    // Each tap's whole-pixel corner and its shift's index, carried into the next pixel where
    // it rounds to a whole one.
    let placed: Vec<(usize, usize, usize, usize)> = shifts
        .iter()
        .map(|&[sx, sy]| {
            let place = |v: f32| {
                // Shifts are at least 1 (the box grows a pixel beyond the path).
                let whole = v as i32 as usize;
                let step = ((v - whole as f32) * steps).round() as usize;
                if step >= STEPS {
                    (whole + 1, 0)
                } else {
                    (whole, step)
                }
            };
            let ((ix, a), (iy, b)) = (place(sx), place(sy));
            (ix, iy, a, b)
        })
        .collect();
    let (sw, sh) = (sub.width, sub.height);
    let mut reach = vec![[usize::MAX, 0usize]; extent.height];
    for &(ix, iy, _, _) in &placed {
        for r in reach.iter_mut().skip(iy).take(sh) {
            *r = [r[0].min(ix), r[1].max((ix + sw).min(width))];
        }
    }
    for ((row, r), w) in out
        .chunks_exact_mut(width)
        .zip(&reach)
        .zip(written.iter_mut())
    {
        if r[0] < r[1] {
            row[r[0]..r[1]].fill(0.0);
            let column = |c: usize| u16::try_from(c).unwrap_or(u16::MAX);
            *w = [column(r[0]), column(r[1])];
        } else {
            *w = [0, 0];
        }
    }
    for &(ix, iy, a, b) in &placed {
        let image = sub.shifted(a, b);
        for (y, src) in image.chunks_exact(sw).enumerate() {
            let at = (iy + y) * width + ix;
            // A box's last column or row beyond the smeared box holds the model's edge,
            // next to nothing: left out.
            let Some(dst) = out.get_mut(at..(at + sw).min((iy + y + 1) * width)) else {
                continue;
            };
            for (d, &v) in dst.iter_mut().zip(src) {
                *d += share * v;
            }
        }
    }
}

/// The turn of quantised step `step` of `steps` over a full turn, radians.
pub fn turn_rad(step: u32, steps: u32) -> f32 {
    step as f32 * std::f32::consts::TAU / steps as f32
}

/// The smeared PSF of `key` from the lens PSFs of `db`, in the image's frame (`None` for an
/// empty lens PSF).
pub fn smeared_psf(db: &PsfDatabase, key: SmearKey) -> Result<Option<PsfImage>, SmearError> {
    let Some(psf) = psf_image(db, key.cell as usize) else {
        return Ok(None);
    };
    let turned = turn(&psf, key.turn_rad());
    smear(&turned, key.length_px(), key.angle_rad(), key.bend_px()).map(Some)
}

/// The union of `images`' boxes: its top-left pixel relative to the centre, width and height
/// (px); `None` for no images.
pub fn union_box(images: &[(&PsfImage, f32)]) -> Option<([i32; 2], usize, usize)> {
    let x0 = images.iter().map(|(t, _)| t.origin[0]).min()?;
    let y0 = images.iter().map(|(t, _)| t.origin[1]).min()?;
    let x1 = images
        .iter()
        .map(|(t, _)| t.origin[0] + t.width as i32)
        .max()?;
    let y1 = images
        .iter()
        .map(|(t, _)| t.origin[1] + t.height as i32)
        .max()?;
    Some(([x0, y0], (x1 - x0) as usize, (y1 - y0) as usize))
}

/// Adds `images`, each times its weight, into `out`: the values of an image of
/// [`union_box`]`(images)` (row-major, each image's channel count). Each pixel adds the
/// images' values in their order.
pub fn add_weighted(out: &mut [f32], images: &[(&PsfImage, f32)]) {
    let Some(([x0, y0], width, _)) = union_box(images) else {
        return;
    };
    for &(img, w) in images {
        let ch = img.channels;
        for v in 0..img.height {
            let row = ((v as i32 + img.origin[1] - y0) as usize * width
                + (img.origin[0] - x0) as usize)
                * ch;
            let src = &img.data[v * img.width * ch..(v + 1) * img.width * ch];
            for (d, &x) in out[row..row + img.width * ch].iter_mut().zip(src) {
                *d += w * x;
            }
        }
    }
}

/// The sum of `images`, each times its weight, over the union of their boxes (`None` for no
/// images, or images of different channel counts). Each pixel adds the images' values in
/// their order.
pub fn weighted_sum(images: &[(&PsfImage, f32)]) -> Option<PsfImage> {
    let ch = images.first()?.0.channels;
    if images.iter().any(|(img, _)| img.channels != ch) {
        return None;
    }
    let (origin, width, height) = union_box(images)?;
    let mut data = vec![0f32; width * height * ch];
    add_weighted(&mut data, images);
    Some(PsfImage {
        origin,
        width,
        height,
        channels: ch,
        data,
    })
}

/// `psf` turned by `angle` radians about its centre (its +x onto `(cos, sin)`, y down): each
/// output pixel samples the PSF at the point that turns onto it with the Catmull-Rom cubic
/// (4 x 4 taps), its negative lobes clamped to zero, and each channel keeps its sum. Bilinear
/// taps, as the splat turns a record's PSF, widen a PSF of 2 px RMS radius by about 5 %; the
/// cubic by about 2 % (a far drop in a corner of `corner-drops`: +9 % -> +7 % against the
/// reference, whose own pixel footprint and the cell's pre-filter make the rest).
pub fn turn(psf: &PsfImage, angle: f32) -> PsfImage {
    turn_scaled(psf, angle, 1.0)
}

/// `psf` turned by `angle` radians about its centre as [`turn`] does, and enlarged by `scale`
/// about it (a point `d` px from the centre lands `scale d` px from it; each channel keeps its
/// sum). A real lens's defocus blur grows in proportion to the point's inverse depth from the
/// focus plane, so a PSF scaled so is the PSF of a nearby depth: its rim stays as sharp as
/// the PSF's own.
pub fn turn_scaled(psf: &PsfImage, angle: f32, scale: f32) -> PsfImage {
    let (turn_sin, turn_cos) = angle.sin_cos();
    // Onto the output (corners) and back from it (each output pixel's sample point).
    let (sin, cos) = (turn_sin * scale, turn_cos * scale);
    let (inv_sin, inv_cos) = (turn_sin / scale, turn_cos / scale);
    let ch = psf.channels;
    let (x0, y0) = (psf.origin[0] as f32 - 0.5, psf.origin[1] as f32 - 0.5);
    let (x1, y1) = (x0 + psf.width as f32, y0 + psf.height as f32);
    let corners = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
        .map(|(x, y)| (cos * x - sin * y, sin * x + cos * y));
    let lo_x = corners
        .iter()
        .map(|c| c.0)
        .fold(f32::INFINITY, f32::min)
        .floor() as i32
        - 2;
    let lo_y = corners
        .iter()
        .map(|c| c.1)
        .fold(f32::INFINITY, f32::min)
        .floor() as i32
        - 2;
    let hi_x = corners
        .iter()
        .map(|c| c.0)
        .fold(f32::NEG_INFINITY, f32::max)
        .ceil() as i32
        + 2;
    let hi_y = corners
        .iter()
        .map(|c| c.1)
        .fold(f32::NEG_INFINITY, f32::max)
        .ceil() as i32
        + 2;
    let (width, height) = ((hi_x - lo_x + 1) as usize, (hi_y - lo_y + 1) as usize);
    let mut data = vec![0f32; width * height * ch];
    // The PSF with a border of three zero pixels: a point whose 4 x 4 taps do not all lie
    // within it reads zeros only.
    const BORDER: usize = 3;
    let (pw, ph) = (psf.width + 2 * BORDER, psf.height + 2 * BORDER);
    // One value more than the image holds: an RGB tap is read four-wide, its fourth lane
    // unused.
    let mut padded = vec![0f32; pw * ph * ch + 1];
    for v in 0..psf.height {
        let at = ((v + BORDER) * pw + BORDER) * ch;
        padded[at..at + psf.width * ch]
            .copy_from_slice(&psf.data[v * psf.width * ch..(v + 1) * psf.width * ch]);
    }
    // Catmull-Rom weights of the four taps around a point `t` past the second.
    let weights = |t: f32| -> [f32; 4] {
        let (t2, t3) = (t * t, t * t * t);
        [
            0.5 * (-t3 + 2.0 * t2 - t),
            0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
            0.5 * (-3.0 * t3 + 4.0 * t2 + t),
            0.5 * (t3 - t2),
        ]
    };
    let (ox, oy) = (psf.origin[0] - BORDER as i32, psf.origin[1] - BORDER as i32);
    let mut sum = vec![0f32; ch];
    for j in 0..height {
        for i in 0..width {
            let (qx, qy) = ((lo_x + i as i32) as f32, (lo_y + j as i32) as f32);
            let (px, py) = (inv_cos * qx + inv_sin * qy, -inv_sin * qx + inv_cos * qy);
            let (fx, fy) = (floor_exact(px), floor_exact(py));
            let (u, v) = (fx as i32 - 1 - ox, fy as i32 - 1 - oy);
            if u < 0 || v < 0 || u + 4 > pw as i32 || v + 4 > ph as i32 {
                // Every tap of a point this far out reads the border's zeros or beyond.
                continue;
            }
            let (wx, wy) = (weights(px - fx), weights(py - fy));
            let out = &mut data[(j * width + i) * ch..(j * width + i + 1) * ch];
            if ch == 3 {
                // The RGB databases' case: each tap one four-wide multiply and add (the
                // fourth lane unused), the channels' sums as the scalar loop forms them.
                let mut acc = glam::Vec4::ZERO;
                for (b, wyb) in wy.iter().enumerate() {
                    let row = ((v as usize + b) * pw + u as usize) * 3;
                    let taps = &padded[row..row + 13];
                    for (a, wxa) in wx.iter().enumerate() {
                        acc += (wxa * wyb) * glam::Vec4::from_slice(&taps[3 * a..3 * a + 4]);
                    }
                }
                for (o, s) in out.iter_mut().zip(acc.to_array()) {
                    *o = s.max(0.0);
                }
                continue;
            }
            sum.iter_mut().for_each(|s| *s = 0.0);
            for (b, wyb) in wy.iter().enumerate() {
                let row = ((v as usize + b) * pw + u as usize) * ch;
                for (a, wxa) in wx.iter().enumerate() {
                    let w = wxa * wyb;
                    let tap = &padded[row + a * ch..row + (a + 1) * ch];
                    for (s, t) in sum.iter_mut().zip(tap) {
                        *s += w * t;
                    }
                }
            }
            for (o, s) in out.iter_mut().zip(&sum) {
                *o = s.max(0.0);
            }
        }
    }
    keep_channel_sums(&psf.data, &mut data, ch);
    PsfImage {
        origin: [lo_x, lo_y],
        width,
        height,
        channels: ch,
        data,
    }
    .trimmed()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rgb_sums_are_kept_to_the_bit_as_any_channel_count_keeps_them() {
        let before: Vec<f32> = (0..300).map(|i| ((i * 37) % 101) as f32 * 0.013).collect();
        let mut after: Vec<f32> = before.iter().map(|v| v * 0.7 + 0.001).collect();
        after[5] = 0.0;
        // A channel that sums to zero is left as it is.
        let mut silent = after.clone();
        silent.iter_mut().skip(2).step_by(3).for_each(|v| *v = 0.0);
        for after in [after, silent] {
            let (mut fast, mut general) = (after.clone(), after);
            keep_rgb_sums(&before, &mut fast);
            keep_any_sums(&before, &mut general, 3);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&fast), bits(&general));
        }
    }

    fn point() -> PsfImage {
        PsfImage::point()
    }

    fn disk(radius: f32, channels: usize) -> PsfImage {
        let r = radius.ceil() as i32 + 1;
        let n = (2 * r + 1) as usize;
        let mut data = vec![0f32; n * n * channels];
        let mut sum = 0.0;
        for y in 0..n {
            for x in 0..n {
                let (px, py) = (x as f32 - r as f32, y as f32 - r as f32);
                if px * px + py * py <= radius * radius {
                    for c in 0..channels {
                        data[(y * n + x) * channels + c] = 1.0;
                    }
                    sum += 1.0;
                }
            }
        }
        data.iter_mut().for_each(|v| *v /= sum);
        PsfImage {
            origin: [-r, -r],
            width: n,
            height: n,
            channels,
            data,
        }
    }

    /// The smear drawn tap by tap, each tap's shifted PSF added with its bilinear weights
    /// straight into the image: the slow path the kernel of summed taps stands for.
    fn smear_tap_by_tap(psf: &PsfImage, length: f32, angle: f32, bend: f32) -> PsfImage {
        let extent = smear_extent(psf, length, angle, bend).unwrap();
        let ch = psf.channels;
        let mut out = vec![0f64; extent.width * extent.height * ch];
        let narrow = psf.width.min(psf.height) < NARROW_PSF_PX;
        let taps = ((length * if narrow { 4.0 } else { 1.0 }).ceil() as usize + 1).max(1);
        let kappa = f64::from(bend) / f64::from(length * length);
        let (dx, dy) = (f64::from(angle.cos()), f64::from(angle.sin()));
        for k in 0..taps {
            let s = ((k as f64 + 0.5) / taps as f64 - 0.5) * f64::from(length);
            let (along, across) = if bend == 0.0 {
                (s, 0.0)
            } else {
                ((kappa * s).sin() / kappa, (1.0 - (kappa * s).cos()) / kappa)
            };
            let sx = along * dx - across * dy + f64::from(extent.grow[0]);
            let sy = along * dy + across * dx + f64::from(extent.grow[1]);
            let (ix, iy) = (sx.floor(), sy.floor());
            let (fx, fy) = (sx - ix, sy - iy);
            for (ox, oy, w) in [
                (0, 0, (1.0 - fx) * (1.0 - fy)),
                (1, 0, fx * (1.0 - fy)),
                (0, 1, (1.0 - fx) * fy),
                (1, 1, fx * fy),
            ] {
                for y in 0..psf.height {
                    for x in 0..psf.width {
                        let at = (y + iy as usize + oy) * extent.width + x + ix as usize + ox;
                        for c in 0..ch {
                            let v = f64::from(psf.data[(y * psf.width + x) * ch + c]);
                            out[at * ch + c] += w * v / taps as f64;
                        }
                    }
                }
            }
        }
        PsfImage {
            origin: extent.origin,
            width: extent.width,
            height: extent.height,
            channels: ch,
            data: out.into_iter().map(|v| v as f32).collect(),
        }
    }

    /// The smear written within the columns it names equals the tap-by-tap smear, holds all
    /// of its light in those columns, and leaves every other pixel of its box untouched: a
    /// single lit pixel (an in-focus PSF), grey and coloured, and a three-channel disk,
    /// straight and bent, at several angles.
    #[test]
    fn a_smear_written_within_its_columns_is_the_tap_by_tap_smear() {
        let point = point();
        let coloured_point = PsfImage {
            channels: 3,
            data: vec![0.2, 0.3, 0.5],
            ..point.clone()
        };
        for psf in [point, coloured_point, disk(3.0, 3)] {
            for (length, angle, bend) in [
                (17.0, 0.0, 0.0),
                (23.5, 0.7, 0.0),
                (23.5, 2.3, 6.0),
                (9.25, -1.1, -3.0),
                (0.0, 0.4, 0.0),
            ] {
                let extent = smear_extent(&psf, length, angle, bend).unwrap();
                let slow = smear_tap_by_tap(&psf, length, angle, bend);
                let ch = psf.channels;
                let mut out = vec![0f32; extent.width * extent.height * ch];
                let mut written = vec![[0u16; 2]; extent.height];
                smear_within(&psf, length, angle, bend, extent, &mut out, &mut written);
                // The pixels outside the columns are not touched: marked, they keep the mark.
                let mut marked = vec![-7.0f32; out.len()];
                for (row, w) in marked.chunks_exact_mut(extent.width * ch).zip(&written) {
                    row[usize::from(w[0]) * ch..usize::from(w[1]) * ch].fill(0.0);
                }
                let mut again = vec![[0u16; 2]; extent.height];
                smear_within(&psf, length, angle, bend, extent, &mut marked, &mut again);
                assert_eq!(again, written);
                for (i, (&a, &b)) in out.iter().zip(&slow.data).enumerate() {
                    assert!(
                        (a - b).abs() <= 1e-6,
                        "{length} {angle} {bend}: {i}: {a} {b}"
                    );
                    let (row, column) = (i / ch / extent.width, i / ch % extent.width);
                    let [first, end] = written[row].map(usize::from);
                    if (first..end).contains(&column) {
                        assert_eq!(marked[i].to_bits(), a.to_bits(), "{i}");
                    } else {
                        assert_eq!(a, 0.0, "{length} {angle} {bend}: light outside at {i}");
                        assert_eq!(marked[i], -7.0, "{length} {angle} {bend}: touched at {i}");
                    }
                }
            }
        }
    }

    fn moments(img: &PsfImage, c: usize) -> (f64, [f64; 2], [f64; 3]) {
        let (mut s, mut mx, mut my) = (0.0f64, 0.0f64, 0.0f64);
        let (mut sxx, mut syy, mut sxy) = (0.0f64, 0.0f64, 0.0f64);
        for y in 0..img.height {
            for x in 0..img.width {
                let v = f64::from(img.data[(y * img.width + x) * img.channels + c]);
                let px = (x as i32 + img.origin[0]) as f64;
                let py = (y as i32 + img.origin[1]) as f64;
                s += v;
                mx += v * px;
                my += v * py;
                sxx += v * px * px;
                syy += v * py * py;
                sxy += v * px * py;
            }
        }
        let (cx, cy) = (mx / s, my / s);
        (
            s,
            [cx, cy],
            [sxx / s - cx * cx, syy / s - cy * cy, sxy / s - cx * cy],
        )
    }

    /// The smear drawn through its summed kernel is the mean of the PSF shifted to every tap
    /// with bilinear weights, drawn tap by tap (the slower, plainer sum), to rounding: narrow
    /// and wide PSFs, grey and RGB, along and across the axes.
    #[test]
    fn the_kernel_smear_is_the_sum_of_its_taps() {
        fn by_taps(psf: &PsfImage, length: f32, angle: f32) -> Vec<f32> {
            let (dx, dy) = (angle.cos(), angle.sin());
            let half = 0.5 * length;
            let grow_x = (half * dx.abs()).ceil() as i32 + 1;
            let grow_y = (half * dy.abs()).ceil() as i32 + 1;
            let width = psf.width + 2 * grow_x as usize;
            let height = psf.height + 2 * grow_y as usize;
            let ch = psf.channels;
            let mut out = vec![0f32; width * height * ch];
            let narrow = psf.width.min(psf.height) < NARROW_PSF_PX;
            let taps_per_px = if narrow { 4.0 } else { 1.0 };
            let taps = ((length * taps_per_px).ceil() as usize + 1).max(1);
            for k in 0..taps {
                let t = ((k as f32 + 0.5) / taps as f32 - 0.5) * length;
                let (sx, sy) = (t * dx + grow_x as f32, t * dy + grow_y as f32);
                let (fx, fy) = (sx - sx.floor(), sy - sy.floor());
                let (ix, iy) = (sx.floor() as usize, sy.floor() as usize);
                for (ox, oy, w) in [
                    (0, 0, (1.0 - fx) * (1.0 - fy)),
                    (1, 0, fx * (1.0 - fy)),
                    (0, 1, (1.0 - fx) * fy),
                    (1, 1, fx * fy),
                ] {
                    for y in 0..psf.height {
                        for x in 0..psf.width * ch {
                            let at = ((y + iy + oy) * width + ix + ox) * ch + x;
                            out[at] += w / taps as f32 * psf.data[y * psf.width * ch + x];
                        }
                    }
                }
            }
            out
        }
        for (psf, ch) in [(disk(1.5, 1), 1), (disk(6.0, 1), 1), (disk(2.5, 3), 3)] {
            for (length, angle) in [(0.7f32, 0.3f32), (9.0, 0.0), (14.5, 1.1), (23.0, -2.6)] {
                let fast = smear(&psf, length, angle, 0.0).expect("smear");
                let slow = by_taps(&psf, length, angle);
                assert_eq!(fast.data.len(), slow.len());
                let worst = fast
                    .data
                    .iter()
                    .zip(&slow)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0f32, f32::max);
                assert!(
                    worst < 1e-6,
                    "{ch} channels, L {length}, angle {angle}: {worst}"
                );
            }
        }
    }

    /// The sub-pixel smear is to the bit the plain sum of each tap's shifted image, in tap
    /// order, placed where its shift rounds to: on paths whose taps reach the box's last
    /// columns, and on images of several widths.
    #[test]
    fn sub_pixel_smears_rows_are_the_taps_plain_sum() {
        use crate::subpixel_psf::SubpixelPsf;
        for (size, r) in [(5usize, 1.2f64), (7, 2.6), (3, 1.0)] {
            let origin = -(size as i32 / 2);
            let sub = SubpixelPsf::of_radii(&[r], [origin; 2], size, size);
            let base = PsfImage {
                origin: sub.origin,
                width: size,
                height: size,
                channels: 1,
                data: vec![1.0; size * size],
            };
            for (length, angle) in [(16.3f32, 0.111f32), (9.0, 0.9), (12.0, 2.8), (5.5, -1.9)] {
                let extent = smear_extent(&base, length, angle, 0.0).expect("extent");
                let n = extent.width * extent.height;
                let (mut ours, mut rows) = (vec![0f32; n], vec![[0u16; 2]; extent.height]);
                smear_within_subpixel(&sub, length, angle, 0.0, extent, &mut ours, &mut rows);
                // The same taps and places, each image added value by value.
                let (shifts, share) =
                    tap_shifts(length, angle, 0.0, extent.grow, SUBPIXEL_TAPS_PER_PX);
                let mut plain = vec![0f32; n];
                for [sx, sy] in shifts {
                    let place = |v: f32| {
                        let whole = v.floor() as usize;
                        let step = ((v - whole as f32) * STEPS as f32).round() as usize;
                        if step >= STEPS {
                            (whole + 1, 0)
                        } else {
                            (whole, step)
                        }
                    };
                    let ((ix, a), (iy, b)) = (place(sx), place(sy));
                    let image = sub.shifted(a, b);
                    for y in 0..sub.height {
                        for x in 0..sub.width {
                            if ix + x < extent.width && iy + y < extent.height {
                                plain[(iy + y) * extent.width + ix + x] +=
                                    share * image[y * sub.width + x];
                            }
                        }
                    }
                }
                for (i, (a, b)) in ours.iter().zip(&plain).enumerate() {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "size {size}, L {length}, angle {angle}: pixel {i}"
                    );
                }
            }
        }
    }

    /// A narrow disc smeared along a slanted path through its images at sub-pixel shifts
    /// against the exact box-filtered streak (each pixel's points, the share of the path
    /// within the disc's radius of each), beside the bilinear taps' smear: the streak's sides
    /// keep their sharpness, and its light and box are the same.
    #[test]
    fn a_narrow_disc_smeared_at_sub_pixel_shifts_keeps_its_streaks_sides() {
        use crate::subpixel_psf::SubpixelPsf;
        let r = 1.2f64;
        let sub = SubpixelPsf::of_radii(&[r], [-2, -2], 5, 5);
        let base = PsfImage {
            origin: sub.origin,
            width: 5,
            height: 5,
            channels: 1,
            data: (0..25)
                .map(|i| sub.shifted(0, 0)[(i / 5) * 6 + i % 5])
                .collect(),
        };
        for (length, angle) in [(16.3f32, 0.111f32), (9.0, 0.9), (12.0, 2.8)] {
            let extent = smear_extent(&base, length, angle, 0.0).expect("extent");
            let n = extent.width * extent.height;
            let (mut bilinear, mut rows) = (vec![0f32; n], vec![[0u16; 2]; extent.height]);
            smear_within(&base, length, angle, 0.0, extent, &mut bilinear, &mut rows);
            let (mut shifted, mut rows_shifted) = (vec![0f32; n], vec![[0u16; 2]; extent.height]);
            let out = (&mut shifted, &mut rows_shifted);
            smear_within_subpixel(&sub, length, angle, 0.0, extent, out.0, out.1);
            // The exact streak: a point's density is the share of the path within r of it.
            let (dx, dy) = (f64::from(angle).cos(), f64::from(angle).sin());
            let half = 0.5 * f64::from(length);
            let m = 24;
            let exact: Vec<f64> = (0..n)
                .map(|i| {
                    let x = (i % extent.width) as i32 + extent.origin[0];
                    let y = (i / extent.width) as i32 + extent.origin[1];
                    let mut share = 0.0;
                    for j in 0..m {
                        for k in 0..m {
                            let px = f64::from(x) - 0.5 + (k as f64 + 0.5) / m as f64;
                            let py = f64::from(y) - 0.5 + (j as f64 + 0.5) / m as f64;
                            // |p - t d| <= r for t in [t0, t1]
                            let along = px * dx + py * dy;
                            let across2 = px * px + py * py - along * along;
                            if across2 <= r * r {
                                let reach = (r * r - across2).sqrt();
                                let t0 = (along - reach).max(-half);
                                let t1 = (along + reach).min(half);
                                share += (t1 - t0).max(0.0);
                            }
                        }
                    }
                    share / (m * m) as f64 / (2.0 * half) / (std::f64::consts::PI * r * r)
                })
                .collect();
            let rms = |image: &[f32]| {
                let squares = image
                    .iter()
                    .zip(&exact)
                    .map(|(&a, &b)| (f64::from(a) - b).powi(2));
                let s: f64 = squares.sum();
                (s / n as f64).sqrt()
            };
            let sum = |image: &[f32]| image.iter().map(|&v| f64::from(v)).sum::<f64>();
            assert!(
                (sum(&shifted) - sum(&bilinear)).abs() < 1e-4,
                "L {length}: light"
            );
            let (ours, theirs) = (rms(&shifted), rms(&bilinear));
            assert!(
                ours < 0.25 * theirs,
                "L {length}, angle {angle}: rms {ours} against bilinear {theirs}"
            );
            // Rows outside their written columns hold zeros.
            for (row, span) in shifted.chunks(extent.width).zip(&rows_shifted) {
                for (x, &v) in row.iter().enumerate() {
                    if x < usize::from(span[0]) || x >= usize::from(span[1]) {
                        assert_eq!(v, 0.0);
                    }
                }
            }
        }
    }

    /// A box of length L adds L^2/12 to the variance along its direction and nothing across
    /// it; the sum and the centroid stay.
    #[test]
    fn smear_adds_the_segments_variance_along_its_direction() {
        let psf = disk(4.0, 3);
        let (_, _, var0) = moments(&psf, 1);
        for (len, angle) in [(12.0f32, 0.0f32), (20.0, 0.7), (7.5, 2.0)] {
            let out = smear(&psf, len, angle, 0.0).expect("smear");
            let (s, c, var) = moments(&out, 1);
            assert!((s - 1.0).abs() < 1e-5, "sum {s}");
            assert!(c[0].abs() < 1e-3 && c[1].abs() < 1e-3, "centroid {c:?}");
            let (dx, dy) = (f64::from(angle.cos()), f64::from(angle.sin()));
            // Variance along the direction and across it.
            let along = var[0] * dx * dx + var[1] * dy * dy + 2.0 * var[2] * dx * dy;
            let across = var[0] * dy * dy + var[1] * dx * dx - 2.0 * var[2] * dx * dy;
            let base = var0[0];
            let taps = (len.ceil() + 1.0) as f64;
            let l = f64::from(len);
            // The taps' discrete variance: L^2 (1 - 1/taps^2) / 12, plus what the bilinear
            // weights add (at most 1/4 px^2 per axis).
            let expected = base + l * l * (1.0 - 1.0 / (taps * taps)) / 12.0;
            assert!(
                (along - expected).abs() < 0.3,
                "L {len} angle {angle}: along {along}, expected {expected}"
            );
            assert!((across - base).abs() < 0.3, "across {across}, base {base}");
        }
    }

    /// A PSF in a box much wider than its light is cut to its light, in place, with each
    /// channel's sum kept.
    #[test]
    fn trimming_keeps_the_light_in_place() {
        let mut psf = disk(3.0, 2);
        let (w0, h0) = (psf.width, psf.height);
        // Pad with empty columns on the left and rows at the bottom, and a faint floor.
        let (pad_x, pad_y) = (9usize, 6usize);
        let (w, h) = (w0 + pad_x, h0 + pad_y);
        let mut data = vec![1e-9f32; w * h * 2];
        for y in 0..h0 {
            for x in 0..w0 {
                for c in 0..2 {
                    data[(y * w + x + pad_x) * 2 + c] = psf.data[(y * w0 + x) * 2 + c];
                }
            }
        }
        let before = moments(
            &PsfImage {
                origin: [psf.origin[0] - pad_x as i32, psf.origin[1]],
                width: w,
                height: h,
                channels: 2,
                data: data.clone(),
            },
            0,
        );
        psf = PsfImage {
            origin: [psf.origin[0] - pad_x as i32, psf.origin[1]],
            width: w,
            height: h,
            channels: 2,
            data,
        }
        .trimmed();
        assert!(
            psf.width <= w0 && psf.height <= h0,
            "{} x {}",
            psf.width,
            psf.height
        );
        let after = moments(&psf, 0);
        assert!(
            (after.0 - before.0).abs() < 1e-6,
            "sum {} -> {}",
            before.0,
            after.0
        );
        assert!((after.1[0] - before.1[0]).abs() < 1e-3 && (after.1[1] - before.1[1]).abs() < 1e-3);
    }

    /// A disk of radius 8 px scaled by 9/8 has the RMS radius of a disk of 9 px (to the
    /// pixel lattice's rounding), keeps its sum, and stays where it was; its rim is as steep
    /// as the larger disk's, where mixing the two disks would leave a step of half height.
    #[test]
    fn scaling_a_psf_gives_the_larger_disks_size_and_rim() {
        let (small, large) = (disk(8.0, 1), disk(9.0, 1));
        let scaled = turn_scaled(&small, 0.7, 9.0 / 8.0);
        let (s0, _, _) = moments(&small, 0);
        let (s1, c1, v1) = moments(&scaled, 0);
        let (_, _, v9) = moments(&large, 0);
        assert!((s1 - s0).abs() < 1e-5, "sum {s0} -> {s1}");
        assert!(c1[0].abs() < 0.02 && c1[1].abs() < 0.02, "centroid {c1:?}");
        let rms = |v: [f64; 3]| (v[0] + v[1]).sqrt();
        assert!(
            (rms(v1) / rms(v9) - 1.0).abs() < 0.01,
            "RMS radius {} against the 9 px disk's {}",
            rms(v1),
            rms(v9)
        );
        // Along +x, the light between 8.5 and 9.5 px from the centre: the scaled disk's rim
        // lies where the larger disk's does.
        let at = |img: &PsfImage, x: i32| {
            let (u, v) = (x - img.origin[0], -img.origin[1]);
            if u < 0 || u >= img.width as i32 {
                return 0.0;
            }
            img.data[v as usize * img.width + u as usize]
        };
        let level = at(&large, 0);
        assert!(at(&scaled, 8) > 0.8 * level && at(&scaled, 10) < 0.05 * level);
    }

    /// Turning keeps the sum and moves the centroid and the spread as a rotation does: a box
    /// off centre turned a quarter turn lands where the quarter turn puts it.
    #[test]
    fn turning_moves_a_psf_as_a_rotation_does() {
        let mut data = vec![0f32; 9 * 5];
        for y in 1..4 {
            for x in 5..9 {
                data[y * 9 + x] = 1.0 / 12.0;
            }
        }
        // Box over x in [1, 4], y in [-1, 1] relative to the centre.
        let psf = PsfImage {
            origin: [-4, -2],
            width: 9,
            height: 5,
            channels: 1,
            data,
        };
        let (s0, c0, v0) = moments(&psf, 0);
        let turned = turn(&psf, std::f32::consts::FRAC_PI_2);
        let (s1, c1, v1) = moments(&turned, 0);
        assert!((s1 - s0).abs() < 1e-5);
        // +x turns onto +y (y down).
        assert!(
            (c1[0] + c0[1]).abs() < 0.05 && (c1[1] - c0[0]).abs() < 0.05,
            "{c0:?} -> {c1:?}"
        );
        assert!(
            (v1[0] - v0[1]).abs() < 0.3 && (v1[1] - v0[0]).abs() < 0.3,
            "{v0:?} -> {v1:?}"
        );
    }

    /// The frame budget's estimate is an upper bound on what a key builds.
    #[test]
    fn the_estimate_bounds_the_smeared_image() {
        let psf = disk(6.0, 3);
        let reach = 7.0 * std::f32::consts::SQRT_2;
        for (len, angle, turn_by, bend) in [
            (30.0f32, 0.4f32, 1.0f32, 0.0f32),
            (3.0, 2.0, 4.0, 0.0),
            (80.0, 1.57, 0.0, 0.0),
            (30.0, 0.4, 1.0, 40.0),
            (80.0, 2.5, 0.0, -200.0),
        ] {
            let m = [len * angle.cos(), len * angle.sin()];
            let (key, _) = SmearKey::new(0, m, bend, [turn_by.cos(), turn_by.sin()], reach);
            let turned = turn(&psf, key.turn_rad());
            let out =
                smear(&turned, key.length_px(), key.angle_rad(), key.bend_px()).expect("smear");
            assert!(
                out.width * out.height <= key.estimated_pixels(reach),
                "{} x {} > {}",
                out.width,
                out.height,
                key.estimated_pixels(reach)
            );
        }
    }

    /// A point smeared along a bent path lies on the arc: its light's mean offset across the
    /// chord is the arc's, `mean over s of (1 - cos(kappa s)) / kappa`, and its ends sit the
    /// sagitta off the chord. Reversing the motion and the bend draws the same arc.
    #[test]
    fn a_bent_smear_lies_on_its_arc() {
        let point = point();
        let (len, bend) = (30.0f32, 12.0f32);
        let out = smear(&point, len, 0.0, bend).expect("smear");
        let total: f64 = out.data.iter().map(|&v| f64::from(v)).sum();
        assert!((total - 1.0).abs() < 1e-5, "{total}");
        let mean_y: f64 = (0..out.height)
            .flat_map(|y| (0..out.width).map(move |x| (x, y)))
            .map(|(x, y)| {
                f64::from(out.data[y * out.width + x]) * f64::from(out.origin[1] + y as i32)
            })
            .sum();
        let kappa = f64::from(bend) / f64::from(len * len);
        let n = 10_000;
        let arc: f64 = (0..n)
            .map(|k| {
                (1.0 - (kappa * ((k as f64 + 0.5) / n as f64 - 0.5) * f64::from(len)).cos()) / kappa
            })
            .sum::<f64>()
            / n as f64;
        assert!(
            (mean_y - arc).abs() < 0.02,
            "mean offset {mean_y}, arc {arc}"
        );
        assert!((f64::from(sagitta(len, bend)) - 1.4950).abs() < 1e-3);
        // The end columns hold light at the sagitta's rows only.
        let end = |x: usize| -> f64 {
            let col: Vec<f64> = (0..out.height)
                .map(|y| f64::from(out.data[y * out.width + x]))
                .collect();
            let w: f64 = col.iter().sum();
            col.iter()
                .enumerate()
                .map(|(y, v)| v * f64::from(out.origin[1] + y as i32))
                .sum::<f64>()
                / w
        };
        let lit: Vec<usize> = (0..out.width)
            .filter(|&x| (0..out.height).any(|y| out.data[y * out.width + x] > 0.0))
            .collect();
        for x in [lit[0], lit[lit.len() - 1]] {
            assert!(
                end(x) > 1.0 && end(x) < 1.6,
                "column {x} centred at {}",
                end(x)
            );
        }
        let reversed = smear(&point, len, std::f32::consts::PI, -bend).expect("smear");
        let sum_diff: f32 = reversed
            .data
            .iter()
            .zip(&out.data)
            .map(|(a, b)| (a - b).abs())
            .sum();
        assert_eq!((reversed.width, reversed.height), (out.width, out.height));
        assert!(sum_diff < 1e-4, "{sum_diff}");
    }

    /// A key bends the same arc whichever way along it the motion points.
    #[test]
    fn a_reversed_motion_keeps_its_arc() {
        let (forward, _) = SmearKey::new(0, [20.0, 5.0], 10.0, [1.0, 0.0], 3.0);
        let (backward, _) = SmearKey::new(0, [-20.0, -5.0], -10.0, [1.0, 0.0], 3.0);
        assert_eq!(forward, backward);
        assert_eq!(forward.bend_px(), 10.0);
        let (up, _) = SmearKey::new(0, [20.0, -5.0], 10.0, [1.0, 0.0], 3.0);
        // Folded onto the opposite direction (angles modulo pi): the bend turns over with it.
        assert_eq!(up.bend_px(), -10.0);
        let (straight, _) = SmearKey::new(0, [20.0, 5.0], 0.9, [1.0, 0.0], 3.0);
        assert_eq!(straight.bend_step, 0);
    }

    #[test]
    fn keys_quantise_lengths_and_angles_finely() {
        for len in [0.6f32, 3.3, 8.0, 9.7, 37.0, 200.0] {
            for angle in [0.0f32, 0.3, 1.5, 2.9, -1.0] {
                let m = [len * angle.cos(), len * angle.sin()];
                let (key, clamped) = SmearKey::new(7, m, 0.0, [0.6, -0.8], 10.0);
                let turn = (-0.8f32).atan2(0.6).rem_euclid(std::f32::consts::TAU);
                let mut dt = (key.turn_rad() - turn).abs();
                dt = dt.min(std::f32::consts::TAU - dt);
                assert!(10.0 * dt <= 0.26, "turn {turn} -> {}", key.turn_rad());
                assert!(!clamped);
                assert_eq!(key.cell, 7);
                let l = key.length_px();
                assert!((l - len).abs() <= 0.125 + 0.01 * len, "length {len} -> {l}");
                // The direction modulo pi: the segment reversed is the same segment.
                let a = angle.rem_euclid(std::f32::consts::PI);
                let mut d = (key.angle_rad() - a).abs();
                d = d.min(std::f32::consts::PI - d);
                let tip = 0.5 * l * d;
                assert!(
                    tip <= 0.3,
                    "length {len} angle {angle}: tip off by {tip} px"
                );
            }
        }
        let (_, clamped) = SmearKey::new(0, [MAX_SMEAR_PX + 10.0, 0.0], 0.0, [1.0, 0.0], 4.0);
        assert!(clamped);
    }

    #[test]
    fn dithered_keys_lengths_step_twice_as_far_and_average_to_the_motion() {
        for len in [12.0f32, 39.5, 90.0, 300.0] {
            let m = [len * 0.6, len * 0.8];
            let key =
                |t: f32, angles| SmearKey::quantised(3, m, 0.0, [1.0, 0.0], 10.0, t, angles).0;
            // The two steps either side of the length, at each resolution.
            let steps = |angles| {
                let (lo, hi) = (key(0.0, angles), key(0.999, angles));
                (
                    lo.length_px(),
                    hi.length_px(),
                    hi.length_step - lo.length_step,
                )
            };
            let (lo, hi, n) = steps(AngleResolution::Rounded);
            assert_eq!(n, 1);
            assert!((hi / lo - COARSE_LENGTH_RATIO).abs() < 1e-4, "{lo} {hi}");
            let (lo, hi, n) = steps(AngleResolution::Dithered);
            assert_eq!(n, 1);
            assert!((hi / lo - DITHERED_LENGTH_RATIO).abs() < 1e-4, "{lo} {hi}");
            assert!(lo <= len && len <= hi, "{len} between {lo} and {hi}");
            // Over thresholds spread evenly, the dithered lengths' mean is the motion's.
            let n = 256;
            let mean = (0..n)
                .map(|k| key((k as f32 + 0.5) / n as f32, AngleResolution::Dithered).length_px())
                .map(f64::from)
                .sum::<f64>()
                / f64::from(n);
            assert!(
                (mean / f64::from(len) - 1.0).abs() < 2e-3,
                "length {len}: mean {mean}"
            );
        }
    }

    #[test]
    fn dithered_angles_average_to_the_motion_with_tips_within_a_pixel() {
        for len in [12.0f32, 39.0, 90.0] {
            for angle in [0.05f32, 0.7, 1.9, 3.0] {
                let m = [len * angle.cos(), len * angle.sin()];
                let dithered = |t: f32| {
                    SmearKey::quantised(3, m, 0.0, [1.0, 0.0], 10.0, t, AngleResolution::Dithered).0
                };
                let rounded =
                    SmearKey::quantised(3, m, 0.0, [1.0, 0.0], 10.0, 0.5, AngleResolution::Rounded)
                        .0;
                // Steps twice as far apart: half the keys a frame's angles can fall on (give or
                // take the dithered length's step, 4 % of it).
                let (nd, nr) = (dithered(0.0).angle_steps(), rounded.angle_steps());
                let half = nr as f32 / 2.0;
                assert!(
                    (nd as f32 - half).abs() <= 0.04 * half + 2.0,
                    "{nd} steps against {nr}"
                );
                // Over thresholds spread evenly, the keys' mean angle is the motion's, and each
                // key's tip is within a pixel of the motion's.
                let n = 256;
                let mut mean = 0.0f64;
                for k in 0..n {
                    let key = dithered((k as f32 + 0.5) / n as f32);
                    let mut d = key.angle_rad() - angle.rem_euclid(std::f32::consts::PI);
                    if d > std::f32::consts::FRAC_PI_2 {
                        d -= std::f32::consts::PI;
                    } else if d < -std::f32::consts::FRAC_PI_2 {
                        d += std::f32::consts::PI;
                    }
                    let tip = 0.5 * key.length_px() * d.abs();
                    assert!(
                        tip <= 1.0 + 0.02 * len,
                        "length {len} angle {angle}: tip {tip} px"
                    );
                    mean += f64::from(d) / f64::from(n);
                }
                let mean_tip = 0.5 * f64::from(len) * mean.abs();
                // (The length's step, dithered by the same threshold, moves the angle steps,
                // and its steps of 4 % more than those of 2 % did: the mean is off by a sixth
                // of a pixel at most on a 90 px streak (a twentieth with 2 %), where a rounded
                // angle is off by up to a quarter and flooring it by up to a half.)
                assert!(
                    mean_tip < 0.2,
                    "length {len} angle {angle}: mean tip {mean_tip} px"
                );
                // A narrow PSF's angle stays in fine steps, rounded: within half a step.
                for t in [0.1, 0.9] {
                    let narrow = SmearKey::quantised(
                        3,
                        m,
                        0.0,
                        [1.0, 0.0],
                        2.0,
                        t,
                        AngleResolution::Dithered,
                    )
                    .0;
                    assert_eq!(narrow.angle_resolution, AngleResolution::Fine);
                    let a = angle.rem_euclid(std::f32::consts::PI);
                    let mut d = (narrow.angle_rad() - a).abs();
                    d = d.min(std::f32::consts::PI - d);
                    let half_step = 0.5 * std::f32::consts::PI / narrow.angle_steps() as f32;
                    assert!(
                        d <= half_step * 1.001,
                        "length {len} angle {angle}: {d} rad off"
                    );
                }
            }
        }
        // Dithering the length alone keeps the rounded angle.
        let (a, _) = SmearKey::dithered(1, [30.0, 11.0], 0.0, [1.0, 0.0], 10.0, 0.8);
        let (b, _) = SmearKey::new(1, [30.0, 11.0], 0.0, [1.0, 0.0], 10.0);
        assert_eq!(
            (a.angle_step, a.angle_resolution),
            (b.angle_step, b.angle_resolution)
        );
    }

    #[test]
    fn re_keying_the_angles_gives_the_keys_of_keying_afresh() {
        // Motions every way, bent either way or not at all (and beyond half a turn), on wide
        // and narrow PSFs, at thresholds across [0, 1): a key re-quantised at another angle
        // resolution is the key quantised at it from the start.
        let resolutions = [
            AngleResolution::Rounded,
            AngleResolution::Dithered,
            AngleResolution::Fine,
        ];
        for len in [0.3f32, 5.0, 12.0, 47.5, 90.0, 600.0] {
            for k in 0..24 {
                let angle = k as f32 * 0.2618 + 0.01;
                let m = [len * angle.cos(), len * angle.sin()];
                for bend in [0.0f32, 0.7, -1.2, 6.0, -40.0, 1e6, f32::NAN] {
                    for reach in [2.0f32, 10.0] {
                        for t in [0.0f32, 0.3, 0.99] {
                            for (from, to) in resolutions
                                .iter()
                                .flat_map(|&a| resolutions.map(|b| (a, b)))
                            {
                                let (first, clamped) =
                                    SmearKey::quantised(3, m, bend, [0.0, 1.0], reach, t, from);
                                let (afresh, clamped_afresh) =
                                    SmearKey::quantised(3, m, bend, [0.0, 1.0], reach, t, to);
                                assert_eq!(
                                    first.with_angles(m, bend, reach, t, to),
                                    afresh,
                                    "{m:?} bent {bend}"
                                );
                                assert_eq!(clamped, clamped_afresh);
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_sparse_psf_integrates_to_its_image() {
        // The Laplacian of a 3x3 box, stored as spreadlets, integrates back to the box.
        let mut image = poisson::Plane::new(9, 9);
        for y in 3..6 {
            for x in 3..6 {
                image.set(x, y, 1.0 / 9.0);
            }
        }
        let lap = poisson::laplacian(&image);
        let (mut pos, mut val) = (Vec::new(), Vec::new());
        for y in 0..9 {
            for x in 0..9 {
                let v = lap.get(x, y);
                if v != 0.0 {
                    pos.push([x as i16 - 4, y as i16 - 4]);
                    val.push(v);
                }
            }
        }
        let space = psf_db::ParamSpace::for_model(psf_db::PsfModel::ThinLens, &[[0.0, 1.0]], 1)
            .expect("space");
        let mut b = psf_db::DatabaseBuilder::new(psf_db::DbHeader::new(
            psf_db::PsfModel::ThinLens,
            space,
            16,
        ));
        b.push_sparse(&pos, &val).expect("push");
        let db = b.finish().expect("db");
        let img = psf_image(&db, 0).expect("image");
        for y in 0..img.height {
            for x in 0..img.width {
                let px = x as i32 + img.origin[0];
                let py = y as i32 + img.origin[1];
                let want = if px.abs() <= 1 && py.abs() <= 1 {
                    1.0 / 9.0
                } else {
                    0.0
                };
                let got = img.data[y * img.width + x];
                assert!((got - want).abs() < 1e-5, "({px},{py}): {got} vs {want}");
            }
        }
    }
}
