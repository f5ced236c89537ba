//! Reconstruction experiments (lead's lab; not part of the product).
use runtime::camera::Camera;
use runtime::pipeline::classify::{classify_fragments, resolve_model, Fragment};
use runtime::pipeline::{Effects, PathCounts};
use runtime::reconstruct::{effects_of, normalize_density};
#[allow(unused_imports)]
use runtime::reconstruct::SamplePlacement;
use runtime::rgba::RgbaImage;
use runtime::synth::{render_classified, SynthOptions, SynthStats};

fn ssim(a: &RgbaImage, b: &RgbaImage) -> f64 {
    let fa: Vec<f32> = a.pixels.iter().flatten().copied().collect();
    let fb: Vec<f32> = b.pixels.iter().flatten().copied().collect();
    metrics::ssim_rgb(&fa, &fb, a.width, a.height).unwrap()
}

fn frags(frames: &scene::StochasticFrames, camera: &Camera, effects: Effects, bilinear: bool, spp_used: usize) -> Vec<Fragment> {
    let lens = camera.thin_lens();
    let shutter = camera.shutter_frames as f32;
    let weight = 1.0 / spp_used as f32;
    let mut out = Vec::new();
    for (k, s) in frames.samples.iter().enumerate() {
        if k % frames.spp >= spp_used { continue; }
        let pixel = k / frames.spp;
        let (px, py) = ((pixel % frames.width) as f32, (pixel / frames.width) as f32);
        if s.color == [0.0; 4] { continue; }
        let coc = lens.map_or(0.0, |l| l.signed_coc_px(f64::from(s.depth)) as f32);
        let motion = if effects.motion { s.motion } else { [0.0; 2] };
        let qx = px + 0.5 + s.jitter[0] - coc * s.lens[0] - motion[0] * s.time;
        let qy = py + 0.5 + s.jitter[1] - coc * s.lens[1] - motion[1] * s.time;
        let base = Fragment { x: 0, y: 0, color: s.color, weight, parallax: 1.0 / s.depth, depth: s.depth, motion: [motion[0] * shutter, motion[1] * shutter] };
        if bilinear {
            let (fx, fy) = (qx - 0.5, qy - 0.5);
            let (x0, y0) = (fx.floor(), fy.floor());
            let (tx, ty) = (fx - x0, fy - y0);
            for (dx, dy, w) in [(0, 0, (1.0 - tx) * (1.0 - ty)), (1, 0, tx * (1.0 - ty)), (0, 1, (1.0 - tx) * ty), (1, 1, tx * ty)] {
                if w > 1e-4 {
                    let mut f = base;
                    f.x = x0 as i32 + dx;
                    f.y = y0 as i32 + dy;
                    f.color = s.color.map(|c| c * w);
                    out.push(f);
                }
            }
        } else {
            let mut f = base;
            f.x = qx.floor() as i32;
            f.y = qy.floor() as i32;
            out.push(f);
        }
    }
    out
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let name = args.get(1).map(String::as_str).unwrap_or("crossing");
    let size: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(256);
    let scene = scene::builtin(name)?.with_size(size, size)?;
    let render = scene::RenderOptions { seed: 1, progress: false, ..Default::default() };
    let camera = Camera::from_json_str(&scene.camera_json())?;
    let frames = scene::render_stochastic(&scene, 16, &render)?;
    let reference = scene::render_reference(&scene, 1024, &render)?;
    let reference = RgbaImage { width: reference.width, height: reference.height, pixels: reference.pixels.clone() };
    let effects = effects_of(&camera, &frames);
    let dbs = runtime::demo::cached_dbs(effects, precompute::Profile::Quick, camera.aperture_blades, false)?;
    let model = resolve_model(effects, &dbs)?;
    let avg = |n: usize| {
        let f = scene::StochasticFrames { width: frames.width, height: frames.height, spp: n, samples: frames.samples.chunks(16).flat_map(|c| c[..n].to_vec()).collect() };
        let a = f.average();
        RgbaImage { width: a.width, height: a.height, pixels: a.pixels }
    };
    println!("{name} {size}: avg1 {:.4} avg4 {:.4} avg16 {:.4}", ssim(&avg(1), &reference), ssim(&avg(4), &reference), ssim(&avg(16), &reference));
    let a16 = avg(16);
    let one = scene::StochasticFrames { width: frames.width, height: frames.height, spp: 1, samples: frames.samples.iter().step_by(16).copied().collect() };
    let mut opts = SynthOptions::default();
    opts.classify.min_coc_px = runtime::reconstruct::min_footprint_px(1);
    let (rec, _) = runtime::reconstruct::reconstruct(&one, &camera, &dbs, &opts)?;
    println!("recon1 {:.4}", ssim(&rec, &reference));
    let crop = |img: &RgbaImage, x0: usize, y0: usize, n: usize| RgbaImage { width: n, height: n, pixels: (0..n * n).map(|i| img.get(x0 + i % n, y0 + i / n)).collect() };
    let n = 32;
    for ty in 0..(size as usize / n) {
        let mut line = String::new();
        for tx in 0..(size as usize / n) {
            let (x0, y0) = (tx * n, ty * n);
            let r = ssim(&crop(&rec, x0, y0, n), &crop(&reference, x0, y0, n));
            let a = ssim(&crop(&a16, x0, y0, n), &crop(&reference, x0, y0, n));
            line.push_str(&format!(" {:+.3}", r - a));
        }
        println!("{line}");
    }
    let _ = (model, SynthStats::default(), frags, classify_fragments, normalize_density, render_classified, PathCounts::default());
    Ok(())
}
