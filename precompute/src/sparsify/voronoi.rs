//! Nearest-site queries (Voronoi cells) over a changing set of spreadlet sites, on `spade`'s
//! Delaunay triangulation: the nearest site of a point is found by a greedy walk on the
//! triangulation, and a site's Delaunay neighbours are the cells that can lose pixels to it.
//!
//! Degenerate inputs (no site, one or two sites, collinear sites) are handled: with three
//! sites or fewer the query is a linear scan; a site spade refuses (non-finite or absurdly
//! large coordinates) is kept aside and scanned linearly too, so nothing panics.

use spade::{DelaunayTriangulation, HasPosition, Point2, Triangulation};

#[derive(Clone, Copy, Debug, PartialEq)]
struct SiteVertex {
    pos: Point2<f64>,
    id: u32,
}

impl HasPosition for SiteVertex {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        self.pos
    }
}

/// A set of sites with ids, at distinct positions (inserting onto an occupied position
/// replaces nothing and reports the occupant).
#[derive(Clone, Default)]
pub struct SiteIndex {
    tri: DelaunayTriangulation<SiteVertex>,
    rejected: Vec<([f64; 2], u32)>,
}

impl SiteIndex {
    /// An empty index.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sites `positions[i]` with id `i`; a position already taken keeps its first id.
    pub fn from_positions(positions: &[[f64; 2]]) -> Self {
        let verts: Vec<SiteVertex> = positions
            .iter()
            .enumerate()
            .map(|(i, p)| SiteVertex {
                pos: Point2::new(p[0], p[1]),
                id: i as u32,
            })
            .collect();
        if verts
            .iter()
            .all(|v| v.pos.x.is_finite() && v.pos.y.is_finite())
        {
            if let Ok(tri) = DelaunayTriangulation::bulk_load_stable(verts) {
                return SiteIndex {
                    tri,
                    rejected: Vec::new(),
                };
            }
        }
        let mut s = SiteIndex::new();
        for (i, p) in positions.iter().enumerate() {
            s.insert(*p, i as u32);
        }
        s
    }

    /// Number of sites.
    pub fn len(&self) -> usize {
        self.tri.num_vertices() + self.rejected.len()
    }

    /// True when there is no site.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The id of the site at exactly `p`, if any.
    pub fn id_at(&self, p: [f64; 2]) -> Option<u32> {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return None;
        }
        if let Some(v) = self.tri.locate_vertex(Point2::new(p[0], p[1])) {
            return Some(v.data().id);
        }
        self.rejected
            .iter()
            .find(|(q, _)| *q == p)
            .map(|&(_, id)| id)
    }

    /// Inserts site `id` at `p`. Returns the id of the site already at `p` instead (and
    /// inserts nothing) when the position is taken.
    pub fn insert(&mut self, p: [f64; 2], id: u32) -> Option<u32> {
        if let Some(other) = self.id_at(p) {
            return Some(other);
        }
        let v = SiteVertex {
            pos: Point2::new(p[0], p[1]),
            id,
        };
        if !(p[0].is_finite() && p[1].is_finite()) || self.tri.insert(v).is_err() {
            self.rejected.push((p, id));
        }
        None
    }

    /// Removes the site at `p`; returns its id.
    pub fn remove_at(&mut self, p: [f64; 2]) -> Option<u32> {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return None;
        }
        if let Some(v) = self.tri.locate_vertex(Point2::new(p[0], p[1])) {
            let h = v.fix();
            return Some(self.tri.remove(h).id);
        }
        let k = self.rejected.iter().position(|(q, _)| *q == p)?;
        Some(self.rejected.swap_remove(k).1)
    }

    /// Ids of the Delaunay neighbours of the site at `p` (all sites when the triangulation is
    /// too small or degenerate to tell).
    pub fn neighbours_of(&self, p: [f64; 2]) -> Vec<u32> {
        let n = self.tri.num_vertices();
        let all = || {
            self.tri
                .vertices()
                .map(|v| v.data().id)
                .chain(self.rejected.iter().map(|r| r.1))
                .collect()
        };
        if n <= 3
            || !self.rejected.is_empty()
            || self.tri.all_vertices_on_line()
            || !(p[0].is_finite() && p[1].is_finite())
        {
            return all();
        }
        match self.tri.locate_vertex(Point2::new(p[0], p[1])) {
            Some(v) => v.out_edges().map(|e| e.to().data().id).collect(),
            None => all(),
        }
    }

    /// The nearest site to `p`: `(id, squared distance)`; `None` when empty.
    #[inline]
    pub fn nearest(&self, p: [f64; 2]) -> Option<(u32, f64)> {
        let d2 = |q: [f64; 2]| (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2);
        let mut best: Option<(u32, f64)> = None;
        let mut consider = |id: u32, q: [f64; 2]| {
            let d = d2(q);
            if best.is_none_or(|(bid, bd)| d < bd || (d == bd && id < bid)) {
                best = Some((id, d));
            }
        };
        if self.tri.num_vertices() <= 3 || !(p[0].is_finite() && p[1].is_finite()) {
            for v in self.tri.vertices() {
                let q = v.position();
                consider(v.data().id, [q.x, q.y]);
            }
        } else if let Some(v) = self.tri.nearest_neighbor(Point2::new(p[0], p[1])) {
            let q = v.position();
            consider(v.data().id, [q.x, q.y]);
        }
        for &(q, id) in &self.rejected {
            consider(id, q);
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(sites: &[[f64; 2]], p: [f64; 2]) -> f64 {
        sites
            .iter()
            .map(|q| (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2))
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn nearest_matches_brute_force_including_degenerate_sets() {
        let sets: Vec<Vec<[f64; 2]>> = vec![
            vec![],
            vec![[3.0, 4.0]],
            vec![[0.0, 0.0], [5.0, 0.0]],
            (0..9).map(|i| [i as f64, 2.0 * i as f64]).collect(), // collinear
            vec![[1.0, 1.0], [1.0, 1.0], [4.0, 2.0]],             // coincident
            (0..40)
                .map(|i| [((i * 17) % 23) as f64, ((i * 7) % 13) as f64])
                .collect(),
        ];
        for sites in sets {
            let idx = SiteIndex::from_positions(&sites);
            for y in -2..15 {
                for x in -2..25 {
                    let p = [x as f64 + 0.25, y as f64 - 0.5];
                    match idx.nearest(p) {
                        None => assert!(sites.is_empty()),
                        Some((id, d)) => {
                            assert!((d - brute(&sites, p)).abs() < 1e-9);
                            let q = sites[id as usize];
                            assert!(
                                ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) - d).abs() < 1e-9
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn move_and_merge() {
        let mut idx = SiteIndex::from_positions(&[[0.0, 0.0], [4.0, 0.0], [0.0, 4.0], [4.0, 4.0]]);
        assert_eq!(idx.remove_at([4.0, 4.0]), Some(3));
        assert_eq!(idx.insert([2.0, 2.0], 3), None);
        assert_eq!(idx.nearest([2.4, 2.1]).map(|r| r.0), Some(3));
        assert_eq!(idx.insert([0.0, 0.0], 9), Some(0));
        assert_eq!(idx.len(), 4);
        assert!(idx.neighbours_of([2.0, 2.0]).len() >= 3);
        assert_eq!(idx.insert([f64::NAN, 0.0], 7), None);
        assert_eq!(idx.len(), 5);
    }
}
