//! The GPU pipeline matches the CPU path (`spreadlet::pipeline`) stage by stage on synthetic
//! record lists: single pixels, every PSF model, image borders, many overlapping splats,
//! rotations, both splat stages (tiled, global atomics), both atomic paths and both
//! integrators; the tiled stage's fixed point against a near worst case of its bound.
#![cfg(feature = "gpu")]

mod gpu_support;

use std::sync::OnceLock;

use formats::image::RgbaImage;
use gpu_support::{context, max_diff};
use poisson::Plane;
use psf_db::{DatabaseBuilder, DbHeader, ParamSpace, PsfDatabase, PsfModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use spreadlet::gpu::tiles::{self, BinSetup};
use spreadlet::gpu::{AtomicMode, GpuSynthOptions, GpuSynthesizer, SplatMode};
use spreadlet::pipeline::types::{FrameParams, SplatPath, SplatRecord};
use spreadlet::pipeline::{
    composite, integrate, splat, Classified, CompositeOptions, Integrator, LayerInfo, PathCounts,
    RotationSampling, SplatOptions,
};

/// Splat planes: largest difference relative to the plane set's largest value (atomic adds
/// in another order than the CPU's bands).
const SPLAT_REL_TOL: f32 = 1e-5;
/// Final image: SSIM (DEVELOPERS.md definition) at least this...
const MIN_SSIM: f64 = 0.999;
/// ...and no channel of any pixel further than this from the CPU's (linear units; the
/// inputs' colours are at most 1; lavapipe measures at most 5e-7).
const MAX_ABS_DIFF: f32 = 1e-5;

/// A hand-made database for `model`: PSF `i` is sparse (a random Laplacian-like set of
/// spreadlets that sums to zero, within 7 px) or, every third one, dense (a small box).
fn hand_database(model: PsfModel, seed: u64) -> PsfDatabase {
    let ranges: Vec<[f64; 2]> = match model {
        PsfModel::ThinLens => vec![[0.0, 8.0]],
        PsfModel::LensMotion => vec![[0.0, 8.0], [0.0, 16.0]],
        PsfModel::PhysicalLens => vec![[1.0, 10.0], [0.0, 5.0]],
    };
    let space = ParamSpace::for_model(model, &ranges, 6).expect("space");
    let n = space.psf_count();
    let mut b = DatabaseBuilder::new(DbHeader::new(model, space, 32));
    let ch = b.header_mut().channels as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for i in 0..n {
        if i % 3 == 2 {
            let (w, h) = (rng.random_range(1..6u16), rng.random_range(1..5u16));
            let origin = [-(w as i16) / 2, -(h as i16) / 2];
            let data: Vec<f32> = (0..w as usize * h as usize * ch)
                .map(|_| {
                    if rng.random_bool(0.2) {
                        0.0
                    } else {
                        rng.random_range(0.0..0.2)
                    }
                })
                .collect();
            b.push_dense(origin, w, h, &data).expect("dense");
        } else {
            // The exact Laplacian of a positive blob (an ellipse of random values), so that
            // the integrated PSF is the blob and the composite is not clamped to black.
            let (rx, ry) = (rng.random_range(1.0..6.0f32), rng.random_range(1.0..6.0f32));
            let blob = Plane::from_fn(17, 17, |x, y| {
                let (dx, dy) = ((x as f32 - 8.0) / rx, (y as f32 - 8.0) / ry);
                if dx * dx + dy * dy <= 1.0 {
                    1.0
                } else {
                    0.0
                }
            });
            let lap = poisson::laplacian(&blob);
            let mut pos = Vec::new();
            let mut val = Vec::new();
            for y in 0..17 {
                for x in 0..17 {
                    let v = lap.get(x, y);
                    if v != 0.0 {
                        pos.push([x as i16 - 8, y as i16 - 8]);
                        for c in 0..ch {
                            val.push(v * (0.02 + 0.01 * c as f32) * rng.random_range(0.9..1.1f32));
                        }
                    }
                }
            }
            b.push_sparse(&pos, &val).expect("sparse");
        }
    }
    b.finish().expect("database")
}

/// The precompute's `test` profile databases, built once per test binary.
fn test_profile_database(model: PsfModel) -> &'static PsfDatabase {
    static DBS: OnceLock<Vec<PsfDatabase>> = OnceLock::new();
    let dbs = DBS.get_or_init(|| {
        [
            PsfModel::ThinLens,
            PsfModel::LensMotion,
            PsfModel::PhysicalLens,
        ]
        .into_iter()
        .map(|m| {
            let cfg = precompute::BuildConfig::new(m, precompute::Profile::Test);
            precompute::build_database(&cfg, false)
                .expect("test database")
                .0
        })
        .collect()
    });
    match model {
        PsfModel::ThinLens => &dbs[0],
        PsfModel::LensMotion => &dbs[1],
        PsfModel::PhysicalLens => &dbs[2],
    }
}

