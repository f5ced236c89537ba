//! Host of the splat stage (`splat.wgsl`, `splat_global.wgsl`, `dense.wgsl`, `atomic_*.wgsl`;
//! tiled: `bin.wgsl`, `splat_tiled.wgsl` through [`super::splat_tiled`]): the GPU twin of
//! [`crate::pipeline::splat`]. Every record's spreadlets (or its dense PSF, or its copied
//! colour) are added into its layer's Laplacian or direct planes.

use super::frame::{Chunk, FrameBuffers};
use super::splat_tiled::TiledPipelines;
use super::synth::GpuSynthesizer;

impl GpuSynthesizer {
    /// Encodes one chunk's splat: clears its planes, bins the records into tiles (tiled splat
    /// only; an empty pass otherwise, so that every timestamp slot is written), then splats
    /// `records` records. `timestamps` are the binning pass's and the splat pass's.
    pub(super) fn encode_splat(
        &self,
        enc: &mut wgpu::CommandEncoder,
        fb: &FrameBuffers,
        chunk: &Chunk,
        records: u32,
        tiled: Option<&TiledPipelines>,
        timestamps: [Option<wgpu::ComputePassTimestampWrites<'_>>; 2],
    ) {
        let [bin_timestamps, splat_timestamps] = timestamps;
        let lap = fb.pyramid.analysis_sets[0];
        let max = self
            .ctx
            .limits()
            .max_compute_workgroups_per_dimension
            .max(1);
        // Workgroups of 64 invocations, `lanes_per_record` of them per record.
        let n = records.div_ceil(64 / self.options.lanes_per_record);
        enc.clear_buffer(
            &fb.pyramid.analysis,
            4 * lap.offset as u64,
            Some(4 * lap.stride as u64 * fb.pyramid.planes as u64),
        );
        enc.clear_buffer(&fb.layer_images, 0, None);
        if tiled.is_some() {
            enc.clear_buffer(&fb.tile_meta, 0, None);
        }
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("bin"),
                timestamp_writes: bin_timestamps,
            });
            let n64 = records.div_ceil(64);
            if let (Some(t), Some(group), true) = (tiled, chunk.tiled_group.as_ref(), n64 > 0) {
                let x = n64.min(max);
                pass.set_bind_group(0, group, &[]);
                pass.set_pipeline(&t.count);
                pass.dispatch_workgroups(x, n64.div_ceil(x), 1);
                pass.set_pipeline(&t.scan);
                pass.dispatch_workgroups(1, 1, 1);
                pass.set_pipeline(&t.scatter);
                pass.dispatch_workgroups(x, n64.div_ceil(x), 1);
            }
        }
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("splat"),
            timestamp_writes: splat_timestamps,
        });
        if n == 0 {
            return;
        }
        let x = n.min(max);
        match (tiled, chunk.tiled_group.as_ref()) {
            (Some(t), Some(group)) => {
                pass.set_bind_group(0, group, &[]);
                // The tiles store their sums; the records they leave out are added on top
                // afterwards.
                pass.set_pipeline(&t.splat);
                pass.dispatch_workgroups(chunk.grid.tiles_x, chunk.grid.tiles_y, chunk.layer_count);
                pass.set_pipeline(&t.rest);
                pass.dispatch_workgroups(x, n.div_ceil(x), 1);
            }
            _ => {
                pass.set_pipeline(&self.splat);
                pass.set_bind_group(0, &chunk.splat_group, &[]);
                pass.dispatch_workgroups(x, n.div_ceil(x), 1);
            }
        }
    }
}
