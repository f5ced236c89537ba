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
//! the field position change along the segment; `tests::factorised_motion_psf_matches_brute_force`
//! measures that against light tracing every instant through the lens.
//!
//! The smear is applied in the PSF's own frame (radial along +x), so the segment's direction is
//! the motion's angle relative to the radial direction; the record then turns the smeared PSF
//! onto the radial direction as for a still pixel. A segment reversed is the same segment, so
//! the relative angle is taken modulo pi.
//!
//! The smeared PSFs are built per frame, for the (cell, length, angle) keys its moving pixels
//! use, and appended to the frame's database as dense PSFs. Keys are quantised so that a
//! streak's ends are off by at most about a quarter pixel: the length in steps of 1/4 px up to
//! 8 px and of 2 % beyond, the angle in steps of at most 1/length radians (the tip of a streak
//! of length `L` moves `L/2 * dtheta/2` px at most).

use psf_db::PsfDatabase;

/// Lengths up to this (px) are quantised in steps of [`FINE_LENGTH_STEP_PX`].
const FINE_LENGTH_MAX_PX: f32 = 8.0;
/// Length step below [`FINE_LENGTH_MAX_PX`], px.
const FINE_LENGTH_STEP_PX: f32 = 0.25;
/// Relative length step beyond [`FINE_LENGTH_MAX_PX`].
const COARSE_LENGTH_RATIO: f32 = 1.02;
/// Largest motion length smeared, px: a longer one is clamped (and counted as clamped).
pub const MAX_SMEAR_PX: f32 = 512.0;
/// Largest smeared PSF image, pixels: its width times height. Beyond it the smear's taps are
/// what costs, not the memory; a frame that needs more is an error rather than a slow crawl.
const MAX_SMEARED_PIXELS: usize = 4 << 20;

/// Which smeared PSF a moving fragment uses: its physical-lens cell (index in the set's
/// combined database), its motion length and its angle to the radial direction, quantised.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SmearKey {
    /// Index of the lens PSF in the combined database.
    pub cell: u32,
    /// Quantised motion length (see [`SmearKey::length_px`]).
    pub length_step: u32,
    /// Quantised angle from the radial direction, in `[0, angle_steps)`, modulo pi.
    pub angle_step: u32,
}

impl SmearKey {
    /// The key of lens PSF `cell` smeared along `motion_rel` (px, in the PSF's frame: the
    /// radial direction along +x, y down). Returns the key and whether the length was clamped.
    pub fn new(cell: u32, motion_rel: [f32; 2]) -> (Self, bool) {
        let len = (motion_rel[0] * motion_rel[0] + motion_rel[1] * motion_rel[1]).sqrt();
        let clamped = len > MAX_SMEAR_PX;
        let len = len.min(MAX_SMEAR_PX);
        let length_step = if len <= FINE_LENGTH_MAX_PX {
            (len / FINE_LENGTH_STEP_PX).round() as u32
        } else {
            let fine = (FINE_LENGTH_MAX_PX / FINE_LENGTH_STEP_PX) as u32;
            fine + ((len / FINE_LENGTH_MAX_PX).ln() / COARSE_LENGTH_RATIO.ln()).round() as u32
        };
        let key = SmearKey {
            cell,
            length_step,
            angle_step: 0,
        };
        let n = key.angle_steps();
        let angle = motion_rel[1].atan2(motion_rel[0]).rem_euclid(std::f32::consts::PI);
        let step = ((angle / std::f32::consts::PI * n as f32).round() as u32) % n;
        (
            SmearKey {
                angle_step: step,
                ..key
            },
            clamped,
        )
    }

    /// The motion length this key smears over, px.
    pub fn length_px(&self) -> f32 {
        let fine = (FINE_LENGTH_MAX_PX / FINE_LENGTH_STEP_PX) as u32;
        if self.length_step <= fine {
            self.length_step as f32 * FINE_LENGTH_STEP_PX
        } else {
            FINE_LENGTH_MAX_PX * COARSE_LENGTH_RATIO.powi((self.length_step - fine) as i32)
        }
    }

    /// How many angle steps cover pi at this key's length: at least 1/length radians apart.
    pub fn angle_steps(&self) -> u32 {
        let len = self.length_px();
        (std::f32::consts::PI * len).ceil().max(4.0) as u32
    }

