//! Real lenses end to end.
//!
//! - The two tracers of a lens prescription agree: the PSF the precompute light-traces from a
//!   point (scene to sensor) against the one the scene renderer's camera gives, tracing from
//!   the sensor through the same surfaces to a small disk around that point.
//! - The database keeps a corner drop's cat's eye: the PSF drawn for it against its own.
//! - In the paraxial limit (a thin lens stopped to f/16) a prescription images like the
//!   textbook thin lens: the blur's size, and the pinhole image's position.
//! - A moving point's PSF through a real lens: light traced at every instant against the
//!   renderer's factorisation (the lens PSF smeared along the motion).
//! - `camera.json` `lens` reaches `spreadlet synth`: a physical-lens database is built for the
//!   camera and reported; bad lenses are clear errors.

use glam::{DVec2, DVec3};
use precompute::optics::{Prescription, Spectrum};
use precompute::prefilter::ParamBox;
use precompute::sampler::psf_rng;
use precompute::trace::{trace_psf, RayCount};
use precompute::{BuildConfig, BuildPlan, LensOptions, Profile, PsfImage};
use psf_db::PsfModel;
use spreadlet_e2e::{
    assert_clean_failure, assert_gpu_run_matches, assert_success, compare_scores, run,
};
use std::path::Path;

/// A plan for the physical-lens model through `lens` focused at `focus_m`, on a sensor of
/// `sensor_mm` mapped onto the test profile's 480 px.
fn plan(lens: Prescription, f_stop: Option<f64>, focus_m: f64, sensor_mm: f64) -> BuildPlan {
    let mut cfg = BuildConfig::new(PsfModel::PhysicalLens, Profile::Test);
    cfg.lens = Some(LensOptions {
        prescription: Some(lens),
        f_stop,
        focus_distance: focus_m,
        sensor_width_mm: sensor_mm,
        image_width_px: Some(480),
        depth_range: [0.3, 20.0],
        max_eccentricity_mm: 0.5 * sensor_mm,
        ..LensOptions::default()
    });
    BuildPlan::new(&cfg).expect("plan")
}

/// The precompute's PSF of a point `depth_m` in front of the entrance pupil whose pinhole
/// image lies `ecc_mm` from the centre along +x, traced with `rays` rays, no pre-filter.
fn forward_psf(plan: &BuildPlan, depth_m: f64, ecc_mm: f64, rays: u64) -> PsfImage {
    let params = ParamBox::fixed(&plan.space, [1.0 / depth_m, ecc_mm]);
    let (img, stats) = trace_psf(
        plan.tracer.as_ref(),
        &params,
        RayCount::Fixed(rays),
        &mut psf_rng(7, 0, 0),
        0,
    )
    .expect("trace");
    assert_eq!(stats.outside, 0);
    img
}

