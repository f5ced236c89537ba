//! Dense PSFs turned once per frame, then drawn upright.
//!
//! A physical-lens PSF is stored with its radial direction along +x, and each pixel's record
//! turns it onto the pixel's own radial direction. Drawn turned, a dense image costs four
//! bilinear taps per pixel, each a read-modify-write of an RGBA value; upright, one add. The
//! still pixels of a frame seen through a real lens are mostly dense records (the backdrop's
//! small bokeh), and many of them share a cell and nearly the same turn: a pixel `r` px from
//! the centre turns about `1/r` radians from its neighbour.
//!
//! So each dense record's turn is quantised so that the PSF's rim moves at most
//! [`RIM_STEP_PX`] between steps (at most half of it, a quarter pixel, off the record's own
//! turn, as the smeared PSFs' turns are), and each (PSF, turn step) that at least
//! [`MIN_SHARED_RECORDS`] records use is turned once, by [`crate::motion_smear::turn`] (a
//! Catmull-Rom cubic, which widens a narrow PSF less than the splat's bilinear taps), and
//! appended to the frame's database. Those records then draw it upright. A record whose key is
//! not shared keeps its own exact turn and is drawn turned as before, so no record is
//! quantised without it paying off.
//!
//! A still pixel's lookup blends its cell's PSF with the neighbouring cell's along inverse
//! depth (two records at one pixel whose colours are the same colour times their shares).
//! Such a pair is premixed: the two PSFs turned, then mixed in the proportion of the
//! records' weights (rounded to [`PAIR_SHARE_STEPS`]), and drawn as one upright record, where
//! drawing the two would cost twice as much.

use rayon::prelude::*;

use psf_db::PsfDatabase;

use super::ClassifyError;
use crate::motion_smear::{psf_image, turn, weighted_sum, PsfImage};
use crate::pipeline::types::{psf_reach, Classified, FrameParams, SplatPath, SplatRecord};

/// Largest move of a PSF's rim between neighbouring turn steps, px: a record drawn from its
/// step's image has its rim at most half of this from where its own turn puts it.
pub const RIM_STEP_PX: f32 = 0.5;

/// Records that must share a (PSF, turn step) for it to be turned once: turning costs about
/// what drawing one record turned costs.
pub const MIN_SHARED_RECORDS: usize = 2;

/// Records that must share a turn of a sparse PSF for it to be integrated and turned once: its
/// image is large, and turning it costs what drawing a dozen records from it saves.
pub const MIN_SHARED_SPARSE_RECORDS: usize = 16;

/// What building one pixel of a sparse PSF's turned image costs, in pixels of an upright dense
/// image drawn: the exact integration of each colour channel on the PSF's own plane, and the
/// cubic turn.
pub const IMAGE_BUILD_COST: usize = 32;

/// What integrating one pixel of one layer's padded frame costs, in pixels of an upright dense
/// image drawn: the exact lattice inverse (an FFT in f64 there and back) of four planes.
pub const LAYER_INTEGRATION_COST: usize = 32;

/// Most pixels of turned images one frame appends, summed (each holds a value per channel):
/// beyond it, the keys used by fewest records are drawn turned as before.
pub const MAX_FRAME_TURNED_PIXELS: usize = 16 << 20;

/// What drawing one spreadlet turned costs, in pixels of an upright dense image: its turn,
/// band test, bilinear split and four read-modify-writes of RGBA, against one add in a row
/// the compiler vectorises. A sparse PSF whose turned box holds at most this many pixels per
/// spreadlet is drawn from a dense image turned once (measured on `rain` at 1024 px, where
/// its near bokeh is sparse: the splat 2.6 s -> 1.35 s).
pub const SPREADLET_COST: usize = 25;

/// Steps of a premixed pair's share over `[0, 1]`: a step moves the blend's size by 1/16 of
/// what a cell spans (through the double Gauss at 512 px, 0.08 px of blur radius).
pub const PAIR_SHARE_STEPS: u32 = 16;

/// A dense PSF and a quantised turn of it, packed into one integer (the PSF's index in the
/// high half, the turn step in the low) so that a frame's keys sort fast; `NONE` for a record
/// drawn upright already.
type TurnKey = u64;
const NONE: TurnKey = u64::MAX;

