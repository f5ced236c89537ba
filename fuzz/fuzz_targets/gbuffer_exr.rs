//! The G-buffer OpenEXR reader on arbitrary bytes (both layouts): an error or a G-buffer that
//! satisfies the reader's policy, never a panic or an unbounded allocation.
#![no_main]

use libfuzzer_sys::fuzz_target;
use spreadlet::gbuffer::{ChannelOptions, GBuffer, Layout};

fuzz_target!(|data: &[u8]| {
    for layout in [Layout::Auto, Layout::Plain] {
        let options = ChannelOptions {
            layout,
            ..ChannelOptions::default()
        };
        if let Ok(g) = GBuffer::read_exr_bytes(data, "<fuzz>", &options) {
            let n = g.width * g.height;
            assert!(n > 0 && n <= spreadlet::gbuffer::MAX_PIXELS);
            assert_eq!(g.color.len(), n);
            assert!(g.color.iter().all(|c| c.iter().all(|v| v.is_finite())));
            if let Some(d) = &g.depth {
                assert_eq!(d.len(), n);
                assert!(d.iter().all(|&d| d > 0.0));
            }
            if let Some(m) = &g.motion {
                assert_eq!(m.len(), n);
                assert!(m.iter().all(|v| v[0].is_finite() && v[1].is_finite()));
            }
        }
    }
});