/// xorshift64*: a dependency-free stream of uniform numbers for the sensor-side tracer.
struct Uniform(u64);
impl Uniform {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The scene renderer's PSF of the same point, on the pixel lattice of `like` (offsets from
/// the pinhole image, +x radially outwards): per pixel, `per_px` rays from the sensor through
/// the lens, each counted (with its channel weights and exit pupil box area) when it passes
/// within `radius_px` (projected to the object plane) of the point; normalised per channel.
fn backward_psf(
    camera: &scene::camera::Camera,
    like: &PsfImage,
    depth_m: f64,
    ecc_mm: f64,
    per_px: usize,
    radius_px: f64,
) -> Vec<Vec<f64>> {
    let lens = camera.physical().expect("a real lens");
    let spec = &camera.spec;
    let ppm = spec.pixels_per_mm();
    let d = lens.pinhole_distance_mm;
    let point = DVec3::new(ecc_mm / d * depth_m, 0.0, -depth_m);
    let pinhole = DVec2::new(
        0.5 * f64::from(spec.width) + ecc_mm * ppm,
        0.5 * f64::from(spec.height),
    );
    let radius_m = radius_px / ppm / d * depth_m;
    let spectrum = Spectrum::new();
    let mut planes = vec![vec![0.0f64; like.width * like.height]; 3];
    let mut rng = Uniform(0x9e37_79b9_7f4a_7c15);
    for y in 0..like.height {
        for x in 0..like.width {
            let offset = DVec2::new(
                x as f64 - like.centre[0] as f64 - 0.5,
                y as f64 - like.centre[1] as f64 - 0.5,
            );
            for _ in 0..per_px {
                let pixel = pinhole + offset + DVec2::new(rng.next(), rng.next());
                let xi = DVec2::new(rng.next(), rng.next());
                let lambda = Spectrum::wavelength_nm(rng.next());
                let Some((ray, area)) = camera.physical_ray(pixel, xi, lambda, 0.0) else {
                    continue;
                };
                let t = (point.z - ray.origin.z) / ray.direction.z;
                let hit = ray.origin + t * ray.direction;
                if t > 0.0 && (hit - point).length() < radius_m {
                    let w = spectrum.rgb(lambda);
                    for c in 0..3 {
                        planes[c][y * like.width + x] += w[c] * area;
                    }
                }
            }
        }
    }
    for p in &mut planes {
        let sum: f64 = p.iter().sum();
        assert!(sum > 0.0, "no ray reached the point");
        p.iter_mut().for_each(|v| *v /= sum);
    }
    planes
}

/// Centroid (x, y) and RMS spread (x, y) of a normalised plane on `like`'s lattice, pixels.
fn moments(plane: &[f64], like: &PsfImage) -> [f64; 4] {
    let (mut mx, mut my) = (0.0, 0.0);
    for (i, v) in plane.iter().enumerate() {
        mx += v * ((i % like.width) as f64 - like.centre[0] as f64);
        my += v * ((i / like.width) as f64 - like.centre[1] as f64);
    }
    let (mut sx, mut sy) = (0.0, 0.0);
    for (i, v) in plane.iter().enumerate() {
        let dx = (i % like.width) as f64 - like.centre[0] as f64 - mx;
        let dy = (i / like.width) as f64 - like.centre[1] as f64 - my;
        sx += v * dx * dx;
        sy += v * dy * dy;
    }
    [mx, my, sx.sqrt(), sy.sqrt()]
}

/// The precompute's tracer (scene to sensor) and the scene renderer's camera (sensor to
/// scene) give the same PSF for the same lens and point: on axis and off axis (cat's eye),
/// in front of and behind the focus plane, per colour channel: centroids within 0.35 px,
/// RMS spreads within 6 %, and the green images within 0.2 in L1 (the two are Monte Carlo
/// estimates; the sensor-side one also sees the point as a disk of half a pixel).
#[test]
fn the_two_tracers_agree_on_psfs() {
    let (width, sensor_mm, focus_m, f_stop) = (480u32, 36.0, 1.2, 2.8);
    let lens = Prescription::builtin("double-gauss-50mm").expect("built-in");
    let plan = plan(lens, Some(f_stop), focus_m, sensor_mm);
    let spec = formats::Camera::from_json_str(&format!(
        r#"{{"width": {width}, "height": 320, "focal_length_mm": 50, "sensor_width_mm": {sensor_mm},
            "f_stop": {f_stop}, "focus_distance": {focus_m}, "lens": "double-gauss-50mm"}}"#
    ))
    .expect("camera");
    let pose = scene::camera::CameraPose {
        position: DVec3::ZERO,
        look_at: DVec3::new(0.0, 0.0, -1.0),
        up: DVec3::Y,
        velocity: DVec3::ZERO,
    };
    let camera = scene::camera::Camera::new(spec, pose, "test").expect("camera");
    for (depth, ecc) in [(0.6, 0.0), (0.6, 14.0), (5.0, 16.0)] {
        let fwd = forward_psf(&plan, depth, ecc, 3_000_000);
        let bwd = backward_psf(&camera, &fwd, depth, ecc, 10_000, 0.5);
        for (c, back) in bwd.iter().enumerate() {
            let f: Vec<f64> = fwd.planes[c].iter().map(|&v| f64::from(v)).collect();
            let (mf, mb) = (moments(&f, &fwd), moments(back, &fwd));
            println!(
                "depth {depth} m, eccentricity {ecc} mm, channel {c}: precompute centroid \
                 ({:.2}, {:.2}) spread ({:.2}, {:.2}) px; scene camera ({:.2}, {:.2}) ({:.2}, {:.2})",
                mf[0], mf[1], mf[2], mf[3], mb[0], mb[1], mb[2], mb[3]
            );
            for k in 0..2 {
                assert!((mf[k] - mb[k]).abs() < 0.35, "centroid {mf:?} vs {mb:?}");
                assert!(
                    (mf[k + 2] / mb[k + 2] - 1.0).abs() < 0.06,
                    "spread {mf:?} vs {mb:?}"
                );
            }
            if c == 1 {
                let l1: f64 = f.iter().zip(back).map(|(a, b)| (a - b).abs()).sum();
                println!("  green L1 {l1:.3}");
                assert!(l1 < 0.2, "L1 {l1}");
            }
        }
    }
}

