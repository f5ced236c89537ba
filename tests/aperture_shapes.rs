//! Aperture shapes end to end: one bright pixel, defocused, splats to the aperture's shape.
//! An anamorphic ratio of 2 gives an ellipse half as wide as tall (second moments r^2 / 16
//! and r^2 / 4 for CoC radius r); a rotated pentagon reaches as far along x and y as the
//! rotated polygon does, turned half a turn in front of the focus plane. Measured on the synthesised image, through the quick databases.

use spreadlet::{Backend, Camera, GBuffer, Renderer, RendererOptions, SynthOptions};
use spreadlet_e2e::cache_dir;

const SIZE: usize = 192;
/// Depth of the bright pixel, metres (the camera focuses at 1 m): in front of the focus
/// plane, a CoC of about 14 px.
const DEPTH: f32 = 0.5;
/// A depth behind the focus plane: a CoC of about 10 px.
const BEHIND: f32 = 3.0;

fn camera(extra: &str) -> Camera {
    Camera::from_json_str(&format!(
        r#"{{"width": {SIZE}, "height": {SIZE}, "focal_length_mm": 85, "sensor_width_mm": 36,
            "f_stop": 1.4, "focus_distance": 1.0 {extra}}}"#
    ))
    .expect("camera")
}

/// A CPU renderer on the quick databases of the test cache.
fn cpu_renderer() -> Renderer {
    Renderer::new(RendererOptions {
        backend: Backend::Cpu,
        databases: spreadlet::DbSource::Cache {
            dir: cache_dir(),
            profile: precompute::Profile::Quick,
        },
        ..Default::default()
    })
    .expect("renderer")
}

/// The image of one bright pixel at the frame's centre at [`DEPTH`] ([`splat_at`]).
fn splat(camera: &Camera) -> (Vec<[f32; 4]>, f64) {
    splat_at(camera, DEPTH)
}

/// The image of one bright pixel at the frame's centre, everything else transparent black at
/// the same depth, and the signed CoC radius in pixels there (negative in front of the focus
/// plane).
fn splat_at(camera: &Camera, depth: f32) -> (Vec<[f32; 4]>, f64) {
    let n = SIZE * SIZE;
    let mut color = vec![[0.0f32; 4]; n];
    color[(SIZE / 2) * SIZE + SIZE / 2] = [100.0, 100.0, 100.0, 1.0];
    let g = GBuffer::from_planes(SIZE, SIZE, color, Some(vec![depth; n]), None).expect("g");
    let mut renderer = cpu_renderer();
    let frame = renderer
        .synthesize(&g, camera, &SynthOptions::default())
        .expect("synthesis");
    let lens = camera.thin_lens().expect("a lens");
    (frame.image.pixels, lens.signed_coc_px(f64::from(depth)))
}

