//! Where two results differ in quality: SSIM of A minus SSIM of B against a reference, per
//! tile, printed as a grid (`cargo run --release -p runtime --example tile_lab A.exr B.exr
//! REF.exr [TILE_PX]`); with `TX TY` after the tile size, also writes the tile of A, B and the
//! reference side by side, enlarged 4x, to /tmp/tile.png.

use anyhow::{bail, Context};
use formats::image::RgbaImage;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};

fn read(path: &str) -> anyhow::Result<RgbaImage> {
    let g = GBuffer::read_exr(std::path::Path::new(path), &ChannelOptions::default())
        .with_context(|| format!("reading {path}"))?;
    Ok(RgbaImage {
        width: g.width,
        height: g.height,
        pixels: g.color,
    })
}

fn ssim(a: &RgbaImage, b: &RgbaImage) -> anyhow::Result<f64> {
    let flat = |i: &RgbaImage| -> Vec<f32> { i.pixels.iter().flatten().copied().collect() };
    Ok(metrics::ssim_rgb(&flat(a), &flat(b), a.width, a.height)?)
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 4 {
        bail!("usage: tile_lab A.exr B.exr REF.exr [TILE_PX [TX TY]]");
    }
    let (a, b, r) = (read(&args[1])?, read(&args[2])?, read(&args[3])?);
    if (a.width, a.height) != (r.width, r.height) || (b.width, b.height) != (r.width, r.height) {
        bail!("the three images differ in size");
    }
    let number = |k: usize, default: usize| -> anyhow::Result<usize> {
        match args.get(k) {
            Some(s) => s
                .parse()
                .with_context(|| format!("argument {k} must be a number")),
            None => Ok(default),
        }
    };
    let n = number(4, 64)?.clamp(8, r.width.min(r.height));
    let crop = |img: &RgbaImage, x0: usize, y0: usize| RgbaImage {
        width: n,
        height: n,
        pixels: (0..n * n).map(|i| img.at(x0 + i % n, y0 + i / n)).collect(),
    };
    println!("A {:.4}  B {:.4}", ssim(&a, &r)?, ssim(&b, &r)?);
    for ty in 0..r.height / n {
        let mut line = String::new();
        for tx in 0..r.width / n {
            let (x0, y0) = (tx * n, ty * n);
            let d = ssim(&crop(&a, x0, y0), &crop(&r, x0, y0))?
                - ssim(&crop(&b, x0, y0), &crop(&r, x0, y0))?;
            line.push_str(&format!(" {d:+.3}"));
        }
        println!("{line}");
    }
    if args.len() >= 7 {
        let (tx, ty) = (number(5, 0)?, number(6, 0)?);
        if (tx + 1) * n > r.width || (ty + 1) * n > r.height {
            bail!("tile ({tx}, {ty}) is outside the image");
        }
        let scale = 4;
        let mut strip = RgbaImage::new(n * scale * 3, n * scale);
        for (k, img) in [&a, &b, &r].iter().enumerate() {
            for py in 0..n * scale {
                for px in 0..n * scale {
                    strip.pixels[py * strip.width + k * n * scale + px] =
                        img.at(tx * n + px / scale, ty * n + py / scale);
                }
            }
        }
        strip.write_png(std::path::Path::new("/tmp/tile.png"))?;
    }
    Ok(())
}
