//! The pixel grid's eight symmetries about a pixel centre, and the smeared PSFs they relate.
//!
//! A lens PSF that the grid's symmetries leave unchanged (a sharp point's single pixel, or any
//! image equal to itself turned a quarter turn and mirrored) smears along a path `g(p)` into
//! the image `g` of its smear along `p`, for every symmetry `g`: the taps along `g(p)` are
//! `g` of those along `p` and a tap's bilinear weights turn with the grid. A turning disc in
//! focus calls for tens of thousands of smeared points whose arcs differ only by such a
//! symmetry (arcs on opposite sides of the disc are one arc turned half a turn, arcs a quarter
//! turn apart one arc turned a quarter turn), so each orbit is smeared once and its other
//! images are that one moved pixel by pixel ([`transform_image`]).
//!
//! A key's motion angle is `s * pi / n` modulo pi and its bend is signed relative to that
//! direction ([`SmearKey`]). With `n` even ([`SmearKey::angle_steps`]), every symmetry maps a
//! key's path onto the path of another key of the same length and step count: in units of
//! `pi / n`, a quarter turn adds `n / 2` to the direction, the mirror `(x, y) -> (x, -y)`
//! negates it. A direction that lands in `[pi, 2 pi)` is reversed to stay within `[0, pi)`,
//! and the bend's sign then follows which side of the new direction the arc lies on: kept by a
//! turn, flipped by the mirror, flipped again by a reversal.

use crate::motion_smear::{PsfImage, SmearKey};

/// One of the pixel grid's eight symmetries about a pixel centre: `quarter_turns` turns of
/// `(x, y) -> (-y, x)`, then, if `mirrored`, `(x, y) -> (x, -y)` (x right, y down, px).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct GridSymmetry {
    /// Quarter turns, in `0..4`.
    pub quarter_turns: u8,
    /// Whether the turned grid is then mirrored across the x axis.
    pub mirrored: bool,
}

impl GridSymmetry {
    /// The identity.
    pub const IDENTITY: Self = Self {
        quarter_turns: 0,
        mirrored: false,
    };

    /// All eight, the identity first.
    pub fn all() -> impl Iterator<Item = Self> {
        (0..8u8).map(|i| Self {
            quarter_turns: i % 4,
            mirrored: i >= 4,
        })
    }

    /// The offset `p` (px from the centre) moved by this symmetry.
    #[inline]
    pub fn apply(self, p: [i32; 2]) -> [i32; 2] {
        let [x, y] = match self.quarter_turns % 4 {
            0 => p,
            1 => [-p[1], p[0]],
            2 => [-p[0], -p[1]],
            _ => [p[1], -p[0]],
        };
        if self.mirrored {
            [x, -y]
        } else {
            [x, y]
        }
    }

    /// The symmetry that undoes this one. A mirrored one is its own inverse (mirror, turn
    /// `k`, mirror is turn `-k`).
    pub fn inverse(self) -> Self {
        if self.mirrored {
            self
        } else {
            Self {
                quarter_turns: (4 - self.quarter_turns % 4) % 4,
                mirrored: false,
            }
        }
    }

    /// The transpose `(x, y) -> (y, x)`.
    pub const TRANSPOSE: Self = Self {
        quarter_turns: 3,
        mirrored: true,
    };

    /// This symmetry as the transpose or not, then mirrors of x and of y: `(transposed, [x
    /// mirrored, y mirrored])`. A mirror keeps a box's rows as rows, so an image is moved by
    /// one row by row once it is transposed.
    pub fn as_transpose_and_mirrors(self) -> (bool, [bool; 2]) {
        let (ex, ey) = (self.apply([1, 0]), self.apply([0, 1]));
        if self.swaps_axes() {
            // g = F . T, so F(x, y) = g(y, x).
            (true, [ey[0] < 0, ex[1] < 0])
        } else {
            (false, [ex[0] < 0, ey[1] < 0])
        }
    }

