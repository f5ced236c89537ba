//! Motion in depth: how fast each pixel's surface nears the camera, read from the stochastic
//! samples' labels, and how its image's path speeds up because of it.
//!
//! A point at camera-space position `(X, Y, Z)` moving with velocity `V` (scene units per
//! frame) projects to `p = f (X, Y) / Z + c`, `f` the focal length in pixels and `c` the
//! principal point, and its image moves at
//!
//! ```text
//! m = dp/dt = (f V_xy - (p - c) V_z) / Z .
//! ```
//!
//! So `m Z`, the motion label times the depth label, is a linear function of the image
//! position with slope `-V_z` on its diagonal, for every point of a surface that translates,
//! at every time within the shutter and whatever the surface's slant: a least-squares fit of
//! `m Z` against the samples' positions round a pixel gives `V_z` from the fit's divergence,
//! `V_z = -div(m Z) / 2`, without reading time at all. A surface sliding across the view has
//! `V_z = 0`; a car driving at the camera a negative one.
//!
//! Differentiating `m` once more along the point's path, with `dZ/dt = V_z`:
//!
//! ```text
//! dm/dt = -2 m V_z / Z ,
//! ```
//!
//! an acceleration along the motion: the image of a nearing surface speeds up over the
//! shutter (its points move outwards ever faster), a receding one slows down. A sample's
//! motion label is the velocity at its own time, so moved back with it as if the path were
//! straight and even, a sample from late in the shutter of a nearing lamp lands too far back
//! and draws a streak too long, overshooting where the lamp was when the shutter opened.
//! [`path_acceleration`] gives the acceleration for [`crate::reconstruct`] to move samples
//! back along the parabola it makes, as it does for a spinning surface's arcs.

use formats::StochasticFrames;
use rayon::prelude::*;

/// The fit for a pixel reads the pixels this many pixels round it (every other one along
/// each axis: 7 x 7 pixels).
pub const FIT_RADIUS_PX: i64 = 6;

/// Pixels within the fit's window whose surface's depth differs from the centre's by more
/// than this fraction are left out: a car's image nears the camera by a quarter of its depth
/// within one frame, and its samples carry the depth at their own time.
const WINDOW_DEPTH_TOLERANCE: f32 = 0.25;

/// Pixels within the fit's window whose surface's motion differs from the centre's by more
/// than this fraction of the centre's speed (plus [`WINDOW_MOTION_SLACK_PX`]) are left out:
/// the road under a car, still while the car moves.
const WINDOW_MOTION_TOLERANCE: f32 = 0.5;

/// Motion difference always allowed within the window, pixels per frame.
const WINDOW_MOTION_SLACK_PX: f32 = 1.0;

/// Pixels whose surface moves less than this, pixels per frame, get no fit: their path's
/// acceleration (proportional to the motion) would move nothing.
pub const MIN_SPEED_PX: f32 = 0.5;

/// The fewest samples a fit reads.
const MIN_FIT_SAMPLES: f32 = 12.0;

/// The relative nearing speed `|V_z| / Z` beyond which a fit is not believed, per frame: a
/// surface twice as near within one frame is beyond what a straight-and-even path or its
/// parabola describes.
pub const MAX_RELATIVE_NEARING: f32 = 0.5;

/// Each pixel's nearest surface as the fit reads it: the sums over its samples of their
/// positions (relative to the pixel's centre, pixels), of `m Z` and of their products, and
/// the surface's mean motion and depth for the window's tests.
#[derive(Clone, Copy, Debug, Default)]
struct PixelMoments {
    n: f32,
    x: f32,
    y: f32,
    xx: f32,
    xy: f32,
    yy: f32,
    /// Sums of `m Z`, x and y components.
    wx: f32,
    wy: f32,
    /// Sums of position times `m Z`: `x w_x`, `y w_x`, `x w_y`, `y w_y`.
    x_wx: f32,
    y_wx: f32,
    x_wy: f32,
    y_wy: f32,
    /// Mean motion label, pixels per frame.
    motion: [f32; 2],
    /// Mean depth, scene units.
    depth: f32,
}

