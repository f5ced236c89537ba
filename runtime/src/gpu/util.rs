//! Small wgpu helpers: buffers, layouts, pipelines, readback.

use wgpu::util::DeviceExt;

use super::{GpuContext, GpuError};

/// A storage buffer initialised with `data` (at least 16 bytes: empty arrays cannot be bound).
pub fn storage_init(ctx: &GpuContext, label: &str, data: &[u8]) -> wgpu::Buffer {
    let mut bytes = data.to_vec();
    if bytes.len() < 16 {
        bytes.resize(16, 0);
    }
    bytes.resize(bytes.len().next_multiple_of(4), 0);
    ctx.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: &bytes,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
        })
}

/// A zeroed storage buffer of `bytes` bytes (at least 16), checked against the device limits.
pub fn storage_zeroed(
    ctx: &GpuContext,
    what: &'static str,
    bytes: u64,
) -> Result<wgpu::Buffer, GpuError> {
    let bytes = bytes.max(16).next_multiple_of(4);
    let limit = ctx
        .limits()
        .max_storage_buffer_binding_size
        .min(ctx.limits().max_buffer_size);
    if bytes > limit {
        return Err(GpuError::TooLarge { what, bytes, limit });
    }
    Ok(ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(what),
        size: bytes,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    }))
}

/// A uniform buffer holding `data`.
pub fn uniform_init(ctx: &GpuContext, label: &str, data: &[u8]) -> wgpu::Buffer {
    ctx.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: data,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        })
}

/// The layout entries of a stage's bindings table (`shaders::bindings`).
pub fn layout_entries(table: &[(u32, shaders::Binding)]) -> Vec<wgpu::BindGroupLayoutEntry> {
    table
        .iter()
        .map(|&(b, kind)| match kind {
            shaders::Binding::Uniform => uniform_entry(b),
            shaders::Binding::Read => storage_entry(b, true),
            shaders::Binding::ReadWrite => storage_entry(b, false),
        })
        .collect()
}

/// Layout entry: binding `b`, a uniform buffer.
pub fn uniform_entry(b: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding: b,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Layout entry: binding `b`, a storage buffer.
pub fn storage_entry(b: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding: b,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A bind group binding `buffers[i]` at binding `i`, whole.
pub fn bind_group(
    ctx: &GpuContext,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout,
        entries: &entries,
    })
}

/// Compute pipelines for `entry_points` of one WGSL source sharing `layout`. Shader or
/// pipeline errors come back as [`GpuError::Wgpu`] instead of wgpu's default panic.
pub fn compute_pipelines(
    ctx: &GpuContext,
    label: &'static str,
    source: &str,
    layout: &wgpu::BindGroupLayout,
    entry_points: &[&str],
    constants: &[(&str, f64)],
) -> Result<Vec<wgpu::ComputePipeline>, GpuError> {
    let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = ctx
        .device
        .create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
    let pipeline_layout = ctx
        .device
        .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &[Some(layout)],
            immediate_size: 0,
        });
    let pipelines = entry_points
        .iter()
        .map(|entry| {
            ctx.device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(label),
                    layout: Some(&pipeline_layout),
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants,
                        ..Default::default()
                    },
                    cache: None,
                })
        })
        .collect();
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(GpuError::Wgpu {
            stage: label,
            message: e.to_string(),
        });
    }
    Ok(pipelines)
}

/// Copies `bytes` bytes from `offset` of `buffer` into a fresh staging buffer and reads them
/// back as f32 (blocking).
pub fn read_f32(
    ctx: &GpuContext,
    what: &'static str,
    buffer: &wgpu::Buffer,
    offset: u64,
    bytes: u64,
) -> Result<Vec<f32>, GpuError> {
    if bytes == 0 {
        return Ok(Vec::new());
    }
    let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: bytes,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = ctx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(what) });
    encoder.copy_buffer_to_buffer(buffer, offset, &staging, 0, bytes);
    ctx.queue.submit([encoder.finish()]);
    map_read(ctx, what, &staging, bytes)
}

/// Maps the first `bytes` of a MAP_READ buffer (after the copy into it was submitted), reads
/// them as f32 and unmaps.
pub fn map_read(
    ctx: &GpuContext,
    what: &'static str,
    staging: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<f32>, GpuError> {
    Ok(bytemuck::pod_collect_to_vec::<u8, f32>(&map_read_bytes(
        ctx, what, staging, bytes,
    )?))
}

/// Maps the first `bytes` of a MAP_READ buffer (after the copy into it was submitted), copies
/// them out and unmaps.
pub fn map_read_bytes(
    ctx: &GpuContext,
    what: &'static str,
    staging: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<u8>, GpuError> {
    let slice = staging.slice(..bytes);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    ctx.wait(what)?;
    let fail = |message: String| GpuError::Readback { what, message };
    rx.recv()
        .map_err(|e| fail(e.to_string()))?
        .map_err(|e| fail(e.to_string()))?;
    let out = {
        let view = slice.get_mapped_range().map_err(|e| fail(e.to_string()))?;
        view.to_vec()
    };
    staging.unmap();
    Ok(out)
}
