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
        noise(&plan, i)?;
        let recon =
            precompute::quality::integrate_spreadlets(&p.spreadlets, p.image.width, p.image.height);
        let masked: Vec<Vec<f32>> = recon
            .iter()
            .zip(&p.image.planes)
            .map(|(r, f)| {
                r.iter()
                    .zip(f)
                    .map(|(&a, &b)| if b == 0.0 { 0.0 } else { a })
                    .collect()
            })
            .collect();
        let max = p.image.max_value();
        let bg: f32 = recon[0]
            .iter()
            .zip(&p.image.planes[0])
            .filter(|(_, &b)| b == 0.0)
            .map(|(&a, _)| a.abs())
            .fold(0.0, f32::max);
        println!(
            "  ssim with the background zeroed {:.4}; max |background| / max {:.4}",
            precompute::quality::similarity(
                &masked,
                &p.image.planes,
                p.image.width,
                p.image.height
            ),
            bg / max
        );
    }
    Ok(())
}

/// Noise of the tracer: two traces with different seeds compared (L1, SSIM).
#[allow(dead_code)]
fn noise(plan: &BuildPlan, i: u32) -> anyhow::Result<()> {
    let params = plan.param_box(i)?;
    let mut r1 = precompute::sampler::psf_rng(11, i, 0);
    let mut r2 = precompute::sampler::psf_rng(12, i, 0);
    let (a, _) =
        precompute::trace::trace_psf(plan.tracer.as_ref(), &params, plan.rays, &mut r1, i)?;
    let (b, _) =
        precompute::trace::trace_psf(plan.tracer.as_ref(), &params, plan.rays, &mut r2, i)?;
    println!(
        "  noise: L1 between two traces {:.4}, SSIM {:.4}",
        precompute::quality::l1(&a.planes, &b.planes),
        precompute::quality::similarity(&a.planes, &b.planes, a.width, a.height)
    );
    Ok(())
}
