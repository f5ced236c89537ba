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
//! depth. Where both are dense, the fragment is emitted as one record that names both PSFs and
//! the neighbour's share ([`pack_pair`]), and that pair is premixed here: the two PSFs turned,
//! then mixed in the proportion of their weights (rounded to [`PAIR_SHARE_STEPS`]), and drawn
//! as one upright record, where drawing the two would cost twice as much. Through the double
//! Gauss half of a frame's fragments blend: as one record each, the frame's records are a third
//! fewer from the start. A pair whose image the frame's memory bound leaves out is split into
//! its two PSFs' records at the rounded share, drawn turned. Near the optical axis the two
//! PSFs' rotational averages are a pair too.
//!
//! Mixed as they are, two PSFs a cell apart draw two rims a cell's blur apart (0.6-1.3 px
//! through the double Gauss at 512 px), and a bokeh's rim comes out softer than the lens's.
//! So each PSF of a pair away from the focus plane is first scaled onto the blend's own
//! defocus ([`morph_scales`]: a lens's blur grows in proportion to the inverse depth from the
//! focus plane) in the same cubic pass that turns it, and the two rims coincide.

use rayon::prelude::*;

use psf_db::PsfDatabase;

use super::ClassifyError;
use crate::motion_smear::{add_weighted, psf_image, turn_scaled, union_box, PsfImage};
use crate::pipeline::types::{frame_psf_reach, Classified, FrameParams, SplatPath, SplatRecord};

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

/// The path of a still pixel's blend of two turned dense PSFs while it is one record (see
/// [`pack_pair`]). It never leaves classification: [`draw_shared_turns_upright`] draws each
/// such record from its premixed image, or splits it into its two PSFs' records.
const PAIR_PATH: u32 = 0x100;

/// A fragment's blend of two turned dense PSFs (or of their rotational averages, upright) as
/// one record, where it would be two records at one pixel with one rotation (`first` and
/// `second`: each PSF and its weight; `color`, the
/// fragment's colour). The record holds the two colours summed and the two weights summed,
/// as premixing them sums them; its PSF is the lower index of the two, the higher goes in the
/// high bits of its layer, and its path is [`PAIR_PATH`] with the higher PSF's share in steps
/// of [`PAIR_SHARE_STEPS`]. `None` where the two do not fit those fields or a weight is not
/// positive: then they are two records.
pub(super) fn pack_pair(
    (x, y): (i32, i32),
    layer: u32,
    (rot_cos, rot_sin): (f32, f32),
    color: [f32; 4],
    first: (u32, f32),
    second: (u32, f32),
) -> Option<SplatRecord> {
    let ((a, wa), (b, wb)) = (first, second);
    if a == b || wa <= 0.0 || wb <= 0.0 || layer > 0xFF {
        return None;
    }
    let (lo, hi, w_hi) = if a < b { (a, b, wb) } else { (b, a, wa) };
    if hi > 0x00FF_FFFF {
        return None;
    }
    let share = w_hi / (wa + wb);
    let share_step = ((share * PAIR_SHARE_STEPS as f32).round() as u32).min(PAIR_SHARE_STEPS);
    let (ca, cb) = (color.map(|v| v * wa), color.map(|v| v * wb));
    Some(SplatRecord {
        center_x: x,
        center_y: y,
        psf_index: lo,
        layer: layer | (hi << 8),
        rot_cos,
        rot_sin,
        weight: wa + wb,
        path: PAIR_PATH | share_step,
        color: [0, 1, 2, 3].map(|c| ca[c] + cb[c]),
    })
}

/// A record made by [`pack_pair`]: its two PSFs (lower index first), the higher one's share
/// in steps of [`PAIR_SHARE_STEPS`], and its layer.
pub(super) fn pair_parts(r: &SplatRecord) -> Option<(u32, u32, u32, u32)> {
    (r.path & !0xFF == PAIR_PATH).then_some((
        r.psf_index,
        r.layer >> 8,
        r.path & 0xFF,
        r.layer & 0xFF,
    ))
}

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