/// A `Classified` as `pipeline::classify` makes it: records sorted by layer, then row, then
/// column, with per-layer counts.
fn classified(
    width: u32,
    height: u32,
    pad: u32,
    layers: u32,
    mut records: Vec<SplatRecord>,
) -> Classified {
    records.sort_by_key(|r| (r.layer, r.center_y, r.center_x));
    let mut infos = vec![LayerInfo::default(); layers as usize];
    let mut counts = PathCounts::default();
    for (i, r) in records.iter().enumerate() {
        let info = &mut infos[r.layer as usize];
        if info.record_count == 0 {
            info.first_record = i;
        }
        info.record_count += 1;
        match r.path {
            p if p == SplatPath::Sparse as u32 => (info.sparse += 1, counts.sparse += 1),
            p if p == SplatPath::Dense as u32 => (info.dense += 1, counts.dense += 1),
            _ => (info.copied += 1, counts.copied += 1),
        };
    }
    Classified {
        frame: FrameParams {
            record_count: records.len() as u32,
            db_channels: 1,
            ..FrameParams::padded(width, height, pad, layers)
        },
        records,
        layers: infos,
        counts,
        database: None,
        packed: None,
        coarse: Vec::new(),
    }
}

fn record(
    x: i32,
    y: i32,
    psf: u32,
    layer: u32,
    angle: f32,
    path: SplatPath,
    color: [f32; 4],
) -> SplatRecord {
    SplatRecord {
        center_x: x,
        center_y: y,
        psf_index: psf,
        layer,
        rot_cos: if angle == 0.0 { 1.0 } else { angle.cos() },
        rot_sin: if angle == 0.0 { 0.0 } else { angle.sin() },
        weight: 1.0,
        path: path as u32,
        color,
    }
}

/// `n` random records over the padded frame (so that some PSFs are cut by its border).
fn random_records(
    db: &PsfDatabase,
    c: (u32, u32, u32, u32),
    n: usize,
    rotate: bool,
    seed: u64,
) -> Vec<SplatRecord> {
    let (w, h, pad, layers) = c;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let psf = rng.random_range(0..db.psf_count() as u32);
            let path = match rng.random_range(0..10) {
                0 => SplatPath::Copy,
                _ if db.dense(psf as usize).is_some() => SplatPath::Dense,
                _ => SplatPath::Sparse,
            };
            let a: f32 = rng.random_range(0.0..1.0);
            let color = [
                rng.random_range(0.0..1.0) * a,
                rng.random_range(0.0..1.0) * a,
                rng.random_range(0.0..1.0) * a,
                a,
            ];
            let angle = if rotate && rng.random_bool(0.7) {
                rng.random_range(-3.2..3.2f32)
            } else {
                0.0
            };
            record(
                rng.random_range(0..(w + 2 * pad) as i32),
                rng.random_range(0..(h + 2 * pad) as i32),
                psf,
                rng.random_range(0..layers),
                angle,
                path,
                color,
            )
        })
        .collect()
}

