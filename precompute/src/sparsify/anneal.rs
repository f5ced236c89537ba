//! Step 5: simulated annealing of the spreadlet positions (paper sec. 5.5).
//!
//! Each step moves a fraction (1 %) of the sites by at most one pixel, re-collapses the
//! Voronoi cells that can have changed, and keeps the new state by the Metropolis rule on the
//! L1 cost between the integrated spreadlets and the PSF, with a temperature falling linearly
//! to zero. A site landing on another merges into it. The best state seen is returned, so the
//! cost never increases.
//!
//! Re-collapsing is exact and local: after removing a site, only its pixels need a new owner;
//! after inserting one, only the cells of its Delaunay neighbours can lose pixels to it. Values
//! move pixel by pixel from the old to the new owner, and the reconstruction is updated by one
//! shifted Green's function per changed spreadlet ([`Reconstruction::add`]).

use rand::Rng;

use super::collapse::{Collapsed, Spreadlets};
use super::green::{Reconstruction, Torus};
use super::target::Target;
use super::voronoi::SiteIndex;

/// Annealing settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AnnealOptions {
    /// Number of steps (paper: 400).
    pub steps: u32,
    /// Fraction of the sites moved per step (paper: 0.01).
    pub fraction: f64,
    /// Initial temperature as a fraction of the starting cost.
    pub temperature: f64,
}

impl Default for AnnealOptions {
    fn default() -> Self {
        AnnealOptions {
            steps: 400,
            fraction: 0.01,
            temperature: 2e-4,
        }
    }
}

/// Sites touched in a step: id, position and values before it.
type Touched = Vec<(u32, Option<[i32; 2]>, Vec<f64>)>;

#[derive(Clone)]
struct State {
    pos: Vec<Option<[i32; 2]>>,
    val: Vec<f64>,
    owner: Vec<u32>,
    indices: Vec<SiteIndex>,
    recon: Reconstruction,
    cost: f64,
}

impl State {
    fn spreadlets(&self, channels: usize) -> Spreadlets {
        let mut positions = Vec::new();
        let mut values = Vec::new();
        for (j, p) in self.pos.iter().enumerate() {
            if let Some(p) = p {
                positions.push(*p);
                values.extend_from_slice(&self.val[j * channels..(j + 1) * channels]);
            }
        }
        Spreadlets {
            positions,
            values,
            channels,
        }
    }
}

/// The reconstruction of `s` on `torus`.
pub fn reconstruct(torus: &Torus, s: &Spreadlets) -> Reconstruction {
    let mut r = Reconstruction::new(torus.clone(), s.channels);
    for (j, &p) in s.positions.iter().enumerate() {
        r.add(p, s.value(j));
    }
    r
}

/// Anneals a collapse; returns the best spreadlets found (coincident ones of different groups
/// merged) and their L1 cost on the proxy integrator.
pub fn anneal(
    t: &Target,
    torus: &Torus,
    start: Collapsed,
    opts: &AnnealOptions,
    rng: &mut impl Rng,
) -> (Spreadlets, f64) {
    let (best, cost) = anneal_sites(t, torus, start, opts, rng);
    (best.merged(), cost)
}

