//! The peer methods of `peers` run on the runtime's inputs, so that `spreadlet synth --method
//! NAME` compares them with spreadlet on the same G-buffer and camera (docs/PEERS.md).

use peers::{GBufferView, InputKind, PeerInput, PeerMethod};

use crate::camera::Camera;
use crate::gbuffer::GBuffer;
use crate::rgba::RgbaImage;

/// Errors of running a peer method.
#[derive(Debug, thiserror::Error)]
pub enum PeerRunError {
    /// The name is not a peer method.
    #[error("unknown method '{0}' (spreadlet, mcguire, guertin; reconstruction methods: shirley, shirley4, shirley-layered, vaidyanathan, munkberg, munkberg44)")]
    Unknown(String),
    /// The method reconstructs from stochastic samples, not from a G-buffer.
    #[error("method '{0}' reconstructs from stochastic samples, not from a pinhole G-buffer; it is not wired to `spreadlet reconstruct` yet")]
    NeedsSamples(&'static str),
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
}