/// The scales that give the two PSFs of pair `p` the size of the blend's own depth before they
/// are mixed, `[lower, higher]`. `defocus[i]` is PSF `i`'s inverse depth less the focus
/// plane's (1 / scene units; NaN where it has none). A lens's blur grows in proportion to it,
/// so at the blend's defocus `d = (1 - s) d_lo + s d_hi` the two PSFs scaled by `d / d_lo` and
/// `d / d_hi` have their rims where the blend's depth has its rim: mixed, the rim stays sharp
/// (mixed unscaled, two rims a cell's blur apart). `[1, 1]` near the focus plane (within
/// [`psf_db::space::SCALED_BLEND_MIN_CELLS_FROM_FOCUS`] cells, whose PSFs the precompute
/// pre-filters over their inverse depths instead) or across it, where the blur does not scale
/// so.
fn morph_scales(defocus: &[f32], p: &PairKey) -> [f32; 2] {
    let at = |i: u32| defocus.get(i as usize).copied().unwrap_or(f32::NAN);
    let (d_lo, d_hi) = (at(p.lo), at(p.hi));
    let width = (d_hi - d_lo).abs();
    let nearest = d_lo.abs().min(d_hi.abs());
    // NaN fails every comparison: no scaling.
    let least = psf_db::space::SCALED_BLEND_MIN_CELLS_FROM_FOCUS as f32;
    if !(d_lo * d_hi > 0.0 && nearest >= least * width && width > 0.0) {
        return [1.0, 1.0];
    }
    let s = p.share_step as f32 / PAIR_SHARE_STEPS as f32;
    let d = (1.0 - s) * d_lo + s * d_hi;
    [d / d_lo, d / d_hi]
}

/// For each of the first `count` PSFs of the frame's database: its inverse depth less the
/// focus plane's (1 / scene units), for the physical-lens PSFs of `dbs` and their rotational
/// averages on the axis; NaN for every other.
pub(super) fn lens_defocus(dbs: &crate::dbset::DbSet, count: usize) -> Vec<f32> {
    let mut defocus = vec![f32::NAN; count];
    let Some(main) = dbs.main.as_ref() else {
        return defocus;
    };
    let Some(lens) = main
        .header()
        .lens
        .as_ref()
        .filter(|l| l.focus_distance > 0.0)
    else {
        return defocus;
    };
    let focus = 1.0 / lens.focus_distance;
    let offset = dbs.main_offset as usize;
    for i in 0..main.psf_count() {
        let Some(centre) = main.space().cell_center(i as u32) else {
            continue;
        };
        let d = (centre[0] - focus) as f32;
        if let Some(slot) = defocus.get_mut(offset + i) {
            *slot = d;
        }
        let round = dbs.axis_round.get(offset + i).copied();
        if let Some(slot) = round
            .filter(|&r| r != crate::dbset::NO_TWIN)
            .and_then(|r| defocus.get_mut(r as usize))
        {
            *slot = d;
        }
    }
    defocus
}

/// A run of records' keys, and its records made by [`pack_pair`] (each one's index in the
/// frame and its pair key).
type KeysAndPairs = (Vec<TurnKey>, Vec<(usize, PairKey)>);

