//! How a pixel's motion path bends over the shutter, from the motion field around it.
//!
//! A G-buffer holds one motion vector per pixel, the chord of the pixel's path over the
//! shutter. Where the motion field changes along the motion, the path is not straight: a point
//! of a spinning wheel travels an arc about the hub. Drawn along its chord, every rim pixel's
//! streak leaves the wheel's silhouette at both ends and the rim is pushed outward (a disc of
//! radius `R` turning `theta` over the shutter: the chord's ends lie `R / cos(theta / 2) - R`
//! outside). The field gives the path's acceleration: a point at `p` moving with the field
//! `m(p)` accelerates by `a = (m . grad) m = J m`, with `J` the field's Jacobian, so over the
//! shutter (`t` in `[-1/2, 1/2]`) it travels `p + t m + t^2 a / 2`. Only the part of `a` across
//! the motion bends the path; the part along it changes the speed, which a streak of uniform
//! weight does not show. For a rigid turn `m = theta A (p - c)` (`A` a quarter turn),
//! `a = -theta^2 (p - c)`: towards the centre, `theta |m|` across the motion.
//!
//! That holds for a field that stays where it is (a wheel turning on its axle, a camera pan).
//! Where the G-buffer holds each pixel's own acceleration (Blender's vector pass has the
//! previous and the next frame's positions: `a = (next - now) + (previous - now)`), that is
//! used instead, which also holds where the field travels (a rolling wheel).
//!
//! `J` is fitted by least squares to the pixels within [`FIT_RADIUS`] of the same surface
//! (depth within [`SAME_SURFACE_DEPTH`], motion within [`SAME_SURFACE_MOTION`]), so a moving
//! object's edge does not take the still background's motion for a bend, and none is fitted
//! where too few neighbours qualify.

use rayon::prelude::*;

/// Largest relative depth difference of two neighbouring pixels of one surface.
const SAME_SURFACE_DEPTH: f32 = 0.03;
/// Largest motion difference of two neighbouring pixels of one surface, as a fraction of the
/// larger motion's length, plus [`SAME_SURFACE_MOTION_PX`].
const SAME_SURFACE_MOTION: f32 = 0.25;
/// See [`SAME_SURFACE_MOTION`], px.
const SAME_SURFACE_MOTION_PX: f32 = 2.0;
/// Paths shorter than this (px per frame) are taken as straight.
const MIN_MOTION_PX: f32 = 1.0;
/// A bend below this from the axis neighbours alone (px) is taken as straight without the
/// window's fit: a quarter of the smallest bend drawn.
const STRAIGHT_AT_A_GLANCE_PX: f32 = 0.25;
/// The fit's window reaches this many pixels from the pixel on each axis.
const FIT_RADIUS: isize = 2;
/// Least determinant of the window's offsets (px^4) for a fit: at least a 2 x 2 block of
/// neighbours (a 1 x 1 pixel neighbour on each axis gives 1).
const MIN_FIT_DETERMINANT: f32 = 1.0;