    /// Whether it swaps the axes (an odd number of quarter turns).
    pub fn swaps_axes(self) -> bool {
        self.quarter_turns % 2 == 1
    }

    /// The key whose smear is this symmetry's image of `key`'s smear, for a lens PSF the grid's
    /// symmetries leave unchanged; `None` where `key`'s angle steps are odd (a quarter turn
    /// then falls between two steps).
    pub fn apply_to_key(self, key: SmearKey) -> Option<SmearKey> {
        self.apply_with_steps(key, key.angle_steps())
    }

    /// [`GridSymmetry::apply_to_key`] for a key of `n` angle steps.
    fn apply_with_steps(self, key: SmearKey, n: u32) -> Option<SmearKey> {
        if n % 2 == 1 {
            return None;
        }
        // Directions in units of pi / n over a full turn of 2 n.
        let full = 2 * i64::from(n);
        let turned =
            i64::from(key.angle_step) + i64::from(self.quarter_turns % 4) * i64::from(n / 2);
        let moved = if self.mirrored { -turned } else { turned }.rem_euclid(full);
        let reversed = moved >= i64::from(n);
        let angle_step = if reversed {
            moved - i64::from(n)
        } else {
            moved
        } as u32;
        let flips = u8::from(self.mirrored) + u8::from(reversed);
        let bend_step = if flips % 2 == 1 {
            -key.bend_step
        } else {
            key.bend_step
        };
        Some(SmearKey {
            angle_step,
            bend_step,
            ..key
        })
    }
}

/// The least key of `key`'s orbit under the grid's symmetries (by angle step, then bend step)
/// and the symmetry that moves that key's smear onto `key`'s: `key` is
/// `symmetry.apply_to_key(canonical)`. `None` where `key`'s angle steps are odd.
pub fn canonical_key(key: SmearKey) -> Option<(SmearKey, GridSymmetry)> {
    let mut best: Option<(SmearKey, GridSymmetry)> = None;
    let n = key.angle_steps();
    for g in GridSymmetry::all() {
        let moved = g.apply_with_steps(key, n)?;
        if best
            .is_none_or(|(b, _)| (moved.angle_step, moved.bend_step) < (b.angle_step, b.bend_step))
        {
            best = Some((moved, g));
        }
    }
    best.map(|(canonical, g)| (canonical, g.inverse()))
}

/// Whether every symmetry of the grid leaves `psf` unchanged, bit for bit (its box centred on
/// its centre pixel and square, its values equal to those of the pixels it is moved onto).
pub fn is_grid_symmetric(psf: &PsfImage) -> bool {
    let (w, h) = (psf.width as i32, psf.height as i32);
    if w != h || psf.origin != [-(w - 1) / 2, -(h - 1) / 2] || w % 2 == 0 {
        return false;
    }
    let ch = psf.channels;
    let r = (w - 1) / 2;
    let at = |p: [i32; 2]| ((p[1] + r) * w + (p[0] + r)) as usize * ch;
    GridSymmetry::all().skip(1).all(|g| {
        (-r..=r).all(|y| {
            (-r..=r).all(|x| {
                let (a, b) = (at([x, y]), at(g.apply([x, y])));
                psf.data[a..a + ch]
                    .iter()
                    .zip(&psf.data[b..b + ch])
                    .all(|(p, q)| p.to_bits() == q.to_bits())
            })
        })
    })
}

/// The box (top-left offset from the centre, width, height, px) that `g` moves the box at
/// `origin`, `width` x `height` onto.
pub fn transform_box(
    origin: [i32; 2],
    width: usize,
    height: usize,
    g: GridSymmetry,
) -> ([i32; 2], usize, usize) {
    let far = [origin[0] + width as i32 - 1, origin[1] + height as i32 - 1];
    let (a, b) = (g.apply(origin), g.apply(far));
    let (w, h) = if g.swaps_axes() {
        (height, width)
    } else {
        (width, height)
    };
    ([a[0].min(b[0]), a[1].min(b[1])], w, h)
}

