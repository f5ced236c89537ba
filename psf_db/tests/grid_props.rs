//! Property tests of the nested grid and the parameter space lookup.

use proptest::prelude::*;
use psf_db::{NestedGrid, ParamSpace, PsfModel};

proptest! {
    #[test]
    fn every_point_maps_to_a_box_containing_it(n in 1u32..300, x in 0.0f64..1.0, y in 0.0f64..1.0) {
        for dims in 1..=2 {
            let g = NestedGrid::new(dims, n).unwrap();
            let u = [x * n as f64, y * n as f64];
            let i = g.index_of(u);
            prop_assert!(i < g.cell_count());
            let b = g.cell_box(i).unwrap();
            prop_assert!(b.contains(u, dims), "dims {} n {} u {:?} cell {} box {:?}", dims, n, u, i, b);
        }
    }

    #[test]
    fn boundary_points_map_to_a_box_containing_them(n in 1u32..300, a in 0u32..300, b in 0u32..300) {
        // Integer grid coordinates are exactly the cell boundaries.
        let g = NestedGrid::new(2, n).unwrap();
        let u = [(a % n) as f64, (b % n) as f64];
        let b = g.cell_box(g.index_of(u)).unwrap();
        prop_assert!(b.contains(u, 2));
        prop_assert!(u[0] < b.max[0] && u[1] < b.max[1], "half-open boxes");
    }

    #[test]
    fn physical_lookup_lands_in_the_physical_box(c in 0.0f32..64.0, m in 0.0f32..192.0, n in 2u32..60) {
        let s = ParamSpace::for_model(PsfModel::LensMotion, &[[0.0, 64.0], [0.0, 192.0]], n).unwrap();
        let (i, clamped) = s.lookup([c, m]);
        prop_assert!(!clamped);
        let b = s.cell_box(i).unwrap();
        // Allow f32 rounding of the query.
        let tol = 1e-4;
        prop_assert!(c as f64 >= b.min[0] - tol && c as f64 <= b.max[0] + tol);
        prop_assert!(m as f64 >= b.min[1] - tol && m as f64 <= b.max[1] + tol);
    }
}

#[test]
fn paper_counts() {
    assert_eq!(NestedGrid::cell_count_for(2, 9), 28);
    // A regular 9x9 grid would need 81.
    assert!(NestedGrid::cell_count_for(2, 9) < 81);
    // 1D: one cell per level, T(l) = l (l+1) / 2 < n.
    assert_eq!(NestedGrid::cell_count_for(1, 5050), 100);
}
