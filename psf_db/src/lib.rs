//! psf_db
