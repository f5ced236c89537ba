//! Property tests of the nested grid and the parameter-space lookup that `grid_props.rs` does
//! not cover: the boxes tile the domain exactly once, levels grow with the distance
//! from the origin, cell edges follow the level, and lookups of values outside the space
//! (negative, beyond the maximum, infinite, NaN) clamp, say so, and land in the space's edge
//! cells, never out of range.

use proptest::prelude::*;
use psf_db::{NestedGrid, ParamSpace, PsfModel};

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Areas add up to the domain (`n^dims`) and a random point lies in exactly one box,
    /// counted half-open (closed only at the domain's far end).
    #[test]
    fn boxes_tile_the_domain_exactly_once(n in 1u32..120, x in 0.0f64..1.0, y in 0.0f64..1.0) {
        for dims in 1..=2usize {
            let g = NestedGrid::new(dims, n).unwrap();
            let boxes = g.boxes();
            prop_assert_eq!(boxes.len() as u32, g.cell_count());
            prop_assert_eq!(NestedGrid::cell_count_for(dims, n), g.cell_count());
            let area: f64 = boxes
                .iter()
                .map(|b| (0..dims).map(|d| b.max[d] - b.min[d]).product::<f64>())
                .sum();
            let nf = f64::from(n);
            prop_assert!((area - nf.powi(dims as i32)).abs() < 1e-9, "area {} for n {}", area, n);
            let u = [x * nf, y * nf];
            let inside = |b: &psf_db::CellBox| {
                (0..dims).all(|d| u[d] >= b.min[d] && (u[d] < b.max[d] || b.max[d] == nf))
            };
            let holders: Vec<usize> = boxes.iter().enumerate().filter(|(_, b)| inside(b)).map(|(i, _)| i).collect();
            prop_assert_eq!(holders.len(), 1, "u {:?} in boxes {:?}", u, holders);
            prop_assert_eq!(holders[0] as u32, g.index_of(u));
        }
    }

    /// The level of the cell holding `u` never decreases as `min(u)` grows, and a cell's edge is
    /// `level + 1` grid units (clipped at the domain's end).
    #[test]
    fn levels_grow_with_the_distance_from_the_origin(n in 2u32..200, a in 0.0f64..1.0, b in 0.0f64..1.0, t in 0.0f64..1.0) {
        let g = NestedGrid::new(2, n).unwrap();
        let nf = f64::from(n);
        let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
        let near = [lo * nf, (lo + t * (1.0 - lo)) * nf];
        let far = [hi * nf, (hi + t * (1.0 - hi)) * nf];
        let (ln, lf) = (g.level_of(g.index_of(near)), g.level_of(g.index_of(far)));
        prop_assert!(ln <= lf, "level {} at {:?} > level {} at {:?}", ln, near, lf, far);
        let i = g.index_of(far);
        let bx = g.cell_box(i).unwrap();
        let edge = f64::from(g.level_of(i) + 1);
        for d in 0..2 {
            let e = bx.max[d] - bx.min[d];
            prop_assert!(e <= edge + 1e-12 && (e == edge || bx.max[d] == nf), "edge {} level edge {}", e, edge);
        }
    }

    /// Values outside the space clamp: the flag is set, the index is in range, and it is the
    /// index of the nearest in-range value (the clamped one); NaN clamps to the minimum.
    #[test]
    fn lookups_outside_the_space_clamp_to_its_edge(
        n in 2u32..60,
        c in prop_oneof![Just(f32::NAN), Just(f32::INFINITY), Just(f32::NEG_INFINITY), -1e30f32..-1e-3, 64.001f32..1e30, 0.0f32..64.0],
        m in prop_oneof![Just(f32::NAN), Just(f32::INFINITY), -1e30f32..-1e-3, 192.001f32..1e30, 0.0f32..192.0],
    ) {
        let s = ParamSpace::for_model(PsfModel::LensMotion, &[[0.0, 64.0], [0.0, 192.0]], n).unwrap();
        let (i, clamped) = s.lookup([c, m]);
        prop_assert!(i < s.psf_count());
        let inside = |v: f32, max: f32| v >= 0.0 && v <= max;
        prop_assert_eq!(clamped, !(inside(c, 64.0) && inside(m, 192.0)));
        let clamp = |v: f32, max: f32| if v.is_nan() { 0.0 } else { v.clamp(0.0, max) };
        let (j, again) = s.lookup([clamp(c, 64.0), clamp(m, 192.0)]);
        prop_assert!(!again);
        prop_assert_eq!(i, j, "({}, {}) -> {} but clamped -> {}", c, m, i, j);
    }
}

/// Degenerate resolutions: n = 1 is one cell; n = 2 in 2D has the origin cell and the level-1
/// strips.
#[test]
fn smallest_grids() {
    for dims in 1..=2 {
        let g = NestedGrid::new(dims, 1).unwrap();
        assert_eq!(g.cell_count(), 1);
        assert_eq!(g.index_of([0.5, 0.5]), 0);
        assert_eq!(g.index_of([f64::NAN, f64::INFINITY]), 0);
    }
    let g = NestedGrid::new(2, 2).unwrap();
    let boxes = g.boxes();
    let area: f64 = boxes
        .iter()
        .map(|b| (b.max[0] - b.min[0]) * (b.max[1] - b.min[1]))
        .sum();
    assert_eq!(area, 4.0);
    assert!(NestedGrid::new(2, 0).is_err());
    assert!(NestedGrid::new(3, 4).is_err());
}
