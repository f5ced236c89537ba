//! Developer probe (not part of the tool): sparsification variants on cached quick lens-motion
//! PSFs. `cargo run --release -p precompute --example probe -- PROC BUDGET[,BUDGET..] [LAMBDA]`
use std::io::{Read, Write};

use precompute::image::PsfImage;
use precompute::quality::{integrate_spreadlets, l1, similarity};
use precompute::sampler::psf_rng;
use precompute::sparsify::{sparsify, SparsifyOptions, Target};
use precompute::{BuildConfig, BuildPlan, Procedure, Profile};
use psf_db::PsfModel;
use rayon::prelude::*;

fn load(plan: &BuildPlan, i: u32) -> PsfImage {
    let path = format!("/tmp/psfcache/{i}.bin");
    if let Ok(mut f) = std::fs::File::open(&path) {
        let mut b = Vec::new();
        f.read_to_end(&mut b).unwrap();
        let u = |k: usize| u32::from_le_bytes(b[4 * k..4 * k + 4].try_into().unwrap()) as usize;
        let (w, h, cx, cy) = (u(0), u(1), u(2), u(3));
        let mut img = PsfImage::zeros(w, h, [cx, cy], 1);
        for k in 0..w * h {
            img.planes[0][k] = f32::from_le_bytes(b[16 + 4 * k..20 + 4 * k].try_into().unwrap());
        }
        return img;
    }
    let (img, _) = plan.trace(i).unwrap();
    let mut b = Vec::new();
    for v in [img.width, img.height, img.centre[0], img.centre[1]] {
        b.extend((v as u32).to_le_bytes());
    }
    for v in &img.planes[0] {
        b.extend(v.to_le_bytes());
    }
    std::fs::create_dir_all("/tmp/psfcache").unwrap();
    std::fs::File::create(&path).unwrap().write_all(&b).unwrap();
    img
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let proc: Procedure = args[1].parse().unwrap();
    let budgets: Vec<f64> = args[2].split(',').map(|b| b.parse().unwrap()).collect();
    let lambda: f64 = args.get(3).map_or(0.0, |l| l.parse().unwrap());
    let cfg = BuildConfig::new(PsfModel::LensMotion, Profile::Quick);
    let plan = BuildPlan::new(&cfg).unwrap();
    let idx: Vec<u32> = (14..plan.space.psf_count()).collect();
    let _ = (budgets, lambda);
    // All rungs per PSF: (sparsity, similarity, l1, support).
    let table: Vec<(u32, usize, Vec<(f64, f64, f64)>)> = idx
        .par_iter()
        .map(|&i| {
            let img = load(&plan, i);
            let (w, h) = (img.width, img.height);
            let t = Target::new(&img, proc.split_signs());
            let support = img.support();
            let rungs = (-3..=4)
                .map(|k| {
                    let b = 2f64.powf(0.5 * k as f64);
                    let opts = SparsifyOptions { procedure: proc, budget: b, ..SparsifyOptions::default() };
                    let s = sparsify(&t, &opts, &mut psf_rng(1, i, 1)).spreadlets;
                    let rec = integrate_spreadlets(&s, w, h);
                    (s.len() as f64 / support as f64, similarity(&rec, &img.planes, w, h), l1(&rec, &img.planes))
                })
                .collect();
            (i, support, rungs)
        })
        .collect();
    for lam in [0.2, 0.25, 0.3, 0.35, 0.4] {
        for full in [false, true] {
            let (mut ss, mut sm, mut k) = (0.0, 0.0, 0);
            for (_, support, r) in &table {
                let sc = |j: usize| r[j].1 - lam * r[j].0;
                let pick = if full {
                    (0..r.len()).max_by(|&a, &b| sc(a).total_cmp(&sc(b))).unwrap()
                } else {
                    let mut best = 3usize;
                    for dir in [1i32, -1] {
                        let mut j = 3i32 + dir;
                        let mut moved = false;
                        while j >= 0 && j < r.len() as i32 {
                            if sc(j as usize) > sc(best) { best = j as usize; moved = true; j += dir; } else { break; }
                        }
                        if moved { break; }
                    }
                    best
                };
                let (sp, sim, e) = r[pick];
                let dense = sp > 0.5 || ((sim < 0.9 || e > 0.15) && *support <= 4096);
                if !dense { ss += sp; sm += sim; k += 1; }
            }
            println!("{} lambda {lam} full-ladder {full}: sparse-stored {k}: sparsity {:.4} similarity {:.4}", proc.name(), ss / k as f64, sm / k as f64);
        }
    }
}
