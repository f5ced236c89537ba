//! From 8 samples per pixel, reconstruction is leaned towards each pixel's plain sample mean
//! where it departs from it by more than the samples' noise explains: on a texture finer than
//! reconstruction's placement keeps (stripes two pixels wide, in focus), the leaned image is
//! much nearer the stripes than the image as drawn.

mod support;

use psf_db::PsfModel;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use scene::{Sample, StochasticFrames};
use spreadlet::dbset::DbSet;
use spreadlet::synth::{render_cpu, SynthOptions};
use spreadlet::{Input, Plan, RgbaImage, SamplePlacement};
use support::{camera, test_db};

const SIZE: usize = 32;

/// The stripes' value at column `x`: two dark and two light columns alternating.
fn stripe(x: usize) -> f32 {
    if (x / 2).is_multiple_of(2) {
        0.1
    } else {
        0.8
    }
}

/// In-focus, still samples of the stripes, jittered within their pixel, each with noise of
/// +-0.1 (uniform).
fn frames(spp: usize) -> StochasticFrames {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut samples = Vec::with_capacity(SIZE * SIZE * spp);
    for _y in 0..SIZE {
        for x in 0..SIZE {
            for _ in 0..spp {
                let v = stripe(x) + rng.random_range(-0.1f32..0.1);
                samples.push(Sample {
                    color: [v, v, v, 1.0],
                    depth: 1.0, // the focus distance
                    lens: [
                        rng.random_range(-0.7f32..0.7),
                        rng.random_range(-0.7f32..0.7),
                    ],
                    time: 0.0,
                    motion: [0.0, 0.0],
                    jitter: [
                        rng.random_range(-0.5f32..0.5),
                        rng.random_range(-0.5f32..0.5),
                    ],
                });
            }
        }
    }
    StochasticFrames::new(SIZE, SIZE, spp, samples)
}

/// Mean squared error against the stripes over the frame's inner pixels (away from the
/// frame's edges).
fn error(image: &RgbaImage) -> f64 {
    let mut sum = 0.0;
    let mut n = 0;
    for y in 4..SIZE - 4 {
        for x in 4..SIZE - 4 {
            let d = (image.pixels[y * SIZE + x][1] - stripe(x)) as f64;
            sum += d * d;
            n += 1;
        }
    }
    sum / n as f64
}

fn reconstruct(frames: &StochasticFrames, lean: bool, dbs: &DbSet) -> RgbaImage {
    let cam = camera(SIZE as u32, SIZE as u32, true, 0.0);
    let mut options = SynthOptions::default();
    options.classify.lean_to_sample_means = lean;
    let plan = Plan::new(
        Input::Samples(frames, SamplePlacement::for_spp(frames.spp)),
        &cam,
        &options,
    )
    .expect("plan");
    render_cpu(plan.prepare(dbs).expect("prepare"), dbs).0
}

#[test]
fn a_texture_finer_than_the_placement_is_drawn_as_its_samples_say() {
    let dbs = DbSet::new(Some(test_db(PsfModel::ThinLens).clone()), None).expect("db set");
    let frames = frames(16);
    let drawn = reconstruct(&frames, false, &dbs);
    let leaned = reconstruct(&frames, true, &dbs);
    let (drawn_error, leaned_error) = (error(&drawn), error(&leaned));
    // The samples' own mean is off by their noise alone: 0.1^2 / 3 / 16.
    let noise = 0.01 / 3.0 / 16.0;
    assert!(
        drawn_error > 8.0 * noise,
        "precondition: the placement blurs the stripes ({drawn_error} against the noise {noise})"
    );
    // The correction is smoothed (0.8 px), so stripes this fine get a good half of it.
    assert!(
        leaned_error < 0.6 * drawn_error,
        "leaned {leaned_error}, drawn {drawn_error}, the samples' noise {noise}"
    );

    // Below 8 samples per pixel nothing is leaned.
    let few = frames.first_samples(4);
    assert_eq!(
        reconstruct(&few, true, &dbs).pixels,
        reconstruct(&few, false, &dbs).pixels
    );
}
