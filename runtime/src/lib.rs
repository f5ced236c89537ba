//! spreadlet runtime: synthesis and reconstruction of depth of field and motion blur by
//! splatting sparse Laplacian PSFs ("spreadlets"), on the CPU and (feature `gpu`) with wgpu.

pub mod pipeline;
#[cfg(feature = "gpu")]
pub mod gpu;
