//! A narrow thin-lens PSF at sub-pixel shifts, so that a motion smear places each of its taps
//! where the path puts it rather than spreading it over the two pixels either side.
//!
//! A database PSF is the point's light binned into pixels: the aperture's image `P` (a disc of
//! the CoC radius for a round aperture) convolved with the pixel's box and sampled at pixel
//! centres, `(P * box)(n)`. Smeared along a path, the exact image is the mean over the path's
//! taps `s_k` of `(P * box)(n - s_k)`, the box-filtered PSF at each tap's sub-pixel shift.
//! Drawn with bilinear weights instead ([`crate::motion_smear::smear`]), each tap is the PSF
//! convolved with a second box: a tent across the streak of variance `f (1 - f)` for a shift
//! `f` off the pixel grid, a sixth of a square pixel on average. A PSF a few pixels wide is
//! widened by that across a streak that is not axis-aligned: a moving lamp's streak comes out
//! with soft sides where the reference's are crisp (a CoC of 1.2 px: the variance across the
//! streak grows by two fifths).
//!
//! For the thin lens `P` is known: the aperture's outline (a disc, or a regular polygon of
//! its blades inscribed in it, squeezed by an anamorphic ratio) scaled by the CoC radius `r`
//! and filled uniformly, averaged over the CoC radii of the PSF's cell where the database is
//! pre-filtered (as its rays draw them), and turned half a turn where the database's image
//! is (in front of the focus plane). A point lies in the outline scaled by `r` where its
//! gauge, the smallest scale whose outline holds it, is at most `r`. Its box-filtered image
//! is computed here at shifts of `1 / STEPS` px on each axis, on a grid `STEPS` times finer
//! than the pixel's (each fine cell's mass from `SUBSAMPLES^2` points), summed over each
//! shifted pixel's fine cells. A model that departs
//! from the database's own image at no shift by more than [`MAX_DEPARTURE`] (relative L1) is
//! not used, nor are PSFs narrower than [`MIN_RADIUS_PX`], whose exact smear is the staircase
//! of a point sample (the bilinear line stands in for a reconstruction filter there), nor
//! user-drawn apertures and other models.

use psf_db::{PsfDatabase, PsfModel};

use crate::motion_smear::{PsfImage, NARROW_PSF_PX};

/// Shifts per pixel on each axis: a tap lands within `1 / (2 STEPS)` px of its place.
pub const STEPS: usize = 8;

/// Sample points per fine cell on each axis.
const SUBSAMPLES: usize = 2;

/// CoC radii a pre-filtered cell's disc is averaged over.
const RADII: usize = 16;

/// Cells whose smallest CoC radius (px) is under this keep bilinear taps.
pub const MIN_RADIUS_PX: f64 = 1.0;

/// Largest relative L1 difference between the model at no shift and the database's image:
/// the quick databases' narrow cells depart by 0.05-0.6 % (round, pentagonal, squeezed).
pub const MAX_DEPARTURE: f64 = 0.02;

/// A grey PSF's box-filtered images at `STEPS x STEPS` sub-pixel shifts, each over the PSF's box
/// grown by one pixel to the right and down (where a shift of up to a pixel moves its light).
#[derive(Clone, Debug, PartialEq)]
pub struct SubpixelPsf {
    /// Top-left pixel of each shifted image relative to the PSF centre (the database image's).
    pub origin: [i32; 2],
    /// Width of each shifted image, px (the database image's plus one).
    pub width: usize,
    /// Height of each shifted image, px (the database image's plus one).
    pub height: usize,
    /// Shift `(a, b) / STEPS` px at `(b * STEPS + a) * width * height`, row-major.
    values: Vec<f32>,
}

