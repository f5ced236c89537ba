//! Where results' light differs from a reference's: the frame, the bright region (reference
//! luminance above a threshold, 1 by default), a ring of 12 px round it, and the rest.
//! Stochastic frames are read as the plain per-pixel average of their samples.
//!
//! ```text
//! cargo run --release -p spreadlet --example energy_lab -- a.exr,b.exr,frames.exr reference.exr [THRESHOLD]
//! ```
use formats::gbuffer::{ChannelOptions, GBuffer};
use std::path::Path;

/// Rec. 709 luminance, as `spreadlet compare`'s mean luminance ratio weighs it.
fn lum(p: &[f32; 4]) -> f64 {
    0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2])
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let read = |p: &str| GBuffer::read_exr(Path::new(p), &ChannelOptions::default()).expect(p);
    let r = read(&args[2]);
    let thr: f64 = args.get(3).map_or(1.0, |s| s.parse().expect("threshold"));
    let (w, h) = (r.width, r.height);
    let want: Vec<f64> = r.color.iter().map(lum).collect();
    let bright: Vec<bool> = want.iter().map(|&v| v > thr).collect();
    let mut ring = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            if !bright[y * w + x] {
                continue;
            }
            for yy in y.saturating_sub(12)..(y + 13).min(h) {
                for xx in x.saturating_sub(12)..(x + 13).min(w) {
                    ring[yy * w + xx] = !bright[yy * w + xx];
                }
            }
        }
    }
    let rest: Vec<bool> = (0..w * h).map(|i| !bright[i] && !ring[i]).collect();
    let sum = |v: &[f64], m: &[bool]| -> f64 {
        v.iter().zip(m).filter(|(_, m)| **m).map(|(v, _)| v).sum()
    };
    let total_ref: f64 = want.iter().sum();
    println!(
        "reference: bright {:.1}%  ring {:.1}%  rest {:.1}% of energy; bright px {}",
        100.0 * sum(&want, &bright) / total_ref,
        100.0 * sum(&want, &ring) / total_ref,
        100.0 * sum(&want, &rest) / total_ref,
        bright.iter().filter(|b| **b).count()
    );
    for path in args[1].split(',') {
        let got: Vec<f64> = match formats::StochasticFrames::read_exr(Path::new(path)) {
            Ok(frames) => frames.average().pixels.iter().map(lum).collect(),
            Err(_) => read(path).color.iter().map(lum).collect(),
        };
        let all = vec![true; w * h];
        let excess = |m: &[bool]| (sum(&got, m) - sum(&want, m)) / total_ref * 100.0;
        println!("{path}: frame {:.4}  bright {:.4}  ring {:.4}  rest {:.4} | excess as % of frame: bright {:+.2} ring {:+.2} rest {:+.2}",
            sum(&got, &all) / total_ref, sum(&got, &bright) / sum(&want, &bright), sum(&got, &ring) / sum(&want, &ring), sum(&got, &rest) / sum(&want, &rest), excess(&bright), excess(&ring), excess(&rest));
    }
}