/// A real lens's bokeh in the corner of the frame is kept by the database: the PSF the runtime
/// draws for a drop 0.45 m from the double Gauss at f/2.1 focused at 1.2 m, 20.8 mm off axis
/// (the rain scene's top-left drop, 512 px wide, the runtime's 160 PSFs), pre-filtered over its
/// cell, against the drop's own light-traced PSF: per colour channel the centroid within 5 % of
/// the RMS radius and the spreads (radial, tangential) within 6 %. Vignetting cuts the cat's eye fastest there, and a
/// nested grid's cell there stood for blurs 47 % apart and eccentricities 3 mm apart: the
/// radial spread came out 39 % wide and the centroid 1.8 px off.
#[test]
fn the_database_keeps_a_corner_drops_cat_eye() {
    let (drawn, own) = cell_and_own_psf(&corner_drops_plan(), 0.45, 20.8);
    for c in 0..3 {
        let plane =
            |img: &PsfImage| -> Vec<f64> { img.planes[c].iter().map(|&v| f64::from(v)).collect() };
        let (md, mo) = (moments(&plane(&drawn), &drawn), moments(&plane(&own), &own));
        println!(
            "channel {c}: database centroid ({:.2}, {:.2}) spread ({:.2}, {:.2}) px; the drop's \
             own ({:.2}, {:.2}) ({:.2}, {:.2})",
            md[0], md[1], md[2], md[3], mo[0], mo[1], mo[2], mo[3]
        );
        let radius = mo[2].hypot(mo[3]);
        let off = (md[0] - mo[0]).hypot(md[1] - mo[1]);
        assert!(
            off < 0.05 * radius,
            "channel {c}: centroid {off:.2} px off, radius {radius:.2} px"
        );
        // The cell's PSF is traced at the middle of its eccentricities, a little beyond the
        // drop's 20.8 mm, where the rim clips the beam more: blue's radial spread is 5 %
        // narrower there.
        for k in 2..4 {
            assert!(
                (md[k] / mo[k] - 1.0).abs() < 0.06,
                "channel {c}: spread {md:?} vs {mo:?}"
            );
        }
    }
}

/// Monte Carlo image of a point moving through the lens over the shutter, on a `2 half + 1`
/// square lattice centred on the point's pinhole image at the shutter's centre (px from it, x
/// right, y down): each ray at a uniform instant `t` in [-1/2, 1/2], its pinhole image at
/// `e0 + t m` (px from the sensor centre, `e0` along +x). `brute`: every instant traced at its
/// own eccentricity and turned onto its own radial direction, as the light goes; else every
/// instant with the lens PSF of the shutter's centre (the renderer's factorisation).
#[allow(clippy::too_many_arguments)]
fn moving_point_image(
    plan: &BuildPlan,
    depth_m: f64,
    e0_px: f64,
    motion_px: [f64; 2],
    pixel_mm: f64,
    rays: usize,
    half: usize,
    brute: bool,
) -> Vec<Vec<f64>> {
    let n = 2 * half + 1;
    let mut planes = vec![vec![0.0f64; n * n]; 3];
    let mut rng = Uniform(0x2545_f491_4f6c_dd1d);
    let mut u = [0.0f64; 3];
    for _ in 0..rays {
        let t = rng.next() - 0.5;
        u.iter_mut().for_each(|v| *v = rng.next());
        let shift = [t * motion_px[0], t * motion_px[1]];
        let (ecc_px, (sin, cos)) = if brute {
            let p = [e0_px + shift[0], shift[1]];
            (p[0].hypot(p[1]), p[1].atan2(p[0]).sin_cos())
        } else {
            (e0_px, (0.0, 1.0))
        };
        let Some(hit) = plan.tracer.trace([1.0 / depth_m, ecc_px * pixel_mm], &u) else {
            continue;
        };
        let o = hit.offset;
        let x = o[0] * cos - o[1] * sin + shift[0];
        let y = o[0] * sin + o[1] * cos + shift[1];
        let px = (x + half as f64 + 0.5).floor();
        let py = (y + half as f64 + 0.5).floor();
        if px < 0.0 || py < 0.0 || px >= n as f64 || py >= n as f64 {
            continue;
        }
        let i = py as usize * n + px as usize;
        for (plane, w) in planes.iter_mut().zip(hit.weight) {
            plane[i] += w;
        }
    }
    for p in &mut planes {
        let sum: f64 = p.iter().sum();
        assert!(sum > 0.0, "no ray passed the lens");
        p.iter_mut().for_each(|v| *v /= sum);
    }
    planes
}

