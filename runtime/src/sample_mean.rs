//! Reconstruction leaned towards its samples' own per-pixel mean where it departs from them by
//! more than their noise explains.
//!
//! The plain mean `A` of a pixel's samples is an unbiased estimate of the pixel (a box over the
//! pixel, the lens and the shutter), noisy with the variance `v` its samples show.
//! Reconstruction `R` has next to no noise but keeps the bias `b` of its approximations: a PSF
//! pre-filtered over its cell, a lamp's rim drawn at one width where the lamp widens as it
//! nears, an edge placed by samples moved back to the lens centre. As the samples grow more,
//! `v` falls below `b²`, and a reconstruction that ignored the mean would stop converging to
//! the image. Of the mixes `R + α (A - R)` of an estimate with bias `b` and none of noise and
//! one with no bias and variance `v`, the one of least expected squared error has
//!
//! ```text
//! α = b² / (b² + v),    b² ≈ max(⟨(R - A)²⟩ - K ⟨v⟩, 0)
//! ```
//!
//! since `E[(R - A)²] = b² + v`; `⟨⟩` is the mean over the pixel's 3 x 3 neighbourhood, and
//! [`NOISE_MARGIN`] (`K`) leaves the noise's own spread of `(R - A)²` out of the bias, so that
//! where `R` is right the mix stays `R`. All on luminance, one `α` for the four channels
//! (premultiplied alpha stays consistent).
//!
//! Below [`MIN_SPP`] samples a pixel's variance says too little: a pixel whose four samples all
//! missed the bright lamp it lies in reads as quiet, and the mix would punch it dark. There
//! reconstruction is kept as it is.
//!
//! Nor is the mean the pixel's where every sample lies at its pixel centre (Blender's pinhole
//! sub-renders, [`crate::reconstruct::from_pinhole_sub_renders`]): it is then a point sample,
//! the staircase of an in-focus edge that reconstruction's pixel filter smooths, not the
//! pixel's box. Such frames are kept as drawn too (leaned, Cycles frames of the shared `fence`
//! at 64 paths lost SSIM 0.9936 -> 0.9844, and 0.9926 with the mean filtered as reconstruction
//! filters it).

use formats::{RgbaImage, StochasticFrames};
use rayon::prelude::*;

/// Fewest samples per pixel whose spread is trusted as the mean's noise (measured at 4, 8 and
/// 16 spp: at 4 the mix lost SSIM on a car's headlamps, from 8 it gained FLIP everywhere).
pub const MIN_SPP: usize = 8;

/// How many times the neighbourhood's mean noise variance is taken from `⟨(R - A)²⟩` before
/// what is left counts as reconstruction's bias (2, 3, 4, 8 and 16 tried; 4 kept SSIM within
/// 0.0003 at 8 and 16 spp and took most of the FLIP p99 gain).
pub const NOISE_MARGIN: f64 = 4.0;

/// Each pixel's plain sample mean (premultiplied linear RGBA) and the variance of that mean's
/// luminance (squared linear luminance), from frames of at least [`MIN_SPP`] samples per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct PixelSampleMeans {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Per pixel, row-major: the mean of its samples' colours.
    pub mean: Vec<[f32; 4]>,
    /// Per pixel: the sample variance of its samples' luminance over the sample count (the
    /// variance of the mean); infinite where a sample is not finite, so the pixel keeps
    /// reconstruction's value.
    pub variance_of_mean: Vec<f64>,
}

impl PixelSampleMeans {
    /// The means of `frames`, or `None` below [`MIN_SPP`] samples per pixel and for frames
    /// sampled at their pixel centres alone (module documentation).
    pub fn of(frames: &StochasticFrames) -> Option<Self> {
        let spp = frames.spp;
        if spp < MIN_SPP
            || frames.samples.len() != frames.width * frames.height * spp
            || crate::reconstruct::from_pinhole_sub_renders(frames)
        {
            return None;
        }
        let (mean, variance_of_mean) = frames
            .samples
            .par_chunks(spp)
            .map(|pixel| {
                let mut sum = [0.0f64; 4];
                let (mut lum_sum, mut lum_sq) = (0.0f64, 0.0f64);
                for s in pixel {
                    for (acc, &c) in sum.iter_mut().zip(&s.color) {
                        *acc += c as f64;
                    }
                    let l = luminance(s.color);
                    lum_sum += l;
                    lum_sq += l * l;
                }
                let n = spp as f64;
                let mean = sum.map(|c| (c / n) as f32);
                let variance = ((lum_sq - lum_sum * lum_sum / n) / (n - 1.0)).max(0.0) / n;
                let finite = mean.iter().all(|c| c.is_finite()) && variance.is_finite();
                (mean, if finite { variance } else { f64::INFINITY })
            })
            .unzip();
        Some(Self {
            width: frames.width,
            height: frames.height,
            mean,
            variance_of_mean,
        })
    }

