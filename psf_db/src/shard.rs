//! Sharded builds: a database split into N contiguous ranges of PSF indices, each built on its
//! own machine into a partial file, then joined by [`merge_shards`].
//!
//! The split is deterministic (part k of n holds PSFs `[total*k/n, total*(k+1)/n)`) and every
//! PSF keeps the seed it has in a single build, so the merged file is byte-identical to a
//! single-machine build of the same settings.

use serde::{Deserialize, Serialize};

use crate::error::DbError;
use crate::format::{DatabaseBuilder, DbHeader, PsfDatabase};

/// The range of PSFs one part of a sharded build holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardRange {
    /// This part's index, `0..count`.
    pub index: u32,
    /// Number of parts the build is split into.
    pub count: u32,
    /// Index of the first PSF of the part in the whole database.
    pub first_psf: u32,
    /// Number of PSFs in the part (may be 0 when there are more parts than PSFs).
    pub len: u32,
}

impl ShardRange {
    /// Part `index` of `count` of a database of `psf_total` PSFs.
    pub fn of(index: u32, count: u32, psf_total: u32) -> Result<Self, DbError> {
        if count == 0 || index >= count {
            return Err(DbError::Invalid(format!(
                "shard {index}/{count}: the index must be below the count, and the count at least 1"
            )));
        }
        let start = |k: u32| (u64::from(psf_total) * u64::from(k) / u64::from(count)) as u32;
        let first_psf = start(index);
        Ok(ShardRange {
            index,
            count,
            first_psf,
            len: start(index + 1) - first_psf,
        })
    }

    /// Parses `"K/N"` (0-based K) into `(K, N)`.
    pub fn parse_spec(spec: &str) -> Result<(u32, u32), DbError> {
        let bad = || {
            DbError::Invalid(format!(
                "shard {spec:?}: expected K/N with 0 <= K < N, e.g. 0/4"
            ))
        };
        let (k, n) = spec.split_once('/').ok_or_else(bad)?;
        let k: u32 = k.trim().parse().map_err(|_| bad())?;
        let n: u32 = n.trim().parse().map_err(|_| bad())?;
        if n == 0 || k >= n {
            return Err(bad());
        }
        Ok((k, n))
    }

    /// The PSF indices of the part.
    pub fn indices(&self) -> std::ops::Range<u32> {
        self.first_psf..self.first_psf + self.len
    }

    /// Checks the range against a space of `psf_total` PSFs: it must be exactly the range
    /// [`ShardRange::of`] gives, so that parts of one build always tile the same way.
    pub(crate) fn validate(&self, psf_total: u32) -> Result<(), DbError> {
        match ShardRange::of(self.index, self.count, psf_total) {
            Ok(expected) if expected == *self => Ok(()),
            _ => Err(DbError::OutOfBounds {
                what: format!(
                    "shard {}/{} claims PSFs {}..{} of {psf_total}, which is not that part's range",
                    self.index,
                    self.count,
                    self.first_psf,
                    u64::from(self.first_psf) + u64::from(self.len)
                ),
            }),
        }
    }
}

/// The header with the per-part fields cleared, for comparing parts. The PSF resolution is
/// the largest PSF image of the part, so the whole database's is the largest over the parts.
fn settings_of(header: &DbHeader) -> DbHeader {
    let mut h = header.clone();
    h.shard = None;
    h.stats.clear();
    h.psf_resolution = 0;
    h
}

/// Names the first build setting in which `a` and `b` differ.
fn first_difference(a: &DbHeader, b: &DbHeader) -> String {
    macro_rules! differ {
        ($($field:ident),*) => {
            $(if a.$field != b.$field {
                return format!("{} differs ({:?} vs {:?})", stringify!($field), a.$field, b.$field);
            })*
        };
    }
    differ!(
        model,
        seed,
        rays_per_psf,
        spreadlet_budget,
        prefilter,
        channels
    );
    if a.space != b.space {
        return "the parameter space (ranges, betas or grid) differs".into();
    }
    if a.aperture != b.aperture {
        return "the aperture differs".into();
    }
    if a.lens != b.lens {
        return "the lens prescription differs".into();
    }
    "the build information differs".into()
}

