//! spreadlet runtime: synthesis and reconstruction of depth of field and motion blur by
//! splatting sparse Laplacian PSFs ("spreadlets"), on the CPU and (feature `gpu`) with wgpu.
//!
//! The CPU path is [`synth::synthesize`]: [`pipeline::classify`] -> [`pipeline::splat`] ->
//! [`pipeline::integrate`] -> [`pipeline::composite`], each a pure function the GPU path
//! mirrors. Inputs come from [`gbuffer::GBuffer::read_exr`] and [`camera::Camera`]; databases
//! from [`dbcache`].

pub mod baseline;
#[cfg(feature = "gpu")]
pub mod bench;
pub mod camera;
pub mod condition;
pub mod dbcache;
pub mod dbset;
pub mod demo;
pub mod gbuffer;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod peer;
pub mod peer_study;
pub mod pipeline;
pub mod reconstruct;
pub mod rgba;
pub mod study;
pub mod synth;
