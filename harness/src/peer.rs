//! The peer methods of `peers` run on the runtime's inputs, so that `spreadlet synth --method
//! NAME` and `spreadlet reconstruct --method NAME` compare them with spreadlet on the same
//! G-buffer, stochastic frames and camera (docs/PEERS.md).
//!
//! Effects a method does not reproduce: `vaidyanathan` and `shirley-layered` do defocus only,
//! `mcguire` and `guertin` motion blur only. [`reconstruct_peer`] refuses a sample method on a
//! frame with an effect it does not handle ([`PeerRunError::UnhandledEffect`]) unless the
//! caller allows it, and then names what was ignored in [`PeerRun::ignored`]: the CLI errors
//! by default (`--allow-unhandled-effects` runs it anyway), the study runs it and flags the row.

use spreadlet::synth::ms_since;
use std::time::Instant;

use peers::{GBufferView, InputKind, PeerInput, PeerMethod, SampleView};
use scene::StochasticFrames;

use formats::image::RgbaImage;
use spreadlet::camera::Camera;
use spreadlet::gbuffer::GBuffer;
use spreadlet::pipeline::Effects;
use spreadlet::reconstruct::effects_of;

/// Every method name `--method` accepts for `reconstruct`, ours first.
pub const RECONSTRUCT_METHODS: [&str; 7] = [
    "spreadlet",
    "shirley",
    "shirley4",
    "shirley-layered",
    "vaidyanathan",
    "munkberg",
    "munkberg44",
];

/// Checks that `name` is a `reconstruct` method (spreadlet or a sample-based peer), with the
/// error [`reconstruct_peer`] would give otherwise (unknown, or a G-buffer method).
pub fn check_reconstruct_method(name: &str) -> Result<(), PeerRunError> {
    if name == "spreadlet" {
        return Ok(());
    }
    let method = PeerMethod::from_name(name).ok_or_else(|| PeerRunError::Unknown(name.into()))?;
    if method.input_kind() != InputKind::Samples {
        return Err(PeerRunError::NeedsGBuffer(method.name()));
    }
    Ok(())
}