fn or_zeros(p: &Plane, w: usize, h: usize) -> Plane {
    if p.is_empty() {
        Plane::new(w, h)
    } else {
        p.clone()
    }
}

fn compare_planes(what: &str, gpu: &[Plane], cpu: &[Plane], w: usize, h: usize, tol: f32) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: plane count");
    let cpu: Vec<Plane> = cpu.iter().map(|p| or_zeros(p, w, h)).collect();
    let scale = cpu
        .iter()
        .flat_map(|p| &p.data)
        .map(|v| v.abs())
        .fold(1.0f32, f32::max);
    for (i, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
        assert_eq!((g.width, g.height), (w, h), "{what} plane {i} size");
        let (d, _) = max_diff(&g.data, &c.data);
        assert!(
            d <= tol * scale,
            "{what} plane {i}: differs by {d} (scale {scale})"
        );
    }
}

fn flat(img: &RgbaImage) -> Vec<f32> {
    img.pixels.iter().flatten().copied().collect()
}

/// Runs both paths on `c` and checks every stage; returns (SSIM, max difference) of the images.
fn check_case(
    name: &str,
    db: Option<&PsfDatabase>,
    c: &Classified,
    integrator: Integrator,
    options: GpuSynthOptions,
) -> (f64, f32) {
    let ctx = context().expect("context checked by caller");
    let mut gpu = match db {
        Some(db) => GpuSynthesizer::new(ctx, db, options),
        None => GpuSynthesizer::without_database(ctx, options),
    }
    .expect("GPU synthesizer");
    let f = c.frame;
    let (pw, ph) = (f.padded_width as usize, f.padded_height as usize);

    let stack = splat(
        c,
        db,
        &SplatOptions {
            rotation: options.rotation,
        },
    );
    let planes = gpu.splat_planes(&f, &c.records).expect("GPU splat");
    compare_planes(
        &format!("{name}: laplacian"),
        &planes.laplacian,
        &stack.laplacian,
        pw,
        ph,
        SPLAT_REL_TOL,
    );
    compare_planes(
        &format!("{name}: direct"),
        &planes.direct,
        &stack.direct,
        pw,
        ph,
        SPLAT_REL_TOL,
    );

    let layers = integrate(&stack, integrator);
    let gpu_layers = gpu
        .layer_images(&f, &c.records, integrator)
        .expect("GPU integrate");
    compare_planes(
        &format!("{name}: layers"),
        &gpu_layers,
        &layers.planes,
        pw,
        ph,
        2e-5,
    );

    let cpu_img = composite(&layers, &options.composite);
    let (gpu_img, times) = gpu.run(&f, &c.records, integrator).expect("GPU run");
    assert_eq!(
        (gpu_img.width, gpu_img.height),
        (cpu_img.width, cpu_img.height)
    );
    let (a, b) = (flat(&gpu_img), flat(&cpu_img));
    let (d, m) = max_diff(&a, &b);
    let ssim = metrics::ssim_rgb(&a, &b, cpu_img.width, cpu_img.height).expect("ssim");
    eprintln!(
        "{name}: SSIM {ssim:.6}, max diff {d:.2e} (max value {m:.3}), GPU {:.2} ms (timestamps: {})",
        times.total_ms, times.gpu_timestamps
    );
    assert!(
        m > 0.0,
        "{name}: the CPU image is black: the case tests nothing"
    );
    assert!(ssim >= MIN_SSIM, "{name}: SSIM {ssim} < {MIN_SSIM}");
    assert!(
        d <= MAX_ABS_DIFF,
        "{name}: max difference {d} > {MAX_ABS_DIFF}"
    );
    let counters = gpu.counters();
    assert_eq!(
        (
            counters.pipeline_builds,
            counters.database_uploads,
            counters.frame_allocations
        ),
        (1, 1, 1)
    );
    (ssim, d)
}