fn psf_of(key: TurnKey) -> u32 {
    (key >> 32) as u32
}

/// Two dense PSFs (`lo < hi`), the share of `hi` in steps of [`PAIR_SHARE_STEPS`], and each
/// one's turn step (over its own turn steps, as a single record of it would be turned).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
struct PairKey {
    lo: u32,
    hi: u32,
    share_step: u32,
    lo_step: u32,
    hi_step: u32,
}

/// A run of records' keys, and the blended pairs that start in it (the first record's index,
/// the pair's key).
type KeysAndPairs = (Vec<TurnKey>, Vec<(usize, PairKey)>);

/// What a shared image is: one PSF turned, or two turned and mixed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
enum Shared {
    Single(TurnKey),
    Pair(PairKey),
}

/// Turn steps over a full turn for a PSF reaching `reach_px` from its centre: its rim moves
/// at most [`RIM_STEP_PX`] per step.
pub fn turn_steps(reach_px: f32) -> u32 {
    (std::f32::consts::TAU * reach_px.max(1.0) / RIM_STEP_PX)
        .ceil()
        .clamp(8.0, 4096.0) as u32
}

/// The angle of `r`'s rotation in `[0, 2 pi)`, radians.
fn turn_angle(r: &SplatRecord) -> f32 {
    r.rot_sin.atan2(r.rot_cos).rem_euclid(std::f32::consts::TAU)
}

/// The nearest of `n` turn steps to `angle` (radians, in `[0, 2 pi)`).
fn step_of_angle(angle: f32, n: u32) -> u32 {
    ((angle / std::f32::consts::TAU * n as f32).round() as u32) % n
}

/// The keys of records taken in order: a dense record turned by its rotation has its PSF and
/// turn step, one drawn upright already [`NONE`] (`steps[i]` is PSF `i`'s turn steps, 0 for
/// a PSF without a dense image). The last rotation's angle is remembered: the records of one
/// fragment (a blend's two, the share drawn round) share their rotation.
struct Keys<'s> {
    steps: &'s [u32],
    last: Option<((u32, u32), f32)>,
}

impl Keys<'_> {
    fn of(&mut self, r: &SplatRecord) -> TurnKey {
        let drawn = r.path == SplatPath::Dense as u32 || r.path == SplatPath::Sparse as u32;
        if !drawn || (r.rot_cos == 1.0 && r.rot_sin == 0.0) {
            return NONE;
        }
        let n = match self.steps.get(r.psf_index as usize) {
            Some(&n) if n > 0 => n,
            _ => return NONE,
        };
        let rotation = (r.rot_cos.to_bits(), r.rot_sin.to_bits());
        let angle = match self.last {
            Some((last, angle)) if last == rotation => angle,
            _ => {
                let angle = turn_angle(r);
                self.last = Some((rotation, angle));
                angle
            }
        };
        (u64::from(r.psf_index) << 32) | u64::from(step_of_angle(angle, n))
    }
}

/// The pair key of records `a` and `b` (keys `ka`, `kb`), where they are one fragment's blend
/// of two PSFs: both turned dense records at one pixel of one layer, with one rotation, other
/// PSFs, positive weights, and colours that are one colour times their weights. Each PSF's turn
/// step is its record's.
fn pair_of(a: &SplatRecord, b: &SplatRecord, ka: TurnKey, kb: TurnKey) -> Option<PairKey> {
    let blend = ka != NONE
        && kb != NONE
        && a.layer == b.layer
        && (a.center_x, a.center_y) == (b.center_x, b.center_y)
        && a.rot_cos.to_bits() == b.rot_cos.to_bits()
        && a.rot_sin.to_bits() == b.rot_sin.to_bits()
        && a.psf_index != b.psf_index
        && a.weight > 0.0
        && b.weight > 0.0;
    if !blend {
        return None;
    }
    let same_colour = a.color.iter().zip(&b.color).all(|(&ca, &cb)| {
        let (x, y) = (ca * b.weight, cb * a.weight);
        (x - y).abs() <= 1e-6 * x.abs().max(y.abs())
    });
    if !same_colour {
        return None;
    }
    let ((lo, lo_key), (hi, hi_key), w_hi) = if a.psf_index < b.psf_index {
        ((a.psf_index, ka), (b.psf_index, kb), b.weight)
    } else {
        ((b.psf_index, kb), (a.psf_index, ka), a.weight)
    };
    let share = w_hi / (a.weight + b.weight);
    let share_step = (share * PAIR_SHARE_STEPS as f32).round() as u32;
    Some(PairKey {
        lo,
        hi,
        share_step: share_step.min(PAIR_SHARE_STEPS),
        lo_step: lo_key as u32,
        hi_step: hi_key as u32,
    })
}