/// Centroid along and across `dir`, and RMS spread along and across it, px.
fn moments_along(plane: &[f64], half: usize, dir: [f64; 2]) -> [f64; 4] {
    let n = 2 * half + 1;
    let at = |i: usize| {
        let (x, y) = ((i % n) as f64 - half as f64, (i / n) as f64 - half as f64);
        [x * dir[0] + y * dir[1], -x * dir[1] + y * dir[0]]
    };
    let (mut ma, mut mc) = (0.0, 0.0);
    for (i, v) in plane.iter().enumerate() {
        let p = at(i);
        ma += v * p[0];
        mc += v * p[1];
    }
    let (mut sa, mut sc) = (0.0, 0.0);
    for (i, v) in plane.iter().enumerate() {
        let p = at(i);
        sa += v * (p[0] - ma).powi(2);
        sc += v * (p[1] - mc).powi(2);
    }
    [ma, mc, sa.sqrt(), sc.sqrt()]
}

/// The motion PSF of a real lens: a point moving 18 px over the shutter, at 60 degrees to its
/// radial direction, 14 mm off axis through the double Gauss at f/2.8, 0.6 m from the lens
/// (focused at 1.2 m: a cat's eye about 11 px across). Light traced at every instant through
/// the lens (its eccentricity and radial direction changing along the motion) against the
/// renderer's factorisation (the lens PSF of the shutter's centre convolved with the motion's
/// segment): per channel the centroids within 0.15 px and the spreads along and across the
/// motion within 3 %, the green images within 0.06 in L1 (both are Monte Carlo estimates of
/// 1.5 M rays). The renderer's smear (`motion_smear::smear`, taps along the segment with
/// bilinear weights) of the traced still PSF matches the factorisation's Monte Carlo image
/// within the same bounds.
#[test]
fn the_motion_psf_of_a_real_lens_matches_light_tracing() {
    let (width, sensor_mm, focus_m, f_stop) = (480u32, 36.0, 1.2, 2.8);
    let lens = Prescription::builtin("double-gauss-50mm").expect("built-in");
    let plan = plan(lens, Some(f_stop), focus_m, sensor_mm);
    let pixel_mm = sensor_mm / f64::from(width);
    let (depth, ecc_mm) = (0.6, 14.0);
    let e0 = ecc_mm / pixel_mm;
    let angle = 60f64.to_radians();
    let len = 18.0;
    let motion = [len * angle.cos(), len * angle.sin()];
    let dir = [angle.cos(), angle.sin()];
    let half = 24;
    let rays = 1_500_000;
    let brute = moving_point_image(&plan, depth, e0, motion, pixel_mm, rays, half, true);
    let factor = moving_point_image(&plan, depth, e0, motion, pixel_mm, rays, half, false);

    // The renderer's smear of the still PSF (traced, not pre-filtered), on the same lattice.
    let still = forward_psf(&plan, depth, ecc_mm, 3_000_000);
    let mut data = vec![0f32; still.width * still.height * 3];
    for (c, plane) in still.planes.iter().enumerate() {
        for (i, v) in plane.iter().enumerate() {
            data[i * 3 + c] = *v;
        }
    }
    let image = spreadlet::motion_smear::PsfImage {
        origin: [-(still.centre[0] as i32), -(still.centre[1] as i32)],
        width: still.width,
        height: still.height,
        channels: 3,
        data,
    };
    let smeared =
        spreadlet::motion_smear::smear(&image, len as f32, angle as f32, 0.0).expect("smear");
    let renderer = on_lattice(&smeared, half);
    for (c, light) in brute.iter().enumerate() {
        let mb = moments_along(light, half, dir);
        for (name, other) in [
            ("factorised", &factor[c]),
            ("renderer's smear", &renderer[c]),
        ] {
            let mo = moments_along(other, half, dir);
            println!(
                "channel {c}: light traced centroid ({:.2}, {:.2}) spread ({:.2}, {:.2}) px; \
                 {name} ({:.2}, {:.2}) ({:.2}, {:.2})",
                mb[0], mb[1], mb[2], mb[3], mo[0], mo[1], mo[2], mo[3]
            );
            for k in 0..2 {
                assert!(
                    (mb[k] - mo[k]).abs() < 0.15,
                    "{name}: centroid {mb:?} vs {mo:?}"
                );
                assert!(
                    (mb[k + 2] / mo[k + 2] - 1.0).abs() < 0.03,
                    "{name}: spread {mb:?} vs {mo:?}"
                );
            }
            if c == 1 {
                let l1: f64 = light.iter().zip(other).map(|(a, b)| (a - b).abs()).sum();
                println!("  green L1 {l1:.3}");
                assert!(l1 < 0.06, "{name}: L1 {l1}");
            }
        }
    }
    // The motion shows: the spread along it far exceeds the still PSF's.
    let ms = moments_along(&on_lattice(&image, half)[1], half, dir);
    let mb = moments_along(&brute[1], half, dir);
    assert!(mb[2] > ms[2] + 3.0, "still {ms:?}, moving {mb:?}");
}