fn options(
    (splat, atomics): (SplatMode, AtomicMode),
    rotation: RotationSampling,
) -> GpuSynthOptions {
    GpuSynthOptions {
        atomics,
        rotation,
        splat,
        ..GpuSynthOptions::default()
    }
}

/// The splat variants: tiled, and global atomics with float atomics (where the device has
/// them) and with compare-exchange.
const SPLATS: [(SplatMode, AtomicMode); 3] = [
    (SplatMode::Tiled, AtomicMode::Auto),
    (SplatMode::GlobalAtomic, AtomicMode::Auto),
    (SplatMode::GlobalAtomic, AtomicMode::CompareExchange),
];

#[test]
fn single_pixels_every_hand_model_both_atomic_paths() {
    if context().is_none() {
        return;
    }
    for model in [
        PsfModel::ThinLens,
        PsfModel::LensMotion,
        PsfModel::PhysicalLens,
    ] {
        let db = hand_database(model, 3);
        for psf in 0..db.psf_count() as u32 {
            let path = if db.dense(psf as usize).is_some() {
                SplatPath::Dense
            } else {
                SplatPath::Sparse
            };
            let recs = vec![record(20, 18, psf, 0, 0.0, path, [0.9, 0.5, 0.2, 1.0])];
            let c = classified(24, 20, 8, 1, recs);
            for splat in SPLATS {
                let name = format!("{model:?} psf {psf} {splat:?}");
                check_case(
                    &name,
                    Some(&db),
                    &c,
                    Integrator::Pyramid,
                    options(splat, RotationSampling::Bilinear),
                );
            }
        }
    }
}

#[test]
fn borders_rotations_and_overlaps_hand_databases() {
    if context().is_none() {
        return;
    }
    for (k, model) in [
        PsfModel::ThinLens,
        PsfModel::LensMotion,
        PsfModel::PhysicalLens,
    ]
    .into_iter()
    .enumerate()
    {
        let db = hand_database(model, 11 + k as u64);
        let geometry = (48, 40, 9, 3);
        let mut recs = random_records(
            &db,
            geometry,
            3000,
            model != PsfModel::ThinLens,
            5 + k as u64,
        );
        // Corners of the padded frame and of the image.
        for &(x, y) in &[(0, 0), (65, 0), (0, 57), (65, 57), (9, 9), (56, 48)] {
            recs.push(record(
                x,
                y,
                0,
                1,
                0.0,
                SplatPath::Sparse,
                [1.0, 1.0, 1.0, 1.0],
            ));
        }
        let c = classified(geometry.0, geometry.1, geometry.2, geometry.3, recs);
        for rotation in [
            RotationSampling::Bilinear,
            RotationSampling::Nearest,
            RotationSampling::Bspline,
        ] {
            for splat in SPLATS {
                let name = format!("{model:?} overlaps {rotation:?} {splat:?}");
                check_case(
                    &name,
                    Some(&db),
                    &c,
                    Integrator::Pyramid,
                    options(splat, rotation),
                );
            }
        }
        for (max_layers_per_chunk, splat) in [(1, SplatMode::Tiled), (2, SplatMode::GlobalAtomic)] {
            let name = format!("{model:?} overlaps, chunks of {max_layers_per_chunk} layers");
            let o = GpuSynthOptions {
                max_layers_per_chunk,
                splat,
                ..GpuSynthOptions::default()
            };
            check_case(&name, Some(&db), &c, Integrator::Pyramid, o);
            check_case(
                &format!("{name}, exact"),
                Some(&db),
                &c,
                Integrator::Exact,
                o,
            );
        }
        // Every record drawn by tiles, and almost none (the rest by global atomics).
        for max_tiles_per_record in [1, 1000] {
            let name = format!("{model:?} overlaps, at most {max_tiles_per_record} tiles");
            let o = GpuSynthOptions {
                max_tiles_per_record,
                ..GpuSynthOptions::default()
            };
            check_case(&name, Some(&db), &c, Integrator::Pyramid, o);
        }
        for lanes in [1, 64] {
            let name = format!("{model:?} overlaps, {lanes} lanes per record");
            let o = GpuSynthOptions {
                lanes_per_record: lanes,
                ..GpuSynthOptions::default()
            };
            check_case(&name, Some(&db), &c, Integrator::Pyramid, o);
        }
        let name = format!("{model:?} overlaps exact");
        check_case(
            &name,
            Some(&db),
            &c,
            Integrator::Exact,
            options(SPLATS[0], RotationSampling::Bilinear),
        );
    }
}

