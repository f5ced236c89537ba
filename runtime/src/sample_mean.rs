//! Reconstruction leaned towards its samples' own per-pixel mean where it departs from them by
//! more than their noise explains.
//!
//! The plain mean `A` of a pixel's samples is an unbiased estimate of the pixel (a box over the
//! pixel, the lens and the shutter), noisy with the variance `v` its samples show.
//! Reconstruction `R` has next to no noise but keeps the bias `b` of its approximations: a PSF
//! pre-filtered over its cell, an edge placed by samples moved back to the lens centre. As the
//! samples grow more, `v` falls below `b²`, and there the mean is the better estimate. Of the
//! mixes `R + α (A - R)` of an estimate with bias `b` and none of noise and one with no bias
//! and variance `v`, the one of least expected squared error has `α = b² / (b² + v)`; here
//!
//! ```text
//! α = b² / (b² + ⟨v⟩),    b² ≈ max(⟨(R - A)²⟩ - K ⟨v⟩, 0)
//! ```
//!
//! since `E[(R - A)²] = b² + v`; `⟨⟩` is the mean over the pixel's 3 x 3 neighbourhood, and
//! [`NOISE_MARGIN`] (`K`) leaves the noise's own spread of `(R - A)²` out of the bias, so that
//! where `R` is right the mix stays `R`. All on luminance, one `α` for the four channels
//! (premultiplied alpha stays consistent). The corrections `α (A - R)` are smoothed by a
//! Gaussian of [`CORRECTION_SIGMA_PX`] before they are added, so that the mean's own noise,
//! which comes with them, does not show as speckles; detail finer than about two pixels is
//! then corrected only in part (a 2 px stripe by about half).
//!
//! Below [`MIN_SPP`] samples a pixel's variance says too little: a pixel whose four samples all
//! missed the bright lamp it lies in reads as quiet, and the mix would punch it dark. There
//! reconstruction is kept as it is.
//!
//! Nor is a pixel's spread trusted within the blur's reach of a light (a sample brighter than
//! 1 in a channel, as reconstruction counts a light's): a defocused highlight's bokeh is lit by
//! a few rare samples, each a light seen through a small part of the lens, and most pixels in
//! its disc hold none of them. Their samples agree on the dark background and say nothing of
//! the light they missed: leaned, the disc of `physical` at 8 spp came out punched with holes
//! (SSIM 0.9838 -> 0.9588). Such pixels keep reconstruction, which draws the light over its
//! whole disc: every pixel within a square reaching twice a light's sample's blur (CoC radius
//! and half its motion over the shutter, plus a pixel) from it. A miss whose background is
//! that bright (an HDR sky) counts as a light too. Pixels with a sample that is not finite
//! keep reconstruction, and so do those with a sample that missed (alpha 0): there the mean's
//! alpha is the hits' share where reconstruction's is normalised to 1.
//!
//! Nor is the mean the pixel's where every sample lies at its pixel centre (Blender's pinhole
//! sub-renders, [`crate::reconstruct::from_pinhole_sub_renders`]): it is then a point sample,
//! the staircase of an in-focus edge that reconstruction's pixel filter smooths, not the
//! pixel's box. Such frames are kept as drawn too (leaned, Cycles frames of the shared `fence`
//! at 64 paths lost SSIM 0.9936 -> 0.9844, and 0.9926 with the mean filtered as reconstruction
//! filters it).

use formats::{RgbaImage, StochasticFrames};
use rayon::prelude::*;

use crate::camera::Camera;
use crate::grid::{dilate, gaussian_blur};

/// Standard deviation of the Gaussian the corrections `α (A - R)` are smoothed with before they
/// are added, pixels: at full weight the mean's own noise came through with them, speckles
/// along a moving silhouette (`crossing` at 16 spp); 0.5 px left some, 0.8 none, and raised
/// SSIM. Texture finer than about two pixels is then corrected less.
pub const CORRECTION_SIGMA_PX: f32 = 0.8;

/// A sample brighter than this in R, G or B (linear) is a light's: the pixels its blur reaches
/// keep reconstruction (module documentation).
pub const LIGHT_SAMPLE: f32 = 1.0;

/// Fewest samples per pixel whose spread is trusted as the mean's noise (measured at 4, 8 and
/// 16 spp: at 4 the mix lost SSIM inside a car's headlamps, whose samples all missed the lamp
/// in some pixels; from 8, away from lights, it gained in FLIP on every built-in scene).
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
    /// Per pixel: whether it keeps reconstruction's value: a light's sample may reach it
    /// ([`LIGHT_SAMPLE`]), or one of its samples is not finite or missed.
    pub keep: Vec<bool>,
}