/// Errors of running a peer method.
#[derive(Debug, thiserror::Error)]
pub enum PeerRunError {
    /// The name is not a peer method.
    #[error("unknown method '{0}' (spreadlet, mcguire, guertin; reconstruction methods: shirley, shirley4, shirley-layered, vaidyanathan, munkberg, munkberg44)")]
    Unknown(String),
    /// The method reconstructs from stochastic samples, not from a G-buffer.
    #[error("method '{0}' reconstructs from stochastic samples, not from a pinhole G-buffer: use `spreadlet reconstruct --method {0}`")]
    NeedsSamples(&'static str),
    /// The method post-processes a pinhole G-buffer, not stochastic samples.
    #[error("method '{0}' post-processes a pinhole G-buffer, not stochastic samples: use `spreadlet synth --method {0}`")]
    NeedsGBuffer(&'static str),
    /// The input calls for an effect the method does not reproduce.
    #[error("method '{method}' does not handle {effect}, which this input has (use munkberg or shirley for defocus with motion, or allow it to run anyway and ignore the {effect})")]
    UnhandledEffect {
        /// The method.
        method: &'static str,
        /// The effect it would ignore ("motion blur" or "depth of field").
        effect: &'static str,
    },
    /// The camera and the frames disagree on the image size.
    #[error("the camera is {cam_w}x{cam_h} but the frames are {img_w}x{img_h}")]
    SizeMismatch {
        /// Camera width, pixels.
        cam_w: u32,
        /// Camera height, pixels.
        cam_h: u32,
        /// Frames width, pixels.
        img_w: usize,
        /// Frames height, pixels.
        img_h: usize,
    },
    /// The G-buffer lacks a pass the method needs.
    #[error("method '{method}' needs the {pass} pass")]
    MissingPass {
        /// The method.
        method: &'static str,
        /// The pass.
        pass: &'static str,
    },
    /// The method itself refused the input.
    #[error(transparent)]
    Peer(#[from] peers::PeerError),
}

/// The effects (of those `effects` calls for) that `method` does not reproduce, by name:
/// "motion blur" and/or "depth of field".
pub fn unhandled_effects(method: PeerMethod, effects: Effects) -> Vec<&'static str> {
    let mut out = Vec::new();
    if effects.defocus && !method.handles_defocus() {
        out.push("depth of field");
    }
    if effects.motion && !method.handles_motion() {
        out.push("motion blur");
    }
    out
}

/// A peer method's result on one frame.
#[derive(Clone, Debug)]
pub struct PeerRun {
    /// The reconstructed frame (linear, premultiplied RGBA).
    pub image: RgbaImage,
    /// Wall-clock time of the method alone, milliseconds (the conversion of the input to the
    /// peers' sample layout excluded: a few milliseconds).
    pub ms: f64,
    /// Effects of the input the method ignored (empty when it handles them all).
    pub ignored: Vec<&'static str>,
}

/// The stochastic frames in the peers' sample layout: the same samples, plus the signed CoC
/// radius (pixels) the camera's thin lens gives each depth (0 for a pinhole). Motion is zeroed
/// when `effects` has no motion blur (closed shutter), as the spreadlet reconstruction does.
pub fn peer_samples(
    frames: &StochasticFrames,
    camera: &Camera,
    effects: Effects,
) -> Vec<peers::Sample> {
    let lens = camera.thin_lens();
    frames
        .samples
        .iter()
        .map(|s| peers::Sample {
            jitter: s.jitter,
            color: s.color,
            depth: s.depth,
            lens: s.lens,
            time: s.time,
            motion: if effects.motion { s.motion } else { [0.0; 2] },
            coc: lens.map_or(0.0, |l| l.signed_coc_px(f64::from(s.depth)) as f32),
        })
        .collect()
}

/// Reconstructs depth of field and motion blur from stochastic frames with the sample-based
/// peer method `name` (shirley, shirley4, shirley-layered, vaidyanathan, munkberg,
/// munkberg44) and its default parameters, on the same samples and camera as
/// [`spreadlet::reconstruct::reconstruct`]. With `allow_unhandled` false, a method that does not
/// reproduce an effect the frames have is an error; with it true the method runs and
/// [`PeerRun::ignored`] names the effect.
pub fn reconstruct_peer(
    name: &str,
    frames: &StochasticFrames,
    camera: &Camera,
    allow_unhandled: bool,
) -> Result<PeerRun, PeerRunError> {
    let method = PeerMethod::from_name(name).ok_or_else(|| PeerRunError::Unknown(name.into()))?;
    if method.input_kind() != InputKind::Samples {
        return Err(PeerRunError::NeedsGBuffer(method.name()));
    }
    if camera.width as usize != frames.width || camera.height as usize != frames.height {
        return Err(PeerRunError::SizeMismatch {
            cam_w: camera.width,
            cam_h: camera.height,
            img_w: frames.width,
            img_h: frames.height,
        });
    }
    let effects = effects_of(camera, frames);
    let ignored = unhandled_effects(method, effects);
    if let (Some(effect), false) = (ignored.first(), allow_unhandled) {
        return Err(PeerRunError::UnhandledEffect {
            method: method.name(),
            effect,
        });
    }
    let samples = peer_samples(frames, camera, effects);
    let view = SampleView {
        width: frames.width,
        height: frames.height,
        spp: frames.spp,
        shutter_frames: if effects.motion {
            camera.shutter_frames as f32
        } else {
            0.0
        },
        samples: &samples,
    };
    let t = Instant::now();
    let pixels = method.run(&PeerInput::Samples(view))?;
    let ms = ms_since(t);
    Ok(PeerRun {
        image: RgbaImage {
            width: frames.width,
            height: frames.height,
            pixels,
        },
        ms,
        ignored,
    })
}

/// Motion blur by a G-buffer peer method (`mcguire` or `guertin`, which do no defocus). The
/// motion is the per-frame motion times the camera's shutter.
pub fn synthesize_peer(
    name: &str,
    gbuffer: &GBuffer,
    camera: &Camera,
) -> Result<RgbaImage, PeerRunError> {
    let method = PeerMethod::from_name(name).ok_or_else(|| PeerRunError::Unknown(name.into()))?;
    if method.input_kind() != InputKind::GBuffer {
        return Err(PeerRunError::NeedsSamples(method.name()));
    }
    let n = gbuffer.width * gbuffer.height;
    let depth = match &gbuffer.depth {
        Some(d) => d.clone(),
        None => vec![1e10; n],
    };
    let shutter = camera.shutter_frames as f32;
    let motion: Vec<[f32; 2]> = match (&gbuffer.motion, camera.has_shutter()) {
        (Some(m), true) => m.iter().map(|v| [v[0] * shutter, v[1] * shutter]).collect(),
        (None, true) => {
            return Err(PeerRunError::MissingPass {
                method: method.name(),
                pass: "motion vector",
            })
        }
        (_, false) => vec![[0.0; 2]; n],
    };
    let view = GBufferView {
        width: gbuffer.width,
        height: gbuffer.height,
        color: &gbuffer.color,
        depth: &depth,
        motion: &motion,
    };
    let pixels = method.run(&PeerInput::GBuffer(view))?;
    Ok(RgbaImage {
        width: gbuffer.width,
        height: gbuffer.height,
        pixels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(shutter: f64) -> Camera {
        Camera::from_json_str(&format!(
            r#"{{"width":24,"height":16,"focal_length_mm":50,"sensor_width_mm":36,
            "f_stop":null,"focus_distance":null,"shutter_frames":{shutter}}}"#
        ))
        .expect("camera")
    }

    fn gbuffer(motion_x: f32) -> GBuffer {
        let (w, h) = (24, 16);
        let color = (0..w * h)
            .map(|i| {
                let v = if (i % w) == 12 { 1.0 } else { 0.1 };
                [v, v, v, 1.0]
            })
            .collect();
        GBuffer::from_planes(
            w,
            h,
            color,
            Some(vec![2.0; w * h]),
            Some(vec![[motion_x, 0.0]; w * h]),
        )
        .expect("gbuffer")
    }

    #[test]
    fn still_input_comes_back_unchanged_from_both_methods() {
        let g = gbuffer(0.0);
        for m in ["mcguire", "guertin"] {
            let out = synthesize_peer(m, &g, &camera(1.0)).expect("runs");
            assert_eq!(out.pixels, g.color, "{m}");
        }
    }

    #[test]
    fn motion_spreads_a_bright_column_and_the_shutter_scales_it() {
        let g = gbuffer(8.0);
        let out = synthesize_peer("guertin", &g, &camera(1.0)).expect("runs");
        // The bright column at x = 12 is smeared horizontally: its neighbours brighten.
        let row = 8 * 24;
        assert!(out.pixels[row + 14][0] > 0.15, "{:?}", out.pixels[row + 14]);
        // With the shutter closed there is nothing to blur.
        let closed = synthesize_peer("guertin", &g, &camera(0.0)).expect("runs");
        assert_eq!(closed.pixels, g.color);
    }

    #[test]
    fn sample_methods_and_unknown_names_are_refused_by_name() {
        let g = gbuffer(0.0);
        let e = synthesize_peer("munkberg", &g, &camera(1.0)).unwrap_err();
        assert!(e.to_string().contains("stochastic samples"), "{e}");
        let e = synthesize_peer("nope", &g, &camera(1.0)).unwrap_err();
        assert!(e.to_string().contains("unknown method"), "{e}");
    }

    fn lens_camera(shutter: f64) -> Camera {
        Camera::from_json_str(&format!(
            r#"{{"width":24,"height":16,"focal_length_mm":50,"sensor_width_mm":4,
            "f_stop":1.4,"focus_distance":1.0,"aperture_blades":0,"shutter_frames":{shutter}}}"#
        ))
        .expect("camera")
    }

