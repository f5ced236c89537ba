//! Property tests of the layer binning in `spreadlet::pipeline::classify`: every
//! fragment lands in exactly one layer with its whole weight, or (soft layering) in two
//! neighbouring layers whose weights sum to its weight; the layer is monotone in parallax
//! (so in signed CoC: nearer, more negative CoC, is a higher layer); hard layers hold the
//! fragment's parallax inside their bin; and records come out sorted by layer.

use proptest::prelude::*;
use psf_db::{DatabaseBuilder, DbHeader, ParamSpace, PsfModel};
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::pipeline::classify::{classify_fragments, DataWindow, Fragment};
use spreadlet::pipeline::{ClassifyOptions, PathCounts};

fn camera(w: u32) -> Camera {
    Camera {
        width: w,
        height: 1,
        focal_length_mm: 50.0,
        sensor_width_mm: 36.0,
        f_stop: Some(2.0),
        focus_distance: Some(1.0),
        aperture_blades: 0,
        aperture_rotation_deg: 0.0,
        aperture_ratio: 1.0,
        aperture_image: None,
        lens: None,
        shutter_frames: 0.0,
        scene_unit_mm: 1000.0,
    }
}

/// A thin-lens database of one-spreadlet PSFs (binning does not look at their shape).
fn dbs() -> DbSet {
    let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 32.0]], 8).expect("space");
    let mut b = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space.clone(), 64));
    for _ in 0..space.psf_count() {
        b.push_sparse(&[[0, 0]], &[-1.0]).expect("push");
    }
    DbSet::single(b.finish().expect("db")).expect("set")
}

/// Per fragment (one per pixel of a `n x 1` frame): its records as (layer, weight).
fn bin(
    fragments: &[Fragment],
    options: &ClassifyOptions,
) -> (Vec<Vec<(u32, f32)>>, spreadlet::pipeline::Classified) {
    let n = fragments.len();
    let c = classify_fragments(
        fragments.to_vec(),
        n,
        1,
        DataWindow::frame(n, 1),
        &camera(n as u32),
        &dbs(),
        Some(PsfModel::ThinLens),
        options,
        PathCounts::default(),
    )
    .expect("classify");
    let mut per = vec![Vec::new(); n];
    for r in &c.records {
        // Only the frame's own records: the extension beyond its edges repeats them.
        let (x, y) = (
            r.center_x - c.frame.pad as i32,
            r.center_y - c.frame.pad as i32,
        );
        if y == 0 && (0..n as i32).contains(&x) {
            per[x as usize].push((r.layer, r.weight));
        }
    }
    (per, c)
}

fn fragments_from(parallax: &[f32], weights: &[f32]) -> Vec<Fragment> {
    parallax
        .iter()
        .zip(weights)
        .enumerate()
        .map(|(x, (&p, &w))| Fragment {
            x: x as i32,
            y: 0,
            color: [0.5, 0.25, 1.0, 1.0],
            weight: w,
            parallax: p,
            depth: 1.0 / p,
            motion: [0.0, 0.0],
            bend: 0.0,
            source: 0,
        })
        .collect()
}

/// Mean layer of a fragment's records, weighted.
fn mean_layer(recs: &[(u32, f32)]) -> f64 {
    let w: f64 = recs.iter().map(|r| f64::from(r.1)).sum();
    recs.iter()
        .map(|r| f64::from(r.0) * f64::from(r.1))
        .sum::<f64>()
        / w
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    #[test]
    fn every_fragment_lands_once_or_in_two_neighbours(
        parallax in prop::collection::vec(0.05f32..20.0, 1..48),
        weight_seed in prop::collection::vec(0.01f32..1.0, 48),
        layers in 1u32..17,
        soft in prop_oneof![Just(None), (0.05f32..1.0).prop_map(Some)],
    ) {
        let weights = &weight_seed[..parallax.len()];
        let frags = fragments_from(&parallax, weights);
        let options = ClassifyOptions {
            layers,
            soft_layers: soft,
            edge_split: false,
            // Soft layering of every fragment, however sharp or still (the binning under
            // test).
            soft_layers_min_blur_px: 0.0,
            continue_layers: false,
            // One PSF per layer target: no blend of neighbouring cells.
            continuous_lookup: false,
            ..ClassifyOptions::default()
        };
        let (per, c) = bin(&frags, &options);
        prop_assert!(c.records.windows(2).all(|p| p[0].layer <= p[1].layer), "sorted by layer");
        prop_assert_eq!(c.layers.len() as u32, layers);
        for (i, recs) in per.iter().enumerate() {
            let w = weights[i];
            match recs.as_slice() {
                [(l, rw)] => {
                    prop_assert!(*l < layers);
                    prop_assert!((rw - w).abs() <= 1e-6 * w, "one record of weight {} for {}", rw, w);
                    if soft.is_none() {
                        let info = &c.layers[*l as usize];
                        let p = parallax[i];
                        let tol = 1e-5 * p.abs().max(1.0);
                        prop_assert!(p >= info.parallax_min - tol && p <= info.parallax_max + tol,
                            "parallax {} outside layer {} [{}, {}]", p, l, info.parallax_min, info.parallax_max);
                    }
                }
                [(a, wa), (b, wb)] => {
                    prop_assert!(soft.is_some(), "two records need soft layering");
                    prop_assert_eq!(*a + 1, *b, "neighbouring layers");
                    prop_assert!(*wa > 0.0 && *wb > 0.0);
                    prop_assert!((wa + wb - w).abs() <= 1e-6, "weights {} + {} != {}", wa, wb, w);
                }
                other => prop_assert!(false, "fragment {} has records {:?}", i, other),
            }
        }
        // Monotone in parallax: a nearer fragment (larger parallax, more negative signed CoC)
        // never sits in a farther layer.
        let lens = camera(1).thin_lens().expect("lens");
        let mut order: Vec<usize> = (0..parallax.len()).collect();
        order.sort_by(|&a, &b| parallax[a].total_cmp(&parallax[b]));
        for pair in order.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            let coc = |i: usize| lens.signed_coc_px(f64::from(frags[i].depth));
            prop_assert!(coc(a) >= coc(b) - 1e-9);
            prop_assert!(mean_layer(&per[a]) <= mean_layer(&per[b]) + 1e-6,
                "parallax {} in layer {} but {} in layer {}", parallax[a], mean_layer(&per[a]), parallax[b], mean_layer(&per[b]));
        }
    }

    /// All fragments at one parallax: one layer (0), whole weights, whatever the options.
    #[test]
    fn one_depth_is_one_layer(p in 0.05f32..20.0, n in 1usize..20, layers in 1u32..17, soft in prop_oneof![Just(None), Just(Some(1.0f32))]) {
        let frags = fragments_from(&vec![p; n], &vec![1.0; n]);
        let options = ClassifyOptions { layers, soft_layers: soft, edge_split: false, continuous_lookup: false, ..ClassifyOptions::default() };
        let (per, _) = bin(&frags, &options);
        for recs in per {
            prop_assert_eq!(recs, vec![(0u32, 1.0f32)]);
        }
    }
}
