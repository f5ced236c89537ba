//! Rough timings (ignored by default; the numbers belong in docs/BENCHMARKS.md, not in asserts).
//! `cargo test -p poisson --release --test timing -- --ignored --nocapture`

use std::time::Instant;

use poisson::{ExactIntegrator, Plane, PyramidWorkspace};

fn median_ms(mut f: impl FnMut(), runs: usize) -> f64 {
    f();
    let mut t: Vec<f64> = (0..runs)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(|a, b| a.total_cmp(b));
    t[runs / 2]
}

#[test]
#[ignore]
fn timings() {
    for &(w, h) in &[(1024, 1024), (1920, 1080)] {
        let lap = Plane::from_fn(w, h, |x, y| ((x ^ y) % 7) as f32 - 3.0);
        let mut ws = PyramidWorkspace::new(w, h);
        let mut out = Plane::default();
        let p = median_ms(|| ws.integrate_into(&lap, &mut out), 9);
        let ex = ExactIntegrator::new(w, h);
        let e = median_ms(|| drop(ex.integrate(&lap)), 5);
        let e2 = median_ms(|| drop(ex.integrate_pair(&lap, &lap)), 5);
        println!(
            "{w}x{h}: pyramid {p:.1} ms, exact {e:.1} ms, exact pair {e2:.1} ms (threads {})",
            rayon::current_num_threads()
        );
    }
}

#[test]
#[ignore]
fn pyramid_step_timings() {
    use poisson::pyramid::{analysis_step, level_sizes, pad_input, synthesis_step, top_step};
    let (w, h) = (1920, 1080);
    let lap = Plane::from_fn(w, h, |x, y| ((x ^ y) % 7) as f32 - 3.0);
    let sizes = level_sizes(w, h);
    let mut a: Vec<Plane> = sizes.iter().map(|&(w, h)| Plane::new(w, h)).collect();
    let mut f = a.clone();
    let mut scratch = Vec::new();
    let l = sizes.len();
    let pad = median_ms(|| pad_input(&lap, &mut a[0]), 9);
    let mut an = 0.0;
    for i in 1..l {
        let (lo, hi) = a.split_at_mut(i);
        an += median_ms(|| analysis_step(&lo[i - 1], &mut hi[0], &mut scratch), 9);
    }
    let top = median_ms(|| top_step(&a[l - 1], &mut f[l - 1], &mut scratch), 9);
    let mut syn0 = 0.0;
    let mut syn = 0.0;
    for i in (0..l - 1).rev() {
        let (lo, hi) = f.split_at_mut(i + 1);
        let t = median_ms(
            || synthesis_step(&hi[0], &a[i], &mut lo[i], &mut scratch),
            9,
        );
        if i == 0 {
            syn0 = t;
        }
        syn += t;
    }
    println!("{w}x{h}: pad {pad:.2} ms, analysis {an:.2} ms, top {top:.3} ms, synthesis {syn:.2} ms (level 0: {syn0:.2} ms)");
}
