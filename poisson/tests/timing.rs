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