#[test]
fn copies_only_without_database() {
    if context().is_none() {
        return;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut recs = Vec::new();
    for y in 0..32 {
        for x in 0..40 {
            let a = rng.random_range(0.2..1.0f32);
            recs.push(record(
                x + 4,
                y + 4,
                0,
                0,
                0.0,
                SplatPath::Copy,
                [0.3 * a, 0.6 * a, 0.9 * a, a],
            ));
        }
    }
    let c = classified(40, 32, 4, 1, recs);
    check_case(
        "copies",
        None,
        &c,
        Integrator::Pyramid,
        GpuSynthOptions::default(),
    );
}

#[test]
fn test_profile_databases_every_model() {
    if context().is_none() {
        return;
    }
    for model in [
        PsfModel::ThinLens,
        PsfModel::LensMotion,
        PsfModel::PhysicalLens,
    ] {
        let db = test_profile_database(model);
        let pad = db.max_extent_px() + 2;
        let geometry = (64, 48, pad, 4);
        // One record of every PSF, spread over the frame, then random overlapping ones.
        let mut recs: Vec<SplatRecord> = (0..db.psf_count() as u32)
            .map(|psf| {
                let path = if db.dense(psf as usize).is_some() {
                    SplatPath::Dense
                } else {
                    SplatPath::Sparse
                };
                let x = pad as i32 + (psf as i32 * 7) % 64;
                let y = pad as i32 + (psf as i32 * 5) % 48;
                record(x, y, psf, psf % 4, 0.0, path, [0.8, 0.6, 0.4, 1.0])
            })
            .collect();
        recs.extend(random_records(
            db,
            geometry,
            1500,
            model == PsfModel::LensMotion,
            21,
        ));
        let c = classified(geometry.0, geometry.1, geometry.2, geometry.3, recs);
        for splat in [SplatMode::Tiled, SplatMode::GlobalAtomic] {
            check_case(
                &format!("{model:?} test profile {splat:?}"),
                Some(db),
                &c,
                Integrator::Pyramid,
                GpuSynthOptions {
                    splat,
                    ..GpuSynthOptions::default()
                },
            );
        }
    }
}

#[test]
fn frames_of_one_size_reuse_buffers_and_a_new_size_reallocates() {
    let Some(ctx) = context() else { return };
    let db = hand_database(PsfModel::LensMotion, 4);
    let mut gpu = GpuSynthesizer::new(ctx, &db, GpuSynthOptions::default()).expect("synth");
    let geometry = (32, 24, 8, 2);
    for seed in 0..3 {
        let c = classified(
            32,
            24,
            8,
            2,
            random_records(&db, geometry, 200 + 100 * seed as usize, true, seed),
        );
        let (img, _) = gpu
            .run(&c.frame, &c.records, Integrator::Pyramid)
            .expect("run");
        let cpu = composite(
            &integrate(
                &splat(&c, Some(&db), &SplatOptions::default()),
                Integrator::Pyramid,
            ),
            &CompositeOptions::default(),
        );
        let (d, _) = max_diff(&flat(&img), &flat(&cpu));
        assert!(d <= MAX_ABS_DIFF, "frame {seed}: {d}");
    }
    let n = gpu.counters();
    assert_eq!(
        (
            n.pipeline_builds,
            n.database_uploads,
            n.frame_allocations,
            n.frames
        ),
        (1, 1, 1, 3)
    );
    let c = classified(
        40,
        24,
        8,
        2,
        random_records(&db, (40, 24, 8, 2), 50, true, 7),
    );
    gpu.run(&c.frame, &c.records, Integrator::Pyramid)
        .expect("run");
    let n = gpu.counters();
    assert_eq!(
        (n.pipeline_builds, n.database_uploads, n.frame_allocations),
        (1, 1, 2)
    );
}

#[test]
fn bad_frames_are_errors_not_panics() {
    let Some(ctx) = context() else { return };
    let mut gpu = GpuSynthesizer::without_database(ctx, GpuSynthOptions::default()).expect("synth");
    let c = classified(
        8,
        8,
        2,
        1,
        vec![record(3, 3, 0, 0, 0.0, SplatPath::Copy, [1.0; 4])],
    );
    let mut f = c.frame;
    f.padded_width += 1;
    assert!(gpu.run(&f, &c.records, Integrator::Pyramid).is_err());
    let mut f = c.frame;
    f.record_count = 5;
    assert!(gpu.run(&f, &c.records, Integrator::Pyramid).is_err());
    let mut f = c.frame;
    f.width = 0;
    assert!(gpu.run(&f, &c.records, Integrator::Pyramid).is_err());
    let odd = GpuSynthOptions {
        lanes_per_record: 3,
        ..GpuSynthOptions::default()
    };
    assert!(GpuSynthesizer::without_database(ctx, odd).is_err());
    // Records pointing outside the database or the layers draw nothing (as on the CPU).
    let mut recs = c.records.clone();
    recs.push(record(3, 3, 99, 0, 0.0, SplatPath::Sparse, [1.0; 4]));
    recs.push(record(3, 3, 0, 7, 0.0, SplatPath::Copy, [1.0; 4]));
    let mut f = c.frame;
    f.record_count = 3;
    let (img, _) = gpu.run(&f, &recs, Integrator::Pyramid).expect("run");
    let (good, _) = gpu
        .run(&c.frame, &c.records, Integrator::Pyramid)
        .expect("run");
    assert_eq!(img, good);
}

/// A database of sparse PSFs, PSF `i` a single spreadlet of value `values[i]` at offset
/// `offsets[i]` (the last one repeated to fill the space).
fn single_spreadlet_database(values: &[f32], offsets: &[[i16; 2]]) -> PsfDatabase {
    let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 2).expect("space");
    let n = space.psf_count() as usize;
    let mut b = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space, 8));
    for i in 0..n {
        let k = i.min(values.len() - 1);
        b.push_sparse(&[offsets[k]], &[values[k]]).expect("sparse");
    }
    b.finish().expect("database")
}