impl SubpixelPsf {
    /// The model of cell `cell` of the thin-lens database `db`, whose image (trimmed, as
    /// [`crate::motion_smear::psf_image`] gives it, and turned half a turn where
    /// `half_turn`) is `base`; `None` where the model does not apply or departs from `base`
    /// (module documentation).
    pub fn of_cell(db: &PsfDatabase, cell: u32, base: &PsfImage, half_turn: bool) -> Option<Self> {
        let header = db.header();
        let aperture = header.aperture;
        if header.model != PsfModel::ThinLens
            || aperture.image_hash != 0
            || !(aperture.ratio.is_finite() && aperture.ratio >= 1.0)
            || base.channels != 1
            || base.width.min(base.height) >= NARROW_PSF_PX
        {
            return None;
        }
        let radii = cell_radii(db, cell)?;
        if !radii.iter().all(|r| r.is_finite())
            || radii.iter().copied().fold(f64::INFINITY, f64::min) < MIN_RADIUS_PX
        {
            return None;
        }
        let outline = Outline::of(
            aperture.blades,
            f64::from(aperture.rotation_rad),
            f64::from(aperture.ratio),
            half_turn,
        );
        let model = Self::of_outline(&radii, &outline, base.origin, base.width, base.height);
        let base_sum: f64 = base.data.iter().map(|&v| f64::from(v)).sum();
        if !(base_sum.is_finite() && base_sum > 0.0) {
            return None;
        }
        // The database's image as the model's unshifted one, which is a pixel larger.
        let unshifted = model.shifted(0, 0);
        let mut departure = 0.0f64;
        for y in 0..model.height {
            for x in 0..model.width {
                let ours = f64::from(unshifted[y * model.width + x]);
                let theirs = if x < base.width && y < base.height {
                    f64::from(base.data[y * base.width + x]) / base_sum
                } else {
                    0.0
                };
                departure += (ours - theirs).abs();
            }
        }
        if departure > MAX_DEPARTURE {
            return None;
        }
        // The database's light, whatever its normalisation.
        let scale = base_sum as f32;
        let values = model.values.iter().map(|&v| v * scale).collect();
        Some(Self { values, ..model })
    }

    /// The box-filtered images, each summing to 1, of the mean of uniform discs of `radii`
    /// (px) centred on the PSF centre, over the box of `width x height` pixels at `origin`
    /// grown by one pixel right and down.
    pub fn of_radii(radii: &[f64], origin: [i32; 2], width: usize, height: usize) -> Self {
        Self::of_outline(
            radii,
            &Outline::of(0, 0.0, 1.0, false),
            origin,
            width,
            height,
        )
    }

