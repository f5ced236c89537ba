//! SSIM and PSNR against hand-computed and external reference values.

use metrics::{psnr_rgb, srgb_encode, ssim_plane, ssim_rgb, MetricsError};

const W: usize = 32;
const H: usize = 24;

/// The test images of the scikit-image reference script (see `reference_values_from_scikit_image`).
fn image(which: u32) -> Vec<f32> {
    let mut out = Vec::with_capacity(W * H * 3);
    for y in 0..H {
        for x in 0..W {
            for c in 0..3 {
                let (xf, yf, cf) = (x as f64, y as f64, c as f64);
                let mut v = 0.5 + 0.6 * (0.3 * xf + 0.2 * yf + cf).sin();
                if which == 1 {
                    v += 0.15 * (0.7 * xf - 0.5 * yf + 2.0 * cf).cos();
                }
                out.push(v as f32);
            }
        }
    }
    out
}

fn channel(img: &[f32], stride: usize, c: usize) -> Vec<f32> {
    img.chunks_exact(stride).map(|p| p[c]).collect()
}

/// Reference numbers computed once with scikit-image 0.26.0 (numpy 2.4.6):
/// `structural_similarity(srgb(a), srgb(b), channel_axis=2, gaussian_weights=True, sigma=1.5,
/// use_sample_covariance=False, data_range=1.0)` on the images of [`image`] (built in f64 and
/// rounded to f32, sRGB = IEC 61966-2-1 after clipping to [0, 1]),
/// `peak_signal_noise_ratio(srgb(a), srgb(b), data_range=1.0)`, and the same SSIM call on the
/// linear red channels alone with `data_range=2.0`.
#[test]
fn reference_values_from_scikit_image() {
    let (a, b) = (image(0), image(1));
    let s = ssim_rgb(&a, &b, W, H).unwrap();
    assert!((s - 0.860_606_339_073_704_9).abs() < 1e-5, "ssim_rgb {s}");
    let p = psnr_rgb(&a, &b, W, H).unwrap();
    assert!((p - 18.840_623_622_958_383).abs() < 1e-4, "psnr_rgb {p}");
    let sp = ssim_plane(&channel(&a, 3, 0), &channel(&b, 3, 0), W, H, 2.0).unwrap();
    assert!(
        (sp - 0.767_740_486_351_003_1).abs() < 1e-5,
        "ssim_plane {sp}"
    );
}

#[test]
fn identical_images_score_one() {
    let a = image(1);
    assert!((ssim_rgb(&a, &a, W, H).unwrap() - 1.0).abs() < 1e-12);
    assert_eq!(psnr_rgb(&a, &a, W, H).unwrap(), f64::INFINITY);
    let r = channel(&a, 3, 1);
    assert!((ssim_plane(&r, &r, W, H, 1.0).unwrap() - 1.0).abs() < 1e-12);
}

#[test]
fn constant_images_are_the_luminance_term() {
    // Constant planes: variances and covariance vanish, SSIM = (2ab + C1) / (a^2 + b^2 + C1).
    let (a, b) = (0.3f32, 0.5f32);
    let c1 = (0.01f64 * 1.0).powi(2);
    let expect = (2.0 * 0.3 * 0.5 + c1) / (0.09 + 0.25 + c1);
    let s = ssim_plane(&vec![a; 20 * 15], &vec![b; 20 * 15], 20, 15, 1.0).unwrap();
    assert!((s - expect).abs() < 1e-6, "{s} vs {expect}");
    // Through sRGB: the same formula on the encoded values.
    let (ea, eb) = (srgb_encode(a) as f64, srgb_encode(b) as f64);
    let expect = (2.0 * ea * eb + c1) / (ea * ea + eb * eb + c1);
    let s = ssim_rgb(&vec![a; 20 * 15 * 3], &vec![b; 20 * 15 * 3], 20, 15).unwrap();
    assert!((s - expect).abs() < 1e-6, "{s} vs {expect}");
}

#[test]
fn alpha_is_ignored_and_order_does_not_matter() {
    let (a, b) = (image(0), image(1));
    let rgba = |img: &[f32], alpha: f32| -> Vec<f32> {
        img.chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], alpha])
            .collect()
    };
    let s3 = ssim_rgb(&a, &b, W, H).unwrap();
    let s4 = ssim_rgb(&rgba(&a, 1.0), &rgba(&b, 0.2), W, H).unwrap();
    assert!((s3 - s4).abs() < 1e-12);
    assert!((ssim_rgb(&b, &a, W, H).unwrap() - s3).abs() < 1e-12);
}

#[test]
fn srgb_curve() {
    assert_eq!(srgb_encode(0.0), 0.0);
    assert!((srgb_encode(1.0) - 1.0).abs() < 1e-6);
    assert_eq!(srgb_encode(7.0), srgb_encode(1.0));
    assert_eq!(srgb_encode(-1.0), 0.0);
    assert_eq!(srgb_encode(f32::NAN), 0.0);
    assert!((srgb_encode(0.18) - 0.4614).abs() < 1e-3);
}

#[test]
fn bad_sizes_are_errors() {
    let a = image(0);
    assert!(matches!(
        ssim_rgb(&a, &a[..a.len() - 3], W, H),
        Err(MetricsError::Size { .. })
    ));
    assert!(matches!(
        ssim_rgb(&a, &a, W + 1, H),
        Err(MetricsError::Size { .. })
    ));
    assert!(matches!(
        ssim_plane(&[0.0; 50], &[0.0; 50], 10, 5, 1.0),
        Err(MetricsError::TooSmall { .. })
    ));
    assert!(matches!(
        ssim_plane(&[0.0; 144], &[0.0; 144], 12, 12, 0.0),
        Err(MetricsError::DynamicRange(_))
    ));
}
