//! A tiny exact stochastic renderer for tests: fronto-parallel textured planes (nearest first),
//! each with a coverage mask and a screen motion, seen through a thin lens over a shutter.
#![allow(dead_code)]

use peers::{LensModel, Sample, SampleView};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Coverage of a plane, in its own pinhole coordinates at time 0 (pixels).
#[derive(Clone, Copy, Debug)]
pub enum Mask {
    All,
    Rect { x0: f32, y0: f32, x1: f32, y1: f32 },
    Disc { cx: f32, cy: f32, r: f32 },
}

impl Mask {
    fn covers(&self, p: [f32; 2]) -> bool {
        match *self {
            Mask::All => true,
            Mask::Rect { x0, y0, x1, y1 } => p[0] >= x0 && p[0] < x1 && p[1] >= y0 && p[1] < y1,
            Mask::Disc { cx, cy, r } => (p[0] - cx).powi(2) + (p[1] - cy).powi(2) < r * r,
        }
    }
}

#[derive(Clone, Copy, Debug)]
pub struct Plane {
    pub depth: f32,
    /// Screen motion, px per frame.
    pub motion: [f32; 2],
    pub mask: Mask,
    /// Texture: base colour and amplitude/period of a sinusoid along x and y.
    pub base: [f32; 3],
    pub amp: f32,
    pub period: f32,
}

impl Plane {
    pub fn color(&self, p: [f32; 2]) -> [f32; 4] {
        let k = 2.0 * std::f32::consts::PI / self.period;
        let s = self.amp * (k * p[0]).sin() * (0.7 * k * p[1]).cos();
        [self.base[0] + s, self.base[1] + s, self.base[2] - s, 1.0]
    }
}

#[derive(Clone, Debug)]
pub struct Scene {
    pub width: usize,
    pub height: usize,
    /// Nearest first.
    pub planes: Vec<Plane>,
    pub lens: LensModel,
    pub shutter_frames: f32,
}

impl Scene {
    /// Traces one ray from image position `pos` (pixels), lens `u` (unit disk) at time `t`.
    pub fn trace(&self, pos: [f32; 2], u: [f32; 2], t: f32) -> ([f32; 4], f32, [f32; 2], f32) {
        for pl in &self.planes {
            let c = self.lens.coc(pl.depth);
            // The scene crate's convention: the ray lands at pinhole + c * lens.
            let p0 = [
                pos[0] - c * u[0] - pl.motion[0] * t,
                pos[1] - c * u[1] - pl.motion[1] * t,
            ];
            if pl.mask.covers(p0) {
                return (pl.color(p0), pl.depth, pl.motion, c);
            }
        }
        ([0.0; 4], 1e10, [0.0; 2], self.lens.coc(1e10))
    }

    /// `spp` random samples per pixel, pixel-major.
    pub fn render(&self, spp: usize, seed: u64) -> Vec<Sample> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut out = Vec::with_capacity(self.width * self.height * spp);
        for y in 0..self.height {
            for x in 0..self.width {
                for _ in 0..spp {
                    let jitter = [rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5];
                    let r = rng.random::<f32>().sqrt();
                    let a = rng.random::<f32>() * std::f32::consts::TAU;
                    let lens = [r * a.cos(), r * a.sin()];
                    let time = (rng.random::<f32>() - 0.5) * self.shutter_frames;
                    let pos = [x as f32 + 0.5 + jitter[0], y as f32 + 0.5 + jitter[1]];
                    let (color, depth, motion, coc) = self.trace(pos, lens, time);
                    out.push(Sample {
                        jitter,
                        color,
                        depth,
                        lens,
                        time,
                        motion,
                        coc,
                    });
                }
            }
        }
        out
    }

    pub fn view<'a>(&self, spp: usize, samples: &'a [Sample]) -> SampleView<'a> {
        SampleView {
            width: self.width,
            height: self.height,
            spp,
            shutter_frames: self.shutter_frames,
            samples,
        }
    }

    /// Box-filtered (1x1) average of `samples`.
    pub fn box_filter(&self, spp: usize, samples: &[Sample]) -> Vec<[f32; 4]> {
        samples
            .chunks(spp)
            .map(|c| {
                let mut s = [0.0f32; 4];
                for smp in c {
                    for (acc, c) in s.iter_mut().zip(smp.color) {
                        *acc += c / spp as f32;
                    }
                }
                s
            })
            .collect()
    }
}

pub fn rmse(a: &[[f32; 4]], b: &[[f32; 4]]) -> f32 {
    let mut s = 0.0f64;
    for (x, y) in a.iter().zip(b) {
        for ch in 0..3 {
            s += ((x[ch] - y[ch]) as f64).powi(2);
        }
    }
    (s / (3 * a.len()) as f64).sqrt() as f32
}

pub fn max_abs_diff(a: &[[f32; 4]], b: &[[f32; 4]]) -> f32 {
    a.iter()
        .zip(b)
        .flat_map(|(x, y)| (0..4).map(move |c| (x[c] - y[c]).abs()))
        .fold(0.0, f32::max)
}

/// Defocus-only test scene: a blurred bar in front, a sharp textured plane at the focus, a
/// blurred far plane behind (64 x 64).
pub fn defocus_scene() -> Scene {
    let lens = LensModel {
        coc_scale: 40.0,
        focus_depth: 4.0,
    };
    Scene {
        width: 64,
        height: 64,
        planes: vec![
            Plane {
                depth: 2.0,
                motion: [0.0; 2],
                mask: Mask::Rect {
                    x0: 20.0,
                    y0: 0.0,
                    x1: 28.0,
                    y1: 64.0,
                },
                base: [0.8, 0.2, 0.1],
                amp: 0.1,
                period: 16.0,
            },
            Plane {
                depth: 4.0,
                motion: [0.0; 2],
                mask: Mask::Disc {
                    cx: 40.0,
                    cy: 32.0,
                    r: 14.0,
                },
                base: [0.3, 0.6, 0.3],
                amp: 0.25,
                period: 6.0,
            },
            Plane {
                depth: 20.0,
                motion: [0.0; 2],
                mask: Mask::All,
                base: [0.3, 0.3, 0.7],
                amp: 0.2,
                period: 20.0,
            },
        ],
        lens,
        shutter_frames: 0.0,
    }
}