impl PixelMoments {
    /// The moments of a pixel's samples at positions `(x, y)` relative to its centre with
    /// motion labels `m` and depths `z`.
    fn of(samples: impl Iterator<Item = ([f32; 2], [f32; 2], f32)>) -> Self {
        let mut s = PixelMoments::default();
        for ([x, y], m, z) in samples {
            let w = [m[0] * z, m[1] * z];
            s.n += 1.0;
            s.x += x;
            s.y += y;
            s.xx += x * x;
            s.xy += x * y;
            s.yy += y * y;
            s.wx += w[0];
            s.wy += w[1];
            s.x_wx += x * w[0];
            s.y_wx += y * w[0];
            s.x_wy += x * w[1];
            s.y_wy += y * w[1];
            s.motion[0] += m[0];
            s.motion[1] += m[1];
            s.depth += z;
        }
        if s.n > 0.0 {
            s.motion = s.motion.map(|v| v / s.n);
            s.depth /= s.n;
        }
        s
    }

    /// Adds `o`, whose positions are relative to a pixel `(dx, dy)` from this one's.
    fn add_shifted(&mut self, o: &PixelMoments, dx: f32, dy: f32) {
        self.n += o.n;
        self.x += o.x + o.n * dx;
        self.y += o.y + o.n * dy;
        self.xx += o.xx + 2.0 * dx * o.x + o.n * dx * dx;
        self.xy += o.xy + dx * o.y + dy * o.x + o.n * dx * dy;
        self.yy += o.yy + 2.0 * dy * o.y + o.n * dy * dy;
        self.wx += o.wx;
        self.wy += o.wy;
        self.x_wx += o.x_wx + dx * o.wx;
        self.y_wx += o.y_wx + dy * o.wx;
        self.x_wy += o.x_wy + dx * o.wy;
        self.y_wy += o.y_wy + dy * o.wy;
    }

    /// `V_z` from the least-squares plane of `m Z` over these sums: minus half the
    /// divergence of the fitted gradient. `None` where the samples are too few or lie too
    /// near a line to fix a gradient.
    fn nearing_speed(&self) -> Option<f32> {
        if self.n < MIN_FIT_SAMPLES {
            return None;
        }
        let n = self.n;
        let (mx, my) = (self.x / n, self.y / n);
        let cxx = self.xx / n - mx * mx;
        let cxy = self.xy / n - mx * my;
        let cyy = self.yy / n - my * my;
        let det = cxx * cyy - cxy * cxy;
        // At least a pixel's spread along each axis, and not along one line.
        if !(cxx >= 1.0 && cyy >= 1.0 && det >= 0.25 * cxx * cyy) {
            return None;
        }
        let (mwx, mwy) = (self.wx / n, self.wy / n);
        let c_x_wx = self.x_wx / n - mx * mwx;
        let c_y_wx = self.y_wx / n - my * mwx;
        let c_x_wy = self.x_wy / n - mx * mwy;
        let c_y_wy = self.y_wy / n - my * mwy;
        // d(w_x)/dx and d(w_y)/dy of the two planes' normal equations.
        let dwx_dx = (cyy * c_x_wx - cxy * c_y_wx) / det;
        let dwy_dy = (cxx * c_y_wy - cxy * c_x_wy) / det;
        let v = -0.5 * (dwx_dx + dwy_dy);
        v.is_finite().then_some(v)
    }
}

/// Each pixel's nearest surface's speed towards the camera, where it is known: the fits of
/// the moving pixels, indexed by pixel.
pub(crate) struct DepthMotion {
    /// Each pixel's index into `fits`, [`NO_FIT`] where its surface's nearing speed is not
    /// known; empty when no pixel's is.
    fit_of: Vec<u32>,
    fits: Vec<SurfaceFit>,
}

/// A pixel's nearest surface: its speed in depth `V_z` (scene units per frame, negative when
/// nearing), its mean motion (pixels per frame) and its mean depth.
#[derive(Clone, Copy, Debug)]
struct SurfaceFit {
    nearing: f32,
    motion: [f32; 2],
    depth: f32,
}

/// [`DepthMotion::fit_of`]'s mark for a pixel without a fit.
const NO_FIT: u32 = u32::MAX;

