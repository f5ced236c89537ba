//! Beyond the paper: once the positions are fixed, re-fit the values by least squares,
//! `min_v || A v - f ||_2`, where `A` integrates spreadlets ([`Operator`]) and `f` is the PSF.
//! Solved per channel by CGLS (conjugate gradients on the normal equations), warm-started
//! from the collapsed values, with two FFTs per operator application.
//!
//! With `zero_sum`, every step is projected onto values that keep each channel's sum (zero for
//! a collapsed Laplacian: the light of a compact PSF): the spreadlets then stay the Laplacian
//! of a compact image, which the optimiser's torus and the exact integrator reconstruct alike
//! (a non-zero sum leaves a far-reaching logarithmic tail that depends on the padding).

use super::collapse::Spreadlets;
use super::green::{Operator, Torus};
use super::target::Target;

/// Re-fits the values of `s` with `iterations` CGLS steps per channel; `zero_sum` keeps each
/// channel's sum of values.
pub fn refit(
    t: &Target,
    torus: &Torus,
    s: &Spreadlets,
    iterations: u32,
    zero_sum: bool,
) -> Spreadlets {
    let ch = s.channels;
    let n = s.len();
    if n == 0 {
        return s.clone();
    }
    let op = Operator::new(torus.clone(), &s.positions);
    let mut out = s.clone();
    for c in 0..ch {
        let mut v: Vec<f64> = (0..n).map(|j| s.values[j * ch + c]).collect();
        let av = op.apply(&v);
        let mut r: Vec<f64> = t.psf[c]
            .iter()
            .zip(&av)
            .map(|(&f, &a)| f64::from(f) - a)
            .collect();
        let project = |g: &mut Vec<f64>| {
            if zero_sum {
                let mean = g.iter().sum::<f64>() / g.len() as f64;
                g.iter_mut().for_each(|x| *x -= mean);
            }
        };
        let mut g = op.adjoint(&r);
        project(&mut g);
        let mut p = g.clone();
        let mut gamma: f64 = g.iter().map(|x| x * x).sum();
        let gamma0 = gamma;
        for _ in 0..iterations {
            if gamma.is_nan() || gamma <= 1e-24 * gamma0.max(1e-300) {
                break;
            }
            let q = op.apply(&p);
            let qq: f64 = q.iter().map(|x| x * x).sum();
            if qq.is_nan() || qq <= 0.0 {
                break;
            }
            let alpha = gamma / qq;
            for (vi, pi) in v.iter_mut().zip(&p) {
                *vi += alpha * pi;
            }
            for (ri, qi) in r.iter_mut().zip(&q) {
                *ri -= alpha * qi;
            }
            g = op.adjoint(&r);
            project(&mut g);
            let gamma_new: f64 = g.iter().map(|x| x * x).sum();
            let beta = gamma_new / gamma;
            for (pi, gi) in p.iter_mut().zip(&g) {
                *pi = gi + beta * *pi;
            }
            gamma = gamma_new;
        }
        for (j, vj) in v.iter().enumerate() {
            out.values[j * ch + c] = *vj;
        }
    }
    out
}
