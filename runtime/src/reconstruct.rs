//! Reconstruction from stochastic frames (paper sec. 6.2, "Stochastic Frame-buffers").
//!
//! Every sample already sits where its lens position and time put it. Splatting its PSF there
//! would apply the PSF twice, so each sample's PSF is centred on the sensor position the sample
//! would have had through the lens centre at the shutter centre:
//!
//! ```text
//! q0 = p - c(d) * (u, v) - m * t
//! ```
//!
//! with `p` the sample's sensor position (pixel centre plus jitter), `c(d)` the signed CoC
//! radius at its depth, `(u, v)` its unit lens position, `m` its motion (pixels per frame) and
//! `t` its time (frames from the frame time); see `docs/STOCHASTIC.md`. The samples of one
//! pixel share its weight (1 / spp). Layering, splatting, integration and compositing are the
//! synthesis stages, unchanged.

use std::time::Instant;

use scene::StochasticFrames;

use crate::camera::Camera;
use crate::dbset::DbSet;
use crate::pipeline::classify::{classify_fragments, resolve_model, ClassifyError, Fragment};
use crate::pipeline::{Effects, PathCounts};
use crate::rgba::RgbaImage;
use crate::synth::{render_classified, SynthOptions, SynthStats};

/// The effects a camera and stochastic frames call for.
pub fn effects_of(camera: &Camera, frames: &StochasticFrames) -> Effects {
    Effects {
        defocus: camera.has_lens(),
        motion: camera.has_shutter()
            && frames
                .samples
                .iter()
                .any(|s| s.motion[0] != 0.0 || s.motion[1] != 0.0),
    }
}

/// One fragment per finite sample, centred where the lens centre at the shutter centre would
/// have put it. Returns the fragments and the number of samples dropped (non-finite labels).
pub fn sample_fragments(
    frames: &StochasticFrames,
    camera: &Camera,
    effects: Effects,
) -> (Vec<Fragment>, usize) {
    let lens = camera.thin_lens();
    let shutter = camera.shutter_frames as f32;
    let weight = 1.0 / frames.spp.max(1) as f32;
    let mut dropped = 0;
    let mut fragments = Vec::with_capacity(frames.samples.len());
    for (k, s) in frames.samples.iter().enumerate() {
        let pixel = k / frames.spp.max(1);
        let (px, py) = ((pixel % frames.width) as f32, (pixel / frames.width) as f32);
        if s.color == [0.0; 4] {
            continue; // carries nothing, whatever its labels
        }
        let finite = s.color.iter().all(|v| v.is_finite())
            && s.depth.is_finite()
            && s.depth > 0.0
            && s.lens
                .iter()
                .chain(&s.motion)
                .chain(&s.jitter)
                .all(|v| v.is_finite())
            && s.time.is_finite();
        if !finite {
            dropped += 1;
            continue;
        }
        let coc = lens.map_or(0.0, |l| l.signed_coc_px(f64::from(s.depth)) as f32);
        let motion = if effects.motion { s.motion } else { [0.0; 2] };
        // Continuous sensor position (pixel centres at +0.5), moved back to the lens centre and
        // the shutter centre.
        let qx = px + 0.5 + s.jitter[0] - coc * s.lens[0] - motion[0] * s.time;
        let qy = py + 0.5 + s.jitter[1] - coc * s.lens[1] - motion[1] * s.time;
        fragments.push(Fragment {
            x: qx.floor() as i32,
            y: qy.floor() as i32,
            color: s.color,
            weight,
            parallax: 1.0 / s.depth,
            depth: s.depth,
            motion: [motion[0] * shutter, motion[1] * shutter],
        });
    }
    (fragments, dropped)
}