/// The tiled splat's fixed point at its bound: thousands of records pile the same sign onto
/// one pixel, so the tile's bound is the pixel's actual sum and the scale puts that sum just
/// under the i32 limit. A scale one bit too large would wrap the sum negative. Also HDR and
/// tiny magnitudes, and rotated records (whose bound is looser).
#[test]
fn tiled_fixed_point_does_not_overflow_at_its_bound() {
    let Some(ctx) = context() else { return };
    for (value, colour, rotate) in [
        (1.0f32, 1.0f32, false),
        (-0.75, 1.0, false),
        (1.0e6, 3.0e3, false),
        (1.0e-12, 1.0e-8, false),
        (0.5, 1.0, true),
    ] {
        let db = single_spreadlet_database(&[value], &[[0, 0]]);
        let n = 6000;
        let recs: Vec<SplatRecord> = (0..n)
            .map(|_| {
                record(
                    20,
                    17,
                    0,
                    0,
                    if rotate { 0.3 } else { 0.0 },
                    SplatPath::Sparse,
                    [colour, colour, colour, colour],
                )
            })
            .collect();
        let c = classified(32, 24, 4, 1, recs);
        // The bound really is tight: the sum reaches at least half the fixed-point range.
        let fp = tiles::footprints(&db);
        let setup = BinSetup {
            frame: &c.frame,
            layer_base: 0,
            layer_count: 1,
            psf_count: db.psf_count() as u32,
            rotation: RotationSampling::Nearest,
            footprints: &fp,
            max_tiles: 4,
        };
        let bins = tiles::bin_tiles(&setup, &c.records);
        let bin = bins
            .iter()
            .find(|b| b.count > 0)
            .expect("a tile with records");
        let bits = 29 + tiles::low_bits(bin.adds);
        let scale = tiles::tile_scale(bin.laplacian_bound, bits);
        let units = (value.abs() as f64 * colour as f64) * n as f64 * scale as f64;
        if !rotate {
            assert!(
                units >= 2f64.powi(bits - 1) && units < 2f64.powi(bits),
                "{value}: {units} units of 2^{bits}"
            );
        }
        let mut gpu = GpuSynthesizer::new(
            ctx,
            &db,
            GpuSynthOptions {
                rotation: RotationSampling::Nearest,
                ..GpuSynthOptions::default()
            },
        )
        .expect("synth");
        assert_eq!(gpu.splat_mode(), SplatMode::Tiled);
        let planes = gpu.splat_planes(&c.frame, &c.records).expect("splat");
        let cpu = splat(
            &c,
            Some(&db),
            &SplatOptions {
                rotation: RotationSampling::Nearest,
            },
        );
        let expected = value as f64 * colour as f64 * n as f64;
        for ch in 0..4 {
            let cpu_plane = or_zeros(&cpu.laplacian[ch], 40, 32);
            let (x, y) = cpu_plane
                .data
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                .map(|(i, _)| (i % 40, i / 40))
                .expect("pixels");
            // The spreadlet sits at the centre, so rotation leaves it there too.
            assert_eq!((x, y), (20, 17));
            let g = planes.laplacian[ch].get(x, y) as f64;
            assert!(
                (g - expected).abs() <= 1e-6 * expected.abs(),
                "{value} x {colour} x {n}, rotated {rotate}: GPU {g}, expected {expected}"
            );
            // The CPU's f32 running sum of 6000 equal terms is itself off by up to ~1e-4.
            let (d, m) = max_diff(&planes.laplacian[ch].data, &cpu_plane.data);
            assert!(
                d <= 2e-4 * m,
                "{value} rotated {rotate}: GPU and CPU differ by {d} (max {m})"
            );
        }
    }
}