    /// Leans `image` (reconstruction, the frame's size) towards the means, pixel by pixel, by
    /// the weight of least expected squared error (module documentation). Nothing where the
    /// size differs.
    pub fn lean(&self, image: &mut RgbaImage) {
        let (w, h) = (self.width, self.height);
        if image.width != w || image.height != h || w == 0 || h == 0 {
            return;
        }
        let squared_departure: Vec<f64> = image
            .pixels
            .par_iter()
            .zip(&self.mean)
            .map(|(r, a)| {
                let d = luminance(*r) - luminance(*a);
                d * d
            })
            .collect();
        let departure = box3(&squared_departure, w, h);
        let noise = box3(&self.variance_of_mean, w, h);
        image
            .pixels
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(y, row)| {
                for (x, r) in row.iter_mut().enumerate() {
                    let i = y * w + x;
                    let bias = (departure[i] - NOISE_MARGIN * noise[i]).max(0.0);
                    // NaN (no bias and no noise, or a sample not finite) keeps the pixel.
                    let weight = bias / (bias + noise[i]);
                    if weight.is_nan() || weight <= 0.0 {
                        continue;
                    }
                    let weight = weight.min(1.0) as f32;
                    let a = self.mean[i];
                    for (c, m) in r.iter_mut().zip(a) {
                        *c += weight * (m - *c);
                    }
                }
            });
    }
}

/// Linear luminance (Rec. 709 weights) of a colour's R, G, B.
fn luminance(c: [f32; 4]) -> f64 {
    0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64
}

