//! Convolution pyramid (Farbman, Fattal, Lischinski 2011, "Convolution Pyramids"), Poisson
//! kernel set, scaled to approximate the exact lattice inverse of [`crate::laplacian`].
//!
//! # The exact scheme (the GPU mirror follows it stage by stage)
//!
//! Filters (1D, applied separably along x then y; the 2D filter is the outer product):
//! `H1 = [0.15, 0.5, 0.7, 0.5, 0.15]`, `H2 = H1`, `G = [0.175, 0.547, 0.175]`. Every filter is
//! applied as a "same"-size correlation with zero outside the plane: for a 5-tap filter
//! `out[x] = sum_{k=0..4} h[k] in[x + k - 2]` (3-tap: `in[x + k - 1]`). `PAD = 5`.
//!
//! Levels: `L = max(1, ceil(log2(max(w, h)))) + EXTRA_LEVELS` for a `w x h` input
//! (`evalf.m` has no extra levels; see [`EXTRA_LEVELS`]).
//! * Level 0 analysis `a0` = the input with `PAD` zeros on every side: `(w + 10) x (h + 10)`
//!   ([`pad_input`]).
//! * Analysis step ([`analysis_step`]), level i -> i+1 for i = 0..L-2: filter `a_i` with `H1`
//!   (x and y), keep the even samples (0, 2, 4, ...), giving `ceil(W_i/2) x ceil(H_i/2)`, and
//!   pad that with `PAD` zeros on every side: `a_{i+1}` is `(ceil(W_i/2) + 10) x (ceil(H_i/2) + 10)`.
//! * Top ([`top_step`]): `f_{L-1} = G * a_{L-1}`.
//! * Synthesis step ([`synthesis_step`]), i = L-2 down to 0: crop `PAD` from every side of
//!   `f_{i+1}`, insert zeros (`up[2y][2x] = cropped[y][x]`, everything else 0, size of `a_i`),
//!   then `f_i = H2 * up + G * a_i`.
//! * Output ([`crop_output`]): `f_0` without its `PAD` border, multiplied by [`PYRAMID_SCALE`].
//!
//! This is the authors' reference evaluation (`evalf.m` on the project page) with the filter set
//! of their Poisson experiment, plus [`EXTRA_LEVELS`] coarse levels. The scale is calibrated against [`crate::integrate_exact`]; the
//! measured error is in the tests and in the crate report, never assumed.

use rayon::prelude::*;

use crate::plane::Plane;

/// Analysis filter (1D), applied along x and y.
pub const H1: [f32; 5] = [0.15, 0.5, 0.7, 0.5, 0.15];
/// Synthesis (upsampling) filter (1D), applied along x and y after zero insertion.
pub const H2: [f32; 5] = H1;
/// Per-level filter (1D), applied along x and y to the level's own analysis signal.
pub const G: [f32; 3] = [0.175, 0.547, 0.175];
/// Zeros added on every side of every analysis level, px.
pub const PAD: usize = 5;
/// Factor that maps the raw pyramid output onto the lattice inverse of the 5-point stencil.
/// Calibrated once: least-squares fit `exact = s * pyramid + c` of the impulse response of a
/// 257x257 plane within 64 px of the impulse, against `ExactIntegrator` with a 2048 px margin
/// (`tests/pyramid.rs`, which re-checks it). Negative: the Poisson set approximates the Green's
/// function of `-L`. Residual after the fit: mean 0.00037, max 0.0152 within r = 64; a disk of
/// radius 30 px in a 160x160 plane comes back with mean |error| 0.0051 and max 0.130 (at the rim).
pub const PYRAMID_SCALE: f32 = -0.986_035;

/// Levels added beyond the reference code's `ceil(log2(max(w, h)))`. The coarsest levels are
/// a few pixels wide and cost nothing, but they carry the far field of large PSFs: for a disk of
/// radius 30 px in a 160x160 plane the mean absolute error against the exact inverse drops from
/// 0.0141 to 0.0051 (`tests/pyramid.rs`; the far-field bias from -0.0126 to -0.0027 in a NumPy
/// transcription), while a small PSF in a large plane is unchanged. The GPU mirror follows
/// automatically through [`level_sizes`].
pub const EXTRA_LEVELS: usize = 2;