/// Integer sums do not depend on the order of the adds: the tiled splat of a shuffled record
/// list is bit-identical when the tiles draw every record (the float atomics of the pass for
/// records spanning many tiles are not, in general).
#[test]
fn tiled_splat_is_deterministic_under_record_order() {
    let Some(ctx) = context() else { return };
    let db = hand_database(PsfModel::LensMotion, 8);
    let geometry = (40, 32, 9, 2);
    let recs = random_records(&db, geometry, 2000, true, 17);
    let c = classified(geometry.0, geometry.1, geometry.2, geometry.3, recs);
    let o = GpuSynthOptions {
        max_tiles_per_record: u32::MAX,
        ..GpuSynthOptions::default()
    };
    let mut gpu = GpuSynthesizer::new(ctx, &db, o).expect("synth");
    let a = gpu.splat_planes(&c.frame, &c.records).expect("splat");
    let mut shuffled = c.records.clone();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for i in (1..shuffled.len()).rev() {
        shuffled.swap(i, rng.random_range(0..=i));
    }
    let b = gpu.splat_planes(&c.frame, &shuffled).expect("splat");
    for (p, q) in a
        .laplacian
        .iter()
        .zip(&b.laplacian)
        .chain(a.direct.iter().zip(&b.direct))
    {
        assert!(
            p.data
                .iter()
                .zip(&q.data)
                .all(|(x, y)| x.to_bits() == y.to_bits()),
            "tiled splat depends on the record order"
        );
    }
    assert!(a.laplacian.iter().any(|p| p.data.iter().any(|&v| v != 0.0)));
}

