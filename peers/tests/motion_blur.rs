//! Properties Guertin 2014 and McGuire 2012 state: still pixels stay sharp, and a moving thin
//! bar's blur spans its motion.

use peers::{guertin, mcguire, GBufferView, GuertinParams, McGuireParams, SampleSplit};

const W: usize = 64;
const H: usize = 64;

/// A static textured background at depth 10 with a vertical bar (columns `bar_x0..bar_x0+bar_w`,
/// depth 5, colour 1) moving by `motion_px` along +x over the shutter.
fn bar_scene(
    bar_x0: usize,
    bar_w: usize,
    motion_px: f32,
) -> (Vec<[f32; 4]>, Vec<f32>, Vec<[f32; 2]>) {
    let mut color = vec![[0.0; 4]; W * H];
    let mut depth = vec![10.0; W * H];
    let mut motion = vec![[0.0; 2]; W * H];
    for y in 0..H {
        for x in 0..W {
            let i = y * W + x;
            // Background texture: a checker of 0.1 / 0.2 grey (alpha 1).
            let g = if (x / 3 + y / 3) % 2 == 0 { 0.1 } else { 0.2 };
            color[i] = [g, g, g, 1.0];
            if (bar_x0..bar_x0 + bar_w).contains(&x) {
                color[i] = [1.0, 0.0, 0.0, 1.0];
                depth[i] = 5.0;
                motion[i] = [motion_px, 0.0];
            }
        }
    }
    (color, depth, motion)
}

fn view<'a>(c: &'a [[f32; 4]], d: &'a [f32], m: &'a [[f32; 2]]) -> GBufferView<'a> {
    GBufferView {
        width: W,
        height: H,
        color: c,
        depth: d,
        motion: m,
    }
}

type Method = fn(&GBufferView) -> Vec<[f32; 4]>;

fn run_guertin(g: &GBufferView) -> Vec<[f32; 4]> {
    guertin(g, &GuertinParams::default()).expect("valid input")
}
fn run_guertin_variance(g: &GBufferView) -> Vec<[f32; 4]> {
    let p = GuertinParams {
        split: SampleSplit::TileVariance,
        ..Default::default()
    };
    guertin(g, &p).expect("valid input")
}
fn run_mcguire(g: &GBufferView) -> Vec<[f32; 4]> {
    mcguire(g, &McGuireParams::default()).expect("valid input")
}

const METHODS: [(&str, Method); 3] = [
    ("guertin", run_guertin),
    ("guertin-variance", run_guertin_variance),
    ("mcguire", run_mcguire),
];

#[test]
fn a_fully_still_image_is_returned_unchanged() {
    let (c, d, _) = bar_scene(30, 2, 0.0);
    let m = vec![[0.0; 2]; W * H];
    for (name, f) in METHODS {
        let out = f(&view(&c, &d, &m));
        assert_eq!(out, c, "{name} changed a still image");
    }
}

#[test]
fn still_pixels_beside_a_moving_bar_stay_sharp() {
    // Motion 16 px: the blur spans +-8 px around the bar (columns 22..42). Pixels more than a
    // pixel beyond that lie in tiles whose NeighborMax is the bar's velocity, yet must keep
    // their own (textured) colour exactly.
    let (c, d, m) = bar_scene(30, 2, 16.0);
    for (name, f) in METHODS {
        let out = f(&view(&c, &d, &m));
        let mut checked = 0;
        for y in 0..H {
            for x in (0..W).filter(|&x| !(21..=42).contains(&x)) {
                let i = y * W + x;
                for ch in 0..4 {
                    assert!(
                        (out[i][ch] - c[i][ch]).abs() <= 1e-6,
                        "{name}: still pixel ({x},{y}) changed: {:?} vs {:?}",
                        out[i],
                        c[i]
                    );
                }
                checked += 1;
            }
        }
        assert!(checked > 2500);
    }
}