    /// [`SubpixelPsf::of_radii`] for the mean of `outline` scaled by each of `radii` and
    /// filled uniformly.
    pub fn of_outline(
        radii: &[f64],
        outline: &Outline,
        origin: [i32; 2],
        width: usize,
        height: usize,
    ) -> Self {
        let (w, h) = (width + 1, height + 1);
        // Pixel `k` covers offsets `[k - 1/2, k + 1/2)` from the centre; shifted by `a /
        // STEPS`, its window is `[k - 1/2 - a / STEPS, ...)`. The fine grid starts a pixel
        // before the box's first window and ends with its last.
        let (fw, fh) = ((w + 1) * STEPS, (h + 1) * STEPS);
        let x0 = f64::from(origin[0]) - 1.5;
        let y0 = f64::from(origin[1]) - 1.5;
        let fine = 1.0 / STEPS as f64;
        let sub = fine / SUBSAMPLES as f64;
        // The mixture's density at a point of gauge `g`: that of the outlines scaled by the
        // radii of at least `g`.
        let mut sorted: Vec<f64> = radii.to_vec();
        sorted.sort_by(f64::total_cmp);
        // `above[k]`: the density of the outlines `k..` (those reaching at least `sorted[k]`).
        let mut above = vec![0.0f64; sorted.len() + 1];
        for k in (0..sorted.len()).rev() {
            let area = outline.area() * sorted[k] * sorted[k];
            above[k] = above[k + 1] + 1.0 / (area * sorted.len() as f64);
        }
        let density = |p: [f64; 2]| -> f64 {
            let g = outline.gauge(p);
            above[sorted.partition_point(|&r| r < g)]
        };
        // Summed-area table of the fine cells' masses, one row and column of zeros first.
        let stride = fw + 1;
        let mut table = vec![0.0f64; stride * (fh + 1)];
        for j in 0..fh {
            let mut row_sum = 0.0;
            for i in 0..fw {
                let mut mass = 0.0;
                for sj in 0..SUBSAMPLES {
                    let y = y0 + j as f64 * fine + (sj as f64 + 0.5) * sub;
                    for si in 0..SUBSAMPLES {
                        let x = x0 + i as f64 * fine + (si as f64 + 0.5) * sub;
                        mass += density([x, y]);
                    }
                }
                row_sum += mass * sub * sub;
                table[(j + 1) * stride + i + 1] = table[j * stride + i + 1] + row_sum;
            }
        }
        let window = |i0: usize, j0: usize| -> f64 {
            let (i1, j1) = (i0 + STEPS, j0 + STEPS);
            table[j1 * stride + i1] - table[j0 * stride + i1] - table[j1 * stride + i0]
                + table[j0 * stride + i0]
        };
        let mut values = Vec::with_capacity(STEPS * STEPS * w * h);
        for b in 0..STEPS {
            for a in 0..STEPS {
                let start = values.len();
                for y in 0..h {
                    for x in 0..w {
                        // Pixel `origin + x`'s window shifted by `-a / STEPS`, in fine cells.
                        values.push(window((x + 1) * STEPS - a, (y + 1) * STEPS - b));
                    }
                }
                // Each shift's image keeps the whole of the disc's light that the box holds.
                let sum: f64 = values[start..].iter().sum();
                if sum > 0.0 {
                    for v in &mut values[start..] {
                        *v /= sum;
                    }
                }
            }
        }
        Self {
            origin,
            width: w,
            height: h,
            values: values.into_iter().map(|v| v as f32).collect(),
        }
    }

    /// The image at shift `(a, b) / STEPS` px, `a, b < STEPS`.
    pub fn shifted(&self, a: usize, b: usize) -> &[f32] {
        let n = self.width * self.height;
        let at = (b * STEPS + a) * n;
        &self.values[at..at + n]
    }
}

/// The outline of a thin-lens aperture of unit radius (its circumradius for a polygon), as
/// the precompute samples it: `blades` vertices on the unit circle, the first at
/// `rotation_rad` counter-clockwise from +x (y down), or the disc for fewer than three; x then
/// divided by `ratio`; and turned half a turn where `half_turn`.
#[derive(Clone, Debug, PartialEq)]
pub struct Outline {
    /// Each edge's outward normal (x, y down) over the polygon's apothem; empty for the disc.
    normals: Vec<[f64; 2]>,
    ratio: f64,
    half_turn: bool,
    /// Area of the outline at unit radius, squeezed.
    area: f64,
}

impl Outline {
    /// The outline of an aperture of `blades` blades turned `rotation_rad`, squeezed by
    /// `ratio`, turned half a turn where `half_turn`.
    pub fn of(blades: u32, rotation_rad: f64, ratio: f64, half_turn: bool) -> Self {
        use std::f64::consts::PI;
        let (normals, area) = if blades < 3 {
            (Vec::new(), PI)
        } else {
            let n = f64::from(blades);
            let step = 2.0 * PI / n;
            let apothem = (0.5 * step).cos();
            let normals = (0..blades)
                .map(|k| {
                    let (s, c) = (rotation_rad + (f64::from(k) + 0.5) * step).sin_cos();
                    [c / apothem, -s / apothem]
                })
                .collect();
            (normals, 0.5 * n * step.sin())
        };
        Outline {
            normals,
            ratio,
            half_turn,
            area: area / ratio,
        }
    }

    /// Area at unit radius.
    pub fn area(&self) -> f64 {
        self.area
    }

