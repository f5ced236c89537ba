//! Database file format: round trips and corruption handling (never a panic).

use psf_db::{
    Aperture, DatabaseBuilder, DbError, DbHeader, LensPrescription, ParamSpace, PsfDatabase,
    PsfModel, PsfStats, FORMAT_VERSION,
};

/// A small thin-lens database: 4 PSFs, one of them dense.
fn small_db() -> PsfDatabase {
    let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 10).unwrap();
    assert_eq!(space.psf_count(), 4);
    let mut header = DbHeader::new(PsfModel::ThinLens, space, 16);
    header.seed = 7;
    header.rays_per_psf = 1000;
    header.aperture = Aperture {
        blades: 6,
        rotation_rad: 0.25,
        ratio: 1.5,
        image_hash: 0x1234_5678_9abc_def0,
    };
    header.build.profile = "test".into();
    let mut b = DatabaseBuilder::new(header);
    b.push_sparse(&[[0, 0], [1, -1], [-3, 2]], &[-2.0, 1.5, 0.5])
        .unwrap();
    b.push_dense([-1, -1], 3, 2, &[0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        .unwrap();
    b.push_sparse(&[], &[]).unwrap();
    b.push_sparse(&[[5, 5], [-5, 0]], &[1.0, -1.0]).unwrap();
    b.header_mut().stats = (0..4)
        .map(|i| PsfStats {
            coords: [i as f32, 0.0],
            spreadlets: i,
            dense_support: 10 * i,
            l1: 0.01,
            ssim: 0.9,
            extent_px: 3.0,
        })
        .collect();
    b.finish().unwrap()
}

fn physical_db() -> PsfDatabase {
    let space =
        ParamSpace::for_model(PsfModel::PhysicalLens, &[[1.0, 10.0], [0.0, 12.0]], 4).unwrap();
    let n = space.psf_count();
    let mut header = DbHeader::new(PsfModel::PhysicalLens, space, 32);
    header.lens = Some(LensPrescription {
        lens: optics::Prescription::singlet(50.0, -50.0, 5.0, 25.0, 12.0, 2.0),
        focus_distance: 3.0,
        scene_unit_mm: 1000.0,
        focal_length_mm: 50.0,
        f_number: 4.2,
        sensor_distance_mm: 51.0,
        pinhole_distance_mm: 50.8,
        sensor_width_mm: 36.0,
        image_width_px: 1920,
    });
    let mut b = DatabaseBuilder::new(header);
    for i in 0..n {
        let v = i as f32;
        b.push_sparse(&[[1, 2], [-2, 1]], &[v, -v, 0.5, 1.0, 2.0, -3.0])
            .unwrap();
    }
    b.finish().unwrap()
}

#[test]
fn round_trip_bytes_and_file() {
    for db in [small_db(), physical_db()] {
        let bytes = db.to_bytes().unwrap();
        let back = PsfDatabase::from_bytes(&bytes).unwrap();
        assert_eq!(back, db);
        // Deterministic encoding.
        assert_eq!(back.to_bytes().unwrap(), bytes);

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("db.sprdlt");
        db.write_atomic(&path).unwrap();
        let read = PsfDatabase::read(&path).unwrap();
        assert_eq!(read, db);
        // Only the final file is left in the folder (the temp file was renamed).
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}

#[test]
fn accessors() {
    let db = small_db();
    assert_eq!(db.psf_count(), 4);
    assert_eq!(db.channels(), 1);
    let (p, v) = db.spreadlets(0);
    assert_eq!(p, &[[0, 0], [1, -1], [-3, 2]]);
    assert_eq!(v, &[-2.0, 1.5, 0.5]);
    assert!(db.dense(0).is_none());
    let d = db.dense(1).unwrap();
    assert_eq!((d.width, d.height, d.origin), (3, 2, [-1, -1]));
    assert_eq!(d.get(2, 1, 0), 0.6);
    assert!(db.spreadlets(1).0.is_empty());
    assert!(db.spreadlets(2).0.is_empty() && db.dense(2).is_none());
    assert_eq!(db.cumulative(), &[0, 3, 3, 3, 5]);
    assert_eq!(db.dense_slots()[1], 0);
    // Largest |offset|: (5, 5) -> 7.07 -> 8.
    assert_eq!(db.max_extent_px(), 8);
    assert_eq!(db.lookup([100.0, 0.0]), (3, true));

    let phys = physical_db();
    assert_eq!(phys.channels(), 3);
    assert_eq!(phys.spreadlets(2).1, &[2.0, -2.0, 0.5, 1.0, 2.0, -3.0]);
}

#[test]
fn every_flipped_byte_is_an_error() {
    let bytes = small_db().to_bytes().unwrap();
    for i in 0..bytes.len() {
        for mask in [0x01u8, 0x80, 0xff] {
            let mut b = bytes.clone();
            b[i] ^= mask;
            assert!(
                PsfDatabase::from_bytes(&b).is_err(),
                "flipping byte {i} with {mask:#x} was accepted"
            );
        }
    }
}

#[test]
fn every_truncation_is_an_error() {
    let bytes = small_db().to_bytes().unwrap();
    for len in 0..bytes.len() {
        match PsfDatabase::from_bytes(&bytes[..len]) {
            Err(DbError::Truncated { .. }) | Err(DbError::BadMagic) => {}
            other => panic!("truncated to {len} bytes: {other:?}"),
        }
    }
    // Trailing garbage is an error too.
    let mut long = bytes.clone();
    long.push(0);
    assert!(matches!(
        PsfDatabase::from_bytes(&long),
        Err(DbError::LengthMismatch { .. })
    ));
}

/// Offsets of the preamble fields and the counts block.
fn counts_offset(bytes: &[u8]) -> usize {
    20 + u64::from_le_bytes(bytes[12..20].try_into().unwrap()) as usize
}

fn recrc(b: &mut [u8]) {
    let n = b.len() - 4;
    let crc = crc32fast::hash(&b[..n]);
    b[n..].copy_from_slice(&crc.to_le_bytes());
}

#[test]
fn huge_declared_lengths_fail_without_allocating() {
    let bytes = small_db().to_bytes().unwrap();
    let at = counts_offset(&bytes);
    // Each count field in turn declared as 1e12 (checksum fixed so only the length check can
    // catch it); allocating that much would abort the test process.
    for field in 0..5 {
        let mut b = bytes.clone();
        b[at + 8 * field..at + 8 * field + 8].copy_from_slice(&1_000_000_000_000u64.to_le_bytes());
        recrc(&mut b);
        assert!(matches!(
            PsfDatabase::from_bytes(&b),
            Err(DbError::Truncated { .. })
        ));
        b[at + 8 * field..at + 8 * field + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        recrc(&mut b);
        assert!(PsfDatabase::from_bytes(&b).is_err());
    }
    // A huge header length.
    let mut b = bytes.clone();
    b[12..20].copy_from_slice(&1_000_000_000_000u64.to_le_bytes());
    assert!(matches!(
        PsfDatabase::from_bytes(&b),
        Err(DbError::Truncated { .. })
    ));
}

#[test]
fn inconsistent_content_with_a_valid_checksum_is_out_of_bounds() {
    let bytes = small_db().to_bytes().unwrap();
    let arrays = counts_offset(&bytes) + 40;
    // cumulative[1] = 3 -> 9 (beyond the spreadlets).
    let mut b = bytes.clone();
    b[arrays + 4..arrays + 8].copy_from_slice(&9u32.to_le_bytes());
    recrc(&mut b);
    assert!(matches!(
        PsfDatabase::from_bytes(&b),
        Err(DbError::OutOfBounds { .. })
    ));
    // A spreadlet position far outside the PSF resolution (16 px).
    let positions = arrays + 4 * 5;
    let mut b = bytes.clone();
    b[positions..positions + 2].copy_from_slice(&1000i16.to_le_bytes());
    recrc(&mut b);
    assert!(matches!(
        PsfDatabase::from_bytes(&b),
        Err(DbError::OutOfBounds { .. })
    ));
    // A NaN value.
    let values = positions + 4 * 5;
    let mut b = bytes.clone();
    b[values..values + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    recrc(&mut b);
    assert!(matches!(
        PsfDatabase::from_bytes(&b),
        Err(DbError::OutOfBounds { .. })
    ));
    // A dense slot pointing past the dense entries.
    let slots = values + 4 * 5;
    let mut b = bytes.clone();
    b[slots + 4..slots + 8].copy_from_slice(&5u32.to_le_bytes());
    recrc(&mut b);
    assert!(matches!(
        PsfDatabase::from_bytes(&b),
        Err(DbError::OutOfBounds { .. })
    ));
}

#[test]
fn foreign_and_future_files() {
    assert!(matches!(
        PsfDatabase::from_bytes(b"\x89PNG\r\n\x1a\n0000000000000000"),
        Err(DbError::BadMagic)
    ));
    let mut b = small_db().to_bytes().unwrap();
    b[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    match PsfDatabase::from_bytes(&b) {
        Err(DbError::UnsupportedVersion { found, expected }) => {
            assert_eq!((found, expected), (FORMAT_VERSION + 1, FORMAT_VERSION))
        }
        other => panic!("{other:?}"),
    }
    let missing = PsfDatabase::read("/nonexistent/dir/db.sprdlt");
    match missing {
        Err(e @ DbError::Io { .. }) => {
            assert!(e.to_string().contains("/nonexistent/dir/db.sprdlt"))
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn another_model_is_visible_in_the_header() {
    let db = PsfDatabase::from_bytes(&physical_db().to_bytes().unwrap()).unwrap();
    assert_eq!(db.header().model, PsfModel::PhysicalLens);
    assert_ne!(db.header().model, PsfModel::ThinLens);
    assert!(db.header().lens.is_some());
    assert!(db.expect_model(PsfModel::PhysicalLens).is_ok());
    let e = db.expect_model(PsfModel::LensMotion).unwrap_err();
    assert!(matches!(e, DbError::WrongModel { .. }));
    assert_eq!(
        e.to_string(),
        "database holds physical-lens PSFs, lens-motion needed"
    );
}

#[test]
fn builder_rejects_misuse() {
    let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 10).unwrap();
    let mut b = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space, 16));
    assert!(b.push_sparse(&[[0, 0]], &[1.0, 2.0]).is_err());
    assert!(b.push_dense([0, 0], 2, 2, &[1.0]).is_err());
    b.push_sparse(&[[0, 0]], &[1.0]).unwrap();
    // Too few PSFs.
    assert!(matches!(b.clone().finish(), Err(DbError::Invalid(_))));
    for _ in 0..3 {
        b.push_sparse(&[], &[]).unwrap();
    }
    assert!(b.push_sparse(&[], &[]).is_err());
    // A position outside the PSF resolution is caught at finish.
    let space = ParamSpace::for_model(PsfModel::ThinLens, &[[0.0, 8.0]], 1).unwrap();
    let mut b = DatabaseBuilder::new(DbHeader::new(PsfModel::ThinLens, space, 4));
    b.push_sparse(&[[5, 0]], &[1.0]).unwrap();
    assert!(matches!(b.finish(), Err(DbError::OutOfBounds { .. })));
}

/// With the checksum recomputed, a changed byte reaches the header decoder and the bounds
/// checks: the result may be Ok (a changed statistic) or an error, but never a panic, and an
/// accepted file is self-consistent.
#[test]
fn every_byte_changed_behind_a_valid_checksum_never_panics() {
    for db in [small_db(), physical_db()] {
        let bytes = db.to_bytes().unwrap();
        for i in 0..bytes.len() - 4 {
            for v in [0x00u8, 0x01, 0x7f, 0x80, 0xff, bytes[i] ^ 0x01] {
                let mut b = bytes.clone();
                b[i] = v;
                recrc(&mut b);
                if let Ok(d) = PsfDatabase::from_bytes(&b) {
                    for k in 0..d.psf_count() {
                        let (p, val) = d.spreadlets(k);
                        assert_eq!(val.len(), p.len() * d.channels());
                        if let Some(dv) = d.dense(k) {
                            assert_eq!(dv.data.len(), dv.width * dv.height * dv.channels);
                        }
                    }
                }
            }
        }
    }
}

mod fuzz {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        #[test]
        fn random_edits_behind_a_valid_checksum_never_panic(
            edits in proptest::collection::vec((0usize..4096, any::<u8>()), 1..8)
        ) {
            let mut b = small_db().to_bytes().unwrap();
            let n = b.len() - 4;
            for (at, v) in edits {
                b[at % n] = v;
            }
            recrc(&mut b);
            let _ = PsfDatabase::from_bytes(&b);
        }
    }
}

#[test]
fn read_rejects_foreign_and_truncated_files() {
    let dir = tempfile::tempdir().unwrap();
    let foreign = dir.path().join("image.png");
    std::fs::write(
        &foreign,
        b"\x89PNG\r\n\x1a\nnot a database at all, longer than twenty",
    )
    .unwrap();
    assert!(matches!(
        PsfDatabase::read(&foreign),
        Err(DbError::BadMagic)
    ));
    let short = dir.path().join("short.sprdlt");
    std::fs::write(&short, b"SPRDLT").unwrap();
    assert!(matches!(
        PsfDatabase::read(&short),
        Err(DbError::Truncated { .. })
    ));
    let bytes = small_db().to_bytes().unwrap();
    let cut = dir.path().join("cut.sprdlt");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    assert!(matches!(
        PsfDatabase::read(&cut),
        Err(DbError::Truncated { .. })
    ));
}