/// `img`'s channels on the `2 half + 1` square lattice centred on its PSF centre (what falls
/// outside is dropped), each normalised to sum to one.
fn on_lattice(img: &spreadlet::motion_smear::PsfImage, half: usize) -> Vec<Vec<f64>> {
    let n = 2 * half + 1;
    let mut planes = vec![vec![0.0f64; n * n]; img.channels];
    for y in 0..img.height {
        for x in 0..img.width {
            let px = x as i32 + img.origin[0] + half as i32;
            let py = y as i32 + img.origin[1] + half as i32;
            if px < 0 || py < 0 || px >= n as i32 || py >= n as i32 {
                continue;
            }
            for (c, plane) in planes.iter_mut().enumerate() {
                plane[py as usize * n + px as usize] +=
                    f64::from(img.data[(y * img.width + x) * img.channels + c]);
            }
        }
    }
    for p in &mut planes {
        let sum: f64 = p.iter().sum();
        p.iter_mut().for_each(|v| *v /= sum);
    }
    planes
}

/// A thin lens of f = 100 mm stopped to f/16 (a dispersion-free table, pbrt's format) images
/// like the textbook thin lens: the pinhole distance is the image distance `v = f s / (s - f)`
/// and a point at depth `d` blurs to a disk of diameter `A |v_d - v| / v_d` (`A = f / N`),
/// whose RMS radius is the radius over sqrt 2; off axis the blur centres on the pinhole image.
#[test]
fn a_paraxial_lens_images_like_the_thin_lens() {
    let table =
        "# thin f = 100 mm lens, stop in contact\n0 0.01 0 6.25\n100 0.5 1.5 8\n-100 100 1 8\n";
    let lens = Prescription::from_table_str(table, "thin-100mm", "test").expect("table");
    let (focus_m, sensor_mm) = (1.0, 9.6);
    let plan = plan(lens.clone(), None, focus_m, sensor_mm);
    let pixel_mm = sensor_mm / 480.0;
    let system =
        precompute::optics::LensSystem::focused(lens, None, focus_m * 1000.0).expect("focus");
    let f = system.focal_length(precompute::optics::system::LAMBDA_DESIGN_UM);
    assert!((f - 100.0).abs() < 0.5, "f = {f}");
    let v = |s_mm: f64| f * s_mm / (s_mm - f);
    let d_pin = system.pinhole_distance(1000.0, precompute::optics::system::LAMBDA_DESIGN_UM);
    assert!(
        (d_pin / v(1000.0) - 1.0).abs() < 5e-3,
        "D {d_pin} vs v {}",
        v(1000.0)
    );
    let aperture = 6.25;
    for (depth, ecc) in [(0.5, 0.0), (3.0, 0.0), (0.5, 3.0)] {
        let img = forward_psf(&plan, depth, ecc, 1_000_000);
        let vd = v(depth * 1000.0);
        let coc_px = aperture * (vd - v(1000.0)).abs() / vd / pixel_mm;
        let expected = 0.5 * coc_px / 2f64.sqrt();
        let rms = img.rms_radius(1);
        let c = img.centroid(1);
        println!(
            "depth {depth} m, eccentricity {ecc} mm: rms radius {rms:.2} px, thin lens \
             {expected:.2} px; centroid ({:.2}, {:.2}) px",
            c[0], c[1]
        );
        assert!((rms / expected - 1.0).abs() < 0.03, "{rms} vs {expected}");
        assert!(c[0].abs() < 0.3 && c[1].abs() < 0.3, "{c:?}");
    }
}