/// What a shared image appended to the frame's database is drawn from: one PSF turned, or two
/// turned PSFs mixed with their weights.
enum Source<'a> {
    Turned(&'a PsfImage),
    Mix([(&'a PsfImage, f32); 2]),
}

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
        (u64::from(r.psf_index) << 32) | u64::from(step_of_angle(self.angle(r), n))
    }

    /// The pair key of a record made by [`pack_pair`]: each PSF's turn step is what a record
    /// of it alone at this rotation would have. `None` for any other record, or where either
    /// PSF is not turned.
    fn pair(&mut self, r: &SplatRecord) -> Option<PairKey> {
        let (lo, hi, share_step, _) = pair_parts(r)?;
        let steps = |psf: u32| self.steps.get(psf as usize).copied().filter(|&n| n > 0);
        let (n_lo, n_hi) = (steps(lo)?, steps(hi)?);
        let angle = self.angle(r);
        Some(PairKey {
            lo,
            hi,
            share_step,
            lo_step: step_of_angle(angle, n_lo),
            hi_step: step_of_angle(angle, n_hi),
        })
    }

    /// The angle of `r`'s rotation ([`turn_angle`]), remembered for the next record.
    fn angle(&mut self, r: &SplatRecord) -> f32 {
        let rotation = (r.rot_cos.to_bits(), r.rot_sin.to_bits());
        match self.last {
            Some((last, angle)) if last == rotation => angle,
            _ => {
                let angle = turn_angle(r);
                self.last = Some((rotation, angle));
                angle
            }
        }
    }
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
    let sparse = || {
        records
            .iter()
            .filter(|r| r.path == SplatPath::Sparse as u32)
    };
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
    cost += images_cost(&mut keys, side);
    !keys.is_empty() && cost <= most
}

/// What building one image per distinct key of `keys` (PSF, and how it is turned) costs, each
/// `side(psf)` pixels square, in [`IMAGE_BUILD_COST`] per pixel; `keys` is left sorted and
/// without repeats.
pub(super) fn images_cost<K: Ord>(keys: &mut Vec<(u32, K)>, side: impl Fn(u32) -> usize) -> usize {
    keys.sort_unstable();
    keys.dedup();
    keys.iter()
        .map(|&(psf, _)| side(psf).pow(2) * IMAGE_BUILD_COST)
        .sum()
}

/// Redirects the dense records of `classified` whose (PSF, turn step) is shared to that PSF
/// turned once, drawn upright, and premixes the shared blends of two PSFs into one upright
/// record; `base` is the database the records index now. The frame's database becomes `base`
/// followed by the turned images. Returns how many records are drawn from shared images.
pub(super) fn draw_shared_turns_upright(
    classified: &mut Classified,
    base: &PsfDatabase,
    defocus: &[f32],
) -> Result<usize, ClassifyError> {
    let reach = frame_psf_reach(base, classified.packed.as_deref());
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
    // Every record's key, and the premixed pairs' (their records' index and key), in one pass
    // over the records in chunks on every thread.
    const CHUNK: usize = 4096;
    let per_chunk: Vec<KeysAndPairs> = records
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            let mut keyer = Keys {
                steps: &steps,
                last: None,
            };
            let mut pairs = Vec::new();
            let keys: Vec<TurnKey> = chunk
                .iter()
                .enumerate()
                .map(|(i, r)| {
                    if let Some(pair) = keyer.pair(r) {
                        pairs.push((c * CHUNK + i, pair));
                    }
                    keyer.of(r)
                })
                .collect();
            (keys, pairs)
        })
        .collect();
    // The keys and pairs stay in their chunks (the passes below take the records in the same
    // chunks): joined, they were lists as long as the records' written again in fresh memory.
    let key_chunks: Vec<&[TurnKey]> = per_chunk.iter().map(|(keys, _)| &keys[..]).collect();
    // Every shared image with the records that use it: singles in runs of neighbours first
    // (neighbouring records mostly share a key), then sorted and merged.
    let mut uses: Vec<(Shared, usize)> = key_chunks
        .par_iter()
        .flat_map_iter(|chunk| {
            let mut runs: Vec<(Shared, usize)> = Vec::new();
            for &k in chunk.iter().filter(|&&k| k != NONE) {
                match runs.last_mut() {
                    Some((Shared::Single(last), n)) if *last == k => *n += 1,
                    _ => runs.push((Shared::Single(k), 1)),
                }
            }
            runs
        })
        .collect();
    uses.par_extend(per_chunk.par_iter().flat_map_iter(|(_, pairs)| {
        let mut runs: Vec<(Shared, usize)> = Vec::new();
        for &(_, key) in pairs {
            match runs.last_mut() {
                Some((Shared::Pair(last), n)) if *last == key => *n += 1,
                _ => runs.push((Shared::Pair(key), 1)),
            }
        }
        runs
    }));
    if uses.is_empty() {
        split_pairs(classified);
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
        // A pair is one record already: split, it would be two records drawn turned.
        let least = if any_sparse && !every_sparse {
            MIN_SHARED_SPARSE_RECORDS
        } else if any_sparse || matches!(run[0].0, Shared::Pair(_)) {
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
        split_pairs(classified);
        return Ok(0);
    }
    shared.sort_unstable_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
    // The turned box of a w x h image fits in a square of its diagonal, plus the taps'
    // pixels either side.
    let turned_pixels_unscaled = |psf: u32| -> usize {
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
    let scales_of = |p: &PairKey| morph_scales(defocus, p);
    let turned_pixels = |psf: u32, scale: f32| -> usize {
        let grown = scale.max(1.0);
        (turned_pixels_unscaled(psf) as f32 * grown * grown).ceil() as usize
    };
    let mut budget = MAX_FRAME_TURNED_PIXELS;
    let mut chosen: Vec<Shared> = Vec::with_capacity(shared.len());
    for &(_, key) in &shared {
        let pixels = match key {
            Shared::Single(k) => turned_pixels(psf_of(k), 1.0),
            Shared::Pair(p) => {
                let [k_lo, k_hi] = scales_of(&p);
                turned_pixels(p.lo, k_lo).max(turned_pixels(p.hi, k_hi))
            }
        };
        if pixels > budget {
            continue;
        }
        budget -= pixels;
        chosen.push(key);
    }
    chosen.sort_unstable();
    // Each PSF turned once per (turn step, steps, scale) the chosen images need, in parallel
    // (the scale as its bits: a positive float's bits sort as it does).
    let one = 1f32.to_bits();
    let mut turns: Vec<(u32, u32, u32, u32)> = chosen
        .iter()
        .flat_map(|key| match *key {
            Shared::Single(k) => {
                let psf = psf_of(k);
                vec![(psf, k as u32, steps[psf as usize], one)]
            }
            Shared::Pair(p) => {
                let [k_lo, k_hi] = scales_of(&p);
                vec![
                    (p.lo, p.lo_step, steps[p.lo as usize], k_lo.to_bits()),
                    (p.hi, p.hi_step, steps[p.hi as usize], k_hi.to_bits()),
                ]
            }
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
        .map(|&(psf, step, n, scale)| {
            let at = psfs.binary_search(&psf).ok()?;
            let image = upright[at].as_ref()?;
            let angle = crate::motion_smear::turn_rad(step, n);
            Some(turn_scaled(image, angle, f32::from_bits(scale)))
                .filter(|img| img.width > 0 && img.height > 0)
        })
        .collect();
    let turned_of = |psf: u32, step: u32, n: u32, scale: f32| -> Option<&PsfImage> {
        let at = turns.binary_search(&(psf, step, n, scale.to_bits())).ok()?;
        turned[at].as_ref()
    };
    // Singles are their turned image; pairs are mixed as they are written into the frame's
    // database, not built on their own first.
    let sources: Vec<Option<Source>> = chosen
        .iter()
        .map(|key| match *key {
            Shared::Single(k) => {
                turned_of(psf_of(k), k as u32, steps[psf_of(k) as usize], 1.0).map(Source::Turned)
            }
            Shared::Pair(p) => {
                let [k_lo, k_hi] = scales_of(&p);
                let a = turned_of(p.lo, p.lo_step, steps[p.lo as usize], k_lo)?;
                let b = turned_of(p.hi, p.hi_step, steps[p.hi as usize], k_hi)?;
                let s = p.share_step as f32 / PAIR_SHARE_STEPS as f32;
                (a.channels == b.channels).then_some(Source::Mix([(a, 1.0 - s), (b, s)]))
            }
        })
        .collect();
    let mut boxes = Vec::with_capacity(sources.len());
    let mut index_of_key: Vec<Option<u32>> = Vec::with_capacity(chosen.len());
    let mut drawn: Vec<&Source> = Vec::with_capacity(sources.len());
    let first = base.psf_count() as u32;
    for source in &sources {
        let shape = source.as_ref().and_then(|source| match source {
            Source::Turned(image) => Some((image.origin, image.width, image.height)),
            Source::Mix(parts) => union_box(parts),
        });
        index_of_key.push(shape.zip(source.as_ref()).map(|(shape, source)| {
            boxes.push(shape);
            drawn.push(source);
            first + drawn.len() as u32 - 1
        }));
    }
    let not_built = |e: psf_db::DbError| ClassifyError::PhysicalLens(e.to_string());
    let extension = crate::dbset::extend_with_dense(base, &boxes).map_err(not_built)?;
    let database = extension
        .fill(|i, out| match drawn[i] {
            Source::Turned(image) => out.copy_from_slice(&image.data),
            Source::Mix(parts) => {
                // Written before it is read: a fresh page read first is mapped twice (the
                // zero page, then its own copy), which made the mixing ten times slower.
                out.fill(0.0);
                add_weighted(out, parts);
            }
        })
        .map_err(not_built)?;
    let index_of = |key: Shared| -> Option<u32> {
        let k = chosen.binary_search(&key).ok()?;
        index_of_key[k]
    };
    // Premixed pairs: the record draws its premixed image upright (its colours and weights
    // are the two PSFs' summed already). Records in chunks, each remembering the last pair it
    // looked up.
    let (mut drawn_shared, unmixed) = classified
        .records
        .par_chunks_mut(CHUNK)
        .zip(per_chunk.par_iter())
        .enumerate()
        .map(|(c, (records, (_, pairs)))| {
            let mut last: Option<(PairKey, Option<u32>)> = None;
            let (mut mixed, mut unmixed) = (0, 0);
            for &(i, key) in pairs {
                let index = match last {
                    Some((k, index)) if k == key => index,
                    _ => {
                        let index = index_of(Shared::Pair(key));
                        last = Some((key, index));
                        index
                    }
                };
                let Some(index) = index else {
                    unmixed += 1;
                    continue;
                };
                let r = &mut records[i - c * CHUNK];
                r.psf_index = index;
                r.layer &= 0xFF;
                (r.rot_cos, r.rot_sin) = (1.0, 0.0);
                r.path = SplatPath::Dense as u32;
                mixed += 1;
            }
            (mixed, unmixed)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    // Records in chunks, each remembering the last key it looked up: neighbours share keys.
    drawn_shared += classified
        .records
        .par_chunks_mut(CHUNK)
        .zip(key_chunks.par_iter())
        .map(|(records, keys)| {
            let mut last: Option<(TurnKey, Option<u32>)> = None;
            let mut redirected = 0;
            for (r, &key) in records.iter_mut().zip(keys.iter()) {
                if key == NONE {
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
    // Pairs without a premixed image become their two PSFs' records; sparse records drawn
    // from dense images moved to the other kind of plane: the layers' counts say which
    // planes the splat makes, so they are counted again.
    if unmixed > 0 {
        split_pairs(classified);
    } else {
        count_paths_again(classified);
    }
    classified.database = Some(std::sync::Arc::new(database));
    Ok(drawn_shared)
}

/// Every record of `classified` still made by [`pack_pair`] replaced by its two PSFs' records,
/// the lower index first, each with its share of the pair's colour and weight (the share as
/// premixing rounds it) and the pair's rotation; then each layer's place and path counts.
fn split_pairs(classified: &mut Classified) {
    let pairs = classified
        .records
        .par_iter()
        .filter(|r| pair_parts(r).is_some())
        .count();
    if pairs > 0 {
        let mut records = Vec::with_capacity(classified.records.len() + pairs);
        for info in &mut classified.layers {
            let layer = &classified.records[info.first_record..][..info.record_count];
            info.first_record = records.len();
            for r in layer {
                let Some((lo, hi, share_step, l)) = pair_parts(r) else {
                    records.push(*r);
                    continue;
                };
                let s = share_step as f32 / PAIR_SHARE_STEPS as f32;
                for (psf, share) in [(lo, 1.0 - s), (hi, s)] {
                    if share == 0.0 {
                        continue;
                    }
                    records.push(SplatRecord {
                        psf_index: psf,
                        layer: l,
                        weight: r.weight * share,
                        path: SplatPath::Dense as u32,
                        color: r.color.map(|c| c * share),
                        ..*r
                    });
                }
            }
            info.record_count = records.len() - info.first_record;
        }
        classified.records = records;
        classified.frame.record_count = classified.records.len() as u32;
    }
    count_paths_again(classified);
}

/// Each layer's path counts, and the frame's, from its records as they are now.
pub(super) fn count_paths_again(classified: &mut Classified) {
    let records = &classified.records;
    let counts = &mut classified.counts;
    (counts.sparse, counts.dense, counts.copied) = (0, 0, 0);
    classified.layers.par_iter_mut().for_each(|info| {
        (info.sparse, info.dense, info.copied) = (0, 0, 0);
        info.count_paths(&records[info.first_record..info.first_record + info.record_count]);
    });
    for info in &classified.layers {
        counts.add_layer(info);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::types::{LayerInfo, PathCounts};

    /// Half a turn's eighth: a rotation a pair may be packed at.
    const TURNED: (f32, f32) = (
        std::f32::consts::FRAC_1_SQRT_2,
        std::f32::consts::FRAC_1_SQRT_2,
    );

    fn pair(share_step: u32) -> PairKey {
        PairKey {
            lo: 0,
            hi: 1,
            share_step,
            lo_step: 0,
            hi_step: 0,
        }
    }

    /// Behind the focus plane, two cells 0.2 and 0.25 inverse units from it: the blend's
    /// share moves its defocus linearly between them, and each PSF is scaled onto it. Near
    /// the focus plane, across it, or without a defocus, the PSFs are mixed as they are.
    #[test]
    fn a_pair_is_scaled_onto_the_blends_own_defocus() {
        let [lo, hi] = morph_scales(&[0.2, 0.25], &pair(PAIR_SHARE_STEPS / 4));
        let d = 0.75 * 0.2 + 0.25 * 0.25;
        assert!(
            (lo - d / 0.2).abs() < 1e-6 && (hi - d / 0.25).abs() < 1e-6,
            "{lo} {hi}"
        );
        assert!(lo > 1.0 && hi < 1.0);
        // In front of it (negative): the same scales.
        let [lo_f, hi_f] = morph_scales(&[-0.2, -0.25], &pair(PAIR_SHARE_STEPS / 4));
        assert_eq!([lo_f, hi_f], [lo, hi]);
        for defocus in [[0.1, 0.14], [-0.02, 0.03], [f32::NAN, 0.25], [0.2, 0.2]] {
            assert_eq!(morph_scales(&defocus, &pair(8)), [1.0, 1.0], "{defocus:?}");
        }
        // A PSF without a defocus entry (beyond the table) is not scaled either.
        assert_eq!(morph_scales(&[0.2], &pair(8)), [1.0, 1.0]);
    }

    #[test]
    fn a_packed_pair_holds_both_psfs_their_summed_light_and_the_higher_ones_share() {
        let colour = [0.5, 0.25, 2.0, 1.0];
        let (wa, wb) = (0.3f32, 0.1f32);
        // The first part's PSF is the higher index: the share is the first part's.
        let r = pack_pair((7, 9), 3, TURNED, colour, (40, wa), (12, wb)).expect("packed");
        let (lo, hi, share_step, layer) = pair_parts(&r).expect("a pair");
        assert_eq!((lo, hi, layer), (12, 40, 3));
        assert_eq!(
            share_step,
            (wa / (wa + wb) * PAIR_SHARE_STEPS as f32).round() as u32
        );
        assert_eq!(r.weight, wa + wb);
        for (&c, &v) in r.color.iter().zip(&colour) {
            assert_eq!(c, v * wa + v * wb);
        }
        assert_eq!(
            (r.center_x, r.center_y, r.rot_cos, r.rot_sin),
            (7, 9, TURNED.0, TURNED.1)
        );
        // Upright (two rotational averages on the axis) is a pair too.
        assert!(pack_pair((0, 0), 0, (1.0, 0.0), colour, (1, wa), (2, wb)).is_some());
        // Not a pair: a weight of zero, one PSF twice, indices or a layer beyond the fields,
        // or a record of any path.
        assert!(pack_pair((0, 0), 0, TURNED, colour, (1, 0.0), (2, wb)).is_none());
        assert!(pack_pair((0, 0), 0, TURNED, colour, (2, wa), (2, wb)).is_none());
        assert!(pack_pair((0, 0), 0, TURNED, colour, (1, wa), (1 << 24, wb)).is_none());
        assert!(pack_pair((0, 0), 256, TURNED, colour, (1, wa), (2, wb)).is_none());
        for path in [SplatPath::Sparse, SplatPath::Dense, SplatPath::Copy] {
            let plain = SplatRecord {
                path: path as u32,
                layer: 5,
                ..r
            };
            assert!(pair_parts(&plain).is_none());
        }
    }

    #[test]
    fn an_unmixed_pair_splits_into_its_two_psfs_at_the_rounded_share() {
        let colour = [1.0, 2.0, 4.0, 1.0];
        let plain = |x: i32, layer: u32| SplatRecord {
            center_x: x,
            layer,
            psf_index: 1,
            rot_cos: 1.0,
            weight: 1.0,
            path: SplatPath::Dense as u32,
            color: colour,
            ..SplatRecord::default()
        };
        let pair = pack_pair((2, 0), 1, TURNED, colour, (5, 0.75), (4, 0.25)).expect("packed");
        let records = vec![plain(0, 0), plain(1, 1), pair, plain(3, 1)];
        let layers = vec![
            LayerInfo {
                first_record: 0,
                record_count: 1,
                ..LayerInfo::default()
            },
            LayerInfo {
                first_record: 1,
                record_count: 3,
                ..LayerInfo::default()
            },
        ];
        let mut classified = Classified {
            frame: FrameParams {
                layers: 2,
                record_count: records.len() as u32,
                ..FrameParams::default()
            },
            records,
            layers,
            counts: PathCounts::default(),
            database: None,
            packed: None,
            coarse: Vec::new(),
        };
        split_pairs(&mut classified);
        let r = &classified.records;
        assert_eq!(r.len(), 5);
        assert_eq!(classified.frame.record_count, 5);
        assert_eq!(
            (
                classified.layers[1].first_record,
                classified.layers[1].record_count
            ),
            (1, 4)
        );
        assert_eq!(
            (classified.layers[1].dense, classified.counts.dense),
            (4, 5)
        );
        // The pair's place, lower index first: 0.75 of the light is PSF 5's, 12 steps of 16.
        let share = 12.0 / PAIR_SHARE_STEPS as f32;
        for (k, (psf, s)) in [(4, 1.0 - share), (5, share)].into_iter().enumerate() {
            let part = &r[2 + k];
            assert_eq!((part.psf_index, part.layer, part.center_x), (psf, 1, 2));
            assert_eq!(part.path, SplatPath::Dense as u32);
            assert_eq!((part.rot_cos, part.rot_sin), TURNED);
            assert_eq!(part.weight, pair.weight * s);
            assert_eq!(part.color, pair.color.map(|c| c * s));
        }
        assert_eq!((r[1].center_x, r[4].center_x), (1, 3));
    }

    #[test]
    fn a_step_moves_the_rim_at_most_the_bound() {
        for reach in [1.0f32, 2.0, 5.5, 12.0, 40.0] {
            let steps = turn_steps(reach);
            let rim_move = reach * std::f32::consts::TAU / steps as f32;
            assert!(
                rim_move <= RIM_STEP_PX + 1e-6,
                "reach {reach}: {rim_move} px"
            );
        }
    }
}