/// Every pixel's path bend (px, `Fragment::bend`, for the motion given) of a `w x h` frame
/// whose pixel `i` moves `motion[i]` px at planar depth `depth[i]` (none: no depth pass, one
/// surface) with coverage `color[i][3]`. Uncovered and slow pixels get 0.
pub(crate) fn path_bends(
    w: usize,
    h: usize,
    motion: &[[f32; 2]],
    depth: Option<&[f32]>,
    color: &[[f32; 4]],
) -> Vec<f32> {
    let depth_at = |i: usize| depth.map_or(f32::INFINITY, |d| d[i]);
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let m = motion[i];
            let len = (m[0] * m[0] + m[1] * m[1]).sqrt();
            if len < MIN_MOTION_PX || color[i][3] <= 0.0 {
                return 0.0;
            }
            let (x, y) = (i % w, i / w);
            let d = depth_at(i);
            // A neighbour of the same surface: its motion.
            let same = |j: usize| -> Option<[f32; 2]> {
                if color[j][3] <= 0.0 {
                    return None;
                }
                if !same_surface_depth(d, depth_at(j)) {
                    return None;
                }
                let mj = motion[j];
                let (ex, ey) = (mj[0] - m[0], mj[1] - m[1]);
                let lj = (mj[0] * mj[0] + mj[1] * mj[1]).sqrt();
                let limit = SAME_SURFACE_MOTION * len.max(lj) + SAME_SURFACE_MOTION_PX;
                (ex * ex + ey * ey <= limit * limit).then_some(mj)
            };
            // A first look along the axes: where the field does not change along the motion
            // (a translation, a surface sliding across the frame), the path is straight, and
            // the window's fit is not needed. That is most moving pixels of most frames.
            let derivative = |before: Option<usize>, after: Option<usize>| -> [f32; 2] {
                match (before.and_then(same), after.and_then(same)) {
                    (Some(b), Some(a)) => [0.5 * (a[0] - b[0]), 0.5 * (a[1] - b[1])],
                    (Some(b), None) => [m[0] - b[0], m[1] - b[1]],
                    (None, Some(a)) => [a[0] - m[0], a[1] - m[1]],
                    (None, None) => [0.0, 0.0],
                }
            };
            let ddx = derivative((x > 0).then(|| i - 1), (x + 1 < w).then_some(i + 1));
            let ddy = derivative((y > 0).then(|| i - w), (y + 1 < h).then_some(i + w));
            if across(m, len, ddx, ddy).abs() < STRAIGHT_AT_A_GLANCE_PX {
                return 0.0;
            }
            // The field's Jacobian by least squares over the window's pixels of the same
            // surface: J = (sum dm d^T) (sum d d^T)^-1, d the offset and dm the motion's change.
            // A pixel's motion is the mean over its samples' positions, which scatter about the
            // centre: its error, times the motion's length, is the bend's; a window's fit
            // averages it out where neighbouring differences amplify it.
            let (mut sxx, mut sxy, mut syy) = (0.0f32, 0.0f32, 0.0f32);
            let mut dm = [[0.0f32; 2]; 2];
            for oy in -FIT_RADIUS..=FIT_RADIUS {
                let ny = y as isize + oy;
                if ny < 0 || ny >= h as isize {
                    continue;
                }
                for ox in -FIT_RADIUS..=FIT_RADIUS {
                    let nx = x as isize + ox;
                    if nx < 0 || nx >= w as isize || (ox == 0 && oy == 0) {
                        continue;
                    }
                    let Some(mj) = same(ny as usize * w + nx as usize) else {
                        continue;
                    };
                    let (ex, ey) = (mj[0] - m[0], mj[1] - m[1]);
                    let (fx, fy) = (ox as f32, oy as f32);
                    sxx += fx * fx;
                    sxy += fx * fy;
                    syy += fy * fy;
                    dm[0][0] += ex * fx;
                    dm[0][1] += ex * fy;
                    dm[1][0] += ey * fx;
                    dm[1][1] += ey * fy;
                }
            }
            let det = sxx * syy - sxy * sxy;
            // Too few neighbours, or all on one line (a thin sliver): no bend.
            if det < MIN_FIT_DETERMINANT {
                return 0.0;
            }
            // J = dm * inverse([[sxx, sxy], [sxy, syy]]); row r: d m_r / d(x, y).
            let inv = [[syy / det, -sxy / det], [-sxy / det, sxx / det]];
            let jac = |r: usize| {
                [
                    dm[r][0] * inv[0][0] + dm[r][1] * inv[1][0],
                    dm[r][0] * inv[0][1] + dm[r][1] * inv[1][1],
                ]
            };
            let (jx, jy) = (jac(0), jac(1));
            let dx = [jx[0], jy[0]];
            let dy = [jx[1], jy[1]];
            across(m, len, dx, dy)
        })
        .collect()
}

/// Whether two neighbouring pixels' planar depths can be one surface's: within
/// [`SAME_SURFACE_DEPTH`] of the nearer (infinite depths equal).
pub(super) fn same_surface_depth(a: f32, b: f32) -> bool {
    a == b || (a - b).abs() <= SAME_SURFACE_DEPTH * a.min(b)
}

/// Every pixel's path bend (px, `Fragment::bend`, for the motion given) from its own
/// acceleration (`acceleration[i]`, px per the motion's time unit squared), as Blender's two
/// vectors give it: exact where the field itself moves, which the field's derivatives miss (a
/// rolling wheel's field travels with the wheel; `(m . grad) m` then adds `theta A v` to the
/// rim's true `-theta^2 (p - c)`).
pub(super) fn bends_from_acceleration(motion: &[[f32; 2]], acceleration: &[[f32; 2]]) -> Vec<f32> {
    motion
        .par_iter()
        .zip(acceleration.par_iter())
        .map(|(&m, &a)| {
            let len = (m[0] * m[0] + m[1] * m[1]).sqrt();
            if len < MIN_MOTION_PX {
                0.0
            } else {
                across_motion(m, len, a)
            }
        })
        .collect()
}

/// The path's acceleration `a = J m` across the motion `m` (of length `len`), towards
/// `(-m_y, m_x) / |m|`, from the field's derivatives along x and y (`dx = d m / d x`); 0 where
/// it is not finite.
fn across(m: [f32; 2], len: f32, dx: [f32; 2], dy: [f32; 2]) -> f32 {
    let a = [m[0] * dx[0] + m[1] * dy[0], m[0] * dx[1] + m[1] * dy[1]];
    across_motion(m, len, a)
}

