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
//! Runs are found once per frame, each row on its own thread: a row mostly draws one or two
//! PSFs and comes in column order, so it is grouped by PSF by scanning it once per PSF (16 ms
//! for the 2.36 M records of a 1024 px bokeh frame, where sorting each row and joining the
//! runs on one thread took about 50).
//! A record is drawn in a run when the single-record loop would
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
            // Per row, on every thread: its records drawn in runs, ordered by PSF, then column,
            // then record, and its runs (`first` counted from the row's first member).
            let per_row: Vec<(Vec<Run>, Vec<u32>)> = rows
                .into_par_iter()
                .map(|row| {
                    let members: Vec<u32> = row
                        .filter(|&i| drawn_in_run(&recs[i], reach, width, true, 1))
                        .map(|i| i as u32)
                        .collect();
                    let members = ordered_by_psf(members, recs);
                    let mut runs: Vec<Run> = Vec::new();
                    let mut previous: Option<&SplatRecord> = None;
                    for (k, &i) in members.iter().enumerate() {
                        let r = &recs[i as usize];
                        let continues = previous.is_some_and(|p| {
                            p.psf_index == r.psf_index && p.center_x + 1 == r.center_x
                        });
                        match runs.last_mut() {
                            Some(run) if continues => run.len += 1,
                            _ => runs.push(Run {
                                center_y: r.center_y,
                                center_x: r.center_x,
                                psf_index: r.psf_index,
                                first: k as u32,
                                len: 1,
                            }),
                        }
                        previous = Some(r);
                    }
                    (runs, members)
                })
                .collect();
            let mut out = LayerRuns {
                runs: Vec::with_capacity(per_row.iter().map(|(runs, _)| runs.len()).sum()),
                members: Vec::with_capacity(per_row.iter().map(|(_, m)| m.len()).sum()),
            };
            for (runs, members) in per_row {
                let base = out.members.len() as u32;
                out.runs.extend(runs.into_iter().map(|run| Run {
                    first: run.first + base,
                    ..run
                }));
                out.members.extend_from_slice(&members);
            }
            out
        })
        .collect()
}

/// Most PSFs one row's records may draw for [`ordered_by_psf`] to group them by scanning once
/// per PSF rather than sorting.
const MOST_PSFS_PER_ROW_SCANNED: usize = 8;

/// `members` (indices into `recs`, one row's, in index order) ordered by PSF, then column, then
/// index. A row mostly draws one or two PSFs and comes ordered by column already, so it is
/// grouped by scanning it once per PSF; otherwise sorted.
fn ordered_by_psf(members: Vec<u32>, recs: &[SplatRecord]) -> Vec<u32> {
    let psf = |i: u32| recs[i as usize].psf_index;
    let mut psfs: Vec<u32> = Vec::new();
    let by_column = members
        .windows(2)
        .all(|w| recs[w[0] as usize].center_x <= recs[w[1] as usize].center_x);
    if by_column {
        for &i in &members {
            if !psfs.contains(&psf(i)) {
                psfs.push(psf(i));
                if psfs.len() > MOST_PSFS_PER_ROW_SCANNED {
                    break;
                }
            }
        }
    }
    if !by_column || psfs.len() > MOST_PSFS_PER_ROW_SCANNED {
        let mut members = members;
        members.sort_unstable_by_key(|&i| {
            let r = &recs[i as usize];
            (r.psf_index, r.center_x, i)
        });
        return members;
    }
    psfs.sort_unstable();
    let mut ordered = Vec::with_capacity(members.len());
    for &p in &psfs {
        ordered.extend(members.iter().filter(|&&i| psf(i) == p));
    }
    ordered
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

#[cfg(test)]
mod tests {
    use super::*;

    /// One row of sparse records at columns `xs`, drawing `psfs`.
    fn row(xs: &[i32], psfs: &[u32]) -> Vec<SplatRecord> {
        xs.iter()
            .zip(psfs)
            .map(|(&x, &psf)| SplatRecord {
                center_x: x,
                center_y: 7,
                psf_index: psf,
                layer: 0,
                rot_cos: 1.0,
                rot_sin: 0.0,
                weight: 1.0,
                path: SplatPath::Sparse as u32,
                color: [1.0; 4],
            })
            .collect()
    }

    /// Grouping a row by scanning it once per PSF orders it as sorting by (PSF, column,
    /// index) does: rows in column order with pairs of PSFs per pixel and repeated columns, a
    /// row of many PSFs, and a row out of column order.
    #[test]
    fn a_row_grouped_by_psf_is_the_row_sorted() {
        let mut state = 12345u32;
        let mut next = |n: u32| {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) % n
        };
        for (count, psfs, in_order) in
            [(40, 2, true), (60, 5, true), (50, 20, true), (30, 3, false)]
        {
            let mut xs: Vec<i32> = (0..count).map(|_| next(25) as i32).collect();
            if in_order {
                xs.sort_unstable();
            }
            let ps: Vec<u32> = (0..count).map(|_| 3 + next(psfs)).collect();
            let recs = row(&xs, &ps);
            let members: Vec<u32> = (0..count).collect();
            let mut sorted = members.clone();
            sorted.sort_unstable_by_key(|&i| {
                let r = &recs[i as usize];
                (r.psf_index, r.center_x, i)
            });
            assert_eq!(
                ordered_by_psf(members, &recs),
                sorted,
                "{count} records, {psfs} PSFs, in column order: {in_order}"
            );
        }
    }
}
