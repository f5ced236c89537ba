//! The splat records of one pixel and its two horizontal neighbours, and the dense PSFs 20-23
//! of the combined database (`cargo run --release -p runtime --example records_at G.exr
//! camera.json X Y`), to see how classification treats them.
use anyhow::{bail, Context};
fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() != 5 {
        bail!("usage: records_at G.exr camera.json X Y");
    }
    let g =
        spreadlet::gbuffer::GBuffer::read_exr(std::path::Path::new(&a[1]), &Default::default())?;
    let cam = spreadlet::camera::Camera::from_json_str(&std::fs::read_to_string(&a[2])?)?;
    let (x, y): (i32, i32) = (a[3].parse().context("x")?, a[4].parse().context("y")?);
    let effects = spreadlet::pipeline::Effects::of(&cam, &g);
    let dbs = spreadlet_harness::demo::cached_dbs(
        effects,
        precompute::Profile::Quick,
        spreadlet::databases::aperture_of(&cam),
        false,
    )?;
    let c = spreadlet::pipeline::classify(&g, &cam, &dbs, &Default::default())?;
    let pad = c.frame.pad as i32;
    for r in &c.records {
        if (r.center_x - pad - x).abs() <= 1 && r.center_y - pad == y {
            println!("{r:?}");
        }
    }
    if let Some(db) = dbs.combined.as_ref() {
        println!("{} PSFs in the combined database", db.psf_count());
        for i in [20usize, 21, 22, 23] {
            if let Some(d) = db.dense(i) {
                let (mut sum, mut mx, mut my) = (0.0f64, 0.0f64, 0.0f64);
                let ch = db.channels();
                for yy in 0..d.height {
                    for xx in 0..d.width {
                        let v = f64::from(d.data[(yy * d.width + xx) * ch]);
                        sum += v;
                        mx += v * (xx as f64 + f64::from(d.origin[0]));
                        my += v * (yy as f64 + f64::from(d.origin[1]));
                    }
                }
                let row: Vec<String> = (0..d.width * d.height)
                    .map(|k| format!("{:.3}", d.data[k * ch]))
                    .collect();
                println!("  {}", row.join(" "));
                println!(
                    "PSF {i}: dense {}x{} at {:?}, sum {sum:.4}, centroid ({:.3}, {:.3})",
                    d.width,
                    d.height,
                    d.origin,
                    mx / sum,
                    my / sum
                );
            }
        }
    }
    Ok(())
}
