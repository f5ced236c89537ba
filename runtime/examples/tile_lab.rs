//! Tile-wise SSIM of two results against a reference (lead's lab): A B REF [TILE].
use runtime::gbuffer::{ChannelOptions, GBuffer};
use runtime::rgba::RgbaImage;

fn read(p: &str) -> anyhow::Result<RgbaImage> {
    let g = GBuffer::read_exr(std::path::Path::new(p), &ChannelOptions::default())?;
    Ok(RgbaImage { width: g.width, height: g.height, pixels: g.color })
}
fn ssim(a: &RgbaImage, b: &RgbaImage) -> f64 {
    let fa: Vec<f32> = a.pixels.iter().flatten().copied().collect();
    let fb: Vec<f32> = b.pixels.iter().flatten().copied().collect();
    metrics::ssim_rgb(&fa, &fb, a.width, a.height).unwrap_or(f64::NAN)
}
fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let (x, y, r) = (read(&a[1])?, read(&a[2])?, read(&a[3])?);
    let n: usize = a.get(4).and_then(|s| s.parse().ok()).unwrap_or(64);
    let crop = |img: &RgbaImage, x0: usize, y0: usize| RgbaImage { width: n, height: n, pixels: (0..n * n).map(|i| img.get(x0 + i % n, y0 + i / n)).collect() };
    println!("A {:.4} B {:.4}", ssim(&x, &r), ssim(&y, &r));
    for ty in 0..r.height / n {
        let mut line = String::new();
        for tx in 0..r.width / n {
            let (x0, y0) = (tx * n, ty * n);
            line.push_str(&format!(" {:+.3}", ssim(&crop(&x, x0, y0), &crop(&r, x0, y0)) - ssim(&crop(&y, x0, y0), &crop(&r, x0, y0))));
        }
        println!("{line}");
    }
    if let (Some(tx), Some(ty)) = (a.get(5).and_then(|s| s.parse::<usize>().ok()), a.get(6).and_then(|s| s.parse::<usize>().ok())) {
        let imgs = [&x, &y, &r];
        let scale = 4;
        let mut strip = RgbaImage::new(n * scale * 3, n * scale);
        for (k, img) in imgs.iter().enumerate() {
            for py in 0..n * scale {
                for px in 0..n * scale {
                    strip.pixels[py * strip.width + k * n * scale + px] = img.get(tx * n + px / scale, ty * n + py / scale);
                }
            }
        }
        strip.write_preview_png(std::path::Path::new("/tmp/tile.png"))?;
    }
    Ok(())
}