/// Whether the frame's sparse records are few enough that each is drawn from a turned image,
/// whatever it shares: then no layer has a Laplacian plane, and the frame's integration is
/// skipped. They must all be turned (an upright one is drawn as it is), and drawing their
/// images plus building one per PSF and turn step they use must cost less than integrating
/// one layer of the frame.
fn turns_every_sparse_record(records: &[SplatRecord], reach: &[i32], frame: FrameParams) -> bool {
    let plane = frame.padded_width as usize * frame.padded_height as usize;
    let most = LAYER_INTEGRATION_COST * plane;
    let reach_of = |psf: u32| reach.get(psf as usize).copied().unwrap_or(0).max(0) as usize;
    let side = |psf: u32| 2 * reach_of(psf) + 9;
    let sparse = || records.iter().filter(|r| r.path == SplatPath::Sparse as u32);
    // Drawing them first, which a frame of many sparse records exceeds early, before keys
    // are gathered.
    let mut cost = 0usize;
    for r in sparse() {
        if r.rot_cos == 1.0 && r.rot_sin == 0.0 {
            return false;
        }
        cost += side(r.psf_index).pow(2);
        if cost > most {
            return false;
        }
    }
    // The (PSF, turn step) of each.
    let mut keys: Vec<(u32, u32)> = sparse()
        .map(|r| {
            let steps = turn_steps(reach_of(r.psf_index) as f32);
            (r.psf_index, step_of_angle(turn_angle(r), steps))
        })
        .collect();
    keys.sort_unstable();
    keys.dedup();
    cost += keys
        .iter()
        .map(|&(psf, _)| side(psf).pow(2) * IMAGE_BUILD_COST)
        .sum::<usize>();
    !keys.is_empty() && cost <= most
}

