//! Options are per call on the GPU as on the CPU: one GPU synthesizer, made with the default
//! options, run with other rotation sampling and compositing, gives what the CPU gives with
//! those options (and not what it gives with the defaults).
#![cfg(feature = "gpu")]

mod gpu_support;
mod support;

use gpu_support::{context, max_diff, synthesize_gpu};
use psf_db::PsfModel;
use spreadlet::dbset::DbSet;
use spreadlet::gpu::{GpuSynthOptions, GpuSynthesizer};
use spreadlet::pipeline::{CompositeOptions, RotationSampling, SplatOptions};
use spreadlet::synth::{synthesize, SynthOptions};

#[test]
fn rotation_and_compositing_apply_per_call() {
    let Some(ctx) = context() else { return };
    let scene = scene::builtin("crossing")
        .and_then(|s| s.with_size(64, 64))
        .expect("scene");
    let options = scene::RenderOptions {
        seed: 5,
        ..Default::default()
    };
    let gbuffer = support::gbuffer_of(&scene::render_gbuffer(&scene, 2, &options).expect("render"));
    let camera = spreadlet::Camera::from_json_str(&scene.camera_json()).expect("camera");
    let dbs = DbSet::new(
        Some(support::test_db(PsfModel::ThinLens).clone()),
        Some(support::test_db(PsfModel::LensMotion).clone()),
    )
    .expect("databases");
    // Moving pixels drawn with the lens-motion database's PSFs: turned by the record, so that
    // rotation sampling matters, and indexing the set's database, which the one synthesizer
    // holds (a frame with PSFs of its own needs a synthesizer for them, as `Renderer` makes).
    let mut defaults = SynthOptions::default();
    defaults.classify.smear_motion = false;
    let mut gpu = GpuSynthesizer::for_database(
        ctx,
        dbs.combined.as_ref(),
        GpuSynthOptions::from_synth(&defaults),
    )
    .expect("GPU synthesizer");
    let other = SynthOptions {
        splat: SplatOptions {
            rotation: RotationSampling::Nearest,
        },
        composite: CompositeOptions {
            renormalize_coverage: false,
            restore_occluded: false,
        },
        ..defaults.clone()
    };
    let flat =
        |i: &spreadlet::RgbaImage| -> Vec<f32> { i.pixels.iter().flatten().copied().collect() };
    let (cpu_other, _) = synthesize(&gbuffer, &camera, &dbs, &other).expect("CPU, other");
    let (cpu_default, _) = synthesize(&gbuffer, &camera, &dbs, &defaults).expect("CPU, defaults");
    let (gpu_first, _, _) =
        synthesize_gpu(&mut gpu, &gbuffer, &camera, &dbs, &defaults).expect("GPU, defaults");
    let (d, m) = max_diff(&flat(&gpu_first), &flat(&cpu_default));
    assert!(
        d <= 1e-4 * m.max(1.0),
        "GPU with defaults vs CPU: {d} (max {m})"
    );
    let (gpu_other, _, _) =
        synthesize_gpu(&mut gpu, &gbuffer, &camera, &dbs, &other).expect("GPU, other");
    let (d, m) = max_diff(&flat(&gpu_other), &flat(&cpu_other));
    assert!(
        d <= 1e-4 * m.max(1.0),
        "GPU with other options vs CPU: {d} (max {m})"
    );
    let (apart, _) = max_diff(&flat(&cpu_default), &flat(&cpu_other));
    assert!(
        apart > 10.0 * d.max(1e-6),
        "the options make no visible difference ({apart}), so the test proves nothing"
    );
    // And back to the defaults, on the same synthesizer.
    let (gpu_default, _, _) =
        synthesize_gpu(&mut gpu, &gbuffer, &camera, &dbs, &defaults).expect("GPU, defaults");
    let (d, m) = max_diff(&flat(&gpu_default), &flat(&cpu_default));
    assert!(
        d <= 1e-4 * m.max(1.0),
        "GPU with defaults vs CPU: {d} (max {m})"
    );
}