impl DepthMotion {
    /// The field of `frames`, whose samples' CoC radius at a depth (pixels, signed) is
    /// `signed_coc`: a sample is read where its ray's pinhole image lies, its pixel's centre
    /// plus its jitter less its CoC times its lens position. `speed(pixel)` is how fast the
    /// pixel's nearest surface moves (pixels per frame): only pixels within
    /// [`FIT_RADIUS_PX`] of one moving at [`MIN_SPEED_PX`] or more are read, and only those
    /// moving get a fit.
    pub fn of(
        frames: &StochasticFrames,
        signed_coc: impl Fn(f32) -> f32 + Sync,
        speed: impl Fn(usize) -> f32 + Sync,
    ) -> Self {
        let (w, h, spp) = (frames.width, frames.height, frames.spp.max(1));
        let none = DepthMotion {
            fit_of: Vec::new(),
            fits: Vec::new(),
        };
        // Pixels are numbered in 32 bits; no frame that fits in memory has 4 G of them.
        if frames.samples.len() != w * h * spp || w * h >= NO_FIT as usize {
            return none;
        }
        let moving: Vec<u32> = (0..w * h)
            .into_par_iter()
            .filter(|&i| speed(i) >= MIN_SPEED_PX)
            .map(|i| i as u32)
            .collect();
        if moving.is_empty() {
            return none;
        }
        // The pixels the fits read, each given a slot: the moving ones' windows. Most frames
        // move in a small part of the frame; where their windows could cover it, every
        // pixel is read.
        let window_pixels = (FIT_RADIUS_PX as usize + 1).pow(2);
        let (slot, read): (Vec<u32>, Vec<usize>) = if moving.len() * window_pixels >= w * h {
            ((0..(w * h) as u32).collect(), (0..w * h).collect())
        } else {
            let (mut slot, mut read) = (vec![NO_FIT; w * h], Vec::new());
            for &i in &moving {
                for j in window(i as usize, w, h) {
                    if slot[j] == NO_FIT {
                        slot[j] = read.len() as u32;
                        read.push(j);
                    }
                }
            }
            (slot, read)
        };
        let usable = |s: &&formats::Sample| {
            s.color[3] > 0.0
                && s.depth.is_finite()
                && s.depth > 0.0
                && s.motion
                    .iter()
                    .chain(&s.lens)
                    .chain(&s.jitter)
                    .all(|v| v.is_finite())
        };
        let moments: Vec<PixelMoments> = read
            .par_iter()
            .map(|&j| {
                let pixel = &frames.samples[j * spp..(j + 1) * spp];
                let nearest = pixel
                    .iter()
                    .filter(usable)
                    .map(|s| s.depth)
                    .fold(f32::INFINITY, f32::min);
                // The pixel's nearest surface, as its motion field reads it.
                let limit = nearest * (1.0 + crate::reconstruct::FIELD_SAME_SURFACE_DEPTH);
                PixelMoments::of(
                    pixel
                        .iter()
                        .filter(usable)
                        .filter(|s| s.depth <= limit)
                        .map(|s| {
                            let coc = signed_coc(s.depth);
                            let at = [s.jitter[0] - coc * s.lens[0], s.jitter[1] - coc * s.lens[1]];
                            (at, s.motion, s.depth)
                        }),
                )
            })
            .collect();
        let fitted: Vec<(u32, SurfaceFit)> = moving
            .par_iter()
            .filter_map(|&i| {
                let i = i as usize;
                let me = &moments[slot[i] as usize];
                let speed = me.motion[0].hypot(me.motion[1]);
                if me.n == 0.0 || speed.is_nan() || speed < MIN_SPEED_PX {
                    return None;
                }
                let motion_limit = WINDOW_MOTION_TOLERANCE * speed + WINDOW_MOTION_SLACK_PX;
                let mut sum = PixelMoments::default();
                // The window's pixels as `window` lists them, each with its offset from the
                // centre: two integer divisions per pixel to recover the offsets were a fifth
                // of the fit's time on a camera pan.
                for (j, [dx, dy]) in window_offsets(i, w, h) {
                    let o = &moments[slot[j] as usize];
                    let same = o.n > 0.0
                        && (o.depth - me.depth).abs() <= WINDOW_DEPTH_TOLERANCE * me.depth
                        && within(
                            [o.motion[0] - me.motion[0], o.motion[1] - me.motion[1]],
                            motion_limit,
                        );
                    if same {
                        sum.add_shifted(o, dx as f32, dy as f32);
                    }
                }
                let nearing = sum
                    .nearing_speed()
                    .filter(|v| *v != 0.0 && v.abs() <= MAX_RELATIVE_NEARING * me.depth)?;
                Some((
                    i as u32,
                    SurfaceFit {
                        nearing,
                        motion: me.motion,
                        depth: me.depth,
                    },
                ))
            })
            .collect();
        drop(moments);
        let mut fit_of = slot;
        fit_of.fill(NO_FIT);
        for (k, &(i, _)) in fitted.iter().enumerate() {
            fit_of[i as usize] = k as u32;
        }
        DepthMotion {
            fit_of,
            fits: fitted.into_iter().map(|(_, f)| f).collect(),
        }
    }