impl PixelSampleMeans {
    /// The means of `frames` seen through `camera`, or `None` below [`MIN_SPP`] samples per
    /// pixel and for frames sampled at their pixel centres alone (module documentation).
    pub fn of(frames: &StochasticFrames, camera: &Camera) -> Option<Self> {
        let spp = frames.spp;
        let count = frames
            .width
            .checked_mul(frames.height)
            .and_then(|n| n.checked_mul(spp));
        if spp < MIN_SPP
            || count != Some(frames.samples.len())
            || crate::reconstruct::from_pinhole_sub_renders(frames)
        {
            return None;
        }
        let (mean, variance_of_mean): (Vec<[f32; 4]>, Vec<f64>) = frames
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
        let mut keep = near_lights(frames, camera);
        for ((k, pixel), v) in keep
            .iter_mut()
            .zip(frames.samples.chunks(spp))
            .zip(&variance_of_mean)
        {
            let hits = pixel.iter().filter(|s| s.color[3] > 0.0).count();
            *k |= !v.is_finite() || hits != spp;
        }
        Some(Self {
            width: frames.width,
            height: frames.height,
            mean,
            variance_of_mean,
            keep,
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
        // A kept pixel's departure says nothing of reconstruction's bias (a rare light missed,
        // alpha normalised differently): it does not count towards its neighbours'.
        let squared_departure: Vec<f64> = image
            .pixels
            .par_iter()
            .zip(&self.mean)
            .zip(&self.keep)
            .map(|((r, a), &keep)| {
                if keep {
                    return 0.0;
                }
                let d = luminance(*r) - luminance(*a);
                d * d
            })
            .collect();
        let departure = box3(&squared_departure, w, h);
        let noise = box3(&self.variance_of_mean, w, h);
        let image_pixels = &image.pixels;
        let correction: Vec<[f32; 4]> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                if self.keep[i] {
                    return [0.0; 4];
                }
                let bias = (departure[i] - NOISE_MARGIN * noise[i]).max(0.0);
                // NaN (no bias and no noise, or a sample not finite) keeps the pixel.
                let weight = bias / (bias + noise[i]);
                if weight.is_nan() || weight <= 0.0 {
                    return [0.0; 4];
                }
                let weight = weight.min(1.0) as f32;
                let (r, a) = (image_pixels[i], self.mean[i]);
                std::array::from_fn(|c| weight * (a[c] - r[c]))
            })
            .collect();
        let mut smoothed = correction;
        gaussian_blur(&mut smoothed, w, h, CORRECTION_SIGMA_PX);
        image
            .pixels
            .par_iter_mut()
            .zip(&smoothed)
            .zip(&self.keep)
            .for_each(|((p, c), &keep)| {
                // The smoothing spreads a neighbour's correction onto a kept pixel too.
                if keep {
                    return;
                }
                for (v, &d) in p.iter_mut().zip(c) {
                    // Untouched pixels keep their bytes (adding 0 would turn -0 into +0).
                    if d != 0.0 {
                        *v += d;
                    }
                }
            });
    }
}

