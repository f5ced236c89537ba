//! Prints percentiles of CoC radius and motion length (over the shutter) of a G-buffer:
//! `cargo run --release -p runtime --example gbuffer_stats -- IN.exr camera.json`.

use spreadlet::camera::Camera;
use spreadlet::gbuffer::{ChannelOptions, GBuffer};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(input), Some(cam)) = (args.get(1), args.get(2)) else {
        anyhow::bail!("usage: gbuffer_stats IN.exr camera.json");
    };
    let g = GBuffer::read_exr(input.as_ref(), &ChannelOptions::default())?;
    let cam = Camera::from_json_file(cam.as_ref())?;
    let lens = cam.thin_lens();
    let mut coc: Vec<f64> = Vec::new();
    let mut mot: Vec<f64> = Vec::new();
    let mut lum: Vec<f64> = Vec::new();
    for i in 0..g.width * g.height {
        let d = g.depth.as_ref().map_or(f32::INFINITY, |d| d[i]);
        coc.push(lens.map_or(0.0, |l| l.signed_coc_px(f64::from(d))));
        let m = g.motion.as_ref().map_or([0.0; 2], |m| m[i]);
        mot.push(f64::from(m[0].hypot(m[1])) * cam.shutter_frames);
        let c = g.color[i];
        lum.push(f64::from(0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]));
    }
    for (name, mut v) in [
        ("signed CoC px", coc),
        ("motion px", mot),
        ("luminance", lum),
    ] {
        v.sort_by(|a, b| a.total_cmp(b));
        let p = |q: f64| v[((v.len() - 1) as f64 * q) as usize];
        println!(
            "{name:>14}: min {:.3} p1 {:.3} p10 {:.3} p50 {:.3} p90 {:.3} p99 {:.3} p99.9 {:.3} max {:.3}",
            p(0.0), p(0.01), p(0.1), p(0.5), p(0.9), p(0.99), p(0.999), p(1.0)
        );
    }
    Ok(())
}