/// The mean of each value's 3 x 3 neighbourhood in a `w x h` grid, the edge repeated beyond
/// the grid. Infinite values stay infinite around them.
fn box3(values: &[f64], w: usize, h: usize) -> Vec<f64> {
    let across: Vec<f64> = values
        .par_chunks(w)
        .flat_map_iter(|row| {
            (0..w).map(move |x| {
                (row[x.saturating_sub(1)] + row[x] + row[(x + 1).min(w - 1)]) / 3.0
            })
        })
        .collect();
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let (up, down) = (y.saturating_sub(1), (y + 1).min(h - 1));
            let across = &across;
            (0..w).map(move |x| (across[up * w + x] + across[y * w + x] + across[down * w + x]) / 3.0)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use formats::Sample;

    fn sample(value: f32) -> Sample {
        Sample {
            color: [value, value, value, 1.0],
            depth: 1.0,
            lens: [0.0, 0.0],
            time: 0.0,
            motion: [0.0, 0.0],
            jitter: [0.25, -0.125],
        }
    }

    /// Frames of `w x h` pixels whose pixel `(x, y)` has the samples `values(x, y)`.
    fn frames(w: usize, h: usize, spp: usize, values: impl Fn(usize, usize) -> Vec<f32>) -> StochasticFrames {
        let mut samples = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let v = values(x, y);
                assert_eq!(v.len(), spp);
                samples.extend(v.into_iter().map(sample));
            }
        }
        StochasticFrames::new(w, h, spp, samples)
    }

    fn image(w: usize, h: usize, value: impl Fn(usize, usize) -> f32) -> RgbaImage {
        let mut pixels = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let v = value(x, y);
                pixels.push([v, v, v, 1.0]);
            }
        }
        RgbaImage {
            width: w,
            height: h,
            pixels,
        }
    }

    /// Noise-free samples that disagree with reconstruction take the pixel over entirely
    /// (the mean's variance is zero, so any bias outweighs it); where reconstruction agrees
    /// with them it stays, bit for bit.
    #[test]
    fn quiet_samples_correct_a_biased_pixel_and_leave_a_right_one() {
        let (w, h, spp) = (6, 5, 8);
        let truth = |x: usize, _y: usize| if x < 3 { 0.2 } else { 0.7 };
        let frames = frames(w, h, spp, |x, y| vec![truth(x, y); spp]);
        let means = PixelSampleMeans::of(&frames).expect("8 spp");
        // Reconstruction right everywhere but a softened edge at columns 2 and 3.
        let mut recon = image(w, h, |x, y| match x {
            2 => 0.35,
            3 => 0.55,
            _ => truth(x, y),
        });
        let before = recon.clone();
        means.lean(&mut recon);
        for y in 0..h {
            for x in 0..w {
                let got = recon.pixels[y * w + x];
                if x == 2 || x == 3 {
                    assert!((got[0] - truth(x, y)).abs() < 1e-6, "({x},{y}) {got:?}");
                } else {
                    assert_eq!(got, before.pixels[y * w + x], "({x},{y})");
                }
            }
        }
    }

    /// Where the samples are noisy and reconstruction departs from their mean by no more than
    /// that noise, reconstruction is kept; a departure far beyond the noise is pulled by the
    /// weight `b² / (b² + v)` of the module's formula, checked against it.
    #[test]
    fn departures_within_the_noise_are_kept_and_beyond_it_follow_the_formula() {
        let (w, h, spp) = (5, 5, 8);
        // Each pixel's samples alternate 0.4 and 0.6: mean 0.5, luminance variance of the mean
        // (0.1^2 * 8 / 7) / 8 = 0.01 / 7.
        let noisy = |_: usize, _: usize| (0..spp).map(|k| if k % 2 == 0 { 0.4 } else { 0.6 }).collect();
        let frames = frames(w, h, spp, noisy);
        let means = PixelSampleMeans::of(&frames).expect("8 spp");
        let v = 0.01 / 7.0;
        assert!((means.variance_of_mean[0] - v).abs() < 1e-9);

        let close = 0.5 + (NOISE_MARGIN * v).sqrt() as f32 * 0.9;
        let mut recon = image(w, h, |_, _| close);
        means.lean(&mut recon);
        assert!(recon.pixels.iter().all(|p| p[0] == close), "within the noise: kept");

        let far = 0.9f32;
        let mut recon = image(w, h, |_, _| far);
        means.lean(&mut recon);
        let d2 = ((far - 0.5) as f64).powi(2);
        let bias = d2 - NOISE_MARGIN * v;
        let weight = bias / (bias + v);
        let expected = far as f64 + weight * (0.5 - far as f64);
        for p in &recon.pixels {
            assert!((p[0] as f64 - expected).abs() < 1e-5, "{} against {expected}", p[0]);
            assert_eq!(p[3], 1.0);
        }
    }

    /// Too few samples per pixel to trust their spread, or samples all at their pixel
    /// centres: no means, nothing leaned.
    #[test]
    fn fewer_samples_than_the_minimum_or_unjittered_give_no_means() {
        let few = frames(3, 3, MIN_SPP - 1, |_, _| vec![0.5; MIN_SPP - 1]);
        assert!(PixelSampleMeans::of(&few).is_none());
        let mut centred = frames(3, 3, MIN_SPP, |_, _| vec![0.5; MIN_SPP]);
        assert!(PixelSampleMeans::of(&centred).is_some());
        for s in &mut centred.samples {
            s.jitter = [0.0, 0.0];
        }
        assert!(PixelSampleMeans::of(&centred).is_none());
    }

    /// A sample that is not finite leaves its pixel's reconstruction as it is and does not
    /// spread NaN to its neighbours.
    #[test]
    fn a_pixel_with_a_non_finite_sample_keeps_reconstruction() {
        let (w, h, spp) = (3, 3, 8);
        let frames = frames(w, h, spp, |x, y| {
            let mut v = vec![0.5; spp];
            if (x, y) == (1, 1) {
                v[3] = f32::INFINITY;
            }
            v
        });
        let means = PixelSampleMeans::of(&frames).expect("8 spp");
        let mut recon = image(w, h, |_, _| 0.8);
        means.lean(&mut recon);
        assert!(recon.pixels.iter().all(|p| p.iter().all(|c| c.is_finite())));
        assert_eq!(recon.pixels[4][0], 0.8);
    }
}