/// A dense image in a box: its top-left offset from the centre (px), width and channels,
/// values row-major, and per row the columns `[first, end)` outside which it is zero.
pub struct BoxImage<'a> {
    /// Top-left pixel relative to the centre, px.
    pub origin: [i32; 2],
    /// Width, px.
    pub width: usize,
    /// Channels per pixel.
    pub channels: usize,
    /// `width * rows.len() * channels` values (garbage outside each row's columns).
    pub values: &'a [f32],
    /// Per row, the columns `[first, end)` that may hold non-zero values.
    pub rows: &'a [[u16; 2]],
}

/// `src` moved by `g` into `out`, the box [`transform_box`] gives (`out` is resized to it and
/// written only within the columns `out_rows` then gives per row; `out_rows` resized to its
/// height). Returns the box's origin and width.
pub fn transform_image(
    src: &BoxImage,
    g: GridSymmetry,
    out: &mut Vec<f32>,
    out_rows: &mut Vec<[u16; 2]>,
) -> ([i32; 2], usize) {
    let ch = src.channels;
    let height = src.rows.len();
    let (origin, width, out_height) = transform_box(src.origin, src.width, height, g);
    out_rows.clear();
    out_rows.resize(out_height, [u16::MAX, 0]);
    if out.len() < width * out_height * ch {
        out.resize(width * out_height * ch, 0.0);
    }
    // Where source pixel (x, y) of the box lands in the output box.
    let land = |x: usize, y: usize| {
        let p = g.apply([src.origin[0] + x as i32, src.origin[1] + y as i32]);
        ((p[0] - origin[0]) as usize, (p[1] - origin[1]) as usize)
    };
    let span = |r: [u16; 2]| usize::from(r[0])..usize::from(r[1]).min(src.width);
    for (y, &r) in src.rows.iter().enumerate() {
        for x in span(r) {
            let (u, v) = land(x, y);
            let row = &mut out_rows[v];
            // Box widths are the format's u16 widths.
            *row = [row[0].min(u as u16), row[1].max(u as u16 + 1)];
        }
    }
    for (v, row) in out_rows.iter_mut().enumerate() {
        if row[0] >= row[1] {
            *row = [0, 0];
            continue;
        }
        let [a, b] = row.map(usize::from);
        out[(v * width + a) * ch..(v * width + b) * ch].fill(0.0);
    }
    for (y, &r) in src.rows.iter().enumerate() {
        for x in span(r) {
            let (u, v) = land(x, y);
            let from = (y * src.width + x) * ch;
            let to = (v * width + u) * ch;
            out[to..to + ch].copy_from_slice(&src.values[from..from + ch]);
        }
    }
    (origin, width)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion_smear::{smear, SmearKey};

    fn point() -> PsfImage {
        PsfImage::point()
    }

    #[test]
    fn symmetries_form_the_group_of_the_square() {
        let p = [3, -7];
        for g in GridSymmetry::all() {
            assert_eq!(g.inverse().apply(g.apply(p)), p, "{g:?}");
        }
        let images: std::collections::HashSet<_> =
            GridSymmetry::all().map(|g| g.apply(p)).collect();
        assert_eq!(images.len(), 8);
    }

    #[test]
    fn a_symmetry_is_a_transpose_then_mirrors() {
        for g in GridSymmetry::all() {
            let (transposed, [mx, my]) = g.as_transpose_and_mirrors();
            for p in [[3, -7], [-2, 5], [1, 0]] {
                let t = if transposed {
                    GridSymmetry::TRANSPOSE.apply(p)
                } else {
                    p
                };
                let f = [if mx { -t[0] } else { t[0] }, if my { -t[1] } else { t[1] }];
                assert_eq!(f, g.apply(p), "{g:?}");
            }
        }
        assert_eq!(GridSymmetry::TRANSPOSE.apply([3, -7]), [-7, 3]);
    }

    /// Every symmetry's image of a smeared point is the smear along the key it names: the
    /// same pixels, within float rounding of the taps' sines and cosines.
    #[test]
    fn a_moved_smear_is_the_smear_of_the_moved_key() {
        let psf = point();
        let mut checked = 0;
        for (motion, bend) in [
            ([23.0, 7.0], 9.0),
            ([-5.0, 31.0], -14.0),
            ([40.0, 0.5], 0.0),
            ([3.0, 2.0], 2.5),
        ] {
            let (key, _) = SmearKey::new(0, motion, bend, [1.0, 0.0], 0.0);
            assert_eq!(key.angle_steps() % 2, 0);
            let src = smear(&psf, key.length_px(), key.angle_rad(), key.bend_px()).expect("smears");
            let rows = vec![[0u16, src.width as u16]; src.height];
            let boxed = BoxImage {
                origin: src.origin,
                width: src.width,
                channels: 1,
                values: &src.data,
                rows: &rows,
            };
            for g in GridSymmetry::all() {
                let moved_key = g.apply_to_key(key).expect("even steps");
                let direct = smear(
                    &psf,
                    moved_key.length_px(),
                    moved_key.angle_rad(),
                    moved_key.bend_px(),
                )
                .expect("smears");
                let (mut out, mut out_rows) = (Vec::new(), Vec::new());
                let (origin, width) = transform_image(&boxed, g, &mut out, &mut out_rows);
                let at = |o: [i32; 2],
                          w: usize,
                          h: usize,
                          data: &[f32],
                          rows: Option<&[[u16; 2]]>,
                          p: [i32; 2]| {
                    let (x, y) = (p[0] - o[0], p[1] - o[1]);
                    if x < 0 || y < 0 || x as usize >= w || y as usize >= h {
                        return 0.0;
                    }
                    let (x, y) = (x as usize, y as usize);
                    if let Some(r) = rows {
                        if x < usize::from(r[y][0]) || x >= usize::from(r[y][1]) {
                            return 0.0;
                        }
                    }
                    data[y * w + x]
                };
                let mut worst = 0f32;
                for y in -60..60 {
                    for x in -60..60 {
                        let a = at(origin, width, out_rows.len(), &out, Some(&out_rows), [x, y]);
                        let b = at(
                            direct.origin,
                            direct.width,
                            direct.height,
                            &direct.data,
                            None,
                            [x, y],
                        );
                        worst = worst.max((a - b).abs());
                    }
                }
                let peak = direct.data.iter().fold(0f32, |m, &v| m.max(v));
                assert!(
                    worst <= 1e-4 * peak,
                    "{key:?} {g:?} -> {moved_key:?}: off by {worst} of {peak}"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 32);
    }

    #[test]
    fn the_canonical_key_moves_back_onto_the_key() {
        for (motion, bend) in [
            ([23.0, 7.0], 9.0),
            ([-5.0, 31.0], -14.0),
            ([0.0, 12.0], 4.0),
        ] {
            let (key, _) = SmearKey::new(0, motion, bend, [1.0, 0.0], 0.0);
            let (canonical, g) = canonical_key(key).expect("even steps");
            assert_eq!(g.apply_to_key(canonical), Some(key));
            for h in GridSymmetry::all() {
                let other = h.apply_to_key(key).expect("even steps");
                assert_eq!(canonical_key(other).map(|(c, _)| c), Some(canonical));
            }
        }
    }

    #[test]
    fn only_images_the_grid_keeps_are_symmetric() {
        assert!(is_grid_symmetric(&point()));
        let mut disk = PsfImage {
            origin: [-1, -1],
            width: 3,
            height: 3,
            channels: 1,
            data: vec![0.5, 1.0, 0.5, 1.0, 2.0, 1.0, 0.5, 1.0, 0.5],
        };
        assert!(is_grid_symmetric(&disk));
        disk.data[1] = 0.9;
        assert!(!is_grid_symmetric(&disk));
        disk.data[1] = 1.0;
        disk.origin = [-1, 0];
        assert!(!is_grid_symmetric(&disk));
    }
}
