//! Step 4: collapse each Voronoi cell of the Laplacian into its site: the spreadlet's value is
//! the sum of the Laplacian over the cell, per channel. Sites sit on integer pixels.

use std::collections::HashMap;

use super::darts::Site;
use super::target::Target;
use super::voronoi::SiteIndex;

/// Spreadlets on the PSF image: integer pixel positions (image coordinates, not yet relative
/// to the centre) and `channels` values per spreadlet, interleaved.
#[derive(Clone, Debug, PartialEq)]
pub struct Spreadlets {
    /// Pixel positions `[x, y]` in the PSF image.
    pub positions: Vec<[i32; 2]>,
    /// Values, `positions.len() * channels`, interleaved.
    pub values: Vec<f64>,
    /// Channels per spreadlet.
    pub channels: usize,
}

impl Spreadlets {
    /// Number of spreadlets.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when there are none.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// The values of spreadlet `j`.
    pub fn value(&self, j: usize) -> &[f64] {
        &self.values[j * self.channels..(j + 1) * self.channels]
    }

    /// Merges spreadlets on the same pixel (summing values; exact, since splatting is linear)
    /// and drops those whose values are all zero. Keeps first-occurrence order.
    pub fn merged(&self) -> Spreadlets {
        let ch = self.channels;
        let mut slot: HashMap<[i32; 2], usize> = HashMap::new();
        let mut positions = Vec::new();
        let mut values: Vec<f64> = Vec::new();
        for (j, &p) in self.positions.iter().enumerate() {
            let k = *slot.entry(p).or_insert_with(|| {
                positions.push(p);
                values.extend(std::iter::repeat_n(0.0, ch));
                positions.len() - 1
            });
            for c in 0..ch {
                values[k * ch + c] += self.values[j * ch + c];
            }
        }
        let mut out = Spreadlets {
            positions: Vec::new(),
            values: Vec::new(),
            channels: ch,
        };
        for (k, p) in positions.iter().enumerate() {
            let v = &values[k * ch..(k + 1) * ch];
            if v.iter().any(|&x| x != 0.0) {
                out.positions.push(*p);
                out.values.extend_from_slice(v);
            }
        }
        out
    }
}

/// Sites on pixels, with their groups.
#[derive(Clone, Debug, PartialEq)]
pub struct PixelSites {
    /// Pixel positions `[x, y]`.
    pub positions: Vec<[i32; 2]>,
    /// Group of each site.
    pub groups: Vec<u8>,
}

/// Rounds continuous sites to pixels inside the `width x height` image, merging sites of the
/// same group that land on the same pixel (keeping the first occurrence's order).
pub fn round_sites(sites: &[Site], width: usize, height: usize) -> PixelSites {
    let mut seen = std::collections::HashSet::new();
    let mut out = PixelSites {
        positions: Vec::with_capacity(sites.len()),
        groups: Vec::with_capacity(sites.len()),
    };
    for s in sites {
        if !(s.pos[0].is_finite() && s.pos[1].is_finite()) {
            continue;
        }
        let x = (s.pos[0].round() as i64).clamp(0, width as i64 - 1) as i32;
        let y = (s.pos[1].round() as i64).clamp(0, height as i64 - 1) as i32;
        if seen.insert((s.group, x, y)) {
            out.positions.push([x, y]);
            out.groups.push(s.group);
        }
    }
    out
}

/// The result of collapsing: spreadlets plus the Voronoi bookkeeping annealing continues from.
#[derive(Clone)]
pub struct Collapsed {
    /// The spreadlets (one per site, possibly two on a pixel from different groups).
    pub spreadlets: Spreadlets,
    /// Group of each site.
    pub groups: Vec<u8>,
    /// Owner site of every active pixel.
    pub owner: Vec<u32>,
    /// One site index per group (ids are site indices).
    pub indices: Vec<SiteIndex>,
}

/// Collapses the Laplacian into `sites` (distinct pixels within each group).
pub fn collapse(t: &Target, sites: PixelSites) -> Collapsed {
    let ch = t.channels();
    let mut indices: Vec<SiteIndex> = (0..t.groups).map(|_| SiteIndex::new()).collect();
    for (j, (p, &g)) in sites.positions.iter().zip(&sites.groups).enumerate() {
        if let Some(index) = indices.get_mut(g as usize) {
            index.insert([f64::from(p[0]), f64::from(p[1])], j as u32);
        }
    }
    let mut values = vec![0.0; sites.positions.len() * ch];
    let mut owner = vec![u32::MAX; t.active.len()];
    for k in 0..t.active.len() {
        if let Some((o, _)) = indices[t.group[k] as usize].nearest(t.active_xy(k)) {
            owner[k] = o;
            for c in 0..ch {
                values[o as usize * ch + c] += t.active_lap(k, c);
            }
        }
    }
    Collapsed {
        spreadlets: Spreadlets {
            positions: sites.positions,
            values,
            channels: ch,
        },
        groups: sites.groups,
        owner,
        indices,
    }
}
