//! poisson
