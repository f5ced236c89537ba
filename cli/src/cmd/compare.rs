//! `spreadlet compare`: SSIM, PSNR, FLIP and the brightness of the frame's edges and of the
//! whole frame, of an EXR image against a reference (the terms are defined in `--help`).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};
use spreadlet::RgbaImage;

#[derive(Args, Debug)]
pub(crate) struct CompareArgs {
    /// First image (OpenEXR; Blender multilayer or plain RGBA).
    pub(crate) a: PathBuf,
    /// Second image.
    pub(crate) b: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub(crate) json: bool,
    /// Write FLIP's per-pixel error map (magma colour map, as NVIDIA's tool shows it) as PNG.
    #[arg(long)]
    pub(crate) flip_map: Option<PathBuf>,
}

/// The colour of an EXR file (G-buffer, multilayer or plain RGBA), its frame only.
fn read_rgba(path: &Path) -> Result<RgbaImage> {
    let mut g = GBuffer::read_exr(path, &ChannelOptions::default())?;
    if !g.overscan.is_none() {
        g = g.frame_only();
    }
    Ok(RgbaImage {
        width: g.width,
        height: g.height,
        pixels: g.color,
    })
}

/// Runs `spreadlet compare`.
pub(crate) fn run(args: CompareArgs) -> Result<()> {
    let a = read_rgba(&args.a)?;
    let b = read_rgba(&args.b)?;
    if (a.width, a.height) != (b.width, b.height) {
        bail!(
            "the images differ in size: {} is {}x{}, {} is {}x{}",
            args.a.display(),
            a.width,
            a.height,
            args.b.display(),
            b.width,
            b.height
        );
    }
    let fa: &[f32] = bytemuck::cast_slice(&a.pixels);
    let fb: &[f32] = bytemuck::cast_slice(&b.pixels);
    let (scores, flip) = metrics::score_rgb(fa, fb, a.width, a.height)?;
    if let Some(path) = &args.flip_map {
        write_rgb8_png(path, a.width, a.height, flip.magma_rgb8())?;
    }
    let e = scores.edge_luminance_ratio;
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "a": args.a,
                "b": args.b,
                "ssim": scores.ssim,
                "psnr_db": scores.psnr_db,
                "flip_mean": scores.flip_mean,
                "flip_p99": scores.flip_p99,
                "edge_luminance_ratio": e,
                "mean_luminance_ratio": scores.mean_luminance_ratio,
            })
        );
    } else {
        let psnr = scores
            .psnr_db
            .map_or("inf".to_string(), |p| format!("{p:.2}"));
        println!(
            "SSIM {:.4}  PSNR {psnr} dB  FLIP mean {:.4} p99 {:.4}  edge luminance ratio \
             (left, top, right, bottom) {:.3} {:.3} {:.3} {:.3}  mean luminance ratio {:.4}",
            scores.ssim,
            scores.flip_mean,
            scores.flip_p99,
            e.left,
            e.top,
            e.right,
            e.bottom,
            scores.mean_luminance_ratio
        );
    }
    Ok(())
}

/// Writes interleaved 8-bit RGB as a PNG, atomically.
fn write_rgb8_png(path: &Path, width: usize, height: usize, rgb: Vec<u8>) -> Result<()> {
    let buffer = image::RgbImage::from_raw(width as u32, height as u32, rgb)
        .context("an RGB buffer of the wrong size")?;
    formats::write_atomically(path, |file| {
        buffer
            .write_to(&mut std::io::BufWriter::new(file), image::ImageFormat::Png)
            .map_err(|source| formats::Error::Png {
                path: path.to_path_buf(),
                source,
            })
    })?;
    Ok(())
}