/// Redirects the dense records of `classified` whose (PSF, turn step) is shared to that PSF
/// turned once, drawn upright, and premixes the shared blends of two PSFs into one upright
/// record; `base` is the database the records index now. The frame's database becomes `base`
/// followed by the turned images. Returns how many records are drawn from shared images.
pub(super) fn draw_shared_turns_upright(
    classified: &mut Classified,
    base: &PsfDatabase,
) -> Result<usize, ClassifyError> {
    let reach = psf_reach(base);
    let every_sparse = turns_every_sparse_record(&classified.records, &reach, classified.frame);
    // A sparse PSF is drawn from a turned dense image where that costs less per record
    // ([`SPREADLET_COST`]), or where its records are the frame's few sparse ones.
    let steps: Vec<u32> = (0..base.psf_count())
        .map(|i| {
            let reach_px = reach[i].max(0) as usize;
            let worth = base.dense(i).is_some() || every_sparse || {
                let side = 2 * reach_px + 5;
                SPREADLET_COST * base.spreadlets(i).0.len() >= side * side
            };
            if worth {
                turn_steps(reach_px as f32)
            } else {
                0
            }
        })
        .collect();
    let records = &classified.records;
    // Every record's key and the blended pairs, in order, in one pass over the records in
    // chunks on every thread: each record with the next where the two are a blend (the last
    // of a chunk with the first of the next), then taken from the left, a record in one pair
    // at most.
    const CHUNK: usize = 4096;
    let per_chunk: Vec<KeysAndPairs> = records
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            let start = c * CHUNK;
            let mut keyer = Keys {
                steps: &steps,
                last: None,
            };
            let keys: Vec<TurnKey> = chunk.iter().map(|r| keyer.of(r)).collect();
            let next = records.get(start + chunk.len()).map(|r| (r, keyer.of(r)));
            let mut candidates = Vec::new();
            for (i, (r, &key)) in chunk.iter().zip(&keys).enumerate() {
                let following = match chunk.get(i + 1) {
                    Some(b) => Some((b, keys[i + 1])),
                    None => next,
                };
                let Some((b, b_key)) = following else { break };
                if let Some(pair) = pair_of(r, b, key, b_key) {
                    candidates.push((start + i, pair));
                }
            }
            (keys, candidates)
        })
        .collect();
    // The keys stay in their chunks (the passes below take the records in the same chunks):
    // joined, they were a list as long as the records' written again in fresh memory.
    let candidates = per_chunk.iter().map(|(_, candidates)| candidates.len()).sum();
    let mut pairs: Vec<(usize, PairKey)> = Vec::with_capacity(candidates);
    for &(i, key) in per_chunk.iter().flat_map(|(_, candidates)| candidates) {
        if pairs.last().is_none_or(|&(last, _)| last + 1 < i) {
            pairs.push((i, key));
        }
    }
    let key_chunks: Vec<&[TurnKey]> = per_chunk.iter().map(|(keys, _)| &keys[..]).collect();
    let mut in_pair = vec![false; records.len()];
    for &(i, _) in &pairs {
        in_pair[i] = true;
        in_pair[i + 1] = true;
    }
    // Every shared image with the records that use it: singles in runs of neighbours first
    // (neighbouring records mostly share a key), then sorted and merged.
    let mut uses: Vec<(Shared, usize)> = key_chunks
        .par_iter()
        .zip(in_pair.par_chunks(CHUNK))
        .flat_map_iter(|(chunk, paired)| {
            let mut runs: Vec<(Shared, usize)> = Vec::new();
            for (&k, _) in chunk.iter().zip(paired).filter(|(&k, &p)| k != NONE && !p) {
                match runs.last_mut() {
                    Some((Shared::Single(last), n)) if *last == k => *n += 1,
                    _ => runs.push((Shared::Single(k), 1)),
                }
            }
            runs
        })
        .collect();
    uses.par_extend(pairs.par_chunks(4096).flat_map_iter(|chunk| {
        let mut runs: Vec<(Shared, usize)> = Vec::new();
        for &(_, key) in chunk {
            match runs.last_mut() {
                Some((Shared::Pair(last), n)) if *last == key => *n += 1,
                _ => runs.push((Shared::Pair(key), 1)),
            }
        }
        runs
    }));
    if uses.is_empty() {
        return Ok(0);
    }
    uses.par_sort_unstable();
    // The most used first, then in key order, so that the memory bound drops the same images
    // on every run.
    let mut shared: Vec<(usize, Shared)> = Vec::new();
    let sparse = |psf: u32| base.dense(psf as usize).is_none();
    for run in uses.chunk_by(|a, b| a.0 == b.0) {
        let n: usize = run.iter().map(|r| r.1).sum();
        let any_sparse = match run[0].0 {
            Shared::Single(k) => sparse(psf_of(k)),
            Shared::Pair(p) => sparse(p.lo) || sparse(p.hi),
        };
        let least = if any_sparse && !every_sparse {
            MIN_SHARED_SPARSE_RECORDS
        } else if any_sparse {
            1
        } else {
            MIN_SHARED_RECORDS
        };
        if n >= least {
            shared.push((n, run[0].0));
        }
    }
    drop(uses);
    if shared.is_empty() {
        return Ok(0);
    }
    shared.sort_unstable_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
    // The turned box of a w x h image fits in a square of its diagonal, plus the taps'
    // pixels either side.
    let turned_pixels = |psf: u32| -> usize {
        base.dense(psf as usize).map_or_else(
            || {
                let side = 2 * reach.get(psf as usize).copied().unwrap_or(0).max(0) as usize + 9;
                side * side
            },
            |v| {
                let diagonal = ((v.width * v.width + v.height * v.height) as f32).sqrt();
                let side = diagonal.ceil() as usize + 5;
                side * side
            },
        )
    };
    let mut budget = MAX_FRAME_TURNED_PIXELS;
    let mut chosen: Vec<Shared> = Vec::with_capacity(shared.len());
    for &(_, key) in &shared {
        let pixels = match key {
            Shared::Single(k) => turned_pixels(psf_of(k)),
            Shared::Pair(p) => turned_pixels(p.lo).max(turned_pixels(p.hi)),
        };
        if pixels > budget {
            continue;
        }
        budget -= pixels;
        chosen.push(key);
    }
    chosen.sort_unstable();
    // Each PSF turned once per (turn step, steps) the chosen images need, in parallel.
    let mut turns: Vec<(u32, u32, u32)> = chosen
        .iter()
        .flat_map(|key| match *key {
            Shared::Single(k) => {
                let psf = psf_of(k);
                vec![(psf, k as u32, steps[psf as usize])]
            }
            Shared::Pair(p) => vec![
                (p.lo, p.lo_step, steps[p.lo as usize]),
                (p.hi, p.hi_step, steps[p.hi as usize]),
            ],
        })
        .collect();
    turns.sort_unstable();
    turns.dedup();
    let mut psfs: Vec<u32> = turns.iter().map(|t| t.0).collect();
    psfs.dedup();
    let upright: Vec<Option<PsfImage>> = psfs
        .par_iter()
        .map(|&i| psf_image(base, i as usize))
        .collect();
    let turned: Vec<Option<PsfImage>> = turns
        .par_iter()
        .map(|&(psf, step, n)| {
            let at = psfs.binary_search(&psf).ok()?;
            let image = upright[at].as_ref()?;
            let angle = crate::motion_smear::turn_rad(step, n);
            Some(turn(image, angle)).filter(|img| img.width > 0 && img.height > 0)
        })
        .collect();
    let turned_of = |psf: u32, step: u32, n: u32| -> Option<&PsfImage> {
        let at = turns.binary_search(&(psf, step, n)).ok()?;
        turned[at].as_ref()
    };
    // Singles are their turned image; pairs are mixed.
    let mixes: Vec<Option<PsfImage>> = chosen
        .par_iter()
        .map(|key| match *key {
            Shared::Single(_) => None,
            Shared::Pair(p) => {
                let a = turned_of(p.lo, p.lo_step, steps[p.lo as usize])?;
                let b = turned_of(p.hi, p.hi_step, steps[p.hi as usize])?;
                let s = p.share_step as f32 / PAIR_SHARE_STEPS as f32;
                weighted_sum(&[(a, 1.0 - s), (b, s)])
            }
        })
        .collect();
    let images: Vec<Option<&PsfImage>> = chosen
        .iter()
        .zip(&mixes)
        .map(|(key, mix)| match *key {
            Shared::Single(k) => turned_of(psf_of(k), k as u32, steps[psf_of(k) as usize]),
            Shared::Pair(_) => mix.as_ref(),
        })
        .collect();
    let boxes: Vec<_> = images
        .iter()
        .flatten()
        .map(|img| (img.origin, img.width, img.height))
        .collect();
    let mut index_of_key: Vec<Option<u32>> = Vec::with_capacity(chosen.len());
    let mut drawn: Vec<&PsfImage> = Vec::with_capacity(boxes.len());
    let first = base.psf_count() as u32;
    for img in &images {
        index_of_key.push(img.map(|img| {
            drawn.push(img);
            first + drawn.len() as u32 - 1
        }));
    }
    let not_built = |e: psf_db::DbError| ClassifyError::PhysicalLens(e.to_string());
    let extension = crate::dbset::extend_with_dense(base, &boxes).map_err(not_built)?;
    let database = extension
        .fill(|i, out| out.copy_from_slice(&drawn[i].data))
        .map_err(not_built)?;
    let index_of = |key: Shared| -> Option<u32> {
        let k = chosen.binary_search(&key).ok()?;
        index_of_key[k]
    };
    // Premixed pairs: the first record draws both (their colours and weights summed), the
    // second is dropped.
    let pair_images: Vec<Option<u32>> = pairs
        .par_chunks(4096)
        .flat_map_iter(|chunk| {
            let mut last: Option<(PairKey, Option<u32>)> = None;
            chunk.iter().map(move |&(_, key)| match last {
                Some((k, index)) if k == key => index,
                _ => {
                    let index = index_of(Shared::Pair(key));
                    last = Some((key, index));
                    index
                }
            })
        })
        .collect();
    let mut dropped = vec![false; classified.records.len()];
    let mut drawn_shared = 0;
    for (&(i, _), index) in pairs.iter().zip(pair_images) {
        if let Some(index) = index {
            let second = classified.records[i + 1];
            let r = &mut classified.records[i];
            r.psf_index = index;
            (r.rot_cos, r.rot_sin) = (1.0, 0.0);
            r.path = SplatPath::Dense as u32;
            r.weight += second.weight;
            for (c, s) in r.color.iter_mut().zip(second.color) {
                *c += s;
            }
            dropped[i + 1] = true;
            drawn_shared += 1;
        }
    }
    // Records in chunks, each remembering the last key it looked up: neighbours share keys.
    drawn_shared += classified
        .records
        .par_chunks_mut(CHUNK)
        .zip(key_chunks.par_iter())
        .zip(in_pair.par_chunks(CHUNK))
        .map(|((records, keys), paired)| {
            let mut last: Option<(TurnKey, Option<u32>)> = None;
            let mut redirected = 0;
            for ((r, &key), &p) in records.iter_mut().zip(keys.iter()).zip(paired) {
                if key == NONE || p {
                    continue;
                }
                let index = match last {
                    Some((k, index)) if k == key => index,
                    _ => {
                        let index = index_of(Shared::Single(key));
                        last = Some((key, index));
                        index
                    }
                };
                if let Some(i) = index {
                    r.psf_index = i;
                    (r.rot_cos, r.rot_sin) = (1.0, 0.0);
                    r.path = SplatPath::Dense as u32;
                    redirected += 1;
                }
            }
            redirected
        })
        .sum::<usize>();
    // Sparse records drawn from dense images moved to the other kind of plane: the layers'
    // counts say which planes the splat makes, so they are counted again.
    drop_records(classified, &dropped);
    classified.database = Some(std::sync::Arc::new(database));
    Ok(drawn_shared)
}