/// Number of levels for a `w x h` input: `max(1, ceil(log2(max(w, h)))) + EXTRA_LEVELS`.
pub fn level_count(w: usize, h: usize) -> usize {
    let m = w.max(h).max(1);
    let mut l = 0;
    while (1usize << l) < m {
        l += 1;
    }
    l.max(1) + EXTRA_LEVELS
}

/// Sizes (px, padding included) of the analysis planes `a_0 .. a_{L-1}` for a `w x h` input;
/// `f_i` has the size of `a_i`.
pub fn level_sizes(w: usize, h: usize) -> Vec<(usize, usize)> {
    let mut sizes = vec![(w + 2 * PAD, h + 2 * PAD)];
    for _ in 1..level_count(w, h) {
        let (pw, ph) = sizes[sizes.len() - 1];
        sizes.push((pw.div_ceil(2) + 2 * PAD, ph.div_ceil(2) + 2 * PAD));
    }
    sizes
}

/// `a_0`: `input` with `PAD` zeros on every side (`dst` is resized).
pub fn pad_input(input: &Plane, dst: &mut Plane) {
    dst.reset(input.width + 2 * PAD, input.height + 2 * PAD);
    let dw = dst.width;
    dst.data
        .par_chunks_mut(dw)
        .skip(PAD)
        .take(input.height)
        .enumerate()
        .for_each(|(y, row)| row[PAD..PAD + input.width].copy_from_slice(input.row(y)));
}

/// `out[x] = sum_k h[k] in[x + k - 2]`, zero outside, for a 5-tap `h`, output at every `step`-th
/// input position starting at 0 (`step` 1 or 2).
#[inline]
fn filter5_row(h: &[f32; 5], src: &[f32], step: usize, out: &mut [f32]) {
    let n = src.len() as isize;
    for (o, v) in out.iter_mut().enumerate() {
        let c = (o * step) as isize;
        let mut s = 0.0;
        if c >= 2 && c + 2 < n {
            let b = (c - 2) as usize;
            s = h[0] * src[b]
                + h[1] * src[b + 1]
                + h[2] * src[b + 2]
                + h[3] * src[b + 3]
                + h[4] * src[b + 4];
        } else {
            for (k, &hk) in h.iter().enumerate() {
                let i = c + k as isize - 2;
                if i >= 0 && i < n {
                    s += hk * src[i as usize];
                }
            }
        }
        *v = s;
    }
}

/// Analysis step `a_i -> a_{i+1}`: `H1` along x and y, even samples kept, `PAD` zeros around.
/// `dst` is resized; `scratch` is reused between calls.
pub fn analysis_step(src: &Plane, dst: &mut Plane, scratch: &mut Vec<f32>) {
    let (sw, sh) = (src.width, src.height);
    let (dw, dh) = (sw.div_ceil(2), sh.div_ceil(2));
    // Horizontal: every source row, even columns.
    scratch.clear();
    scratch.resize(dw * sh, 0.0);
    scratch
        .par_chunks_mut(dw.max(1))
        .enumerate()
        .for_each(|(y, out)| filter5_row(&H1, src.row(y), 2, out));
    // Vertical: even rows, into the padded destination.
    dst.reset(dw + 2 * PAD, dh + 2 * PAD);
    let stride = dst.width;
    let tmp = &scratch[..];
    dst.data
        .par_chunks_mut(stride)
        .skip(PAD)
        .take(dh)
        .enumerate()
        .for_each(|(yy, row)| {
            let c = (2 * yy) as isize;
            let out = &mut row[PAD..PAD + dw];
            out.fill(0.0);
            for (k, &hk) in H1.iter().enumerate() {
                let y = c + k as isize - 2;
                if y >= 0 && (y as usize) < sh {
                    let r = &tmp[y as usize * dw..(y as usize + 1) * dw];
                    for (o, &v) in out.iter_mut().zip(r) {
                        *o += hk * v;
                    }
                }
            }
        });
}

/// `out[x] = G[0] in[x-1] + G[1] in[x] + G[2] in[x+1]`, zero outside (edges apart so the
/// interior loop vectorises).
#[inline]
fn g3_row(r: &[f32], out: &mut [f32]) {
    let w = r.len();
    match w {
        0 => {}
        1 => out[0] = G[1] * r[0],
        _ => {
            out[0] = G[1] * r[0] + G[2] * r[1];
            out[w - 1] = G[0] * r[w - 2] + G[1] * r[w - 1];
            for ((o, a), (b, c)) in out[1..w - 1]
                .iter_mut()
                .zip(&r[..w - 2])
                .zip(r[1..w - 1].iter().zip(&r[2..]))
            {
                *o = G[0] * a + G[1] * b + G[2] * c;
            }
        }
    }
}