    /// The angle of the segment from the radial direction, radians in `[0, pi)`.
    pub fn angle_rad(&self) -> f32 {
        self.angle_step as f32 * std::f32::consts::PI / self.angle_steps() as f32
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
}

/// PSF `index` of `db` as a non-negative image: a dense PSF as stored, a sparse one integrated
/// from its spreadlets (the exact inverse of the one Laplacian stencil, on a plane two pixels
/// wider on every side than the spreadlets) with the sparse fit's negative residue clamped to
/// zero and each channel scaled back to its sum (a bright pixel times a negative residue
/// draws a dark speck). `None` for an empty PSF.
pub fn psf_image(db: &PsfDatabase, index: usize) -> Option<PsfImage> {
    let channels = db.channels();
    if let Some(d) = db.dense(index) {
        return Some(PsfImage {
            origin: d.origin,
            width: d.width,
            height: d.height,
            channels: d.channels,
            data: d.data.to_vec(),
        });
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
    let mut data = vec![0f32; width * height * channels];
    for c in 0..channels {
        let mut lap = poisson::Plane::new(width, height);
        for (k, p) in positions.iter().enumerate() {
            let x = (i32::from(p[0]) - origin[0]) as usize;
            let y = (i32::from(p[1]) - origin[1]) as usize;
            lap.add(x, y, values[k * channels + c]);
        }
        let image = poisson::integrate_exact(&lap);
        let sum: f64 = image.data.iter().map(|&v| f64::from(v)).sum();
        let kept: f64 = image.data.iter().map(|&v| f64::from(v.max(0.0))).sum();
        let scale = if kept > 0.0 { (sum / kept) as f32 } else { 0.0 };
        for y in 0..height {
            for x in 0..width {
                data[(y * width + x) * channels + c] = image.get(x, y).max(0.0) * scale;
            }
        }
    }
    Some(PsfImage {
        origin,
        width,
        height,
        channels,
        data,
    })
}

/// `psf` convolved with a uniform segment of `length` px centred on the PSF centre, at
/// `angle` radians from +x (y down): the mean of `psf` shifted to `taps` points spaced at most
/// one pixel apart along the segment (the midpoints of equal parts), each shift drawn with
/// bilinear weights. Every channel keeps its sum.
pub fn smear(psf: &PsfImage, length: f32, angle: f32) -> Result<PsfImage, SmearError> {
    let (dx, dy) = (angle.cos(), angle.sin());
    let half = 0.5 * length;
    // One pixel more on each side than the segment reaches: the bilinear weights of a shift
    // spill one pixel beyond its integer part.
    let grow_x = (half * dx.abs()).ceil() as i32 + 1;
    let grow_y = (half * dy.abs()).ceil() as i32 + 1;
    let width = psf.width + 2 * grow_x as usize;
    let height = psf.height + 2 * grow_y as usize;
    if width * height > MAX_SMEARED_PIXELS {
        return Err(SmearError::TooLarge {
            length_px: length,
            width,
            height,
        });
    }
    let ch = psf.channels;
    let mut out = vec![0f32; width * height * ch];
    let taps = (length.ceil() as usize + 1).max(1);
    let share = 1.0 / taps as f32;
    for k in 0..taps {
        let t = ((k as f32 + 0.5) / taps as f32 - 0.5) * length;
        // The shift of this tap, in output pixels relative to the input's placement.
        let sx = t * dx + grow_x as f32;
        let sy = t * dy + grow_y as f32;
        let (ix, iy) = (sx.floor(), sy.floor());
        let (fx, fy) = (sx - ix, sy - iy);
        let (ix, iy) = (ix as usize, iy as usize);
        let weights = [
            (0, 0, (1.0 - fx) * (1.0 - fy) * share),
            (1, 0, fx * (1.0 - fy) * share),
            (0, 1, (1.0 - fx) * fy * share),
            (1, 1, fx * fy * share),
        ];
        for &(ox, oy, w) in &weights {
            if w == 0.0 {
                continue;
            }
            for y in 0..psf.height {
                let src = &psf.data[y * psf.width * ch..(y + 1) * psf.width * ch];
                let row = (y + iy + oy) * width + ix + ox;
                let dst = &mut out[row * ch..(row + psf.width) * ch];
                for (d, s) in dst.iter_mut().zip(src) {
                    *d += w * s;
                }
            }
        }
    }
    Ok(PsfImage {
        origin: [psf.origin[0] - grow_x, psf.origin[1] - grow_y],
        width,
        height,
        channels: ch,
        data: out,
    })
}

/// The smeared PSF of `key` from the lens PSFs of `db` (`None` for an empty lens PSF).
pub fn smeared_psf(db: &PsfDatabase, key: SmearKey) -> Result<Option<PsfImage>, SmearError> {
    let Some(psf) = psf_image(db, key.cell as usize) else {
        return Ok(None);
    };
    smear(&psf, key.length_px(), key.angle_rad()).map(Some)
}

#[cfg(test)]
mod tests {
    use super::*;

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

    /// A box of length L adds L^2/12 to the variance along its direction and nothing across
    /// it; the sum and the centroid stay.
    #[test]
    fn smear_adds_the_segments_variance_along_its_direction() {
        let psf = disk(4.0, 3);
        let (_, _, var0) = moments(&psf, 1);
        for (len, angle) in [(12.0f32, 0.0f32), (20.0, 0.7), (7.5, 2.0)] {
            let out = smear(&psf, len, angle).expect("smear");
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

    #[test]
    fn keys_quantise_lengths_and_angles_finely() {
        for len in [0.6f32, 3.3, 8.0, 9.7, 37.0, 200.0] {
            for angle in [0.0f32, 0.3, 1.5, 2.9, -1.0] {
                let m = [len * angle.cos(), len * angle.sin()];
                let (key, clamped) = SmearKey::new(7, m);
                assert!(!clamped);
                assert_eq!(key.cell, 7);
                let l = key.length_px();
                assert!(
                    (l - len).abs() <= 0.125 + 0.01 * len,
                    "length {len} -> {l}"
                );
                // The direction modulo pi: the segment reversed is the same segment.
                let a = angle.rem_euclid(std::f32::consts::PI);
                let mut d = (key.angle_rad() - a).abs();
                d = d.min(std::f32::consts::PI - d);
                let tip = 0.5 * l * d;
                assert!(tip <= 0.3, "length {len} angle {angle}: tip off by {tip} px");
            }
        }
        let (_, clamped) = SmearKey::new(0, [MAX_SMEAR_PX + 10.0, 0.0]);
        assert!(clamped);
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