/// Per pixel of `frames`: whether it lies within twice the blur radius (pixels: the CoC radius
/// at the sample's depth and half its motion over the shutter, plus one) of a light's sample
/// ([`LIGHT_SAMPLE`]), which can land anywhere in the light's blur. Square neighbourhoods, one
/// per power-of-two reach, so the cost stays linear in the pixels however many lights.
fn near_lights(frames: &StochasticFrames, camera: &Camera) -> Vec<bool> {
    let (w, h, spp) = (frames.width, frames.height, frames.spp.max(1));
    let lens = camera.thin_lens();
    let shutter = camera.shutter_frames as f32;
    let largest = w.max(h);
    let reach_of = |s: &formats::Sample| -> usize {
        let coc = lens.map_or(0.0, |l| l.signed_coc_px(s.depth as f64).abs() as f32);
        let smear = 0.5 * shutter * s.motion[0].hypot(s.motion[1]);
        let reach = 2.0 * (coc + smear) + 1.0;
        // Not finite (a depth of zero or NaN, motion out of range): the whole frame.
        if reach.is_finite() {
            (reach.ceil() as usize).min(largest)
        } else {
            largest
        }
    };
    // Each pixel's largest reach of a light's sample in it, 0 where there is none.
    let reach: Vec<usize> = frames
        .samples
        .par_chunks(spp)
        .map(|pixel| {
            pixel
                .iter()
                .filter(|s| s.color[..3].iter().any(|&c| c > LIGHT_SAMPLE))
                .map(reach_of)
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut near = vec![false; w * h];
    let mut bound = 1usize;
    let mut below = 0usize;
    while below < largest {
        let in_level = |r: usize| r > below && r <= bound;
        let seeds: Vec<bool> = reach.iter().map(|&r| in_level(r)).collect();
        // Grown by the level's largest reach, not its bound: at most twice each reach apart.
        if let Some(radius) = reach.iter().copied().filter(|&r| in_level(r)).max() {
            for (n, d) in near.iter_mut().zip(dilate(&seeds, w, h, radius)) {
                *n |= d;
            }
        }
        below = bound;
        bound *= 2;
    }
    near
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
            (0..w).map(move |x| (row[x.saturating_sub(1)] + row[x] + row[(x + 1).min(w - 1)]) / 3.0)
        })
        .collect();
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let (up, down) = (y.saturating_sub(1), (y + 1).min(h - 1));
            let across = &across;
            (0..w)
                .map(move |x| (across[up * w + x] + across[y * w + x] + across[down * w + x]) / 3.0)
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

    /// A camera focused at 1 (the test samples' depth: no blur there), whose CoC radius at
    /// depth 2 is about 5.8 px on a 21 px wide frame.
    fn camera() -> Camera {
        Camera::from_json_str(
            r#"{"width":21,"height":21,"focal_length_mm":200,"sensor_width_mm":36,
            "f_stop":1.0,"focus_distance":1.0,"aperture_blades":0,"shutter_frames":0.0}"#,
        )
        .expect("camera")
    }

    /// Frames of `w x h` pixels whose pixel `(x, y)` has the samples `values(x, y)`.
    fn frames(
        w: usize,
        h: usize,
        spp: usize,
        values: impl Fn(usize, usize) -> Vec<f32>,
    ) -> StochasticFrames {
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

    /// Noise-free samples that disagree with reconstruction over a band seven pixels wide pull
    /// it to them (the band's middle exactly: the smoothed correction is whole there); pixels
    /// beyond the smoothing's reach of the band keep their bytes.
    #[test]
    fn quiet_samples_correct_a_biased_band_and_leave_the_rest() {
        let (w, h, spp) = (17, 7, 8);
        let truth = |x: usize, _y: usize| if x < 8 { 0.2 } else { 0.7 };
        let frames = frames(w, h, spp, |x, y| vec![truth(x, y); spp]);
        let means = PixelSampleMeans::of(&frames, &camera()).expect("8 spp");
        let band = 5..=11;
        let recon = image(w, h, |x, y| {
            truth(x, y) + if band.contains(&x) { 0.1 } else { 0.0 }
        });
        let mut leaned = recon.clone();
        means.lean(&mut leaned);
        for y in 0..h {
            for x in 0..w {
                let (got, was) = (leaned.pixels[y * w + x][0], recon.pixels[y * w + x][0]);
                if x == 8 {
                    assert!((got - truth(x, y)).abs() < 1e-5, "({x},{y}) {got}");
                } else if band.contains(&x) {
                    assert!(
                        (got - truth(x, y)).abs() < 0.5 * (was - truth(x, y)).abs(),
                        "({x},{y})"
                    );
                } else if !(2..=14).contains(&x) {
                    assert_eq!(
                        leaned.pixels[y * w + x],
                        recon.pixels[y * w + x],
                        "({x},{y})"
                    );
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
        let noisy = |_: usize, _: usize| {
            (0..spp)
                .map(|k| if k % 2 == 0 { 0.4 } else { 0.6 })
                .collect()
        };
        let frames = frames(w, h, spp, noisy);
        let means = PixelSampleMeans::of(&frames, &camera()).expect("8 spp");
        let v = 0.01 / 7.0;
        assert!((means.variance_of_mean[0] - v).abs() < 1e-9);

        let close = 0.5 + (NOISE_MARGIN * v).sqrt() as f32 * 0.9;
        let mut recon = image(w, h, |_, _| close);
        means.lean(&mut recon);
        assert!(
            recon.pixels.iter().all(|p| p[0] == close),
            "within the noise: kept"
        );

        let far = 0.9f32;
        let mut recon = image(w, h, |_, _| far);
        means.lean(&mut recon);
        let d2 = ((far - 0.5) as f64).powi(2);
        let bias = d2 - NOISE_MARGIN * v;
        let weight = bias / (bias + v);
        let expected = far as f64 + weight * (0.5 - far as f64);
        for p in &recon.pixels {
            assert!(
                (p[0] as f64 - expected).abs() < 1e-5,
                "{} against {expected}",
                p[0]
            );
            assert_eq!(p[3], 1.0);
        }
    }

    /// Too few samples per pixel to trust their spread, or samples all at their pixel
    /// centres: no means, nothing leaned.
    #[test]
    fn fewer_samples_than_the_minimum_or_unjittered_give_no_means() {
        let few = frames(3, 3, MIN_SPP - 1, |_, _| vec![0.5; MIN_SPP - 1]);
        assert!(PixelSampleMeans::of(&few, &camera()).is_none());
        let mut centred = frames(3, 3, MIN_SPP, |_, _| vec![0.5; MIN_SPP]);
        assert!(PixelSampleMeans::of(&centred, &camera()).is_some());
        for s in &mut centred.samples {
            s.jitter = [0.0, 0.0];
        }
        assert!(PixelSampleMeans::of(&centred, &camera()).is_none());
    }

    /// A light seen by one sample of one pixel, a little out of focus: the pixels within a
    /// square reaching twice its blur keep reconstruction (its spread light), bit for bit;
    /// beyond it the same departure from the samples is leaned away.
    #[test]
    fn the_pixels_a_lights_blur_reaches_keep_reconstruction() {
        let (w, h, spp) = (40, 40, 8);
        let (lx, ly) = (12usize, 20usize);
        let mut frames = frames(w, h, spp, |_, _| vec![0.1; spp]);
        for s in &mut frames.samples {
            s.depth = 1.05; // CoC radius about 0.56 px: reach 2.1 px, a square of side 7
        }
        frames.samples[(ly * w + lx) * spp + 3].color = [50.0, 50.0, 50.0, 1.0];
        let means = PixelSampleMeans::of(&frames, &camera()).expect("8 spp");
        let near = |x: usize, y: usize| x.abs_diff(lx) <= 3 && y.abs_diff(ly) <= 3;
        for y in 0..h {
            for x in 0..w {
                assert_eq!(means.keep[y * w + x], near(x, y), "({x},{y})");
            }
        }
        // Reconstruction 0.2 too bright round the light and in a band far from it.
        let band = |x: usize| (26..=34).contains(&x);
        let recon = image(w, h, |x, y| if near(x, y) || band(x) { 0.3 } else { 0.1 });
        let mut leaned = recon.clone();
        means.lean(&mut leaned);
        for y in 0..h {
            for x in 0..w {
                let (got, was) = (leaned.pixels[y * w + x], recon.pixels[y * w + x]);
                if near(x, y) {
                    assert_eq!(got, was, "({x},{y}) near the light");
                } else if (29..=31).contains(&x) {
                    assert!((got[0] - 0.1).abs() < 1e-5, "({x},{y}) {got:?}");
                }
            }
        }
    }

    /// A sample that is not finite leaves its pixel's reconstruction as it is, while its
    /// neighbours are leaned, and does not spread NaN or infinity to them.
    #[test]
    fn a_pixel_with_a_non_finite_sample_keeps_reconstruction() {
        let (w, h, spp) = (15, 11, 8);
        let frames = frames(w, h, spp, |x, y| {
            let mut v = vec![0.5; spp];
            if (x, y) == (10, 5) {
                v[3] = f32::NAN;
            }
            v
        });
        let means = PixelSampleMeans::of(&frames, &camera()).expect("8 spp");
        assert!(means.keep[5 * w + 10]);
        // A pixel with a sample that missed (alpha 0) is kept too.
        let mut missed = frames.clone();
        missed.samples[(2 * w + 2) * spp].color = [0.5, 0.5, 0.5, 0.0];
        let missed = PixelSampleMeans::of(&missed, &camera()).expect("8 spp");
        assert!(missed.keep[2 * w + 2] && !missed.keep[2 * w + 3]);
        let mut recon = image(w, h, |_, _| 0.8);
        means.lean(&mut recon);
        assert!(recon.pixels.iter().all(|p| p.iter().all(|c| c.is_finite())));
        assert_eq!(recon.pixels[5 * w + 10][0], 0.8, "kept");
        // Away from it the correction is whole.
        assert!(
            (recon.pixels[5 * w + 3][0] - 0.5).abs() < 1e-5,
            "{:?}",
            recon.pixels[5 * w + 3]
        );
        assert!(recon.pixels[5 * w + 9][0] < 0.8, "a neighbour is leaned");
    }
}