/// Bad input fails while the frame is prepared, before any device draws it: the same typed
/// error on the GPU as on the CPU (a G-buffer whose size is not the camera's).
#[test]
fn a_bad_input_is_the_same_typed_error_on_both_devices() {
    use spreadlet::pipeline::classify::ClassifyError;
    use spreadlet::{Backend, Error, Renderer, RendererOptions};
    if context().is_none() {
        return;
    }
    let camera = support::camera(32, 32, false, 0.0);
    let gbuffer = spreadlet::GBuffer::from_planes(
        16,
        16,
        vec![[0.5, 0.5, 0.5, 1.0]; 16 * 16],
        Some(vec![2.0; 16 * 16]),
        None,
    )
    .expect("G-buffer");
    for backend in [Backend::Cpu, Backend::Gpu] {
        let mut renderer = Renderer::new(RendererOptions {
            backend,
            ..Default::default()
        })
        .expect("renderer");
        let err = renderer
            .synthesize(&gbuffer, &camera, &SynthOptions::default())
            .expect_err("a 16x16 G-buffer for a 32x32 camera");
        assert!(
            matches!(err, Error::Classify(ClassifyError::SizeMismatch { .. })),
            "{backend:?}: {err:?}"
        );
    }
}

/// A renderer on the GPU keeps a layer's few sparse records sparse (it integrates a layer in a
/// fraction of the CPU's time, and PSF images of the frame's own would be uploaded with each
/// frame): it draws what the CPU draws with them kept sparse. The CPU draws them from their
/// PSFs' images, which keep their light.
#[test]
fn a_layers_few_sparse_records_stay_sparse_on_the_gpu() {
    use spreadlet::{Backend, Renderer, RendererOptions};
    if context().is_none() {
        return;
    }
    // At 512 px the thin lens's CoC in front of the focus grows fast: a few points at 20 px,
    // whose PSFs the default database stores sparse, alone in their depth layer.
    let (w, h) = (512usize, 64usize);
    let camera = support::camera(w as u32, h as u32, true, 0.0);
    let mut color = vec![[0.0f32; 4]; w * h];
    let mut depth = vec![1.0f32; w * h];
    for (k, x) in [80usize, 250, 420].into_iter().enumerate() {
        color[32 * w + x] = [0.8, 0.4 + 0.1 * k as f32, 0.3, 1.0];
        depth[32 * w + x] = support::depth_for_coc(&camera, 20.0) as f32;
    }
    let gbuffer = spreadlet::GBuffer::from_planes(w, h, color, Some(depth), None).expect("g");
    let render = |backend: Backend, few_sparse_images: bool| {
        let mut options = SynthOptions::default();
        options.classify.few_sparse_images = few_sparse_images;
        Renderer::new(RendererOptions {
            backend,
            ..Default::default()
        })
        .expect("renderer")
        .synthesize(&gbuffer, &camera, &options)
        .expect("synthesis")
    };
    let gpu = render(Backend::Gpu, true);
    let cpu = render(Backend::Cpu, true);
    let cpu_kept = render(Backend::Cpu, false);
    assert!(
        cpu.stats.counts.sparse_as_images > 0,
        "the CPU draws the few sparse records from images: {:?}",
        cpu.stats.counts
    );
    assert_eq!(
        gpu.stats.counts.sparse_as_images, 0,
        "{:?}",
        gpu.stats.counts
    );
    assert_eq!(gpu.stats.counts.sparse, cpu_kept.stats.counts.sparse);
    let (diff, level) = max_diff(&flat(&gpu.image), &flat(&cpu_kept.image));
    assert!(diff <= 0.01 * level, "largest difference {diff} of {level}");
    let light = |frame: &spreadlet::Frame| -> f64 {
        frame
            .image
            .pixels
            .iter()
            .map(|p| f64::from(p[0] + p[1] + p[2]))
            .sum()
    };
    let ratio = light(&cpu) / light(&gpu);
    assert!(
        (ratio - 1.0).abs() < 0.01,
        "light drawn from images {ratio:.4} of the GPU's"
    );
}

fn flat(image: &spreadlet::RgbaImage) -> Vec<f32> {
    image.pixels.iter().flatten().copied().collect()
}
