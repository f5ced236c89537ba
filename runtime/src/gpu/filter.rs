//! The filter baseline on the GPU (`shaders/filter.wgsl`), the twin of
//! [`crate::baseline::filter`]: the same per-pixel kernels ([`filter_plan`], on the CPU), then
//! one invocation per output pixel gathers the input.

use crate::synth::ms_since;
use std::time::Instant;

use super::layout::{FilterParams, FilterPixel, KernelEntry, NO_KERNEL};
use super::shaders;
use super::util::{
    bind_group, compute_pipelines, layout_entries, read_f32, storage_init, storage_zeroed,
    uniform_init,
};
use super::{GpuContext, GpuError};
use crate::baseline::{filter_plan, DenseKernels, FilterOptions, FilterStats, PixelPsf};
use crate::camera::Camera;
use crate::dbset::DbSet;
use crate::gbuffer::GBuffer;
use crate::pipeline::RotationSampling;
use formats::RgbaImage;

/// Workgroup edge of `filter_pixels` (8 x 8 invocations).
const TILE: u32 = 8;

/// The filter pass and the uploaded kernels, reusable across frames.
pub struct GpuFilter {
    ctx: GpuContext,
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    table: wgpu::Buffer,
    data: wgpu::Buffer,
    /// Per kernel: whether it has values (an empty one keeps the pixel's colour, as on the CPU).
    has_values: Vec<bool>,
    channels: u32,
}

impl GpuFilter {
    /// Compiles the pass and uploads `kernels` (once). Kernels must share one channel count.
    pub fn new(ctx: &GpuContext, kernels: &DenseKernels) -> Result<Self, GpuError> {
        let channels = kernels.kernels.first().map_or(1, |k| k.channels);
        if kernels.kernels.iter().any(|k| k.channels != channels)
            || !(channels == 1 || channels == 3)
        {
            return Err(GpuError::Input(
                "filter kernels must all have 1 or all 3 channels".into(),
            ));
        }
        let mut table = Vec::with_capacity(kernels.kernels.len());
        let mut data: Vec<f32> = Vec::new();
        for k in &kernels.kernels {
            let offset = u32::try_from(data.len())
                .map_err(|_| GpuError::Input("filter kernels beyond u32 offsets".into()))?;
            table.push(KernelEntry {
                offset,
                width: k.width as u32,
                height: k.height as u32,
                origin_x: k.origin[0],
                origin_y: k.origin[1],
                _pad: 0,
            });
            data.extend_from_slice(&k.data);
        }
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("filter"),
                entries: &layout_entries(shaders::bindings::FILTER),
            });
        let pipeline = compute_pipelines(
            ctx,
            "filter",
            &shaders::filter(),
            &layout,
            &["filter_pixels"],
            &[],
        )?
        .remove(0);
        Ok(Self {
            ctx: ctx.clone(),
            layout,
            pipeline,
            table: storage_init(ctx, "filter kernel table", bytemuck::cast_slice(&table)),
            data: storage_init(ctx, "filter kernel data", bytemuck::cast_slice(&data)),
            has_values: kernels.kernels.iter().map(|k| !k.data.is_empty()).collect(),
            channels: channels as u32,
        })
    }

    /// Gathers `input` (`width x height` premultiplied RGBA, row-major) with each pixel's
    /// kernel from `plan` (as [`filter_plan`] gives it). Returns the image and the wall time of
    /// upload, pass and readback, ms.
    pub fn run(
        &self,
        input: &[[f32; 4]],
        width: usize,
        height: usize,
        plan: &[Option<PixelPsf>],
        rotation: RotationSampling,
    ) -> Result<(RgbaImage, f64), GpuError> {
        let n = width * height;
        if input.len() != n || plan.len() != n {
            return Err(GpuError::Input(format!(
                "filter input of {} and plan of {} pixels for a {width}x{height} image",
                input.len(),
                plan.len()
            )));
        }
        let t = Instant::now();
        let pixels: Vec<FilterPixel> = plan
            .iter()
            .map(|p| match p {
                Some(p) if self.has_values.get(p.psf as usize) == Some(&true) => FilterPixel {
                    kernel: p.psf,
                    rot_cos: p.rot_cos,
                    rot_sin: p.rot_sin,
                    _pad: 0,
                },
                _ => FilterPixel {
                    kernel: NO_KERNEL,
                    rot_cos: 1.0,
                    rot_sin: 0.0,
                    _pad: 0,
                },
            })
            .collect();
        let params = FilterParams {
            width: width as u32,
            height: height as u32,
            channels: self.channels,
            rotation: match rotation.for_image_space() {
                RotationSampling::Nearest => 1,
                _ => 0,
            },
        };
        let ctx = &self.ctx;
        let params_buf = uniform_init(ctx, "filter params", bytemuck::bytes_of(&params));
        let pixels_buf = storage_init(ctx, "filter pixels", bytemuck::cast_slice(&pixels));
        let input_buf = storage_init(ctx, "filter input", bytemuck::cast_slice(input));
        let bytes = (n * 16) as u64;
        let output = storage_zeroed(ctx, "filter output", bytes)?;
        let group = bind_group(
            ctx,
            "filter",
            &self.layout,
            &[
                &params_buf,
                &pixels_buf,
                &input_buf,
                &self.table,
                &self.data,
                &output,
            ],
        );
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("filter"),
            });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("filter"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(
                (width as u32).div_ceil(TILE),
                (height as u32).div_ceil(TILE),
                1,
            );
        }
        ctx.queue.submit([encoder.finish()]);
        let values = read_f32(ctx, "filter output", &output, 0, bytes)?;
        let mut image = RgbaImage::new(width, height);
        for (px, v) in image.pixels.iter_mut().zip(values.chunks_exact(4)) {
            *px = [v[0], v[1], v[2], v[3]];
        }
        Ok((image, ms_since(t)))
    }
}

/// The filter baseline with the gathering on the GPU: [`filter_plan`] on the CPU, then
/// [`GpuFilter::run`]. `stats.filter_ms` is the GPU part's wall time (upload, pass, readback).
pub fn filter_gpu(
    gpu: &GpuFilter,
    gbuffer: &GBuffer,
    camera: &Camera,
    dbs: &DbSet,
    options: &FilterOptions,
) -> Result<(RgbaImage, FilterStats), GpuError> {
    let total = Instant::now();
    let (plan, mut stats) =
        filter_plan(gbuffer, camera, dbs, options).map_err(|e| GpuError::Input(e.to_string()))?;
    let (image, ms) = gpu.run(
        &gbuffer.color,
        gbuffer.width,
        gbuffer.height,
        &plan,
        options.rotation,
    )?;
    stats.filter_ms = ms;
    stats.total_ms = ms_since(total);
    Ok((image, stats))
}
