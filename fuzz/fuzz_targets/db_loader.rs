//! The PSF database loader on arbitrary bytes: an error or a database whose every accessor
//! stays in bounds, never a panic or an unbounded allocation.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(db) = psf_db::PsfDatabase::from_bytes(data) {
        // Touch what the runtime touches: every PSF's spreadlets and dense image, a lookup.
        for i in 0..db.psf_count() {
            let _ = db.spreadlets(i);
            let _ = db.dense(i);
        }
        let _ = db.lookup([0.5, 0.5]);
        let _ = db.max_extent_px();
        // A loaded database writes back to the same bytes' meaning.
        let bytes = db.to_bytes().expect("a loaded database serialises");
        let again = psf_db::PsfDatabase::from_bytes(&bytes).expect("its own bytes load");
        assert_eq!(again, db);
    }
});
