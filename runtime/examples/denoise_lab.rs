//! How long the sample denoiser takes on a stochastic-frames file with guides: the median and
//! range of `ROUNDS` calls of `denoise::denoise_samples` alone (the samples already moved back
//! to the lens and shutter centre), and a checksum of its output.
//!
//! ```text
//! cargo run --release -p spreadlet --features harness --example denoise_lab -- frames.exr camera.json [ROUNDS]
//! ```
use spreadlet::{Camera, StochasticFrames};
use std::path::Path;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: denoise_lab FRAMES.exr CAMERA.json [ROUNDS]");
        std::process::exit(2);
    }
    let frames = StochasticFrames::read_exr(Path::new(&args[1])).expect("frames");
    let camera = Camera::from_json_file(Path::new(&args[2])).expect("camera");
    let rounds: usize = args.get(3).map_or(5, |s| s.parse().expect("rounds"));
    let Some(guides) = frames.guides.as_ref() else {
        eprintln!("{}: no denoiser guides", args[1]);
        std::process::exit(1);
    };
    let effects = spreadlet::reconstruct::effects_of(&camera, &frames);
    let moved = spreadlet::reconstruct::moved_samples(&frames, &camera, effects);
    let mut times = Vec::new();
    let mut checksum = 0.0f64;
    for _ in 0..rounds {
        let start = Instant::now();
        let out = spreadlet::denoise::denoise_samples(&frames, guides, &moved);
        times.push(start.elapsed().as_secs_f64() * 1e3);
        checksum = out.iter().flatten().map(|&v| f64::from(v)).sum();
    }
    times.sort_by(f64::total_cmp);
    println!(
        "{} samples: denoise {:.0} ms median ({:.0}-{:.0}), checksum {checksum:.6}",
        frames.samples.len(),
        times[times.len() / 2],
        times[0],
        times[times.len() - 1]
    );
}
