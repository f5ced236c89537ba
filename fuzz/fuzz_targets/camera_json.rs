//! The camera.json parser on arbitrary text: an error or a camera that validates and whose
//! derived quantities are finite, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use spreadlet::camera::Camera;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(cam) = Camera::from_json_str(text) {
        assert!(cam.validate().is_ok());
        assert!(cam.pixels_per_mm().is_finite() && cam.pixels_per_mm() > 0.0);
        if let Some(lens) = cam.thin_lens() {
            for depth in [1e-6, 0.5, 1.0, 1e3, 1e30, f64::INFINITY] {
                let coc = lens.signed_coc_px(depth);
                assert!(!coc.is_nan(), "CoC at depth {depth} is NaN for {cam:?}");
            }
        }
    }
});
