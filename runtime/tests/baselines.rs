//! The study's baselines against what they must be: the dense splat of one bright
//! pixel is its stored pre-filtered PSF; dense and spreadlet agree on a smooth input; filtering
//! equals splatting where the PSF is the same everywhere and differs at an occlusion boundary.

mod support;

use std::sync::OnceLock;

use formats::image::RgbaImage;
use precompute::{build_database, BuildConfig, Profile};
use psf_db::{PsfDatabase, PsfModel};
use spreadlet::baseline::{
    dense_build_config, filter, integrate_spreadlets, sparse_psf_count, DenseKernels, FilterOptions,
};
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::GBuffer;
use spreadlet::pipeline::{ClassifyOptions, FrameEdges, Integrator};
use spreadlet::synth::{synthesize, SynthOptions};
use support::{camera, depth_for_coc, one_pixel, test_db};

/// The Test-profile thin-lens database with every PSF stored dense, conditioned.
fn dense_test_db() -> &'static PsfDatabase {
    static DB: OnceLock<PsfDatabase> = OnceLock::new();
    DB.get_or_init(|| {
        let cfg = dense_build_config(&BuildConfig::new(PsfModel::ThinLens, Profile::Test));
        let (db, _) = build_database(&cfg, false).expect("dense test database");
        spreadlet::condition::condition(&db).expect("condition").0
    })
}

fn set(db: &PsfDatabase) -> DbSet {
    DbSet::single(db.clone()).expect("set")
}

fn lens_camera(n: u32) -> Camera {
    Camera {
        f_stop: Some(1.0),
        ..camera(n, n, true, 0.0)
    }
}

fn flat(i: &RgbaImage) -> Vec<f32> {
    i.pixels.iter().flatten().copied().collect()
}

fn single_layer() -> SynthOptions {
    SynthOptions {
        classify: ClassifyOptions {
            layers: 1,
            soft_layers: None,
            edge_split: false,
            // The filter gathers nothing from beyond the frame; compare like with like.
            frame_edges: FrameEdges::Black,
            fill_hidden: false,
            // The filter takes each pixel's one cell.
            continuous_lookup: false,
            ..ClassifyOptions::default()
        },
        integrator: Integrator::Exact,
        ..SynthOptions::default()
    }
}

#[test]
fn dense_database_stores_every_psf_dense() {
    let db = dense_test_db();
    assert_eq!(sparse_psf_count(db), 0);
    assert!(sparse_psf_count(test_db(PsfModel::ThinLens)) > 0);
    assert!(
        db.header().prefilter,
        "the dense PSFs are the pre-filtered ones"
    );
}

#[test]
fn dense_splat_of_one_bright_pixel_is_its_stored_psf() {
    let n = 48usize;
    let cam = lens_camera(n as u32);
    let depth = depth_for_coc(&cam, 7.0) as f32;
    let g = one_pixel(n, n, 24, 24, [2.0, 1.0, 0.5, 1.0], depth, [0.0, 0.0]);
    let db = dense_test_db();
    let dbs = set(db);
    let mut options = SynthOptions::default();
    // The one PSF of the cell holding the pixel's CoC.
    options.classify.continuous_lookup = false;
    let (image, stats) = synthesize(&g, &cam, &dbs, &options).expect("synth");
    assert_eq!(stats.counts.dense, 1, "{:?}", stats.counts);
    let coc = cam.thin_lens().expect("lens").coc_px(f64::from(depth)) as f32;
    let (idx, _) = db.lookup([coc, 0.0]);
    let psf = db.dense(idx as usize).expect("stored dense");
    assert!(psf.width > 5, "a real blur: {}x{}", psf.width, psf.height);
    let mut expected = vec![0.0f32; n * n];
    for v in 0..psf.height {
        for u in 0..psf.width {
            let x = 24 + psf.origin[0] + u as i32;
            let y = 24 + psf.origin[1] + v as i32;
            expected[y as usize * n + x as usize] = psf.get(u, v, 0);
        }
    }
    let mut max_err = 0.0f32;
    for (i, px) in image.pixels.iter().enumerate() {
        for (c, scale) in [2.0f32, 1.0, 0.5, 1.0].iter().enumerate() {
            max_err = max_err.max((px[c] - scale * expected[i]).abs());
        }
    }
    assert!(max_err < 1e-6, "max error {max_err}");
    let sum: f32 = expected.iter().sum();
    assert!((sum - 1.0).abs() < 1e-4, "unit energy: {sum}");
}

/// A smooth, opaque `n x n` input at uniform depth: a colour gradient.
fn smooth_input(n: usize, depth: f32) -> GBuffer {
    let color = (0..n * n)
        .map(|i| {
            let (x, y) = ((i % n) as f32 / n as f32, (i / n) as f32 / n as f32);
            [0.2 + 0.6 * x, 0.3 + 0.4 * y, 0.8 - 0.5 * x * y, 1.0]
        })
        .collect();
    GBuffer::from_planes(n, n, color, Some(vec![depth; n * n]), None).expect("g")
}