/// `camera.json` naming a lens: `spreadlet synth` builds a physical-lens database for it (and
/// says which), and the image differs from the thin lens's; unknown lenses and broken
/// prescription files are clear errors with a non-zero exit.
#[test]
fn synth_follows_the_camera_lens() {
    let dir = tempfile::tempdir().expect("tmp");
    let cache = dir.path().join("cache");
    let d = |n: &str| dir.path().join(n).to_str().expect("utf-8").to_string();
    // A small rain scene through the singlet (the lens the quick tests can afford to build).
    let scene_json = scene::builtin_json("rain")
        .expect("rain")
        .replace("\"double-gauss-50mm\"", "\"singlet-51mm\"")
        .replace("\"f_stop\": 2.1", "\"f_stop\": 4.3");
    std::fs::write(d("rain.json"), scene_json).expect("write");
    let scene_args = [
        "render",
        &d("rain.json"),
        "--width",
        "96",
        "--gbuffer",
        &d("g.exr"),
        "--aa",
        "4",
        "--camera-out",
        &d("cam.json"),
        "--quiet",
    ];
    assert_success(&run("spreadlet-scene", &scene_args, &cache));
    let cam: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d("cam.json")).expect("cam")).expect("json");
    assert_eq!(cam["lens"], "singlet-51mm");
    let synth = |camera: &str, out: &str| {
        run(
            "spreadlet",
            &[
                "synth",
                "--input",
                &d("g.exr"),
                "--camera",
                camera,
                "--out",
                out,
                "--db-profile",
                "test",
                "--backend",
                "cpu",
                "--stats",
                &d("stats.json"),
            ],
            &cache,
        )
    };
    assert_success(&synth(&d("cam.json"), &d("phys.exr")));
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d("stats.json")).expect("stats"))
            .expect("json");
    let dbs = stats["databases"].as_array().expect("databases");
    assert_eq!(dbs.len(), 1, "{stats}");
    assert_eq!(dbs[0]["model"], "physical-lens");
    assert_eq!(dbs[0]["built_now"], true);
    assert_eq!(dbs[0]["lens"], "singlet-51mm");
    // The thin lens of the same focal length and f-number gives another image.
    let mut thin = cam.clone();
    thin.as_object_mut().expect("object").remove("lens");
    std::fs::write(d("thin.json"), thin.to_string()).expect("write");
    assert_success(&synth(&d("thin.json"), &d("thin.exr")));
    let a = formats::RgbaImage::read_exr(std::path::Path::new(&d("phys.exr"))).expect("phys");
    let b = formats::RgbaImage::read_exr(std::path::Path::new(&d("thin.exr"))).expect("thin");
    let diff: f64 = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .map(|(p, q)| f64::from((p[1] - q[1]).abs()))
        .sum::<f64>()
        / a.pixels.len() as f64;
    assert!(diff > 1e-3, "the lens changed nothing: {diff}");

    // Stochastic frames are labelled for the thin lens: reconstructing them through a real
    // lens is refused, not silently wrong.
    let thin_scene = std::fs::read_to_string(d("rain.json"))
        .expect("scene")
        .replace("\"lens\": \"singlet-51mm\",", "");
    std::fs::write(d("rain-thin.json"), thin_scene).expect("write");
    let frames_args = [
        "render",
        &d("rain-thin.json"),
        "--width",
        "48",
        "--stochastic",
        &d("frames.exr"),
        "--quiet",
    ];
    assert_success(&run("spreadlet-scene", &frames_args, &cache));
    let reconstruct = run(
        "spreadlet",
        &[
            "reconstruct",
            "--input",
            &d("frames.exr"),
            "--camera",
            &d("cam.json"),
            "--out",
            &d("x.exr"),
            "--db-profile",
            "test",
        ],
        &cache,
    );
    assert_clean_failure(&reconstruct, "real lens");

    // Bad lenses.
    let mut unknown = cam.clone();
    unknown["lens"] = "no-such-lens".into();
    std::fs::write(d("unknown.json"), unknown.to_string()).expect("write");
    assert_clean_failure(&synth(&d("unknown.json"), &d("x.exr")), "double-gauss-50mm");
    std::fs::write(d("broken.txt"), "0 1 0 10\n50 oops 1.5 12\n").expect("write");
    let mut broken = cam.clone();
    broken["lens"] = "broken.txt".into();
    std::fs::write(d("broken.json"), broken.to_string()).expect("write");
    assert_clean_failure(&synth(&d("broken.json"), &d("x.exr")), "line 2");
    assert!(
        !dir.path().join("x.exr").exists(),
        "a failed run left an output"
    );
}

