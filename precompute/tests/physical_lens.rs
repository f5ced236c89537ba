//! The physical-lens PSFs show what a real singlet does: axial and lateral chromatic
//! aberration (red and blue differ in size and position) and cat-eye vignetting off axis
//! (the light is clipped by the lens rim, so the PSF gets narrower radially).

use precompute::prefilter::ParamBox;
use precompute::sampler::psf_rng;
use precompute::trace::{trace_psf, RayCount};
use precompute::{BuildConfig, BuildPlan, Profile, PsfImage};
use psf_db::PsfModel;

fn trace(plan: &BuildPlan, depth: f64, ecc: f64) -> (PsfImage, f64) {
    let params = ParamBox::fixed(&plan.space, [1.0 / depth, ecc]);
    let mut rng = psf_rng(1, 0, 0);
    let (img, stats) = trace_psf(
        plan.tracer.as_ref(),
        &params,
        RayCount::Fixed(600_000),
        &mut rng,
        0,
    )
    .unwrap();
    assert_eq!(stats.outside, 0, "rays fell outside the PSF image");
    (img, stats.blocked as f64 / stats.rays as f64)
}

/// Standard deviation of channel `c` along x and y, pixels.
fn spread(img: &PsfImage, c: usize) -> [f64; 2] {
    let m = img.centroid(c);
    let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
    for y in 0..img.height {
        for x in 0..img.width {
            let v = f64::from(img.planes[c][y * img.width + x]);
            let dx = x as f64 - img.centre[0] as f64 - m[0];
            let dy = y as f64 - img.centre[1] as f64 - m[1];
            sx += v * dx * dx;
            sy += v * dy * dy;
            s += v;
        }
    }
    [(sx / s).sqrt(), (sy / s).sqrt()]
}

fn plan() -> BuildPlan {
    BuildPlan::new(&BuildConfig::new(PsfModel::PhysicalLens, Profile::Quick)).unwrap()
}

#[test]
fn in_focus_on_axis_is_small_and_centred() {
    let plan = plan();
    let (img, blocked) = trace(&plan, 1.0, 0.0);
    // Focused (for the design wavelength) at 1 m: a few pixels of spherical and chromatic blur.
    let g = img.rms_radius(1);
    assert!(g < 6.0, "green rms radius {g} px");
    let c = img.centroid(1);
    assert!(c[0].abs() < 0.3 && c[1].abs() < 0.3, "{c:?}");
    assert!(blocked < 1e-3, "on axis nothing is vignetted: {blocked}");
}

#[test]
fn chromatic_aberration_red_and_blue_differ() {
    let plan = plan();
    // On axis, defocused (near): axial colour makes the red and blue disks differ in size.
    let (near, _) = trace(&plan, 0.45, 0.0);
    let (r, b) = (near.rms_radius(0), near.rms_radius(2));
    println!("on axis at 0.45 m: rms radius R {r:.2} px, B {b:.2} px");
    assert!((r - b).abs() > 0.03 * r.max(b), "R {r} B {b}");
    // In focus: blue (shorter focal length) is the blurriest.
    let (focus, _) = trace(&plan, 1.0, 0.0);
    assert!(focus.rms_radius(2) > focus.rms_radius(1));
    // Off axis: lateral colour moves the red and blue centroids apart radially.
    let (off, _) = trace(&plan, 1.0, 16.0);
    let (cr, cb) = (off.centroid(0), off.centroid(2));
    println!("at 16 mm: centroid R {cr:?}, B {cb:?} px");
    assert!((cr[0] - cb[0]).abs() > 0.5, "R {cr:?} B {cb:?}");
    assert!(
        (cr[1] - cb[1]).abs() < 0.2,
        "no tangential shift expected: R {cr:?} B {cb:?}"
    );
}