/// The CPU mirror of the scale: the largest power of two under the range, for bounds over
/// f32's normal range.
#[test]
fn tile_scale_is_the_largest_power_of_two_under_the_range() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for _ in 0..10_000 {
        let bound = 2f32.powf(rng.random_range(-60.0..60.0f32));
        for bits in [29, 37, 45] {
            let s = tiles::tile_scale(bound, bits) as f64;
            let units = s * bound as f64;
            assert!(units < 2f64.powi(bits), "{bound} {bits}: {units}");
            assert!(units >= 2f64.powi(bits - 1), "{bound} {bits}: {units}");
            assert_eq!(s.log2().fract(), 0.0);
        }
    }
    for bound in [1.0f32, 2.0, 0.5, 1024.0] {
        assert!(tiles::tile_scale(bound, 29) as f64 * bound as f64 == 2f64.powi(28));
    }
    assert_eq!(tiles::tile_scale(0.0, 29), 1.0);
    assert_eq!(tiles::tile_scale(f32::NAN, 29), 1.0);
    for adds in [
        0u32,
        1,
        2,
        3,
        1000,
        1 << 14,
        (1 << 14) + 1,
        1 << 20,
        u32::MAX,
    ] {
        let b = tiles::low_bits(adds);
        assert!((0..=16).contains(&b));
        if adds < 1 << 14 {
            assert_eq!(b, 16, "{adds}");
        }
        if adds <= 1 << 30 {
            assert!((adds as u64) << b <= 1 << 30, "{adds} adds, {b} bits");
        }
    }
}

/// The GPU's binning is the CPU mirror's: the same records in the same tiles, the same adds
/// bounds, the same value bounds to float rounding (sums in another order).
#[test]
fn gpu_binning_matches_the_cpu_mirror() {
    let Some(ctx) = context() else { return };
    for (model, rotation, max_tiles) in [
        (PsfModel::LensMotion, RotationSampling::Bspline, 4),
        (PsfModel::PhysicalLens, RotationSampling::Bilinear, 9),
        (PsfModel::ThinLens, RotationSampling::Nearest, 1),
    ] {
        let db = hand_database(model, 21);
        let geometry = (56, 40, 9, 3);
        let recs = random_records(&db, geometry, 2500, true, 23);
        let c = classified(geometry.0, geometry.1, geometry.2, geometry.3, recs);
        let o = GpuSynthOptions {
            rotation,
            max_tiles_per_record: max_tiles,
            ..GpuSynthOptions::default()
        };
        let mut gpu = GpuSynthesizer::new(ctx, &db, o).expect("synth");
        gpu.splat_planes(&c.frame, &c.records).expect("splat");
        let got = gpu.tile_bins().expect("tile state");
        let fp = tiles::footprints(&db);
        let setup = BinSetup {
            frame: &c.frame,
            layer_base: 0,
            layer_count: geometry.3,
            psf_count: db.psf_count() as u32,
            rotation,
            footprints: &fp,
            max_tiles,
        };
        let want = tiles::bin_tiles(&setup, &c.records);
        assert_eq!(got.len(), want.len(), "{model:?}: tiles");
        assert!(
            want.iter().any(|b| b.count > 1),
            "{model:?}: nothing binned"
        );
        for (t, (g, w)) in got.iter().zip(&want).enumerate() {
            assert_eq!((g.count, g.adds), (w.count, w.adds), "{model:?} tile {t}");
            for (a, b) in [
                (g.laplacian_bound, w.laplacian_bound),
                (g.direct_bound, w.direct_bound),
            ] {
                assert!(
                    (a - b).abs() <= 1e-5 * b.abs(),
                    "{model:?} tile {t}: bound {a} against {b}"
                );
            }
        }
        let entries: u64 = want.iter().map(|b| b.count as u64).sum();
        assert_eq!(entries, tiles::entry_count(&setup, &c.records));
    }
}