/// The part of acceleration `a` across the motion `m` (of length `len`), towards
/// `(-m_y, m_x) / |m|`; 0 where it is not finite.
fn across_motion(m: [f32; 2], len: f32, a: [f32; 2]) -> f32 {
    let bend = (m[0] * a[1] - m[1] * a[0]) / len;
    if bend.is_finite() {
        bend
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rigidly turning field bends every path by `theta |m|` towards the centre; a field that
    /// only translates and scales (an object sliding and approaching) bends nothing.
    #[test]
    fn a_turning_field_bends_towards_its_centre_and_a_scaling_one_not_at_all() {
        let (w, h) = (64usize, 48usize);
        let (cx, cy) = (30.0f32, 20.0f32);
        let theta = 0.3f32;
        // x right, y down: (x, y) -> theta (-(y - cy), x - cx).
        let turning = move |i: usize| {
            let (x, y) = ((i % w) as f32 - cx, (i / w) as f32 - cy);
            [-theta * y, theta * x]
        };
        let field: Vec<[f32; 2]> = (0..w * h).map(turning).collect();
        let (flat, all) = (vec![5.0f32; w * h], vec![[1.0f32; 4]; w * h]);
        let bends = path_bends(w, h, &field, Some(&flat), &all);
        for &(x, y) in &[(50usize, 20usize), (30, 40), (10, 5), (45, 33)] {
            let i = y * w + x;
            let m = turning(i);
            let len = (m[0] * m[0] + m[1] * m[1]).sqrt();
            let expected = theta * len;
            assert!(
                (bends[i] - expected).abs() < 1e-3 * expected.max(1.0),
                "({x}, {y}): bend {} expected {expected}",
                bends[i]
            );
            // Towards the centre: the normal (-m_y, m_x) / |m| points at it.
            let n = [-m[1] / len, m[0] / len];
            let to_centre = [cx - x as f32, cy - y as f32];
            assert!(n[0] * to_centre[0] + n[1] * to_centre[1] > 0.0);
        }
        let scaling = move |i: usize| {
            let (x, y) = ((i % w) as f32 - cx, (i / w) as f32 - cy);
            [8.0 + 0.1 * x, -3.0 + 0.1 * y]
        };
        let field: Vec<[f32; 2]> = (0..w * h).map(scaling).collect();
        let bends = path_bends(w, h, &field, Some(&flat), &all);
        assert!(
            bends.iter().all(|b| b.abs() < 1e-3),
            "{:?}",
            bends.iter().fold(0f32, |a, b| a.max(b.abs()))
        );
    }

    /// A rolling wheel: its rim turns about a centre that travels. Its own acceleration (the
    /// two vectors) bends the top of the rim by `theta^2 R` towards the hub; the field's
    /// derivatives, which take the field as standing still, double it.
    #[test]
    fn a_rolling_wheel_bends_by_its_own_acceleration() {
        let (w, h) = (64usize, 64usize);
        let (cx, cy) = (32.0f32, 32.0f32);
        let (theta, radius) = (0.2f32, 20.0f32);
        // Rolling to the right without slipping (y down, turning clockwise on screen): the
        // hub moves theta R, a point at p moves v + theta (-(y - cy), x - cx).
        let v = theta * radius;
        let field = |i: usize| {
            let (x, y) = ((i % w) as f32 - cx, (i / w) as f32 - cy);
            [v - theta * y, theta * x]
        };
        let motion: Vec<[f32; 2]> = (0..w * h).map(field).collect();
        let acceleration: Vec<[f32; 2]> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 - cx, (i / w) as f32 - cy);
                [-theta * theta * x, -theta * theta * y]
            })
            .collect();
        // The top of the rim (y = cy - R) moves 2 v to the right and bends down, towards the
        // hub, by theta^2 R.
        let top = (cy - radius) as usize * w + cx as usize;
        let own = bends_from_acceleration(&motion, &acceleration)[top];
        let expected = theta * theta * radius;
        let m = motion[top];
        let len = (m[0] * m[0] + m[1] * m[1]).sqrt();
        // (-m_y, m_x) / |m| is straight down here: a positive bend.
        assert!((own - expected).abs() < 1e-4, "{own} against {expected}");
        let fitted = path_bends(
            w,
            h,
            &motion,
            Some(&vec![5.0; w * h]),
            &vec![[1.0; 4]; w * h],
        )[top];
        assert!(
            (fitted - 2.0 * expected).abs() < 1e-3,
            "{fitted}, length {len}"
        );
    }

    /// At a silhouette the still background is not taken for the moving surface's field.
    #[test]
    fn a_sliding_slab_over_a_still_wall_does_not_bend() {
        let (w, h) = (32usize, 16usize);
        let slab = |i: usize| (8..20).contains(&(i % w));
        let motion: Vec<[f32; 2]> = (0..w * h)
            .map(|i| if slab(i) { [12.0, 0.0] } else { [0.0, 0.0] })
            .collect();
        let depth: Vec<f32> = (0..w * h)
            .map(|i| if slab(i) { 2.0 } else { 10.0 })
            .collect();
        let bends = path_bends(w, h, &motion, Some(&depth), &vec![[1.0; 4]; w * h]);
        assert!(bends.iter().all(|&b| b == 0.0));
    }
}
