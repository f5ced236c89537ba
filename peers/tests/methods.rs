//! The by-name dispatch: names round-trip, each method runs on its input kind and refuses the
//! other.

mod support;

use peers::{GBufferView, InputKind, PeerError, PeerInput, PeerMethod};
use support::*;

#[test]
fn every_method_runs_by_name_on_its_input() {
    let scene = defocus_scene();
    let samples = scene.render(2, 4);
    let sview = scene.view(2, &samples);
    let n = 64 * 64;
    let color = vec![[0.5f32, 0.4, 0.3, 1.0]; n];
    let depth = vec![3.0f32; n];
    let motion = vec![[4.0f32, 0.0]; n];
    let g = GBufferView {
        width: 64,
        height: 64,
        color: &color,
        depth: &depth,
        motion: &motion,
    };
    for m in PeerMethod::ALL {
        assert_eq!(PeerMethod::from_name(m.name()), Some(m));
        let (right, wrong) = match m.input_kind() {
            InputKind::GBuffer => (PeerInput::GBuffer(g), PeerInput::Samples(sview)),
            InputKind::Samples => (PeerInput::Samples(sview), PeerInput::GBuffer(g)),
        };
        let out = m
            .run(&right)
            .unwrap_or_else(|e| panic!("{}: {e}", m.name()));
        assert_eq!(out.len(), n);
        assert!(
            out.iter().all(|p| p.iter().all(|v| v.is_finite())),
            "{}",
            m.name()
        );
        assert!(
            matches!(m.run(&wrong), Err(PeerError::Unsupported(_))),
            "{}",
            m.name()
        );
    }
    assert_eq!(PeerMethod::from_name("nope"), None);
}