    /// The fit of `pixel`'s nearest surface, where there is one.
    fn fit(&self, pixel: usize) -> Option<&SurfaceFit> {
        let k = *self.fit_of.get(pixel)?;
        self.fits.get(k as usize)
    }

    /// The speed in depth (scene units per frame, negative when nearing) of the surface a
    /// sample in `pixel` at `depth` with motion label `motion` (pixels per frame) lies on,
    /// when it is the pixel's nearest (its depth within [`WINDOW_DEPTH_TOLERANCE`] and its
    /// motion as the fit's window allows) and its speed is known; `None` otherwise.
    pub fn nearing(&self, pixel: usize, depth: f32, motion: [f32; 2]) -> Option<f32> {
        let fit = self.fit(pixel)?;
        let (m, d) = (fit.motion, fit.depth);
        let limit = WINDOW_MOTION_TOLERANCE * m[0].hypot(m[1]) + WINDOW_MOTION_SLACK_PX;
        let same = (depth - d).abs() <= WINDOW_DEPTH_TOLERANCE * d
            && within([motion[0] - m[0], motion[1] - m[1]], limit);
        same.then_some(fit.nearing)
    }

    /// The nearing speed of `pixel`'s nearest surface, scene units per frame (0 where not
    /// known).
    #[cfg(test)]
    fn nearing_speed(&self, pixel: usize) -> f32 {
        self.fit(pixel).map_or(0.0, |f| f.nearing)
    }
}

/// Whether the vector `d` (pixels) is at most `limit` long: its squared length against the
/// limit's, in f64, where f32 values neither overflow nor lose precision. The window's test runs for 49 pixels
/// round every moving pixel, and `hypot` there was a third of the fit's time on a camera pan.
#[inline]
fn within(d: [f32; 2], limit: f32) -> bool {
    let (x, y, l) = (f64::from(d[0]), f64::from(d[1]), f64::from(limit));
    limit >= 0.0 && x * x + y * y <= l * l
}

/// The pixels a fit for pixel `i` of a `w x h` frame reads: every other pixel along each axis
/// within [`FIT_RADIUS_PX`] of it, inside the frame.
fn window(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    window_offsets(i, w, h).map(|(j, _)| j)
}

/// [`window`]'s pixels, each with its offset from pixel `i` (columns, rows).
fn window_offsets(i: usize, w: usize, h: usize) -> impl Iterator<Item = (usize, [i64; 2])> {
    let (cx, cy) = ((i % w) as i64, (i / w) as i64);
    let offsets = || (-FIT_RADIUS_PX..=FIT_RADIUS_PX).step_by(2);
    offsets()
        .filter(move |&dy| cy + dy >= 0 && cy + dy < h as i64)
        .flat_map(move |dy| {
            offsets()
                .filter(move |&dx| cx + dx >= 0 && cx + dx < w as i64)
                .map(move |dx| ((cy + dy) as usize * w + (cx + dx) as usize, [dx, dy]))
        })
}

/// The derivative of the image motion of a point at `depth` (scene units) nearing the camera
/// at `nearing` (scene units per frame) from its central difference over a frame on each side,
/// `(p(t + 1) - p(t - 1)) / 2` (pixels per frame), as Blender's pinhole sub-renders label
/// their samples: along `p(t) = c + P / (Z + V t)` the difference is the derivative divided
/// by `1 - (V / Z)^2`, with `V / Z` bounded by [`MAX_RELATIVE_NEARING`].
pub fn derivative_of_central_difference(
    difference: [f32; 2],
    depth: f32,
    nearing: f32,
) -> [f32; 2] {
    let rate = (nearing / depth).clamp(-MAX_RELATIVE_NEARING, MAX_RELATIVE_NEARING);
    let f = 1.0 - rate * rate;
    [difference[0] * f, difference[1] * f]
}