/// Motion blur through a real lens: the falling-rain scene (drops falling and drifting, a
/// checkered box crossing the frame, shutter open the whole frame) through the singlet at
/// f/4.3, 128 px wide. The physical-lens synthesis (the lens PSF of each moving pixel smeared
/// along its motion) beats the thin lens of the same focal length and f-number with motion
/// blur, in SSIM and in FLIP, against the scene renderer's reference through the same lens;
/// the statistics say which pixels were smeared.
#[test]
fn motion_blur_through_a_real_lens_beats_the_thin_lens() {
    let dir = tempfile::tempdir().expect("tmp");
    let cache = spreadlet_e2e::cache_dir();
    let d = |n: &str| dir.path().join(n).to_str().expect("utf-8").to_string();
    let scene_path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scene/scenes/hard/falling-rain.json");
    let scene_json = std::fs::read_to_string(&scene_path)
        .expect("falling-rain scene")
        .replace("\"double-gauss-50mm\"", "\"singlet-51mm\"")
        .replace("\"f_stop\": 2.1", "\"f_stop\": 4.3");
    std::fs::write(d("scene.json"), scene_json).expect("write");
    let scene_args = [
        "render",
        &d("scene.json"),
        "--width",
        "128",
        "--gbuffer",
        &d("g.exr"),
        "--aa",
        "4",
        "--reference",
        &d("ref.exr"),
        "--ref-spp",
        "256",
        "--camera-out",
        &d("cam.json"),
        "--quiet",
    ];
    assert_success(&run("spreadlet-scene", &scene_args, &cache));
    let cam: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d("cam.json")).expect("cam")).expect("json");
    assert_eq!(cam["lens"], "singlet-51mm");
    assert_eq!(cam["shutter_frames"], 1.0);
    let mut thin = cam.clone();
    thin.as_object_mut().expect("object").remove("lens");
    std::fs::write(d("thin.json"), thin.to_string()).expect("write");
    let synth = |camera: &str, out: &str, stats: &str, backend: &str| {
        run(
            "spreadlet",
            &[
                "synth",
                "--input",
                &d("g.exr"),
                "--camera",
                camera,
                "--out",
                out,
                "--db-profile",
                "test",
                "--backend",
                backend,
                "--stats",
                stats,
            ],
            &cache,
        )
    };
    assert_success(&synth(
        &d("cam.json"),
        &d("phys.exr"),
        &d("phys.json"),
        "cpu",
    ));
    assert_success(&synth(
        &d("thin.json"),
        &d("thin.exr"),
        &d("thin-stats.json"),
        "cpu",
    ));
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d("phys.json")).expect("stats"))
            .expect("json");
    let dbs = stats["databases"].as_array().expect("databases");
    assert_eq!(dbs.len(), 1, "{stats}");
    assert_eq!(dbs[0]["model"], "physical-lens");
    let counts = &stats["synthesis"]["counts"];
    let smeared = counts["smeared"].as_u64().expect("smeared count");
    assert!(smeared > 500, "{counts}");
    // The same database named by hand (`--db`) serves the moving frame too.
    let db_path = dbs[0]["path"].as_str().expect("database path").to_string();
    let by_hand = run(
        "spreadlet",
        &[
            "synth",
            "--input",
            &d("g.exr"),
            "--camera",
            &d("cam.json"),
            "--out",
            &d("by-hand.exr"),
            "--db",
            &db_path,
            "--backend",
            "cpu",
        ],
        &cache,
    );
    assert_success(&by_hand);

    let read = |n: &str| formats::RgbaImage::read_exr(Path::new(&d(n))).expect(n);
    assert_eq!(
        read("by-hand.exr").pixels,
        read("phys.exr").pixels,
        "--db gave another image"
    );
    let score = |n: &str| compare_scores(Path::new(&d(n)), Path::new(&d("ref.exr")));
    let (phys, thin) = (score("phys.exr"), score("thin.exr"));
    println!("SSIM / FLIP mean: physical lens {phys:?}, thin lens {thin:?}");
    assert!(phys.0 > thin.0, "SSIM: physical {phys:?}, thin {thin:?}");
    assert!(phys.1 < thin.1, "FLIP: physical {phys:?}, thin {thin:?}");

    // The GPU draws the frame's own database (the smeared PSFs) as the CPU does (lavapipe in
    // CI).
    let ran = synth(&d("cam.json"), &d("gpu.exr"), &d("gpu.json"), "gpu");
    assert_gpu_run_matches(
        &ran,
        Path::new(&d("gpu.exr")),
        Path::new(&d("phys.exr")),
        "motion through a real lens",
    );
}

/// A sensor larger than the lens's image circle: the corner PSFs get no light, and the build
/// says so instead of writing a database of empty (NaN-normalised) PSFs.
#[test]
fn points_outside_the_image_circle_are_a_clear_error() {
    let mut cfg = BuildConfig::new(PsfModel::PhysicalLens, Profile::Test);
    cfg.lens = Some(LensOptions {
        prescription: Prescription::builtin("wide-angle-22mm"),
        focus_distance: 1.2,
        image_width_px: Some(256),
        depth_range: [0.3, 100.0],
        max_eccentricity_mm: 60.0,
        ..LensOptions::default()
    });
    let err = precompute::build_database(&cfg, false).expect_err("the corners see no light");
    assert!(err.to_string().contains("image circle"), "{err}");
}

