//! `spreadlet study`: what accuracy costs in time, and the peer methods side by side (the
//! harness in `spreadlet_harness::study` and `spreadlet_harness::peer_study`).

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;

#[derive(Args, Debug)]
pub(crate) struct StudyArgs {
    /// Output folder (study.csv, study.md, study.png, study.json).
    #[arg(long, default_value = "out/study")]
    pub(crate) out: PathBuf,
    /// Built-in scene to render (bokeh, crossing, occluder, rotating, physical).
    #[arg(long, default_value = "occluder")]
    pub(crate) scene: String,
    /// Square image size of the built-in scene, pixels (default: the scene's).
    #[arg(long)]
    pub(crate) size: Option<u32>,
    /// Pinhole G-buffer (OpenEXR) to study instead of a built-in scene (with --camera and
    /// --reference).
    #[arg(long, requires_all = ["camera", "reference"])]
    pub(crate) input: Option<PathBuf>,
    /// Camera description of --input.
    #[arg(long)]
    pub(crate) camera: Option<PathBuf>,
    /// Reference image (OpenEXR) of --input.
    #[arg(long)]
    pub(crate) reference: Option<PathBuf>,
    /// Larger sweeps (takes longer).
    #[arg(long)]
    pub(crate) full: bool,
    /// Timed runs per configuration (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub(crate) runs: usize,
    /// Samples per pixel of the built-in scene's reference.
    #[arg(long, default_value_t = 256)]
    pub(crate) reference_spp: usize,
    /// Profile of databases built on demand.
    #[arg(long, default_value = "quick")]
    pub(crate) db_profile: String,
    /// Skip the GPU rows.
    #[arg(long)]
    pub(crate) no_gpu: bool,
    /// Run the peer comparison instead.
    #[arg(long)]
    pub(crate) peers: bool,
    /// Print no progress.
    #[arg(long, short)]
    pub(crate) quiet: bool,
}

/// Runs `spreadlet study`.
pub(crate) fn run(args: StudyArgs) -> Result<()> {
    if args.peers {
        return spreadlet_harness::peer_study::run(
            &spreadlet_harness::peer_study::PeerStudyOptions {
                out_dir: args.out,
                full: args.full,
                db_profile: args.db_profile,
                quiet: args.quiet,
            },
        );
    }
    let input = match (args.input, args.camera, args.reference) {
        (Some(gbuffer), Some(camera), Some(reference)) => {
            Some(spreadlet_harness::study::StudyInput {
                gbuffer,
                camera,
                reference,
            })
        }
        (None, None, None) => None,
        _ => bail!("--input, --camera and --reference go together"),
    };
    if args.runs == 0 || args.runs > 100 {
        bail!("--runs must be between 1 and 100, got {}", args.runs);
    }
    let options = spreadlet_harness::study::StudyOptions {
        out_dir: args.out.clone(),
        scene: args.scene,
        size: args.size,
        input,
        full: args.full,
        tiny: false,
        profile: args.db_profile.parse()?,
        runs: args.runs,
        reference_spp: args.reference_spp,
        gpu: !args.no_gpu,
        quiet: args.quiet,
    };
    let rows = spreadlet_harness::study::run(&options)?;
    let md = std::fs::read_to_string(args.out.join("study.md")).unwrap_or_default();
    let findings = md.split("## All configurations").next().unwrap_or_default();
    println!("{}", findings.trim_end());
    println!(
        "wrote {} rows to {} (study.csv, study.md, study.png, study.json)",
        rows.len(),
        args.out.display()
    );
    Ok(())
}