/// One row of `H2 * zero_insert(c)` along x, `out.len()` fine samples (`ceil(out.len()/2) ==
/// c.len()`). Polyphase form: even x = 2X takes `H2[0] c[X-1] + H2[2] c[X] + H2[4] c[X+1]`,
/// odd x = 2X+1 takes `H2[1] c[X] + H2[3] c[X+1]`, with c = 0 outside.
#[inline]
fn upsample_row(c: &[f32], out: &mut [f32]) {
    let cw = c.len();
    let at = |i: usize| -> f32 {
        if i < cw {
            c[i]
        } else {
            0.0
        }
    };
    let w = out.len();
    // Border samples (those that touch c[-1] or c[cw]) with checks, the rest without.
    for (x, o) in out.iter_mut().enumerate() {
        let xc = x / 2;
        if x >= 2 && xc + 1 < cw {
            continue;
        }
        let prev = if xc >= 1 { at(xc - 1) } else { 0.0 };
        *o = if x % 2 == 0 {
            H2[0] * prev + H2[2] * at(xc) + H2[4] * at(xc + 1)
        } else {
            H2[1] * at(xc) + H2[3] * at(xc + 1)
        };
    }
    // Interior pairs: x = 2X, 2X+1 for 1 <= X and X + 1 < cw.
    if cw >= 3 {
        let pairs = &mut out[2..w.min(2 * (cw - 1))];
        for (k, pair) in pairs.chunks_exact_mut(2).enumerate() {
            let xc = k + 1;
            let (p, m, n) = (c[xc - 1], c[xc], c[xc + 1]);
            pair[0] = H2[0] * p + H2[2] * m + H2[4] * n;
            pair[1] = H2[1] * m + H2[3] * n;
        }
    }
}

/// `G` along x and y of `src`, added into `dst` (same size); `scratch` reused.
fn add_g(src: &Plane, dst: &mut Plane, scratch: &mut Vec<f32>) {
    let (w, h) = (src.width, src.height);
    scratch.clear();
    scratch.resize(w * h, 0.0);
    scratch
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, out)| {
            let r = src.row(y);
            g3_row(r, out);
        });
    let tmp = &scratch[..];
    dst.data
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, out)| {
            let mid = &tmp[y * w..(y + 1) * w];
            for (o, &v) in out.iter_mut().zip(mid) {
                *o += G[1] * v;
            }
            if y > 0 {
                for (o, &v) in out.iter_mut().zip(&tmp[(y - 1) * w..y * w]) {
                    *o += G[0] * v;
                }
            }
            if y + 1 < h {
                for (o, &v) in out.iter_mut().zip(&tmp[(y + 1) * w..(y + 2) * w]) {
                    *o += G[2] * v;
                }
            }
        });
}

/// Top of the pyramid: `dst = G * src` (`dst` resized to `src`'s size).
pub fn top_step(src: &Plane, dst: &mut Plane, scratch: &mut Vec<f32>) {
    dst.reset(src.width, src.height);
    add_g(src, dst, scratch);
}

/// Synthesis step: `dst = H2 * zero_insert(crop_PAD(coarse)) + G * analysis`, `dst` resized to
/// `analysis`'s size. `coarse` is `f_{i+1}`, `analysis` is `a_i`.
pub fn synthesis_step(coarse: &Plane, analysis: &Plane, dst: &mut Plane, scratch: &mut Vec<f32>) {
    let (w, h) = (analysis.width, analysis.height);
    let (cw, ch) = (w.div_ceil(2), h.div_ceil(2));
    debug_assert_eq!((coarse.width, coarse.height), (cw + 2 * PAD, ch + 2 * PAD));
    dst.reset(w, h);
    // Horizontal: for each coarse row (= even fine row), upsample along x: fine x gets
    // sum_k H2[k] up[x + k - 2], where up[2X] = c[X].
    scratch.clear();
    scratch.resize(w * ch, 0.0);
    scratch
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(yc, out)| {
            let c = &coarse.row(yc + PAD)[PAD..PAD + cw];
            // Polyphase form of H2 after zero insertion: even x = 2X takes
            // H2[0] c[X-1] + H2[2] c[X] + H2[4] c[X+1], odd x = 2X+1 takes H2[1] c[X] + H2[3] c[X+1].
            upsample_row(c, out);
        });
    // Vertical: fine y gets sum_k H2[k] tmp[(y + k - 2) / 2] for even y + k - 2.
    let tmp = &scratch[..];
    dst.data
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, out)| {
            for (k, &hk) in H2.iter().enumerate() {
                let i = y as isize + k as isize - 2;
                if i >= 0 && i % 2 == 0 {
                    let yc = (i / 2) as usize;
                    if yc < ch {
                        for (o, &v) in out.iter_mut().zip(&tmp[yc * w..(yc + 1) * w]) {
                            *o += hk * v;
                        }
                    }
                }
            }
        });
    add_g(analysis, dst, scratch);
}