/// The far corner drop of `corner-drops` (3 m, 20.8 mm off axis, the lens focused at 1.2 m):
/// the database's PSF for its cell keeps the size of the drop's own light-traced PSF, per
/// colour channel within 5 % in RMS radius (the cell's PSF pre-filtered over its
/// eccentricities too was 2-6 % larger), and the runtime's turn onto a radial direction 34
/// degrees off +x adds at most 4 % (a bilinear turn added 5-6 %). In the frame, against the
/// scene renderer's reference, the drop is 2-5 % large per channel (docs/BENCHMARKS.md).
#[test]
fn a_far_corner_drops_bokeh_keeps_its_size_through_the_database_and_the_turn() {
    let (drawn, own) = cell_and_own_psf(&corner_drops_plan(), 3.0, 20.8);
    let drawn = runtime_image(&drawn);
    let turned = spreadlet::motion_smear::turn(&drawn, 34f32.to_radians());
    let half = 12;
    let [drawn, turned, own] = [drawn, turned, runtime_image(&own)].map(|i| on_lattice(&i, half));
    let rms = |plane: &[f64]| {
        let m = moments_along(plane, half, [1.0, 0.0]);
        m[2].hypot(m[3])
    };
    for c in 0..3 {
        let (drawn_r, turned_r, own_r) = (rms(&drawn[c]), rms(&turned[c]), rms(&own[c]));
        println!(
            "channel {c}: RMS radius of the cell's PSF {drawn_r:.3} px, turned {turned_r:.3} px; \
             the drop's own {own_r:.3} px"
        );
        assert!(
            (drawn_r / own_r - 1.0).abs() < 0.05,
            "channel {c}: the cell's {drawn_r:.3} px against the drop's {own_r:.3} px"
        );
        assert!(
            turned_r / drawn_r - 1.0 < 0.04,
            "channel {c}: turned {turned_r:.3} px from {drawn_r:.3} px"
        );
    }
}

/// The physical-lens build of the `corner-drops` camera as the runtime makes it (512 x 344 px,
/// 36 mm sensor, double Gauss at f/2.1 focused at 1.2 m, 160 PSFs).
fn corner_drops_plan() -> BuildPlan {
    let (width, height, sensor_mm) = (512.0, 344.0, 36.0);
    let mut cfg = BuildConfig::new(PsfModel::PhysicalLens, Profile::Quick);
    cfg.psf_count = Some(160);
    cfg.lens = Some(LensOptions {
        prescription: Some(Prescription::builtin("double-gauss-50mm").expect("built-in")),
        f_stop: Some(2.1),
        focus_distance: 1.2,
        sensor_width_mm: sensor_mm,
        image_width_px: Some(width as u32),
        depth_range: [0.3, 1200.0],
        max_eccentricity_mm: 0.5 * f64::hypot(width, height) * sensor_mm / width,
        ..LensOptions::default()
    });
    BuildPlan::new(&cfg).expect("plan")
}

/// The PSF the database holds for the cell of a point `depth_m` from the lens and `ecc_mm` off
/// axis (traced as the builder traces it, over the cell's pre-filter box), and the point's own
/// light-traced PSF, 1.5 M rays each.
fn cell_and_own_psf(plan: &BuildPlan, depth_m: f64, ecc_mm: f64) -> (PsfImage, PsfImage) {
    let (cell, clamped) = plan.space.lookup([(1.0 / depth_m) as f32, ecc_mm as f32]);
    assert!(!clamped);
    let rays = 1_500_000;
    let (drawn, _) = trace_psf(
        plan.tracer.as_ref(),
        &plan.param_box(cell).expect("cell"),
        RayCount::Fixed(rays),
        &mut psf_rng(3, cell, 0),
        cell,
    )
    .expect("trace");
    (drawn, forward_psf(plan, depth_m, ecc_mm, rays))
}

/// `img` as the runtime holds a PSF image: RGB interleaved, origin relative to its centre.
fn runtime_image(img: &PsfImage) -> spreadlet::motion_smear::PsfImage {
    let mut data = vec![0f32; img.width * img.height * 3];
    for (c, plane) in img.planes.iter().enumerate() {
        for (i, v) in plane.iter().enumerate() {
            data[i * 3 + c] = *v;
        }
    }
    spreadlet::motion_smear::PsfImage {
        origin: [-(img.centre[0] as i32), -(img.centre[1] as i32)],
        width: img.width,
        height: img.height,
        channels: 3,
        data,
    }
}
