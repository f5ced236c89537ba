//! Sharded builds: a database split into N contiguous ranges of PSF indices, each built on its
//! own machine into a partial file, then joined by [`merge_shards`].
//!
//! The split is deterministic (part k of n holds PSFs `[total*k/n, total*(k+1)/n)`) and every
//! PSF keeps the seed it has in a single build, so the merged file is byte-identical to a
//! single-machine build of the same settings.

use crate::error::DbError;
use crate::format::{DatabaseBuilder, DbHeader, PsfDatabase};
pub use crate::header::ShardRange;

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
