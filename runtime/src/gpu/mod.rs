//! The GPU path: each stage a WGSL compute shader in `shaders/`, mirroring the CPU path.