/// The acceleration along its path of the image of a point at `depth` (scene units) moving
/// at `motion` (pixels per frame) while nearing the camera at `nearing` scene units per frame
/// (negative when nearing): `-2 motion nearing / depth`, pixels per frame squared, with the
/// relative nearing speed bounded by [`MAX_RELATIVE_NEARING`].
pub fn path_acceleration(motion: [f32; 2], depth: f32, nearing: f32) -> [f32; 2] {
    let rate = (nearing / depth).clamp(-MAX_RELATIVE_NEARING, MAX_RELATIVE_NEARING);
    [-2.0 * motion[0] * rate, -2.0 * motion[1] * rate]
}

#[cfg(test)]
mod tests {
    use super::*;
    use formats::Sample;

    /// Each window pixel's offset is its column and row less the centre's, every other pixel
    /// within the radius and inside the frame, at the frame's corners and edges too.
    #[test]
    fn window_offsets_are_the_pixels_offsets() {
        let (w, h) = (9, 7);
        for i in [0, 4, w - 1, 3 * w + 4, w * h - 1, (h - 1) * w + 2] {
            let listed: Vec<(usize, [i64; 2])> = window_offsets(i, w, h).collect();
            let mut expected = Vec::new();
            for j in 0..w * h {
                let dx = (j % w) as i64 - (i % w) as i64;
                let dy = (j / w) as i64 - (i / w) as i64;
                if dx.abs() <= FIT_RADIUS_PX
                    && dy.abs() <= FIT_RADIUS_PX
                    && dx % 2 == 0
                    && dy % 2 == 0
                {
                    expected.push((j, [dx, dy]));
                }
            }
            assert_eq!(listed, expected, "pixel {i}");
            assert!(window(i, w, h).eq(expected.iter().map(|&(j, _)| j)));
        }
    }

    /// The squared test agrees with `hypot`'s wherever the length is not within a rounding of
    /// the limit, and says no for NaN, infinite vectors and negative limits.
    #[test]
    fn within_is_the_length_test() {
        let values = [
            -1e30f32, -300.0, -3.0, -0.7, -0.0, 0.0, 0.2, 1.0, 2.5, 40.0, 1e30,
        ];
        for &x in &values {
            for &y in &values {
                for &limit in &[0.0f32, 0.5, 1.0, 3.0, 50.0, 1e31] {
                    let length = f64::from(x).hypot(f64::from(y));
                    if (length - f64::from(limit)).abs() <= 1e-6 * f64::from(limit) {
                        continue;
                    }
                    assert_eq!(
                        within([x, y], limit),
                        length <= f64::from(limit),
                        "({x}, {y}) against {limit}"
                    );
                }
            }
        }
        assert!(!within([f32::NAN, 0.0], 1.0));
        assert!(!within([f32::INFINITY, 0.0], 1e30));
        assert!(!within([0.0, 0.0], -1.0));
        assert!(within([3.0, 4.0], 5.0));
    }

