//! Host of the composite stage (`composite.wgsl`): the GPU twin of
//! [`crate::pipeline::composite`]. Layers are composited back to front, chunk by chunk, with
//! the coverage renormalisation of Lee et al. 2008 when asked for.

use super::frame::Chunk;
use super::pyramid::TILE;
use super::synth::GpuSynthesizer;
use crate::pipeline::types::FrameParams;

impl GpuSynthesizer {
    /// Encodes the composite of one chunk of layers over what the earlier chunks left.
    pub(super) fn encode_composite(
        &self,
        enc: &mut wgpu::CommandEncoder,
        frame: &FrameParams,
        chunk: &Chunk,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("composite"),
            timestamp_writes: timestamps,
        });
        pass.set_pipeline(&self.composite);
        pass.set_bind_group(0, &chunk.composite_group, &[]);
        pass.dispatch_workgroups(frame.width.div_ceil(TILE), frame.height.div_ceil(TILE), 1);
    }
}