    /// 24x16 frames at 4 spp: a bright plane at 2 m (behind focus) with a stripe, moving
    /// `motion` px/frame; lens and time drawn from a fixed low-discrepancy pattern.
    fn frames(motion: [f32; 2]) -> StochasticFrames {
        let (w, h, spp) = (24, 16, 4);
        let mut samples = Vec::with_capacity(w * h * spp);
        for y in 0..h {
            for x in 0..w {
                for k in 0..spp {
                    let a = (k as f32 + 0.5) / spp as f32;
                    let angle = std::f32::consts::TAU * (a + 0.37 * (x + 3 * y) as f32);
                    let r = a.sqrt() * 0.9;
                    let v = if (x + k) % 7 == 0 { 1.0 } else { 0.2 };
                    samples.push(scene::Sample {
                        color: [v, 0.5 * v, 0.1, 1.0],
                        depth: 2.0,
                        lens: [r * angle.cos(), r * angle.sin()],
                        time: a - 0.5,
                        motion,
                        jitter: [a - 0.5, 0.5 - a - 0.125],
                    });
                }
            }
        }
        StochasticFrames::new(w, h, spp, samples)
    }

    #[test]
    fn reconstruction_equals_the_peers_crate_on_the_converted_samples() {
        let cam = lens_camera(1.0);
        let f = frames([3.0, -1.0]);
        let lens = cam.thin_lens().expect("lens");
        let coc = lens.signed_coc_px(2.0) as f32;
        assert!(coc > 1.0, "the plane is out of focus: {coc}");
        // An independent conversion: the CoC of the scene crate's camera formula.
        let samples: Vec<peers::Sample> = f
            .samples
            .iter()
            .map(|s| peers::Sample {
                jitter: s.jitter,
                color: s.color,
                depth: s.depth,
                lens: s.lens,
                time: s.time,
                motion: s.motion,
                coc,
            })
            .collect();
        let view = SampleView {
            width: 24,
            height: 16,
            spp: 4,
            shutter_frames: 1.0,
            samples: &samples,
        };
        for name in ["shirley", "shirley4", "munkberg", "munkberg44"] {
            let run = reconstruct_peer(name, &f, &cam, false).expect(name);
            assert!(run.ignored.is_empty(), "{name}: {:?}", run.ignored);
            let direct = PeerMethod::from_name(name)
                .expect("name")
                .run(&PeerInput::Samples(view))
                .expect("runs");
            assert_eq!(run.image.pixels, direct, "{name}");
            // And it did something: not the plain per-pixel average.
            let avg = f.average();
            assert_ne!(run.image.pixels, avg.pixels, "{name}");
        }
    }

