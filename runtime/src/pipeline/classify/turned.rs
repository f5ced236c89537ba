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
//! appended to the frame's database. Those records then
//! draw it upright. A record whose key is not shared keeps its own exact turn and is drawn
//! turned as before, so no record is quantised without it paying off.

use rayon::prelude::*;

use psf_db::PsfDatabase;

use super::ClassifyError;
use crate::motion_smear::{psf_image, turn, PsfImage};
use crate::pipeline::types::{psf_reach, Classified, SplatPath, SplatRecord};

/// Largest move of a PSF's rim between neighbouring turn steps, px: a record drawn from its
/// step's image has its rim at most half of this from where its own turn puts it.
pub const RIM_STEP_PX: f32 = 0.5;

/// Records that must share a (PSF, turn step) for it to be turned once: turning costs about
/// what drawing one record turned costs.
pub const MIN_SHARED_RECORDS: usize = 2;

/// Most pixels of turned images one frame appends, summed (each holds a value per channel):
/// beyond it, the keys used by fewest records are drawn turned as before.
pub const MAX_FRAME_TURNED_PIXELS: usize = 16 << 20;

/// A dense PSF and a quantised turn of it, packed into one integer (the PSF's index in the
/// high half, the turn step in the low) so that a frame's keys sort fast; `NONE` for a record
/// drawn upright already.
type TurnKey = u64;
const NONE: TurnKey = u64::MAX;

fn psf_of(key: TurnKey) -> u32 {
    (key >> 32) as u32
}

/// Turn steps over a full turn for a PSF reaching `reach_px` from its centre: its rim moves
/// at most [`RIM_STEP_PX`] per step.
pub fn turn_steps(reach_px: f32) -> u32 {
    (std::f32::consts::TAU * reach_px.max(1.0) / RIM_STEP_PX)
        .ceil()
        .clamp(8.0, 4096.0) as u32
}

/// The key of a dense record turned by its rotation, or [`NONE`] when it is drawn upright
/// already. `steps[i]` is PSF `i`'s turn steps, 0 for a PSF without a dense image.
fn key_of(r: &SplatRecord, steps: &[u32]) -> TurnKey {
    if r.path != SplatPath::Dense as u32 || (r.rot_cos == 1.0 && r.rot_sin == 0.0) {
        return NONE;
    }
    let n = match steps.get(r.psf_index as usize) {
        Some(&n) if n > 0 => n,
        _ => return NONE,
    };
    let angle = r.rot_sin.atan2(r.rot_cos).rem_euclid(std::f32::consts::TAU);
    let step = ((angle / std::f32::consts::TAU * n as f32).round() as u32) % n;
    (u64::from(r.psf_index) << 32) | u64::from(step)
}

/// Redirects the dense records of `classified` whose (PSF, turn step) is shared to that PSF
/// turned once, drawn upright; `base` is the database the records index now. The frame's
/// database becomes `base` followed by the turned images. Returns how many records were
/// redirected.
pub(super) fn draw_shared_turns_upright(
    classified: &mut Classified,
    base: &PsfDatabase,
) -> Result<usize, ClassifyError> {
    let reach = psf_reach(base);
    let steps: Vec<u32> = (0..base.psf_count())
        .map(|i| match base.dense(i) {
            Some(_) => turn_steps(reach[i] as f32),
            None => 0,
        })
        .collect();
    let keys: Vec<TurnKey> = classified
        .records
        .par_iter()
        .map(|r| key_of(r, &steps))
        .collect();
    // Neighbouring records mostly share a key (one cell, nearly one turn): each chunk's runs
    // of one key counted first, then the runs sorted and merged.
    let mut runs: Vec<(TurnKey, usize)> = keys
        .par_chunks(4096)
        .flat_map_iter(|chunk| {
            let mut runs: Vec<(TurnKey, usize)> = Vec::new();
            for &k in chunk.iter().filter(|&&k| k != NONE) {
                match runs.last_mut() {
                    Some((last, n)) if *last == k => *n += 1,
                    _ => runs.push((k, 1)),
                }
            }
            runs
        })
        .collect();
    if runs.is_empty() {
        return Ok(0);
    }
    runs.par_sort_unstable();
    // Each key with the records that use it; the most used first, then in key order, so that
    // the memory bound drops the same keys on every run.
    let mut shared: Vec<(usize, TurnKey)> = Vec::new();
    for run in runs.chunk_by(|a, b| a.0 == b.0) {
        let n: usize = run.iter().map(|r| r.1).sum();
        if n >= MIN_SHARED_RECORDS {
            shared.push((n, run[0].0));
        }
    }
    drop(runs);
    if shared.is_empty() {
        return Ok(0);
    }
    shared.sort_unstable_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut budget = MAX_FRAME_TURNED_PIXELS;
    let mut chosen: Vec<TurnKey> = Vec::with_capacity(shared.len());
    for &(_, key) in &shared {
        let Some(view) = base.dense(psf_of(key) as usize) else {
            continue;
        };
        // The turned box of a w x h image fits in a square of its diagonal, plus the taps'
        // pixel either side.
        let diagonal = ((view.width * view.width + view.height * view.height) as f32).sqrt();
        let side = diagonal.ceil() as usize + 3;
        let pixels = side * side;
        if pixels > budget {
            continue;
        }
        budget -= pixels;
        chosen.push(key);
    }
    chosen.sort_unstable();
    // Each PSF's image once (many keys turn the same PSF), then each key's turn of it.
    let mut psfs: Vec<u32> = chosen.iter().map(|&k| psf_of(k)).collect();
    psfs.dedup();
    let upright: Vec<Option<PsfImage>> = psfs
        .par_iter()
        .map(|&i| psf_image(base, i as usize))
        .collect();
    let images: Vec<Option<PsfImage>> = chosen
        .par_iter()
        .map(|&key| {
            let psf = psf_of(key);
            let at = psfs.binary_search(&psf).ok()?;
            let image = upright[at].as_ref()?;
            let angle = crate::motion_smear::turn_rad(key as u32, steps[psf as usize]);
            Some(turn(image, angle)).filter(|img| img.width > 0 && img.height > 0)
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
        index_of_key.push(img.as_ref().map(|img| {
            drawn.push(img);
            first + drawn.len() as u32 - 1
        }));
    }
    let not_built = |e: psf_db::DbError| ClassifyError::PhysicalLens(e.to_string());
    let extension = crate::dbset::extend_with_dense(base, &boxes).map_err(not_built)?;
    let database = extension
        .fill(|i, out| out.copy_from_slice(&drawn[i].data))
        .map_err(not_built)?;
    // Records in chunks, each remembering the last key it looked up: neighbours share keys.
    let redirected = classified
        .records
        .par_chunks_mut(4096)
        .zip(keys.par_chunks(4096))
        .map(|(records, keys)| {
            let mut last: Option<(TurnKey, Option<u32>)> = None;
            let mut redirected = 0;
            for (r, &key) in records.iter_mut().zip(keys) {
                if key == NONE {
                    continue;
                }
                let index = match last {
                    Some((k, index)) if k == key => index,
                    _ => {
                        let index = chosen.binary_search(&key).ok().and_then(|k| index_of_key[k]);
                        last = Some((key, index));
                        index
                    }
                };
                if let Some(i) = index {
                    r.psf_index = i;
                    (r.rot_cos, r.rot_sin) = (1.0, 0.0);
                    redirected += 1;
                }
            }
            redirected
        })
        .sum();
    classified.database = Some(std::sync::Arc::new(database));
    Ok(redirected)
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
