//! Writes the sRGB PNG preview of an OpenEXR image and prints its channel means:
//! `cargo run --release -p runtime --example exr_preview -- IN.exr OUT.png`.

use formats::image::RgbaImage;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(input), Some(output)) = (args.get(1), args.get(2)) else {
        anyhow::bail!("usage: exr_preview IN.exr OUT.png");
    };
    let g = GBuffer::read_exr(input.as_ref(), &ChannelOptions::default())?;
    let img = RgbaImage {
        width: g.width,
        height: g.height,
        pixels: g.color,
    };
    let n = (img.width * img.height) as f64;
    let sums = img.channel_sums();
    println!(
        "{input}: {}x{}, channel means {:?}",
        img.width,
        img.height,
        sums.map(|s| s / n)
    );
    img.write_png(output.as_ref())?;
    Ok(())
}
