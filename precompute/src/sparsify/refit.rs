//! Beyond the paper: once the positions are fixed, re-fit the values by least squares,
//! `min_v || A v - f ||_2`, where `A` integrates spreadlets ([`Operator`]) and `f` is the PSF.
//! Solved per channel by CGLS (conjugate gradients on the normal equations), warm-started
//! from the collapsed values, with two FFTs per operator application.
//!
//! With `zero_sum` (the `constrained` fit), every step is projected onto values that keep each
//! channel's sum (zero for a collapsed Laplacian) and its second moment `sum_j v_j |x_j|^2`,
//! first set to the PSF Laplacian's, which is 4 times the PSF's light (the 5-point Laplacian of
//! `|x|^2` is 4): the spreadlets stay the Laplacian of a compact image, which the optimiser's
//! torus and the exact integrator reconstruct alike (a non-zero sum leaves a far-reaching
//! logarithmic tail), and they carry exactly the PSF's light (energy is conserved).

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
    // Second moments about the image centre: of each spreadlet position, and of the PSF's
    // Laplacian (for a zero-sum Laplacian, sum_x L(x) |x|^2 = 4 * the PSF's light, whatever
    // the centre).
    let (cx, cy) = (0.5 * t.width as f64, 0.5 * t.height as f64);
    let q: Vec<f64> = s
        .positions
        .iter()
        .map(|p| (f64::from(p[0]) - cx).powi(2) + (f64::from(p[1]) - cy).powi(2))
        .collect();
    // An orthonormal basis of the constraint directions: the constant and the centred moment.
    let u1 = 1.0 / (n as f64).sqrt();
    let q_mean = q.iter().sum::<f64>() / n as f64;
    let qc: Vec<f64> = q.iter().map(|x| x - q_mean).collect();
    let qn = qc.iter().map(|x| x * x).sum::<f64>().sqrt();
    let u2: Option<Vec<f64>> = (qn > 1e-9).then(|| qc.iter().map(|x| x / qn).collect());
    for c in 0..ch {
        let mut v: Vec<f64> = (0..n).map(|j| s.values[j * ch + c]).collect();
        if zero_sum {
            if let Some(u2) = &u2 {
                // Start on the constraint set: the PSF's light (second moment) exactly.
                let target: f64 = (0..t.width * t.height)
                    .map(|i| {
                        let (x, y) = ((i % t.width) as f64 - cx, (i / t.width) as f64 - cy);
                        f64::from(t.lap[c][i]) * (x * x + y * y)
                    })
                    .sum();
                let have: f64 = v.iter().zip(&q).map(|(a, b)| a * b).sum();
                // v += alpha u2 keeps the sum (u2 is centred) and moves the moment by alpha qn.
                let alpha = (target - have) / qn;
                for (vj, uj) in v.iter_mut().zip(u2) {
                    *vj += alpha * uj;
                }
            }
        }
        let av = op.apply(&v);
        let mut r: Vec<f64> = t.psf[c]
            .iter()
            .zip(&av)
            .map(|(&f, &a)| f64::from(f) - a)
            .collect();
        let project = |g: &mut Vec<f64>| {
            if zero_sum {
                let a = g.iter().sum::<f64>() * u1;
                g.iter_mut().for_each(|x| *x -= a * u1);
                if let Some(u2) = &u2 {
                    let b: f64 = g.iter().zip(u2).map(|(x, u)| x * u).sum();
                    g.iter_mut().zip(u2).for_each(|(x, u)| *x -= b * u);
                }
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