#[test]
fn a_moving_bar_blurs_over_its_motion() {
    // Bar of 2 px moving 16 px: the true streak covers 2 + 16 = 18 columns (27..45 exclusive
    // of the ramps' ends), centred on the bar's centre (x = 31).
    for motion in [12.0f32, 16.0, 24.0] {
        let (c, d, m) = bar_scene(30, 2, motion);
        for (name, f) in METHODS {
            let out = f(&view(&c, &d, &m));
            // Mean red excess over the background along the middle rows.
            let mut profile = vec![0.0f32; W];
            for y in 16..48 {
                for (x, p) in profile.iter_mut().enumerate() {
                    *p += (out[y * W + x][0] - out[y * W + x][1]) / 32.0;
                }
            }
            let on: Vec<usize> = (0..W).filter(|&x| profile[x] > 0.005).collect();
            let (first, last) = (on[0], on[on.len() - 1]);
            let extent = (last - first + 1) as f32;
            let centre = 0.5 * (first + last) as f32;
            let energy0: f32 = profile.iter().sum();
            eprintln!("{name} motion {motion}: streak {first}..={last} ({extent} px), red energy {energy0}");
            let expected = motion + 2.0;
            assert!(
                (extent - expected).abs() <= 3.0,
                "{name} motion {motion}: streak {first}..={last} ({extent} px), expected ~{expected}"
            );
            assert!(
                (centre - 30.5).abs() <= 1.0,
                "{name}: streak centred at {centre}"
            );
            // Blurred: the bar no longer reaches its full red anywhere (these filters do not
            // conserve energy exactly: their profiles are cone-shaped, so only bounds here).
            let peak = profile.iter().cloned().fold(0.0f32, f32::max);
            assert!(
                peak < 0.8,
                "{name} motion {motion}: peak {peak}, bar not blurred"
            );
            let energy: f32 = profile.iter().sum();
            assert!(energy > 1.0, "{name} motion {motion}: red energy {energy}");
            // Contiguous: no gaps inside the streak.
            assert_eq!(on.len(), last - first + 1, "{name}: streak has gaps");
        }
    }
}

#[test]
fn deterministic_and_rejects_bad_input() {
    let (c, d, m) = bar_scene(30, 2, 16.0);
    for (_, f) in METHODS {
        assert_eq!(f(&view(&c, &d, &m)), f(&view(&c, &d, &m)));
    }
    let mut bad = d.clone();
    bad[5] = f32::NAN;
    assert!(guertin(&view(&c, &bad, &m), &GuertinParams::default()).is_err());
    assert!(mcguire(&view(&c, &d, &m[1..]), &McGuireParams::default()).is_err());
    let p = GuertinParams {
        r: 0,
        ..Default::default()
    };
    assert!(guertin(&view(&c, &d, &m), &p).is_err());
}

#[test]
fn guertin_blurs_along_a_motion_that_the_dominant_velocity_hides() {
    // Thesis Sec. 3.4.1: a horizontal bar moving down (12 px) shares its tile neighbourhood
    // with a fast horizontal mover (60 px), so v_max is horizontal. McGuire samples only along
    // v_max and cannot blur the bar vertically; Guertin's second (perpendicular) direction
    // does.
    let (w, h) = (80usize, 80usize);
    let mut color = vec![[0.1f32, 0.1, 0.1, 1.0]; w * h];
    let mut depth = vec![10.0f32; w * h];
    let mut motion = vec![[0.0f32; 2]; w * h];
    for y in 5..15 {
        for x in 50..60 {
            color[y * w + x] = [0.0, 0.0, 1.0, 1.0];
            depth[y * w + x] = 5.0;
            motion[y * w + x] = [60.0, 0.0];
        }
    }
    for y in 30..32 {
        for x in 10..40 {
            color[y * w + x] = [1.0, 0.0, 0.0, 1.0];
            depth[y * w + x] = 5.0;
            motion[y * w + x] = [0.0, 12.0];
        }
    }
    let g = GBufferView {
        width: w,
        height: h,
        color: &color,
        depth: &depth,
        motion: &motion,
    };
    let gu = guertin(&g, &GuertinParams::default()).expect("guertin");
    let gv = run_guertin_variance(&g);
    let mc = mcguire(&g, &McGuireParams::default()).expect("mcguire");
    // Red excess in the rows the bar sweeps over (3 px above and below it).
    let red = |img: &[[f32; 4]], y: usize| -> f32 {
        (15..35)
            .map(|x| img[y * w + x][0] - img[y * w + x][1])
            .sum::<f32>()
            / 20.0
    };
    for y in [27usize, 28, 33, 34] {
        let (rg, rv, rm) = (red(&gu, y), red(&gv, y), red(&mc, y));
        eprintln!("row {y}: guertin red {rg:.3} (variance split {rv:.3}), mcguire red {rm:.3}");
        assert!(
            rg > 0.05,
            "guertin does not blur the bar onto row {y}: {rg}"
        );
        assert!(rv > 0.02, "guertin (variance split) misses row {y}: {rv}");
        assert!(
            rm < 0.01,
            "mcguire unexpectedly blurs the bar onto row {y}: {rm}"
        );
    }
}
