//! Step 3: Lloyd relaxation weighted by |Laplacian|: each site moves to the importance-weighted
//! centroid of its Voronoi cell (the active pixels of its group nearest to it).

use super::darts::Site;
use super::target::Target;
use super::voronoi::SiteIndex;

/// Runs up to `iterations` Lloyd steps on `sites` (continuous positions); stops early when no
/// site moves more than 1e-3 px.
pub fn lloyd(t: &Target, sites: &mut [Site], iterations: u32) {
    for g in 0..t.groups as u8 {
        let ids: Vec<usize> = (0..sites.len()).filter(|&j| sites[j].group == g).collect();
        if ids.is_empty() {
            continue;
        }
        for _ in 0..iterations {
            let pos: Vec<[f64; 2]> = ids.iter().map(|&j| sites[j].pos).collect();
            let index = SiteIndex::from_positions(&pos);
            let mut acc = vec![[0.0f64; 3]; ids.len()];
            for k in 0..t.active.len() {
                if t.group[k] != g {
                    continue;
                }
                let p = t.active_xy(k);
                if let Some((id, _)) = index.nearest(p) {
                    let w = t.importance[k];
                    let a = &mut acc[id as usize];
                    a[0] += w * p[0];
                    a[1] += w * p[1];
                    a[2] += w;
                }
            }
            let mut moved = 0.0f64;
            for (&j, a) in ids.iter().zip(&acc) {
                if a[2] > 0.0 {
                    let c = [a[0] / a[2], a[1] / a[2]];
                    let s = &mut sites[j].pos;
                    moved = moved.max((c[0] - s[0]).abs().max((c[1] - s[1]).abs()));
                    *s = c;
                }
            }
            if moved < 1e-3 {
                break;
            }
        }
    }
}
