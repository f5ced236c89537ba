//! Reconstruction from 1 spp with each sample placement, against the plain averages of 1 and
//! 16 spp: `cargo run --release -p runtime --example recon_lab [SCENE] [SIZE]`, SCENE a
//! built-in name or a scene JSON file, SIZE a square size in pixels (default: the scene's).
//! Quick databases come from the cache (built when missing); `LAB_DB=FILE` replaces the
//! lens-motion one, `LAB_ALL=1` adds reconstructions from 2, 4 and 16 spp. The images go to
//! `$TMPDIR/recon_lab` for `tile_lab`.

use anyhow::Context;
use formats::image::RgbaImage;
use spreadlet::camera::Camera;
use spreadlet::reconstruct::{effects_of, SamplePlacement};
use spreadlet::synth::SynthOptions;
use spreadlet::{Input, Plan};

fn ssim(a: &RgbaImage, b: &RgbaImage) -> anyhow::Result<f64> {
    let flat = |i: &RgbaImage| -> Vec<f32> { i.pixels.iter().flatten().copied().collect() };
    Ok(metrics::ssim_rgb(&flat(a), &flat(b), a.width, a.height)?)
}

fn to_runtime(i: scene::RgbaImage) -> RgbaImage {
    RgbaImage {
        width: i.width,
        height: i.height,
        pixels: i.pixels,
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let name = args.get(1).map_or("crossing", String::as_str);
    let scene = if name.ends_with(".json") {
        scene::Scene::load(std::path::Path::new(name))?
    } else {
        scene::builtin(name)?
    };
    let scene = match args.get(2) {
        Some(s) => {
            let size: u32 = s.parse().context("SIZE must be a number of pixels")?;
            scene.with_size(size, size)?
        }
        None => scene,
    };
    let size = scene.camera_spec().width;
    let render = scene::RenderOptions {
        seed: 1,
        progress: false,
        ..Default::default()
    };
    let camera = Camera::from_json_str(&scene.camera_json())?;
    let frames = scene::render_stochastic(&scene, 16, &render)?;
    let reference = to_runtime(scene::render_reference(&scene, 1024, &render)?);
    let one = frames.first_samples(1);
    let effects = effects_of(&camera, &frames);
    let dbs = spreadlet_harness::demo::cached_dbs(
        effects,
        precompute::Profile::Quick,
        spreadlet::databases::aperture_of(&camera),
        false,
    )?;
    let dbs = match std::env::var("LAB_DB") {
        Ok(path) => {
            let main = spreadlet::condition::condition(&psf_db::PsfDatabase::read(&path)?)?.0;
            spreadlet::dbset::DbSet::new(dbs.thin_lens.clone(), Some(main))?
        }
        Err(_) => dbs,
    };
    let out = &std::env::temp_dir().join("recon_lab");
    std::fs::create_dir_all(out)?;
    let average_16 = to_runtime(frames.average());
    reference.write_exr(&out.join("reference.exr"))?;
    average_16.write_exr(&out.join("average_16spp.exr"))?;
    println!(
        "{name} {size}px: average_1spp {:.4}, average_16spp {:.4}",
        ssim(&to_runtime(one.average()), &reference)?,
        ssim(&average_16, &reference)?
    );
    let options = SynthOptions::default();
    let mut placements = vec![
        SamplePlacement::Nearest,
        SamplePlacement::Bilinear,
        SamplePlacement::Footprint { sigma_px: 0.5 },
        SamplePlacement::Footprint { sigma_px: 0.7 },
    ];
    placements.push(SamplePlacement::for_spp(1));
    for placement in placements {
        let prepared =
            Plan::new(Input::Samples(&one, placement), &camera, &options)?.prepare(&dbs)?;
        let (image, stats) = spreadlet::synth::render_cpu(prepared, &dbs);
        image.write_exr(&out.join(format!("reconstruct_{placement:?}.exr")))?;
        println!(
            "reconstruct_1spp, {placement:?} placement: {:.4} ({:.0} ms)",
            ssim(&image, &reference)?,
            stats.times.total_ms
        );
    }
    if std::env::var("LAB_ALL").is_ok() {
        for spp in [2usize, 4, 16] {
            let sub = frames.first_samples(spp);
            let (image, _) = spreadlet::reconstruct::reconstruct(&sub, &camera, &dbs, &options)?;
            println!("reconstruct_{spp}spp: {:.4}", ssim(&image, &reference)?);
        }
    }
    Ok(())
}
