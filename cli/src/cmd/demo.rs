//! `spreadlet demo`: the whole job on built-in data (render a scene, synthesise, reconstruct,
//! score), the first command a new user runs.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

#[derive(Args, Debug)]
pub(crate) struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "out/demo")]
    pub(crate) out: PathBuf,
    /// Built-in scene (bokeh, crossing, occluder, rotating, physical, studio).
    #[arg(long, default_value = "crossing")]
    pub(crate) scene: String,
    /// Square image size override, pixels.
    #[arg(long)]
    pub(crate) size: Option<u32>,
    /// Samples per pixel of the reference.
    #[arg(long, default_value_t = 1024)]
    pub(crate) reference_spp: usize,
    /// Profile of databases built on demand.
    #[arg(long, default_value = "quick")]
    pub(crate) db_profile: String,
    /// Print no progress.
    #[arg(long, short)]
    pub(crate) quiet: bool,
}

/// Runs `spreadlet demo`.
pub(crate) fn run(args: DemoArgs) -> Result<()> {
    let options = spreadlet_harness::demo::DemoOptions {
        out: args.out.clone(),
        scene: args.scene,
        size: args.size,
        reference_spp: args.reference_spp,
        profile: args.db_profile.parse()?,
        progress: !args.quiet,
        ..Default::default()
    };
    let steps = spreadlet_harness::demo::run(&options)?;
    println!("{}", spreadlet_harness::demo::table(&steps));
    println!(
        "wrote {}: side_by_side.png (pinhole | synthesis | reconstruct_1spp | average_1spp | \
         average_16spp | reference), summary.json and the EXRs",
        args.out.display()
    );
    Ok(())
}
