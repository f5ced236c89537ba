//! The filter baseline on the GPU (`shaders/filter.wgsl`) against its CPU twin
//! (`spreadlet::baseline::filter`): the same kernels, the same per-pixel plan, the sums in the
//! same order, so the images agree to f32 rounding.
#![cfg(feature = "gpu")]

mod gpu_support;
mod support;

use gpu_support::{context, max_diff};
use psf_db::PsfModel;
use spreadlet::baseline::{filter, DenseKernels, FilterOptions};
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::gpu::{filter_gpu, GpuFilter};
use spreadlet::pipeline::RotationSampling;
use support::{camera, depth_for_coc, test_db};

/// Textured, with CoC from 0 to 10 px and motion up to 20 px in every direction (so kernels
/// are rotated, copied and clamped), and a transparent corner.
fn busy_gbuffer(w: usize, h: usize, cam: &spreadlet::camera::Camera) -> GBuffer {
    let mut color = Vec::with_capacity(w * h);
    let mut depth = Vec::with_capacity(w * h);
    let mut motion = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let t = ((x as f32 * 0.45).sin() * (y as f32 * 0.3).cos()) * 0.5 + 0.5;
            let a = if x < 6 && y < 6 { 0.0 } else { 1.0 };
            color.push([t * a, (1.0 - t) * a, 0.4 * a, a]);
            depth.push(depth_for_coc(cam, ((x * 3 + y * 5) % 11) as f64) as f32);
            let angle = (x as f32 * 0.21 + y as f32 * 0.37).rem_euclid(std::f32::consts::TAU);
            let len = ((x + 2 * y) % 21) as f32;
            motion.push([len * angle.cos(), len * angle.sin()]);
        }
    }
    GBuffer::from_planes(w, h, color, Some(depth), Some(motion)).expect("g-buffer")
}

#[test]
fn gpu_filter_matches_the_cpu_filter() {
    let Some(ctx) = context() else {
        return;
    };
    let (w, h) = (48usize, 40usize);
    let cam = camera(w as u32, h as u32, true, 1.0);
    let g = busy_gbuffer(w, h, &cam);
    let dbs = DbSet::single(test_db(PsfModel::LensMotion).clone()).expect("set");
    let kernels = DenseKernels::from_db(dbs.combined.as_ref().expect("db"));
    let gpu = GpuFilter::new(ctx, &kernels).expect("gpu filter");
    for rotation in [RotationSampling::Bilinear, RotationSampling::Nearest] {
        let options = FilterOptions {
            rotation,
            ..FilterOptions::default()
        };
        let (cpu, cpu_stats) = filter(&g, &cam, &dbs, &kernels, &options).expect("cpu");
        let (gpu_image, gpu_stats) = filter_gpu(&gpu, &g, &cam, &dbs, &options).expect("gpu");
        assert_eq!(cpu_stats.filtered, gpu_stats.filtered);
        assert_eq!(cpu_stats.copied, gpu_stats.copied);
        assert!(cpu_stats.filtered > w * h / 2, "{cpu_stats:?}");
        let flat = |i: &formats::image::RgbaImage| -> Vec<f32> {
            i.pixels.iter().flat_map(|p| p.iter().copied()).collect()
        };
        let (diff, peak) = max_diff(&flat(&gpu_image), &flat(&cpu));
        eprintln!("{rotation:?}: GPU vs CPU filter max difference {diff:e} (peak {peak})");
        assert!(
            diff <= 1e-5 * peak.max(1.0),
            "{rotation:?}: {diff} (peak {peak})"
        );
        // The rotated kernels matter: the two placements give different images.
        if rotation == RotationSampling::Nearest {
            let (bilinear, _) =
                filter(&g, &cam, &dbs, &kernels, &FilterOptions::default()).expect("cpu bilinear");
            let (d, _) = max_diff(&flat(&bilinear), &flat(&cpu));
            assert!(d > 1e-3, "nearest and bilinear agree to {d}");
        }
    }
}

/// A pixel whose kernel is empty keeps its colour on the GPU as on the CPU (`filter`'s rule);
/// one with a 1x1 kernel of weight 0.5 halves it.
#[test]
fn gpu_filter_keeps_the_colour_of_pixels_with_an_empty_kernel() {
    use spreadlet::baseline::{DenseKernel, PixelPsf};
    let Some(ctx) = context() else {
        return;
    };
    let kernel = |data: Vec<f32>, size: usize| DenseKernel {
        origin: [0, 0],
        width: size,
        height: size,
        channels: 1,
        data,
    };
    let kernels = DenseKernels {
        kernels: vec![kernel(vec![], 0), kernel(vec![0.5], 1)],
        integrated: 0,
    };
    let gpu = GpuFilter::new(ctx, &kernels).expect("gpu filter");
    let input = vec![[0.8, 0.6, 0.4, 1.0]; 4];
    let at = |psf: u32| {
        Some(PixelPsf {
            psf,
            rot_cos: 1.0,
            rot_sin: 0.0,
        })
    };
    let plan = vec![at(0), at(1), None, at(7)];
    let (image, _) = gpu
        .run(&input, 2, 2, &plan, RotationSampling::Bilinear)
        .expect("run");
    assert_eq!(image.pixels[0], input[0], "empty kernel");
    assert_eq!(image.pixels[1], [0.4, 0.3, 0.2, 0.5], "halving kernel");
    assert_eq!(image.pixels[2], input[2], "no kernel");
    assert_eq!(image.pixels[3], input[3], "kernel index beyond the table");
}
