//! Step 2: Poisson-disk dart throwing with |Laplacian| as importance.
//!
//! A candidate pixel is drawn with probability proportional to its importance `w` and kept
//! when no kept site (of its cell group) lies closer than its radius `r = r0 sqrt(w_ref / w)`,
//! clamped to `[1, r_max]` pixels. So a site's disk, and later its Voronoi cell, has an area
//! inversely proportional to the local |Laplacian|, and every spreadlet carries a similar share
//! of it. `w_ref` is the importance above which half of the total importance lies (robust to a
//! few noisy peaks); `r0 = spacing / sqrt(budget)`. Throwing stops after `max_failures`
//! consecutive rejected candidates (the paper: 10,000).

use rand::Rng;

use super::target::Target;
use super::voronoi::SiteIndex;

/// Default dart radius at the reference importance, pixels, for budget 1.
pub const DART_SPACING_PX: f64 = 2.0;

/// A spreadlet site: continuous pixel coordinates and its cell group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Site {
    /// Position `[x, y]`, pixels.
    pub pos: [f64; 2],
    /// Cell group (see [`Target::group`]).
    pub group: u8,
}

/// The dart radius of each active pixel, pixels.
pub fn dart_radii(t: &Target, budget: f64, spacing_px: f64) -> Vec<f64> {
    let total: f64 = t.importance.iter().sum();
    if t.importance.is_empty() || total.is_nan() || total <= 0.0 {
        return vec![1.0; t.importance.len()];
    }
    let mut sorted = t.importance.clone();
    sorted.sort_by(|a, b| b.total_cmp(a));
    let mut acc = 0.0;
    let mut w_ref = sorted[0];
    for &w in &sorted {
        acc += w;
        w_ref = w;
        if acc >= 0.5 * total {
            break;
        }
    }
    let r0 = spacing_px / budget.max(1e-6).sqrt();
    let r_max = (0.25 * t.width.max(t.height) as f64).max(2.0);
    t.importance
        .iter()
        .map(|&w| (r0 * (w_ref / w).sqrt()).clamp(1.0, r_max))
        .collect()
}

/// Throws darts; returns the kept sites (at pixel centres), group by group.
pub fn throw_darts(
    t: &Target,
    budget: f64,
    spacing_px: f64,
    max_failures: u32,
    rng: &mut impl Rng,
) -> Vec<Site> {
    let radii = dart_radii(t, budget, spacing_px);
    let mut sites = Vec::new();
    for g in 0..t.groups as u8 {
        let members: Vec<usize> = (0..t.active.len()).filter(|&k| t.group[k] == g).collect();
        if members.is_empty() {
            continue;
        }
        let mut cdf = Vec::with_capacity(members.len());
        let mut acc = 0.0;
        for &k in &members {
            acc += t.importance[k];
            cdf.push(acc);
        }
        let mut index = SiteIndex::new();
        let mut failures = 0;
        let mut count = 0u32;
        while failures < max_failures {
            let u = rng.random::<f64>() * acc;
            let m = cdf.partition_point(|&c| c <= u).min(cdf.len() - 1);
            let k = members[m];
            let p = t.active_xy(k);
            let r = radii[k];
            let blocked = matches!(index.nearest(p), Some((_, d2)) if d2 < r * r);
            if blocked {
                failures += 1;
            } else {
                index.insert(p, count);
                count += 1;
                sites.push(Site { pos: p, group: g });
                failures = 0;
            }
        }
    }
    sites
}