/// Joins the parts of one sharded build into the whole database.
///
/// Checks that every part is a partial file, that all come from the same build settings (model,
/// seed, rays, budget, space, lens, ...) and the same split, and that together they cover every
/// PSF exactly once; the error names the first problem found.
pub fn merge_shards(parts: &[PsfDatabase]) -> Result<PsfDatabase, DbError> {
    let merge = |m: String| Err(DbError::Merge(m));
    let Some(first) = parts.first() else {
        return merge("no parts given".into());
    };
    let reference = settings_of(first.header());
    let mut by_index: Vec<Option<&PsfDatabase>> = Vec::new();
    for (k, part) in parts.iter().enumerate() {
        let Some(range) = part.header().shard else {
            return merge(format!(
                "input {k} is a whole database, not a part of a sharded build"
            ));
        };
        if k == 0 {
            by_index = vec![None; range.count as usize];
        }
        if range.count as usize != by_index.len() {
            return merge(format!(
                "input {k} is part {}/{}, input 0 belongs to a split into {}",
                range.index,
                range.count,
                by_index.len()
            ));
        }
        let settings = settings_of(part.header());
        if settings != reference {
            return merge(format!(
                "input {k} (part {}/{}) comes from another build: {}",
                range.index,
                range.count,
                first_difference(&reference, &settings)
            ));
        }
        let slot = &mut by_index[range.index as usize];
        if slot.is_some() {
            return merge(format!(
                "part {}/{} is given twice",
                range.index, range.count
            ));
        }
        *slot = Some(part);
    }
    let missing: Vec<String> = by_index
        .iter()
        .enumerate()
        .filter(|(_, p)| p.is_none())
        .map(|(k, _)| format!("{k}/{}", by_index.len()))
        .collect();
    if !missing.is_empty() {
        return merge(format!("missing part(s) {}", missing.join(", ")));
    }

    let mut header = reference;
    header.psf_resolution = by_index
        .iter()
        .flatten()
        .map(|p| p.header().psf_resolution)
        .max()
        .unwrap_or(1);
    let with_stats = by_index
        .iter()
        .flatten()
        .all(|p| p.header().stats.len() == p.header().stored_psf_count());
    let mut builder = DatabaseBuilder::new(header.clone());
    for part in by_index.iter().flatten() {
        for i in 0..part.psf_count() {
            builder.push_copy(part, i)?;
        }
        if with_stats {
            header.stats.extend_from_slice(&part.header().stats);
        }
    }
    builder.header_mut().stats = header.stats;
    builder.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ParamSpace, PsfModel};

    fn build(shard: Option<ShardRange>, seed: u64) -> PsfDatabase {
        let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 28).unwrap();
        let total = space.psf_count();
        let mut header = DbHeader::new(PsfModel::ThinLens, space, 16);
        header.seed = seed;
        header.shard = shard;
        let indices = shard.map_or(0..total, |r| r.indices());
        let mut b = DatabaseBuilder::new(header);
        for i in indices {
            // Deterministic per-PSF content, alternating sparse and dense.
            if i % 3 == 0 {
                let v = i as f32;
                b.push_dense([-1, -1], 3, 3, &[v; 9]).unwrap();
            } else {
                let r = (i % 7) as i16;
                b.push_sparse(&[[r, 0], [-r, 1]], &[1.0, -(i as f32)])
                    .unwrap();
            }
        }
        b.finish().unwrap()
    }

    fn parts(n: u32, seed: u64) -> Vec<PsfDatabase> {
        let total = build(None, seed).psf_count() as u32;
        (0..n)
            .map(|k| build(Some(ShardRange::of(k, n, total).unwrap()), seed))
            .collect()
    }

    #[test]
    fn ranges_tile_the_space() {
        for total in [0u32, 1, 5, 100, 101] {
            for n in 1..9 {
                let mut next = 0;
                for k in 0..n {
                    let r = ShardRange::of(k, n, total).unwrap();
                    assert_eq!(r.first_psf, next);
                    next += r.len;
                }
                assert_eq!(next, total);
            }
        }
    }

    #[test]
    fn merged_parts_equal_the_single_build_bytes() {
        let whole = build(None, 3).to_bytes().unwrap();
        for n in [1, 2, 3, 7] {
            let mut p = parts(n, 3);
            p.reverse(); // order of the inputs must not matter
            let merged = merge_shards(&p).unwrap();
            assert_eq!(merged.to_bytes().unwrap(), whole, "{n} parts");
        }
    }

    #[test]
    fn a_part_round_trips_and_is_refused_as_a_database() {
        let p = &parts(3, 1)[1];
        let back = PsfDatabase::from_bytes(&p.to_bytes().unwrap()).unwrap();
        assert_eq!(&back, p);
        assert!(matches!(
            back.expect_model(PsfModel::ThinLens),
            Err(DbError::Partial { index: 1, count: 3 })
        ));
    }

    #[test]
    fn mismatched_or_incomplete_parts_are_named() {
        let msg = |r: Result<PsfDatabase, DbError>| r.unwrap_err().to_string();
        let p = parts(3, 1);
        assert!(msg(merge_shards(&p[..2])).contains("missing part(s) 2/3"));
        let twice = vec![p[0].clone(), p[1].clone(), p[1].clone()];
        assert!(msg(merge_shards(&twice)).contains("part 1/3 is given twice"));
        let other = parts(3, 2);
        let mixed = vec![p[0].clone(), other[1].clone(), p[2].clone()];
        assert!(msg(merge_shards(&mixed)).contains("seed differs"));
        let four = parts(4, 1);
        let split = vec![p[0].clone(), four[1].clone()];
        assert!(msg(merge_shards(&split)).contains("split into 3"));
        assert!(msg(merge_shards(&[build(None, 1)])).contains("whole database"));
        assert!(msg(merge_shards(&[])).contains("no parts"));
    }

    #[test]
    fn spec_parsing() {
        assert_eq!(ShardRange::parse_spec("2/5").unwrap(), (2, 5));
        for bad in ["5/5", "1/0", "x/2", "3", "-1/2"] {
            assert!(ShardRange::parse_spec(bad).is_err(), "{bad}");
        }
    }
}
