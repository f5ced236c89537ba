//! Same config and seed give the same bytes, whatever the thread count; another seed does not.

use precompute::{build_database, BuildConfig, Profile};
use psf_db::{PsfDatabase, PsfModel};

fn build(model: PsfModel, seed: u64, threads: usize) -> Vec<u8> {
    let mut cfg = BuildConfig::new(model, Profile::Test);
    cfg.seed = seed;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let (db, _) = pool.install(|| build_database(&cfg, false)).unwrap();
    db.to_bytes().unwrap()
}

#[test]
fn same_seed_same_bytes_any_thread_count() {
    for model in [PsfModel::LensMotion, PsfModel::PhysicalLens] {
        let a = build(model, 5, 1);
        let b = build(model, 5, 3);
        assert_eq!(a, b, "{model}: thread count changed the bytes");
        let c = build(model, 6, 2);
        assert_ne!(a, c, "{model}: the seed did not matter");
        let db = PsfDatabase::from_bytes(&a).unwrap();
        assert_eq!(db.model(), model);
        assert_eq!(db.to_bytes().unwrap(), a);
    }
}