    /// The smallest radius whose outline holds `p` (px from the centre).
    pub fn gauge(&self, p: [f64; 2]) -> f64 {
        let sign = if self.half_turn { -1.0 } else { 1.0 };
        let q = [sign * p[0] * self.ratio, sign * p[1]];
        if self.normals.is_empty() {
            return q[0].hypot(q[1]);
        }
        self.normals
            .iter()
            .map(|n| q[0] * n[0] + q[1] * n[1])
            .fold(0.0, f64::max)
    }
}

/// The CoC radii (px) the rays of cell `cell` of a thin-lens database draw: spread evenly over
/// the cell in grid coordinates where it is pre-filtered, its centre's alone where not.
fn cell_radii(db: &PsfDatabase, cell: u32) -> Option<Vec<f64>> {
    let space = db.space();
    if !db.header().prefilter {
        return space.cell_center(cell).map(|c| vec![c[0]]);
    }
    let b = space.grid().cell_box(cell)?;
    Some(
        (0..RADII)
            .map(|j| {
                let t = (j as f64 + 0.5) / RADII as f64;
                let u = [b.min[0] + t * (b.max[0] - b.min[0]), b.min[1]];
                space.from_grid(u)[0]
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The light of a uniform disc of radius `r` centred at `centre` in the pixel of centre
    /// `(x, y)`, over the disc's whole light, from `n x n` points per pixel.
    fn box_filtered_disc(r: f64, centre: [f64; 2], x: i32, y: i32, n: usize) -> f64 {
        let mut inside = 0usize;
        for j in 0..n {
            for i in 0..n {
                let px = f64::from(x) - 0.5 + (i as f64 + 0.5) / n as f64 - centre[0];
                let py = f64::from(y) - 0.5 + (j as f64 + 0.5) / n as f64 - centre[1];
                inside += usize::from(px * px + py * py <= r * r);
            }
        }
        inside as f64 / (n * n) as f64 / (std::f64::consts::PI * r * r)
    }

    #[test]
    fn each_shifted_image_is_the_box_filtered_disc_at_its_shift() {
        let r = 1.6;
        let sub = SubpixelPsf::of_radii(&[r], [-2, -2], 5, 5);
        assert_eq!((sub.width, sub.height), (6, 6));
        for (a, b) in [(0, 0), (3, 0), (0, 5), (4, 4), (7, 2), (7, 7)] {
            let image = sub.shifted(a, b);
            let centre = [a as f64 / STEPS as f64, b as f64 / STEPS as f64];
            let sum: f64 = image.iter().map(|&v| f64::from(v)).sum();
            assert!((sum - 1.0).abs() < 1e-5, "shift ({a}, {b}): light {sum}");
            for y in 0..sub.height {
                for x in 0..sub.width {
                    let (px, py) = (x as i32 + sub.origin[0], y as i32 + sub.origin[1]);
                    let want = box_filtered_disc(r, centre, px, py, 128);
                    let got = f64::from(image[y * sub.width + x]);
                    assert!(
                        (got - want).abs() < 4e-3,
                        "shift ({a}, {b}), pixel ({px}, {py}): {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_cells_radii_are_averaged_as_its_rays_draw_them() {
        // Two radii: the mean of their discs, each holding half the light.
        let sub = SubpixelPsf::of_radii(&[1.2, 2.4], [-3, -3], 7, 7);
        let image = sub.shifted(0, 0);
        for (x, y) in [(0, 0), (1, 0), (2, 1), (3, 0)] {
            let want = 0.5
                * (box_filtered_disc(1.2, [0.0; 2], x, y, 128)
                    + box_filtered_disc(2.4, [0.0; 2], x, y, 128));
            let got = f64::from(image[(y + 3) as usize * sub.width + (x + 3) as usize]);
            assert!(
                (got - want).abs() < 4e-3,
                "pixel ({x}, {y}): {got} vs {want}"
            );
        }
    }
}