/// Mean-centred second moments (x, y) of the red channel, pixels^2.
fn second_moments(pixels: &[[f32; 4]]) -> (f64, f64) {
    let (mut m, mut mx, mut my, mut mxx, mut myy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (i, p) in pixels.iter().enumerate() {
        let v = f64::from(p[0].max(0.0));
        let (x, y) = ((i % SIZE) as f64, (i / SIZE) as f64);
        m += v;
        mx += v * x;
        my += v * y;
        mxx += v * x * x;
        myy += v * y * y;
    }
    let (cx, cy) = (mx / m, my / m);
    (mxx / m - cx * cx, myy / m - cy * cy)
}

/// The farthest lit pixel from the centre along +x, -x, +y (down) and -y, pixels: lit is above
/// a quarter of the splat's mean over its support.
fn reach(pixels: &[[f32; 4]]) -> [f64; 4] {
    let lit: Vec<f64> = pixels.iter().map(|p| f64::from(p[0])).collect();
    let support: Vec<f64> = lit.iter().copied().filter(|&v| v > 1e-3).collect();
    let mean = support.iter().sum::<f64>() / support.len() as f64;
    let c = (SIZE / 2) as f64;
    let mut out = [0.0f64; 4];
    for (i, &v) in lit.iter().enumerate() {
        if v < 0.25 * mean {
            continue;
        }
        let (dx, dy) = ((i % SIZE) as f64 - c, (i / SIZE) as f64 - c);
        out[0] = out[0].max(dx);
        out[1] = out[1].max(-dx);
        out[2] = out[2].max(dy);
        out[3] = out[3].max(-dy);
    }
    out
}

#[test]
fn an_anamorphic_ratio_of_two_splats_an_ellipse_half_as_wide() {
    let (round, r) = splat(&camera(""));
    let (squeezed, r2) = splat(&camera(r#", "aperture_ratio": 2.0"#));
    assert_eq!(r, r2);
    let r = r.abs();
    assert!(r > 12.0, "CoC {r} px is too small to measure a shape");
    let (rx, ry) = second_moments(&round);
    let (sx, sy) = second_moments(&squeezed);
    eprintln!(
        "CoC {r:.2} px; round var {rx:.2} / {ry:.2}, squeezed {sx:.2} / {sy:.2} \
         (analytic {:.2} / {:.2} and {:.2} / {:.2})",
        r * r / 4.0,
        r * r / 4.0,
        r * r / 16.0,
        r * r / 4.0
    );
    // The PSFs are pre-filtered over their database cell and sparsified: a few per cent.
    let near = |v: f64, expected: f64| (v - expected).abs() < 0.08 * expected + 0.5;
    assert!(
        near(rx, r * r / 4.0) && near(ry, r * r / 4.0),
        "round {rx} {ry}"
    );
    assert!(
        near(sx, r * r / 16.0) && near(sy, r * r / 4.0),
        "squeezed {sx} {sy}"
    );
    // Energy stays where it was.
    let total = |p: &[[f32; 4]]| p.iter().map(|c| f64::from(c[0])).sum::<f64>();
    assert!((total(&squeezed) - total(&round)).abs() < 0.01 * total(&round));
}

#[test]
fn a_rotated_pentagon_reaches_as_far_as_the_rotated_polygon_turned_in_front_of_the_focus() {
    for (rotation, depth) in [(0.0f64, DEPTH), (20.0, DEPTH), (20.0, BEHIND)] {
        let (image, signed) = splat_at(
            &camera(&format!(
                r#", "aperture_blades": 5, "aperture_rotation_deg": {rotation}"#
            )),
            depth,
        );
        // Vertices at angles rotation + 72 k degrees, counter-clockwise on the image (y down),
        // scaled by the signed CoC: in front of the focus plane the lens images its aperture
        // turned half a turn. The extent along each axis is the largest vertex projection.
        let vertices: Vec<(f64, f64)> = (0..5)
            .map(|k| {
                let a = (rotation + 72.0 * f64::from(k)).to_radians();
                (signed * a.cos(), -signed * a.sin())
            })
            .collect();
        let analytic = [
            vertices.iter().map(|v| v.0).fold(f64::MIN, f64::max),
            vertices.iter().map(|v| -v.0).fold(f64::MIN, f64::max),
            vertices.iter().map(|v| v.1).fold(f64::MIN, f64::max),
            vertices.iter().map(|v| -v.1).fold(f64::MIN, f64::max),
        ];
        let measured = reach(&image);
        eprintln!(
            "pentagon at {rotation} deg, signed CoC {signed:.2}: reach {measured:?}, analytic {analytic:?}"
        );
        assert!(
            signed.abs() > 9.0,
            "CoC {signed} px is too small to measure a shape"
        );
        for (m, a) in measured.iter().zip(&analytic) {
            assert!((m - a).abs() <= 1.5, "reach {measured:?} vs {analytic:?}");
        }
    }
}

#[test]
fn a_drawn_aperture_is_upright_behind_the_focus_and_turned_in_front() {
    // A PNG lit in its top half only: behind the focus plane the bokeh lies above the
    // pixel (y down: a negative mean), in front of it below; its width is the whole CoC
    // diameter, its height half of it. A rectangle of r x 2r has variances r^2 / 3 (x) and
    // r^2 / 12 (y).
    let dir = tempfile::tempdir().expect("temp dir");
    let png = dir.path().join("top-half.png");
    let mut img = image::GrayImage::new(64, 64);
    for (_, y, p) in img.enumerate_pixels_mut() {
        p.0 = [if y < 32 { 255 } else { 0 }];
    }
    img.save(&png).expect("png");
    let extra = format!(r#", "aperture_image": {:?}"#, png.to_str().expect("utf-8"));
    for depth in [BEHIND, DEPTH] {
        let (image, signed) = splat_at(&camera(&extra), depth);
        let r = signed.abs();
        let (mut m, mut my) = (0.0, 0.0);
        for (i, p) in image.iter().enumerate() {
            let v = f64::from(p[0].max(0.0));
            m += v;
            my += v * ((i / SIZE) as f64 - (SIZE / 2) as f64);
        }
        let mean_y = my / m;
        let (vx, vy) = second_moments(&image);
        eprintln!(
            "top-half aperture, signed CoC {signed:.2}: mean y {mean_y:.2} (analytic {:.2}), \
             var {vx:.2} / {vy:.2} (analytic {:.2} / {:.2})",
            -signed / 2.0,
            r * r / 3.0,
            r * r / 12.0
        );
        assert!(
            (mean_y + signed / 2.0).abs() < 1.0,
            "mean y {mean_y} for CoC {signed}"
        );
        let near = |v: f64, e: f64| (v - e).abs() < 0.1 * e + 0.5;
        assert!(near(vx, r * r / 3.0) && near(vy, r * r / 12.0), "{vx} {vy}");
    }
    // A missing image is a clean error, not a round aperture.
    let missing = camera(r#", "aperture_image": "/no/such/aperture.png""#);
    let n = SIZE * SIZE;
    let g =
        GBuffer::from_planes(SIZE, SIZE, vec![[1.0; 4]; n], Some(vec![DEPTH; n]), None).expect("g");
    let mut renderer = cpu_renderer();
    let e = renderer
        .synthesize(&g, &missing, &SynthOptions::default())
        .expect_err("a missing aperture image");
    assert!(e.to_string().contains("aperture image"), "{e}");
}

/// The model a narrow thin-lens PSF is smeared from at sub-pixel shifts agrees with the
/// light-traced database (the precompute's rays, binned per pixel) of a round aperture, a
/// rotated pentagon and a squeezed disc, upright and turned half a turn, in every narrow cell
/// of CoC 1 px and more: a streak's sides are drawn from the PSF the database holds.
#[test]
fn the_sub_pixel_model_agrees_with_round_polygonal_and_squeezed_databases() {
    use psf_db::PsfModel;
    use spreadlet::dbcache::{build_config, cached_database};
    use spreadlet::motion_smear::{psf_image, turn, NARROW_PSF_PX};
    use spreadlet::subpixel_psf::{SubpixelPsf, MIN_RADIUS_PX};
    for extra in [
        "",
        r#", "aperture_blades": 5, "aperture_rotation_deg": 20"#,
        r#", "aperture_ratio": 2.0"#,
    ] {
        let aperture = spreadlet::databases::aperture_of(&camera(extra));
        let mut cfg = build_config(
            PsfModel::ThinLens,
            precompute::Profile::Quick,
            aperture.blades,
        );
        cfg.blade_rotation_rad = aperture.rotation_rad;
        cfg.aperture_ratio = aperture.ratio;
        let (db, _) = cached_database(&cfg, &cache_dir(), false, &|_| {}).expect("database");
        let (db, _) = spreadlet::condition::condition(&db).expect("condition");
        let space = db.space();
        let mut modelled = 0;
        for cell in 0..space.psf_count() {
            let Some(base) = psf_image(&db, cell as usize) else {
                continue;
            };
            let smallest = space.cell_box(cell).expect("cell").min[0];
            if base.width.min(base.height) >= NARROW_PSF_PX || smallest < MIN_RADIUS_PX {
                continue;
            }
            let turned = turn(&base, std::f32::consts::PI);
            for (image, half_turn) in [(&base, false), (&turned, true)] {
                assert!(
                    SubpixelPsf::of_cell(&db, cell, image, half_turn).is_some(),
                    "{extra}: cell {cell} (CoC from {smallest:.2} px, turned {half_turn}): the model departs"
                );
            }
            modelled += 1;
        }
        assert!(modelled >= 3, "{extra}: only {modelled} narrow cells");
    }
}