    #[test]
    fn defocus_only_methods_refuse_motion_unless_allowed() {
        let cam = lens_camera(1.0);
        let moving = frames([3.0, 0.0]);
        for name in ["vaidyanathan", "shirley-layered"] {
            let e = reconstruct_peer(name, &moving, &cam, false).unwrap_err();
            assert!(
                matches!(
                    e,
                    PeerRunError::UnhandledEffect {
                        effect: "motion blur",
                        ..
                    }
                ),
                "{name}: {e}"
            );
            let run = reconstruct_peer(name, &moving, &cam, true).expect("allowed");
            assert_eq!(run.ignored, vec!["motion blur"], "{name}");
            // Still frames, or a closed shutter, are fine.
            let still = reconstruct_peer(name, &frames([0.0, 0.0]), &cam, false).expect("still");
            assert!(still.ignored.is_empty());
            assert!(reconstruct_peer(name, &moving, &lens_camera(0.0), false).is_ok());
        }
    }

    #[test]
    fn reconstruction_refuses_gbuffer_methods_and_size_mismatches() {
        let f = frames([0.0, 0.0]);
        let e = reconstruct_peer("guertin", &f, &lens_camera(1.0), false).unwrap_err();
        assert!(e.to_string().contains("synth --method guertin"), "{e}");
        let e = reconstruct_peer("nope", &f, &lens_camera(1.0), false).unwrap_err();
        assert!(e.to_string().contains("unknown method"), "{e}");
        let wide = Camera::from_json_str(
            r#"{"width":32,"height":16,"focal_length_mm":50,"sensor_width_mm":36}"#,
        )
        .expect("camera");
        let e = reconstruct_peer("shirley", &f, &wide, false).unwrap_err();
        assert!(matches!(e, PeerRunError::SizeMismatch { .. }), "{e}");
        let mut bad = f.clone();
        bad.samples[5].depth = f32::NAN;
        let e = reconstruct_peer("shirley", &bad, &lens_camera(1.0), false).unwrap_err();
        assert!(e.to_string().contains("not finite"), "{e}");
    }
}
