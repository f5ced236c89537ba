//! `spreadlet`: depth of field and motion blur by splatting sparse Laplacian PSFs.
//!
//! A thin front of the `spreadlet` library: each subcommand (in `cmd/`) parses its flags into
//! the library's options, calls [`spreadlet::Renderer`] or the harness, and writes the files.

mod cmd;

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "spreadlet",
    version,
    about = "Depth of field and motion blur by splatting sparse Laplacian PSFs (Leimkühler et al. 2018)",
    after_help = CACHE_HELP
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Where databases built on demand are kept, for `--help`.
const CACHE_HELP: &str = "PSF databases built on demand are cached in $SPREADLET_CACHE, else \
    $XDG_CACHE_HOME/spreadlet (~/.cache/spreadlet; ~/Library/Caches/spreadlet on macOS, \
    %LOCALAPPDATA%\\spreadlet on Windows).";

#[derive(Subcommand, Debug)]
enum Command {
    /// Synthesise depth of field and motion blur from a pinhole G-buffer (OpenEXR).
    #[command(after_help = CACHE_HELP)]
    Synth(cmd::synth::SynthArgs),
    /// Scores an image against a reference: SSIM, PSNR, FLIP and brightness ratios.
    ///
    /// SSIM: Wang et al. 2004 (Gaussian window, sigma 1.5; mean over R, G and B) on
    /// sRGB-encoded values clamped to [0, 1]; 1 is identical. PSNR: of the same values, in dB.
    /// FLIP: NVIDIA's perceptual difference (LDR mode, 67 pixels per degree) on the same
    /// values, its mean and 99th percentile; 0 is identical. Edge luminance ratio: the median
    /// luminance of the outer 4 px of each frame edge over the reference's (below 1 is a dark
    /// edge). Mean luminance ratio: the frame's mean linear luminance over the reference's
    /// (away from 1, light was added or lost).
    Compare(cmd::compare::CompareArgs),
    /// Reconstruct depth of field and motion blur from noisy stochastic frames (each sample
    /// labelled with its lens position and time; layout in docs/STOCHASTIC.md).
    #[command(after_help = CACHE_HELP)]
    Reconstruct(cmd::reconstruct::ReconstructArgs),
    /// The whole job on built-in data: render a scene, synthesise, reconstruct, score.
    Demo(cmd::demo::DemoArgs),
    /// Per-stage and total times of both backends at several sizes (median of runs), as a
    /// Markdown table.
    #[cfg(feature = "gpu")]
    Bench(cmd::bench::BenchArgs),
    /// What accuracy costs in time: sweeps of every knob and the dense and filter baselines on
    /// a scene, scored against a reference (CSV, Markdown, PNG; docs/STUDY.md).
    Study(cmd::study::StudyArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Synth(args) => cmd::synth::run(args),
        Command::Compare(args) => cmd::compare::run(args),
        Command::Reconstruct(args) => cmd::reconstruct::run(args),
        Command::Demo(args) => cmd::demo::run(args),
        #[cfg(feature = "gpu")]
        Command::Bench(args) => cmd::bench::run(args),
        Command::Study(args) => cmd::study::run(args),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
