//! Reconstruction's sample footprint spreads a sparse sample over neighbouring pixels without
//! changing the PSF the sample is drawn with. (Widening the CoC instead moved in-focus moving
//! samples into coarser cells of the nested grid, whose streaks are pre-filtered over a much
//! wider range of motion lengths: on `rotating` at 1 spp that cost 0.008 SSIM.)

mod support;

use psf_db::PsfModel;
use scene::{Sample, StochasticFrames};
use spreadlet::dbset::DbSet;
use spreadlet::reconstruct::{effects_of, SamplePlacement};
use spreadlet::synth::SynthOptions;
use spreadlet::{Input, Plan};
use support::{camera, test_db};

/// Motion of the test sample, pixels per frame.
const MOTION_PX: f32 = 12.0;

#[test]
fn footprint_keeps_the_psf_of_an_in_focus_moving_sample() {
    let lens_motion = test_db(PsfModel::LensMotion);
    let minimum_old_coc = 1.128; // the CoC the old footprint widened in-focus samples to
    assert_ne!(
        lens_motion.lookup([0.0, MOTION_PX]).0,
        lens_motion.lookup([minimum_old_coc, MOTION_PX]).0,
        "precondition: the test database's nested grid puts these in different cells"
    );
    let dbs = DbSet::new(
        Some(test_db(PsfModel::ThinLens).clone()),
        Some(lens_motion.clone()),
    )
    .expect("db set");
    let cam = camera(32, 32, true, 1.0);
    let mut frames = StochasticFrames::new(32, 32, 1, vec![Sample::default(); 32 * 32]);
    frames.samples[16 * 32 + 12] = Sample {
        color: [1.0, 0.5, 0.25, 1.0],
        depth: 1.0, // the focus distance: CoC 0
        lens: [0.3, -0.2],
        time: 0.25,
        motion: [MOTION_PX, 0.0],
        jitter: [0.15, -0.3],
    };
    assert!(effects_of(&cam, &frames).motion);
    let mut options = SynthOptions::default();
    // One record per footprint pixel, of the lens-motion cell holding its parameters.
    options.classify.continuous_lookup = false;
    options.classify.smear_motion = false;
    let records = |placement| {
        Plan::new(Input::Samples(&frames, placement), &cam, &options)
            .and_then(|plan| plan.prepare(&dbs))
            .expect("prepare")
            .classified()
            .expect("records")
            .records
            .clone()
    };
    let nearest = records(SamplePlacement::Nearest);
    let footprint = records(SamplePlacement::for_spp(1));
    assert_eq!(nearest.len(), 1);
    assert!(footprint.len() > 4, "{} records", footprint.len());
    let expected = lens_motion.lookup([0.0, MOTION_PX]).0 + dbs.main_offset;
    assert_eq!(nearest[0].psf_index, expected);
    for r in &footprint {
        assert_eq!(r.psf_index, expected, "a footprint tap changed the PSF");
        assert_eq!((r.rot_cos, r.rot_sin), (1.0, 0.0));
    }
    let weight: f32 = footprint.iter().map(|r| r.weight).sum();
    assert!((weight - nearest[0].weight).abs() < 1e-5, "weight {weight}");
}
