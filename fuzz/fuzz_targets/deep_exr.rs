//! The deep OpenEXR reader on arbitrary bytes: an error or a deep image that satisfies the
//! reader's policy (consistent offsets, samples sorted front to back at positive depths, alpha
//! in [0, 1], finite colours and motion), never a panic or an unbounded allocation.
#![no_main]

use libfuzzer_sys::fuzz_target;
use spreadlet::formats::DeepImage;

fuzz_target!(|data: &[u8]| {
    if let Ok(d) = DeepImage::read_bytes(data, "<fuzz>") {
        let n = d.width * d.height;
        assert!(n > 0 && n <= spreadlet::gbuffer::MAX_PIXELS);
        assert_eq!(d.offsets.len(), n + 1);
        assert_eq!(d.offsets[n], d.samples.len());
        for i in 0..n {
            let pixel = &d.samples[d.offsets[i]..d.offsets[i + 1]];
            assert!(pixel.windows(2).all(|w| w[0].depth <= w[1].depth));
            for s in pixel {
                assert!(s.depth > 0.0 && s.depth_back >= s.depth);
                assert!(s.color.iter().all(|v| v.is_finite()));
                assert!((0.0..=1.0).contains(&s.color[3]));
                assert!(s.motion.iter().all(|v| v.is_finite()));
            }
        }
    }
});
