//! precompute
