//! The GPU convolution pyramid matches `poisson::pyramid` level by level.
#![cfg(feature = "gpu")]

mod gpu_support;

use gpu_support::{context, max_diff, noise_plane};
use poisson::{Plane, PyramidWorkspace};
use spreadlet::gpu::GpuPyramid;

/// Relative tolerance (of the level's largest value): the GPU sums in the CPU's order, but may
/// fuse multiply-adds.
const REL_TOL: f32 = 2e-6;

fn check_size(pyr: &mut GpuPyramid, w: usize, h: usize, n: usize) {
    let laps: Vec<Plane> = (0..n).map(|i| noise_plane(w, h, 17 + i as u64)).collect();
    let gpu = pyr.integrate(&laps).expect("GPU pyramid");
    let levels = pyr.levels().expect("levels");
    for (p, lap) in laps.iter().enumerate() {
        let mut ws = PyramidWorkspace::new(w, h);
        let cpu = ws.integrate(lap);
        assert_eq!((gpu[p].width, gpu[p].height), (w, h));
        let (d, m) = max_diff(&gpu[p].data, &cpu.data);
        assert!(
            d <= REL_TOL * m.max(1.0),
            "{w}x{h} plane {p}: output differs by {d} (max {m})"
        );
        assert_eq!(levels.analysis.len(), ws.levels());
        for (i, cpu_level) in ws.analysis_levels().iter().enumerate() {
            let g = &levels.analysis[i][p];
            assert_eq!(
                (g.width, g.height),
                (cpu_level.width, cpu_level.height),
                "a_{i} size"
            );
            let (d, m) = max_diff(&g.data, &cpu_level.data);
            assert!(
                d <= REL_TOL * m.max(1e-3),
                "{w}x{h} a_{i} plane {p}: {d} (max {m})"
            );
        }
        for (i, cpu_level) in ws.synthesis_levels().iter().enumerate() {
            let g = &levels.synthesis[i][p];
            let (d, m) = max_diff(&g.data, &cpu_level.data);
            assert!(
                d <= REL_TOL * m.max(1e-3),
                "{w}x{h} f_{i} plane {p}: {d} (max {m})"
            );
        }
    }
}

#[test]
fn pyramid_levels_match_cpu() {
    let Some(ctx) = context() else { return };
    let mut pyr = GpuPyramid::new(ctx).expect("pipelines");
    for (w, h, n) in [(37, 23, 3), (64, 64, 2), (1, 1, 1), (1, 9, 2), (130, 5, 1)] {
        check_size(&mut pyr, w, h, n);
    }
    // The same size twice reuses the buffers and still gives the right answer.
    check_size(&mut pyr, 37, 23, 3);
}

#[test]
fn pyramid_integrates_an_impulse_like_the_cpu() {
    let Some(ctx) = context() else { return };
    let mut pyr = GpuPyramid::new(ctx).expect("pipelines");
    let mut lap = Plane::new(48, 40);
    lap.set(20, 17, 1.0);
    let gpu = pyr
        .integrate(std::slice::from_ref(&lap))
        .expect("GPU pyramid");
    let cpu = poisson::integrate_pyramid(&lap);
    let (d, m) = max_diff(&gpu[0].data, &cpu.data);
    assert!(m > 0.0 && d <= REL_TOL * m, "impulse: {d} (max {m})");
}

/// Timing probe (run on demand): the GPU pyramid alone against the CPU's, 32 planes.
#[test]
#[ignore]
fn pyramid_timing_probe() {
    let Some(ctx) = context() else { return };
    let mut pyr = GpuPyramid::new(ctx).expect("pipelines");
    let n: usize = std::env::var("PROBE_SIZE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(310);
    let laps: Vec<Plane> = (0..32).map(|i| noise_plane(n, n, i)).collect();
    pyr.integrate(&laps).expect("warm-up");
    for _ in 0..3 {
        let t = std::time::Instant::now();
        pyr.integrate(&laps).expect("gpu");
        let g = t.elapsed().as_secs_f64() * 1e3;
        let t = std::time::Instant::now();
        let mut ws = PyramidWorkspace::new(n, n);
        for l in &laps {
            std::hint::black_box(ws.integrate(l));
        }
        let c = t.elapsed().as_secs_f64() * 1e3;
        eprintln!("{n}x{n} x 32 planes: GPU {g:.1} ms (with upload and readback), CPU {c:.1} ms");
    }
}
