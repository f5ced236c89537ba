//! Prints the figures of single PSFs of a build: `cargo run --release -p precompute --example
//! inspect_psf -- MODEL PROFILE INDEX...`.

use precompute::{BuildConfig, BuildPlan, Profile};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        anyhow::bail!("usage: inspect_psf MODEL PROFILE INDEX...");
    }
    let mut cfg = BuildConfig::new(args[0].parse()?, args[1].parse::<Profile>()?);
    if let Ok(p) = std::env::var("PROCEDURE") {
        cfg.procedure = p.parse().map_err(|e: String| anyhow::anyhow!(e))?;
    }
    let plan = BuildPlan::new(&cfg)?;
    for a in &args[2..] {
        let i: u32 = a.parse()?;
        let p = plan.process(i)?;
        let r = &p.report;
        println!(
            "psf {i}: coords {:?} size {:?} rays {} support {} spreadlets {} sparsity {:.3} ssim {:.4} l1 {:.4}",
            r.coords, r.image_size, r.rays, r.dense_support, r.spreadlets, r.sparsity, r.similarity, r.l1
        );
    }
    Ok(())
}