#[test]
fn cat_eye_vignetting_off_axis() {
    // The same lens with an oversized rim (nothing but the stop limits the beam) against the
    // real one: off axis the rim clips the beam on its outer side (the cat's eye), so the
    // PSF loses light and gets narrower radially (x) while its tangential extent (y) stays.
    let plan = plan();
    let mut wide = BuildConfig::new(PsfModel::PhysicalLens, Profile::Quick);
    wide.lens = Some(precompute::LensOptions {
        lens_diameter_mm: 30.0,
        ..Default::default()
    });
    let unclipped = BuildPlan::new(&wide).unwrap();
    let (centre, blocked_centre) = trace(&plan, 0.45, 0.0);
    let (edge, blocked_edge) = trace(&plan, 0.45, 18.0);
    let (free, blocked_free) = trace(&unclipped, 0.45, 18.0);
    let width = |img: &PsfImage, axis: usize| {
        let mut lo = i64::MAX;
        let mut hi = i64::MIN;
        for y in 0..img.height {
            for x in 0..img.width {
                if img.planes[1][y * img.width + x] > 1e-6 {
                    let v = if axis == 0 { x } else { y } as i64;
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
            }
        }
        (hi - lo + 1) as f64
    };
    let (sc, se, sf) = (spread(&centre, 1), spread(&edge, 1), spread(&free, 1));
    println!(
        "defocused at 0.45 m, spread (x, y) px: on axis {sc:?} (blocked {blocked_centre:.3}); \
         at 18 mm {se:?} (blocked {blocked_edge:.3}); at 18 mm without the rim {sf:?} \
         (blocked {blocked_free:.3}); support width x/y clipped {}/{}, free {}/{}",
        width(&edge, 0),
        width(&edge, 1),
        width(&free, 0),
        width(&free, 1)
    );
    assert!(
        (sc[0] / sc[1] - 1.0).abs() < 0.03,
        "on axis the blur is round"
    );
    assert!(blocked_edge > blocked_centre + 0.1);
    assert!(blocked_edge > blocked_free + 0.1);
    assert!(
        width(&edge, 0) < 0.9 * width(&free, 0),
        "the rim did not clip radially"
    );
    assert!(se[0] < 0.9 * sf[0], "{se:?} vs {sf:?}");
    assert!((width(&edge, 1) / width(&free, 1) - 1.0).abs() < 0.25);
}

/// A physical-lens PSF is traced at the middle of its eccentricities unless asked: the runtime
/// takes a box's PSF for every pixel in it with no blend across eccentricity, so the box's
/// average widened the bokeh at a corner. Along inverse depth it is traced at the middle of
/// its box where the runtime scales it onto each pixel's defocus (a few boxes or more from
/// the focus plane), and pre-filtered over the box nearer the focus plane, where it is blended
/// as it is; over every box when asked.
#[test]
fn a_psf_is_traced_at_the_middle_of_its_eccentricities() {
    let plan = plan();
    let mut spread_cfg = BuildConfig::new(PsfModel::PhysicalLens, Profile::Quick);
    spread_cfg.lens = Some(precompute::LensOptions {
        prefilter_eccentricity: true,
        ..Default::default()
    });
    let spread_plan = BuildPlan::new(&spread_cfg).unwrap();
    let mut depth_cfg = BuildConfig::new(PsfModel::PhysicalLens, Profile::Quick);
    depth_cfg.lens = Some(precompute::LensOptions {
        prefilter_inverse_depth: true,
        ..Default::default()
    });
    let depth_plan = BuildPlan::new(&depth_cfg).unwrap();
    assert_eq!(plan.space.psf_count(), spread_plan.space.psf_count());
    let focus = 1.0 / precompute::LensOptions::default().focus_distance;
    let (mut scaled, mut near_focus) = (0, 0);
    for i in 0..plan.space.psf_count() {
        let (depth, ecc) = {
            let r = plan.param_box(i).unwrap().range();
            (r[0], r[1])
        };
        let spread = spread_plan.param_box(i).unwrap().range();
        let cell = plan.space.cell_box(i).unwrap();
        if plan.space.blend_scales_cell(i, focus) {
            scaled += 1;
            assert_eq!(depth[0], depth[1], "PSF {i}: one inverse depth");
            assert!(cell.min[0] < depth[0] && depth[0] < cell.max[0]);
        } else {
            near_focus += 1;
            assert!(depth[1] > depth[0], "PSF {i}: inverse depths {depth:?}");
        }
        let all_depths = depth_plan.param_box(i).unwrap().range();
        assert_eq!(
            all_depths[0],
            [cell.min[0], cell.max[0]],
            "PSF {i}: over its box"
        );
        assert_eq!(ecc[0], ecc[1], "PSF {i}: one eccentricity");
        assert_eq!(
            depth, spread[0],
            "PSF {i}: the same inverse depths either way"
        );
        assert!(
            spread[1][0] < ecc[0] && ecc[0] < spread[1][1],
            "PSF {i}: {ecc:?} inside its box's {:?}",
            spread[1]
        );
    }
    assert!(
        scaled > 0 && near_focus > 0,
        "{scaled} scaled, {near_focus} near the focus plane"
    );
}