    /// Frames of a plane `Z = z0 + gz x_cam` translating at `v` (scene units per frame),
    /// seen by a pinhole of focal length `f` pixels, one sample per pixel at the pixel's
    /// centre at time `t(x, y)`: depth and motion labels as the projection gives them.
    fn translating_plane(z0: f32, slope: f32, v: [f32; 3], f: f32) -> StochasticFrames {
        let (w, h) = (48, 48);
        let c = [24.0f32, 24.0];
        let mut samples = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let p = [x as f32 + 0.5, y as f32 + 0.5];
                // The ray through p meets the plane Z = z0 + slope X, X = (p - c) Z / f.
                let u = (p[0] - c[0]) / f;
                let z = z0 / (1.0 - slope * u);
                let motion = [
                    (f * v[0] - (p[0] - c[0]) * v[2]) / z,
                    (f * v[1] - (p[1] - c[1]) * v[2]) / z,
                ];
                samples.push(Sample {
                    color: [0.5, 0.5, 0.5, 1.0],
                    depth: z,
                    lens: [0.0; 2],
                    time: ((x * 7 + y * 3) % 11) as f32 / 11.0 - 0.5,
                    motion,
                    jitter: [0.0; 2],
                });
            }
        }
        StochasticFrames::new(w, h, 1, samples)
    }

    #[test]
    fn a_surface_driving_at_the_camera_reads_its_speed() {
        let frames = translating_plane(4.0, 0.0, [0.05, 0.0, -0.3], 300.0);
        let field = DepthMotion::of(&frames, |_| 0.0, |_| 1.0);
        for (x, y) in [(24, 24), (10, 30), (40, 8)] {
            let v = field.nearing_speed(y * 48 + x);
            assert!((v + 0.3).abs() < 0.003, "V_z at ({x}, {y}): {v}, not -0.3");
        }
    }

    #[test]
    fn a_slanted_surface_sliding_across_does_not_near() {
        // Its motion varies with its depth across the image, but no point nears the camera.
        let frames = translating_plane(4.0, 0.4, [0.2, 0.05, 0.0], 300.0);
        let field = DepthMotion::of(&frames, |_| 0.0, |_| 1.0);
        for (x, y) in [(24, 24), (10, 30), (40, 8)] {
            let v = field.nearing_speed(y * 48 + x);
            assert!(v.abs() < 1e-3, "V_z at ({x}, {y}): {v}, not 0");
        }
    }

    #[test]
    fn labels_beyond_reason_give_a_bounded_speed_and_no_panic() {
        // Motion labels near f32's limit (their products with depth overflow), a depth near
        // zero, and a plane's labels with one pixel's made infinite.
        for (motion, depth) in [(1e30f32, 4.0f32), (3.0e38, 1e30), (5.0, 1e-30)] {
            let mut frames = translating_plane(4.0, 0.0, [0.05, 0.0, -0.3], 300.0);
            for s in frames.samples.iter_mut() {
                s.motion = [motion, -motion];
                s.depth = depth;
            }
            frames.samples[100].motion = [f32::INFINITY, 0.0];
            let field = DepthMotion::of(&frames, |_| 0.0, |_| 1.0);
            for pixel in 0..48 * 48 {
                let v = field.nearing_speed(pixel);
                assert!(v.is_finite(), "pixel {pixel}: {v}");
                assert!(
                    v.abs() <= MAX_RELATIVE_NEARING * depth,
                    "pixel {pixel}: {v}"
                );
            }
        }
    }

    #[test]
    fn a_central_difference_of_a_nearing_point_becomes_its_derivative() {
        // p(t) = f X / (Z0 + V t): Blender's label (p(1) - p(-1)) / 2 against dp/dt at 0.
        let (f, x, z0, v) = (300.0f64, 0.4f64, 4.0f64, -1.2f64);
        let p = |t: f64| f * x / (z0 + v * t);
        let difference = (p(1.0) - p(-1.0)) / 2.0;
        let derivative = -f * x * v / (z0 * z0);
        assert!(
            (difference / derivative - 1.0).abs() > 0.05,
            "precondition: they differ"
        );
        let got = derivative_of_central_difference([difference as f32, 0.0], z0 as f32, v as f32);
        let got = f64::from(got[0]);
        assert!(
            (got - derivative).abs() < 1e-4 * derivative.abs(),
            "{got} against {derivative}"
        );
    }

    #[test]
    fn a_nearing_point_speeds_up_as_its_projection_does() {
        // p(t) = f X / (Z0 + V t), differentiated twice numerically at t = 0.
        let (f, x, z0, v) = (300.0f64, 0.4f64, 4.0f64, -0.3f64);
        let p = |t: f64| f * x / (z0 + v * t);
        let dt = 1e-3;
        let numeric = (p(dt) - 2.0 * p(0.0) + p(-dt)) / (dt * dt);
        let motion = (p(dt) - p(-dt)) / (2.0 * dt);
        let a = f64::from(path_acceleration([motion as f32, 0.0], z0 as f32, v as f32)[0]);
        assert!(
            (a - numeric).abs() < 1e-3 * numeric.abs(),
            "{a} against {numeric}"
        );
    }
}