fn anneal_sites(
    t: &Target,
    torus: &Torus,
    start: Collapsed,
    opts: &AnnealOptions,
    rng: &mut impl Rng,
) -> (Spreadlets, f64) {
    let ch = t.channels();
    let Collapsed {
        spreadlets: start,
        groups,
        owner,
        indices,
    } = start;
    let recon = reconstruct(torus, &start);
    let cost = recon.l1(&t.psf);
    let n = start.len();
    let mut cur = State {
        pos: start.positions.iter().map(|&p| Some(p)).collect(),
        val: start.values.clone(),
        owner,
        indices,
        recon,
        cost,
    };
    if n == 0 || opts.steps == 0 {
        return (start, cost);
    }
    let mut best_cost = cost;
    let mut best = start;
    let t0 = opts.temperature * cost;
    let (w, h) = (t.width as i32, t.height as i32);
    for step in 0..opts.steps {
        let alive: Vec<u32> = (0..n as u32)
            .filter(|&j| cur.pos[j as usize].is_some())
            .collect();
        if alive.is_empty() {
            break;
        }
        let m = ((opts.fraction * alive.len() as f64).round() as usize).clamp(1, alive.len());
        let mut pick = alive;
        for i in 0..m {
            let j = rng.random_range(i..pick.len());
            pick.swap(i, j);
        }
        let mut s = cur.clone();
        // Touched sites with their position and values before this step.
        let mut touched: Touched = Vec::new();
        let mut is_touched = vec![false; n];
        let touch = |id: u32, s: &State, touched: &mut Touched, is_touched: &mut Vec<bool>| {
            if !is_touched[id as usize] {
                is_touched[id as usize] = true;
                let v = s.val[id as usize * ch..(id as usize + 1) * ch].to_vec();
                touched.push((id, s.pos[id as usize], v));
            }
        };
        for &id in &pick[..m] {
            let Some(p) = s.pos[id as usize] else {
                continue;
            };
            let (dx, dy) = loop {
                let d = (rng.random_range(-1..=1), rng.random_range(-1..=1));
                if d != (0, 0) {
                    break d;
                }
            };
            let q = [p[0] + dx, p[1] + dy];
            if q[0] < 0 || q[1] < 0 || q[0] >= w || q[1] >= h {
                continue;
            }
            touch(id, &s, &mut touched, &mut is_touched);
            let g = groups[id as usize];
            let index = &mut s.indices[g as usize];
            let pf = [f64::from(p[0]), f64::from(p[1])];
            let qf = [f64::from(q[0]), f64::from(q[1])];
            index.remove_at(pf);
            let mut affected = vec![false; n];
            affected[id as usize] = true;
            match index.id_at(qf) {
                Some(_) => {
                    // Merge: the site disappears; its pixels go to their nearest (mostly the
                    // site it landed on).
                    s.pos[id as usize] = None;
                }
                None => {
                    index.insert(qf, id);
                    s.pos[id as usize] = Some(q);
                    for nb in index.neighbours_of(qf) {
                        affected[nb as usize] = true;
                    }
                }
            }
            let index = &s.indices[g as usize];
            for k in 0..t.active.len() {
                let o = s.owner[k];
                if o == u32::MAX || !affected[o as usize] {
                    continue;
                }
                let Some((new, _)) = index.nearest(t.active_xy(k)) else {
                    continue;
                };
                if new != o {
                    touch(o, &s, &mut touched, &mut is_touched);
                    touch(new, &s, &mut touched, &mut is_touched);
                    for c in 0..ch {
                        let l = t.active_lap(k, c);
                        s.val[o as usize * ch + c] -= l;
                        s.val[new as usize * ch + c] += l;
                    }
                    s.owner[k] = new;
                }
            }
            if s.pos[id as usize].is_none() {
                // A merged site keeps no value (all its pixels moved away).
                for c in 0..ch {
                    s.val[id as usize * ch + c] = 0.0;
                }
            }
        }
        if touched.is_empty() {
            continue;
        }
        let mut diff = vec![0.0; ch];
        for (id, old_pos, old_val) in &touched {
            let new_pos = s.pos[*id as usize];
            let new_val = &s.val[*id as usize * ch..(*id as usize + 1) * ch];
            if *old_pos == new_pos {
                if let Some(p) = new_pos {
                    for c in 0..ch {
                        diff[c] = new_val[c] - old_val[c];
                    }
                    s.recon.add(p, &diff);
                }
            } else {
                if let Some(p) = old_pos {
                    let neg: Vec<f64> = old_val.iter().map(|v| -v).collect();
                    s.recon.add(*p, &neg);
                }
                if let Some(p) = new_pos {
                    s.recon.add(p, new_val);
                }
            }
        }
        s.cost = s.recon.l1(&t.psf);
        let temperature = t0 * (1.0 - f64::from(step) / f64::from(opts.steps));
        let delta = s.cost - cur.cost;
        let accept = delta <= 0.0
            || (temperature > 0.0 && rng.random::<f64>() < (-delta / temperature).exp());
        if accept {
            cur = s;
            if cur.cost < best_cost {
                best_cost = cur.cost;
                best = cur.spreadlets(ch);
            }
        }
    }
    (best, best_cost)
}