/// Reconstructs depth of field and motion blur from stochastic frames with the synthesis
/// pipeline. `dbs` must hold a database of the model the camera and samples call for.
pub fn reconstruct(
    frames: &StochasticFrames,
    camera: &Camera,
    dbs: &DbSet,
    options: &SynthOptions,
) -> Result<(RgbaImage, SynthStats), ClassifyError> {
    if camera.width as usize != frames.width || camera.height as usize != frames.height {
        return Err(ClassifyError::SizeMismatch {
            cam_w: camera.width,
            cam_h: camera.height,
            img_w: frames.width,
            img_h: frames.height,
        });
    }
    let total = Instant::now();
    let effects = effects_of(camera, frames);
    let mut stats = SynthStats {
        defocus: effects.defocus,
        motion: effects.motion,
        width: frames.width,
        height: frames.height,
        layers: options.classify.layers,
        integrator: options.integrator,
        ..SynthStats::default()
    };
    let t = Instant::now();
    let model = resolve_model(effects, dbs)?;
    let (fragments, dropped) = sample_fragments(frames, camera, effects);
    let counts = PathCounts {
        dropped,
        ..PathCounts::default()
    };
    let classified = classify_fragments(
        &fragments,
        frames.width,
        frames.height,
        camera,
        dbs,
        model,
        &options.classify,
        counts,
    )?;
    stats.times.classify_ms = ms_since(t);
    let mut image = render_classified(&classified, dbs, options, &mut stats);
    normalize_density(&mut image);
    stats.times.total_ms = ms_since(total);
    Ok((image, stats))
}

/// Divides every pixel by its accumulated coverage. Samples moved back to their lens-centre
/// positions land unevenly (two in one pixel, none in its neighbour); with opaque samples the
/// coverage is the local sample density, and dividing by it is the normalisation of a
/// reconstruction filter (sum of weighted samples over sum of weights). Pixels no sample
/// reached stay as they are. Assumes the frame is opaque where samples hit something (misses
/// carry alpha 0 and do not count).
pub fn normalize_density(image: &mut RgbaImage) {
    for p in &mut image.pixels {
        let a = p[3];
        if a > 1e-3 {
            let inv = 1.0 / a;
            for v in p.iter_mut() {
                *v *= inv;
            }
        }
    }
}

/// The footprint radius (pixels) that makes `spp` samples per pixel overlap: a disk of area
/// `4 / spp` pixels, at least half a pixel.
pub fn min_footprint_px(spp: usize) -> f32 {
    (4.0 / (std::f32::consts::PI * spp.max(1) as f32))
        .sqrt()
        .max(0.5)
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;
    use scene::Sample;

    fn camera() -> Camera {
        Camera::from_json_str(
            r#"{"width":16,"height":16,"focal_length_mm":50,"sensor_width_mm":36,
            "f_stop":2.0,"focus_distance":1.0,"aperture_blades":0,"shutter_frames":1.0}"#,
        )
        .expect("camera")
    }

    /// A sample displaced by its lens offset and motion lands back on its pinhole pixel.
    #[test]
    fn samples_are_moved_back_to_the_lens_and_shutter_centre() {
        let cam = camera();
        let lens = cam.thin_lens().expect("lens");
        let depth = 2.0f32;
        let coc = lens.signed_coc_px(f64::from(depth)) as f32;
        let (qx, qy) = (5.5f32, 7.5f32); // pinhole position at t = 0: pixel (5, 7)
        let (u, v, t, m) = (0.6f32, -0.3f32, 0.25f32, [8.0f32, -4.0f32]);
        let (sx, sy) = (qx + coc * u + m[0] * t, qy + coc * v + m[1] * t);
        let (x, y) = (sx.floor() as usize, sy.floor() as usize);
        let mut frames = StochasticFrames {
            width: 16,
            height: 16,
            spp: 1,
            samples: vec![Sample::default(); 256],
        };
        frames.samples[y * 16 + x] = Sample {
            color: [1.0; 4],
            depth,
            lens: [u, v],
            time: t,
            motion: m,
            jitter: [sx - x as f32 - 0.5, sy - y as f32 - 0.5],
        };
        let effects = effects_of(&cam, &frames);
        assert!(effects.defocus && effects.motion);
        let (fragments, dropped) = sample_fragments(&frames, &cam, effects);
        assert_eq!(dropped, 0);
        assert_eq!(fragments.len(), 1);
        assert_eq!((fragments[0].x, fragments[0].y), (5, 7));
        assert_eq!(fragments[0].motion, m); // shutter 1 frame
    }

    #[test]
    fn non_finite_samples_are_dropped_and_counted() {
        let cam = camera();
        let mut frames = StochasticFrames {
            width: 16,
            height: 16,
            spp: 1,
            samples: vec![
                Sample {
                    color: [1.0; 4],
                    depth: 1.0,
                    ..Sample::default()
                };
                256
            ],
        };
        frames.samples[3].depth = f32::NAN;
        frames.samples[4].color[0] = f32::INFINITY;
        let (fragments, dropped) = sample_fragments(&frames, &cam, effects_of(&cam, &frames));
        assert_eq!(dropped, 2);
        assert_eq!(fragments.len(), 254);
    }
}
