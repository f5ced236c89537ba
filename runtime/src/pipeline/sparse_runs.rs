//! Sparse records drawn a row of pixels at a time.
//!
//! A layer's sparse records come in pixel order, and neighbouring pixels mostly share a PSF:
//! on a defocused wall every pixel of a row draws the same one or two PSFs (a pixel between
//! two cells of the nested grid draws both, interleaved with its neighbours'). A PSF's
//! spreadlets drawn for pixel after pixel are scattered read-modify-writes of 16 bytes each.
//! Gathered into runs (one source row, one PSF, consecutive columns), the same sums are a
//! handful of straight loops: each spreadlet `(o, v)` adds `v` times the run's colours to the
//! run's pixels shifted by `o`, `L(x0 + j + o) += v c_j` for `j` in the run. Every addition is
//! the one the record-by-record loop makes (`c v`, then added); only the order in which a pixel
//! receives them differs, which is fixed by the records and the band, not by the threads.
//!
//! Runs are found once per frame. A record is drawn in a run when the single-record loop would
//! draw it without any test per spreadlet: upright, one value per spreadlet, spreadlets in row
//! order, and its whole PSF inside the padded layer's columns.

use psf_db::PsfDatabase;
use rayon::prelude::*;

use super::splat::Band;
use super::types::{SplatPath, SplatRecord};

/// Consecutive sparse records of one layer with the same centre row and PSF, one pixel apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Run {
    /// Centre row of every record of the run, padded-layer pixels.
    pub center_y: i32,
    /// Centre column of the run's first record, padded-layer pixels.
    pub center_x: i32,
    /// The PSF every record of the run draws.
    pub psf_index: u32,
    /// Where its records' indices start in [`LayerRuns::members`].
    pub first: u32,
    /// Number of records (and pixels) in the run.
    pub len: u32,
}

/// The runs of one layer, in centre-row order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(super) struct LayerRuns {
    /// Runs sorted by centre row.
    pub runs: Vec<Run>,
    /// The records of each run (indices into the layer's records), run after run, left to
    /// right.
    pub members: Vec<u32>,
}

/// Whether record `r` is drawn in a run rather than alone: sparse, upright, from a database
/// of one value per spreadlet in row order, its PSF (reach `reach[psf]`, px) inside columns
/// `[0, width)`.
#[inline]
pub(super) fn drawn_in_run(
    r: &SplatRecord,
    reach: &[i32],
    width: i32,
    in_row_order: bool,
    channels: usize,
) -> bool {
    in_row_order
        && channels == 1
        && r.path == SplatPath::Sparse as u32
        && r.rot_cos == 1.0
        && r.rot_sin == 0.0
        && reach
            .get(r.psf_index as usize)
            .is_some_and(|&k| r.center_x - k >= 0 && r.center_x + k < width)
}

/// The runs of every layer of `records` (`layers[l]` = the layer's first record and count,
/// its records in row order), for a padded layer `width` pixels wide.
pub(super) fn find_runs(
    records: &[SplatRecord],
    layers: &[(usize, usize)],
    db: &PsfDatabase,
    reach: &[i32],
    width: i32,
    in_row_order: bool,
) -> Vec<LayerRuns> {
    let channels = db.channels();
    layers
        .iter()
        .map(|&(first, count)| {
            let recs = &records[first..first + count];
            if !in_row_order || channels != 1 {
                return LayerRuns::default();
            }
            // The layer's rows: records with one centre row follow each other.
            let mut rows = Vec::new();
            let mut start = 0;
            while start < recs.len() {
                let y = recs[start].center_y;
                let end = start + recs[start..].partition_point(|r| r.center_y == y);
                rows.push(start..end);
                start = end;
            }
            // Per row, its records drawn in runs, ordered by PSF, then column, then record.
            let ordered: Vec<Vec<u32>> = rows
                .into_par_iter()
                .map(|row| {
                    let mut members: Vec<u32> = row
                        .filter(|&i| drawn_in_run(&recs[i], reach, width, true, 1))
                        .map(|i| i as u32)
                        .collect();
                    members.sort_unstable_by_key(|&i| {
                        let r = &recs[i as usize];
                        (r.psf_index, r.center_x, i)
                    });
                    members
                })
                .collect();
            let mut out = LayerRuns {
                runs: Vec::new(),
                members: Vec::with_capacity(ordered.iter().map(Vec::len).sum()),
            };
            for members in ordered {
                let mut previous: Option<&SplatRecord> = None;
                for i in members {
                    let r = &recs[i as usize];
                    let continues = previous.is_some_and(|p| {
                        p.psf_index == r.psf_index && p.center_x + 1 == r.center_x
                    });
                    match out.runs.last_mut() {
                        Some(run) if continues => run.len += 1,
                        _ => out.runs.push(Run {
                            center_y: r.center_y,
                            center_x: r.center_x,
                            psf_index: r.psf_index,
                            first: out.members.len() as u32,
                            len: 1,
                        }),
                    }
                    out.members.push(i);
                    previous = Some(r);
                }
            }
            out
        })
        .collect()
}

/// Adds the spreadlets of `run` (its records in `runs.members`, indices into `recs`) that fall
/// into `band`. `colors` is scratch.
pub(super) fn draw_run(
    band: &mut Band,
    run: &Run,
    runs: &LayerRuns,
    recs: &[SplatRecord],
    db: &PsfDatabase,
    colors: &mut Vec<[f32; 4]>,
) {
    let (y0, y1) = (band.y0, band.y1);
    let (positions, values) = db.spreadlets(run.psf_index as usize);
    // Spreadlets in row order: only those whose row falls into the band.
    let lo = positions.partition_point(|p| run.center_y + i32::from(p[1]) < y0);
    let hi = positions.partition_point(|p| run.center_y + i32::from(p[1]) < y1);
    if lo == hi {
        return;
    }
    let len = run.len as usize;
    colors.clear();
    colors.extend(
        runs.members[run.first as usize..][..len]
            .iter()
            .map(|&i| recs[i as usize].color),
    );
    let row = band.width as isize;
    let start = (run.center_y - y0) as isize * row + run.center_x as isize;
    for (p, &v) in positions[lo..hi].iter().zip(&values[lo..hi]) {
        let at = (start + isize::from(p[1]) * row + isize::from(p[0])) as usize;
        // Flat lanes, so that the loop is four-wide multiplies and adds.
        let lanes: &mut [f32] = bytemuck::cast_slice_mut(&mut band.data[at..at + len]);
        let source: &[f32] = bytemuck::cast_slice(colors);
        for (px, &c) in lanes.iter_mut().zip(source) {
            *px += c * v;
        }
    }
}