/// The result: `f_0` without its `PAD` border, times [`PYRAMID_SCALE`] (`dst` resized).
pub fn crop_output(f0: &Plane, dst: &mut Plane) {
    let (w, h) = (f0.width - 2 * PAD, f0.height - 2 * PAD);
    dst.reset(w, h);
    dst.data
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, out)| {
            for (o, &v) in out.iter_mut().zip(&f0.row(y + PAD)[PAD..PAD + w]) {
                *o = PYRAMID_SCALE * v;
            }
        });
}

/// Reusable buffers for integrating planes of one size (no allocation after the first call).
#[derive(Clone, Debug, Default)]
pub struct PyramidWorkspace {
    width: usize,
    height: usize,
    analysis: Vec<Plane>,
    synthesis: Vec<Plane>,
    scratch: Vec<f32>,
}

impl PyramidWorkspace {
    /// Buffers for `width x height` planes.
    pub fn new(width: usize, height: usize) -> Self {
        let sizes = level_sizes(width, height);
        let planes = || {
            sizes
                .iter()
                .map(|&(w, h)| Plane::new(w, h))
                .collect::<Vec<_>>()
        };
        PyramidWorkspace {
            width,
            height,
            analysis: planes(),
            synthesis: planes(),
            scratch: Vec::new(),
        }
    }

    /// Plane size this workspace is for, px.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Number of levels.
    pub fn levels(&self) -> usize {
        self.analysis.len()
    }

    /// Analysis planes `a_i` of the last call (for level-by-level comparisons).
    pub fn analysis_levels(&self) -> &[Plane] {
        &self.analysis
    }

    /// Synthesis planes `f_i` of the last call.
    pub fn synthesis_levels(&self) -> &[Plane] {
        &self.synthesis
    }

    /// Integrates `lap` (the Laplacian of an image) into `out` (resized to the plane's size).
    /// A `lap` of another size re-sizes the workspace first.
    pub fn integrate_into(&mut self, lap: &Plane, out: &mut Plane) {
        if (lap.width, lap.height) != (self.width, self.height) || self.analysis.is_empty() {
            *self = PyramidWorkspace::new(lap.width, lap.height);
        }
        let levels = self.analysis.len();
        pad_input(lap, &mut self.analysis[0]);
        for i in 1..levels {
            let (lo, hi) = self.analysis.split_at_mut(i);
            analysis_step(&lo[i - 1], &mut hi[0], &mut self.scratch);
        }
        top_step(
            &self.analysis[levels - 1],
            &mut self.synthesis[levels - 1],
            &mut self.scratch,
        );
        for i in (0..levels - 1).rev() {
            let (lo, hi) = self.synthesis.split_at_mut(i + 1);
            synthesis_step(&hi[0], &self.analysis[i], &mut lo[i], &mut self.scratch);
        }
        crop_output(&self.synthesis[0], out);
    }

    /// Integrates `lap` into a new plane.
    pub fn integrate(&mut self, lap: &Plane) -> Plane {
        let mut out = Plane::default();
        self.integrate_into(lap, &mut out);
        out
    }
}

/// Integrates the Laplacian `lap` with a convolution pyramid (allocates a workspace; keep a
/// [`PyramidWorkspace`] for repeated use).
pub fn integrate_pyramid(lap: &Plane) -> Plane {
    PyramidWorkspace::new(lap.width, lap.height).integrate(lap)
}
