//! Host of the tiled splat (`bin.wgsl`, `splat_tiled.wgsl`): binning records into 16 x 16 px
//! screen tiles (count, scan, scatter), the per-tile sums in workgroup memory, and the global
//! atomic pass for the records that span too many tiles. Its CPU mirror is [`super::tiles`].

use super::tiles;
use super::util::{compute_pipelines, layout_entries};
use super::{shaders, GpuContext, GpuError};

/// The tiled splat: binning (count, scan, scatter) and the per-tile sums.
pub(super) struct TiledPipelines {
    pub(super) layout: wgpu::BindGroupLayout,
    pub(super) count: wgpu::ComputePipeline,
    pub(super) scan: wgpu::ComputePipeline,
    pub(super) scatter: wgpu::ComputePipeline,
    pub(super) splat: wgpu::ComputePipeline,
    /// The records that span too many tiles, with global atomics.
    pub(super) rest: wgpu::ComputePipeline,
}

impl TiledPipelines {
    /// `None` when the device lacks the workgroup memory, invocations or storage bindings.
    pub(super) fn new(
        ctx: &GpuContext,
        lanes: u32,
        max_tiles: u32,
        float_atomics: bool,
    ) -> Result<Option<Self>, GpuError> {
        let l = ctx.limits();
        if l.max_compute_workgroup_storage_size < tiles::TILED_WORKGROUP_BYTES
            || l.max_compute_invocations_per_workgroup < 256
            || l.max_compute_workgroup_size_x < 256
            || l.max_storage_buffers_per_shader_stage < tiles::TILED_STORAGE_BUFFERS
        {
            return Ok(None);
        }
        let entries = layout_entries(shaders::bindings::TILED_SPLAT);
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("tiled splat"),
                entries: &entries,
            });
        let mut p = compute_pipelines(
            ctx,
            "tiled splat",
            &shaders::splat_tiled(),
            &layout,
            &["bin_count", "bin_scan", "bin_scatter", "splat_tiles"],
            &[("LANES", lanes as f64), ("MAX_TILES", max_tiles as f64)],
        )?
        .into_iter();
        let rest = compute_pipelines(
            ctx,
            "tiled splat (rest)",
            &shaders::splat_rest(float_atomics),
            &layout,
            &["splat_records"],
            &[
                ("LANES", lanes as f64),
                ("MAX_TILES", max_tiles as f64),
                ("SKIP_TILED", 1.0),
            ],
        )?
        .pop()
        .ok_or_else(|| GpuError::Wgpu {
            stage: "tiled splat (rest)",
            message: "missing pipeline".into(),
        })?;
        let mut next = || {
            p.next().ok_or_else(|| GpuError::Wgpu {
                stage: "tiled splat",
                message: "missing pipeline".into(),
            })
        };
        Ok(Some(Self {
            count: next()?,
            scan: next()?,
            scatter: next()?,
            splat: next()?,
            rest,
            layout,
        }))
    }
}