/// `classified` without the records `dropped` marks, each layer's place and path counts
/// updated.
fn drop_records(classified: &mut Classified, dropped: &[bool]) {
    if !dropped.iter().any(|&d| d) {
        count_paths_again(classified);
        return;
    }
    let kept_per_layer: Vec<usize> = classified
        .layers
        .par_iter()
        .map(|info| {
            let range = info.first_record..info.first_record + info.record_count;
            dropped[range].iter().filter(|&&d| !d).count()
        })
        .collect();
    // Compacted in place: layers are contiguous and in order, so one pass keeps them so,
    // without a second list of records to allocate and fault in.
    let mut at = 0;
    classified.records.retain(|_| {
        at += 1;
        !dropped[at - 1]
    });
    let kept = &classified.records;
    let mut first_record = 0;
    let counts = &mut classified.counts;
    (counts.sparse, counts.dense, counts.copied) = (0, 0, 0);
    for (info, &n) in classified.layers.iter_mut().zip(&kept_per_layer) {
        *info = crate::pipeline::types::LayerInfo {
            first_record,
            record_count: n,
            sparse: 0,
            dense: 0,
            copied: 0,
            ..*info
        };
        info.count_paths(&kept[first_record..first_record + n]);
        counts.add_layer(info);
        first_record += n;
    }
    classified.frame.record_count = classified.records.len() as u32;
}

/// Each layer's path counts, and the frame's, from its records as they are now.
fn count_paths_again(classified: &mut Classified) {
    let records = &classified.records;
    let counts = &mut classified.counts;
    (counts.sparse, counts.dense, counts.copied) = (0, 0, 0);
    for info in &mut classified.layers {
        (info.sparse, info.dense, info.copied) = (0, 0, 0);
        info.count_paths(&records[info.first_record..info.first_record + info.record_count]);
        counts.add_layer(info);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_moves_the_rim_at_most_the_bound() {
        for reach in [1.0f32, 2.0, 5.5, 12.0, 40.0] {
            let steps = turn_steps(reach);
            let rim_move = reach * std::f32::consts::TAU / steps as f32;
            assert!(rim_move <= RIM_STEP_PX + 1e-6, "reach {reach}: {rim_move} px");
        }
    }
}