#[test]
fn dense_and_spreadlet_agree_on_a_smooth_input() {
    let n = 64;
    let cam = lens_camera(n as u32);
    let g = smooth_input(n, depth_for_coc(&cam, 8.0) as f32);
    let (dense, _) = synthesize(&g, &cam, &set(dense_test_db()), &single_layer()).expect("dense");
    let (sparse, st) = synthesize(&g, &cam, &set(test_db(PsfModel::ThinLens)), &single_layer())
        .expect("spreadlet");
    assert!(st.counts.sparse > 0, "{:?}", st.counts);
    // Away from the border (where the images fade out alike).
    let mut worst = 0.0f32;
    for y in 12..n - 12 {
        for x in 12..n - 12 {
            let (a, b) = (dense.at(x, y), sparse.at(x, y));
            for c in 0..3 {
                worst = worst.max((a[c] - b[c]).abs() / a[c].max(1e-3));
            }
        }
    }
    let ssim = metrics::ssim_rgb(&flat(&dense), &flat(&sparse), n, n).expect("ssim");
    eprintln!("dense vs spreadlet: largest relative difference {worst}, SSIM {ssim}");
    assert!(worst < 0.05, "largest relative difference {worst}");
    assert!(ssim > 0.98, "SSIM {ssim}");
}

/// A checkered, opaque `n x n` input at uniform depth.
fn checker_input(n: usize, depth: f32) -> GBuffer {
    let color = (0..n * n)
        .map(|i| {
            let (x, y) = (i % n, i / n);
            let a = if (x / 5 + y / 7) % 2 == 0 { 0.9 } else { 0.1 };
            [a, 0.5 * a + 0.2, 1.0 - a, 1.0]
        })
        .collect();
    GBuffer::from_planes(n, n, color, Some(vec![depth; n * n]), None).expect("g")
}

#[test]
fn filter_equals_splat_where_the_psf_is_the_same_everywhere() {
    let n = 56;
    let cam = lens_camera(n as u32);
    let g = checker_input(n, depth_for_coc(&cam, 6.0) as f32);
    let db = dense_test_db();
    let dbs = set(db);
    let (splatted, _) = synthesize(&g, &cam, &dbs, &single_layer()).expect("splat");
    let kernels = DenseKernels::from_db(db);
    assert_eq!(kernels.integrated, 0);
    let (filtered, stats) =
        filter(&g, &cam, &dbs, &kernels, &FilterOptions::default()).expect("filter");
    assert_eq!(stats.filtered, n * n);
    let max = flat(&splatted)
        .iter()
        .zip(flat(&filtered))
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    eprintln!("filter vs splat, uniform depth: max difference {max}");
    assert!(max < 1e-5, "max difference {max}");
}

#[test]
fn filter_differs_from_splat_at_an_occlusion_boundary() {
    // A bright square near the lens, strongly defocused, over an in-focus dark checker.
    let n = 64;
    let cam = lens_camera(n as u32);
    let near = depth_for_coc(&cam, 8.0) as f32;
    let mut color = Vec::with_capacity(n * n);
    let mut depth = Vec::with_capacity(n * n);
    let inside = |x: usize, y: usize| (24..40).contains(&x) && (24..40).contains(&y);
    for y in 0..n {
        for x in 0..n {
            if inside(x, y) {
                color.push([1.0, 0.9, 0.8, 1.0]);
                depth.push(near);
            } else {
                let a = if (x / 3 + y / 3) % 2 == 0 { 0.2 } else { 0.05 };
                color.push([a, a, a, 1.0]);
                depth.push(1.0);
            }
        }
    }
    let g = GBuffer::from_planes(n, n, color.clone(), Some(depth), None).expect("g");
    let db = dense_test_db();
    let dbs = set(db);
    let options = SynthOptions {
        classify: ClassifyOptions {
            layers: 4,
            ..ClassifyOptions::default()
        },
        ..SynthOptions::default()
    };
    let (splatted, _) = synthesize(&g, &cam, &dbs, &options).expect("splat");
    let (filtered, _) = filter(
        &g,
        &cam,
        &dbs,
        &DenseKernels::from_db(db),
        &FilterOptions::default(),
    )
    .expect("filter");
    // The ring of background pixels within 4 px outside the square.
    let mut diff = 0.0f64;
    let mut count = 0usize;
    for y in 20..44 {
        for x in 20..44 {
            if inside(x, y) {
                continue;
            }
            // In focus: the filter keeps the background as it is ...
            let f = filtered.at(x, y);
            assert!(
                (f[0] - color[y * n + x][0]).abs() < 1e-6,
                "filter at ({x},{y})"
            );
            // ... while the splat spreads the blurred square over it.
            diff += f64::from(splatted.at(x, y)[0] - f[0]);
            count += 1;
        }
    }
    let mean = diff / count as f64;
    eprintln!("splat minus filter over the ring: {mean}");
    assert!(
        mean > 0.1,
        "mean brightening of the ring by the splat: {mean}"
    );
}

#[test]
fn spreadlets_of_one_pixel_integrate_to_that_pixel() {
    let positions = [[0i16, 0], [1, 0], [-1, 0], [0, 1], [0, -1]];
    let values = [-4.0f32, 1.0, 1.0, 1.0, 1.0];
    let k = integrate_spreadlets(&positions, &values, 1);
    assert_eq!((k.width, k.height, k.origin), (1, 1, [0, 0]), "{k:?}");
    assert!((k.data[0] - 1.0).abs() < 1e-5, "{}", k.data[0]);
}
