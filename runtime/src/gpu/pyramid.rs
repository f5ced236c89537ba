//! Integration by convolution pyramid on the GPU (`shaders/pyramid.wgsl`), mirroring
//! `poisson::pyramid` step by step: the same level sizes, filters, padding and order.

use poisson::pyramid::{level_sizes, G, H1, H2, PAD, PYRAMID_SCALE};
use poisson::Plane;

use super::layout::{PassParams, PlaneSet};
use super::util::{
    bind_group, compute_pipelines, layout_entries, read_f32, storage_zeroed, uniform_init,
};
use super::{shaders, GpuContext, GpuError};

/// Workgroup edge of the per-pixel passes (`@workgroup_size(16, 16, 1)`).
pub(crate) const TILE: u32 = 16;

/// The pyramid's compute pipelines (created once per synthesizer).
pub(crate) struct PyramidPipelines {
    layout: wgpu::BindGroupLayout,
    analysis: wgpu::ComputePipeline,
    top: wgpu::ComputePipeline,
    synthesis: wgpu::ComputePipeline,
    output: wgpu::ComputePipeline,
}

impl PyramidPipelines {
    pub(crate) fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("pyramid"),
                entries: &layout_entries(shaders::bindings::PYRAMID),
            });
        let names = ["h1_0", "h1_1", "h1_2", "h1_3", "h1_4"];
        let names2 = ["h2_0", "h2_1", "h2_2", "h2_3", "h2_4"];
        let mut constants: Vec<(&str, f64)> = Vec::new();
        constants.extend(names.iter().zip(H1).map(|(n, v)| (*n, v as f64)));
        constants.extend(names2.iter().zip(H2).map(|(n, v)| (*n, v as f64)));
        constants.extend(
            ["g_0", "g_1", "g_2"]
                .iter()
                .zip(G)
                .map(|(n, v)| (*n, v as f64)),
        );
        constants.push(("pad", PAD as f64));
        let mut p = compute_pipelines(
            ctx,
            "pyramid",
            &shaders::pyramid(),
            &layout,
            &["analysis_step", "top_step", "synthesis_step", "output"],
            &constants,
        )?
        .into_iter();
        let mut next = || {
            p.next().ok_or_else(|| GpuError::Wgpu {
                stage: "pyramid",
                message: "missing pipeline".into(),
            })
        };
        Ok(Self {
            analysis: next()?,
            top: next()?,
            synthesis: next()?,
            output: next()?,
            layout,
        })
    }
}

/// One dispatch of a pyramid pass.
struct Pass {
    kind: PassKind,
    group: wgpu::BindGroup,
    // Kept alive with the bind group.
    _params: wgpu::Buffer,
    size: [u32; 3],
}

#[derive(Clone, Copy)]
enum PassKind {
    Analysis,
    Top,
    Synthesis,
    Output,
    /// The output pass with scale 1, for exact integration (primal planes uploaded into
    /// synthesis level 0).
    ExactOutput,
}

/// GPU buffers and bind groups for integrating `planes` planes of one size; created once per
/// frame size and reused.
pub(crate) struct PyramidFrame {
    /// Plane size (the padded layer), px.
    pub width: usize,
    /// Plane size (the padded layer), px.
    pub height: usize,
    /// Number of planes (`layers * 4`).
    pub planes: usize,
    /// Where each analysis level `a_i` lies in [`PyramidFrame::analysis`].
    pub analysis_sets: Vec<PlaneSet>,
    /// Where each synthesis level `f_i` lies in [`PyramidFrame::synthesis`].
    pub synthesis_sets: Vec<PlaneSet>,
    /// All analysis levels; level 0 (padded by `PAD`) is where the Laplacian is splatted.
    pub analysis: wgpu::Buffer,
    /// All synthesis levels.
    pub synthesis: wgpu::Buffer,
    passes: Vec<Pass>,
}

impl PyramidFrame {
    /// Buffers for `planes` planes of `width x height`; the output pass adds `scale` times the
    /// integral into the layer images (a buffer and where its planes lie).
    pub(crate) fn new(
        ctx: &GpuContext,
        pipelines: &PyramidPipelines,
        width: usize,
        height: usize,
        planes: usize,
        (layer_images, layer_set): (&wgpu::Buffer, PlaneSet),
        scale: f32,
    ) -> Result<Self, GpuError> {
        let sizes = level_sizes(width, height);
        let mut analysis_sets = Vec::with_capacity(sizes.len());
        let mut offset = 0usize;
        for &(w, h) in &sizes {
            analysis_sets.push(PlaneSet::packed(w, h, offset));
            offset += w * h * planes;
        }
        let total = offset;
        if total > u32::MAX as usize {
            return Err(GpuError::TooLarge {
                what: "pyramid levels",
                bytes: 4 * total as u64,
                limit: 4 * u32::MAX as u64,
            });
        }
        let synthesis_sets = analysis_sets.clone();
        let analysis = storage_zeroed(ctx, "pyramid analysis levels", 4 * total as u64)?;
        let synthesis = storage_zeroed(ctx, "pyramid synthesis levels", 4 * total as u64)?;
        let levels = sizes.len();
        let mut passes = Vec::new();
        let planes_u = planes as u32;
        let mut push = |kind: PassKind, params: PassParams| {
            let buf = uniform_init(ctx, "pyramid pass", bytemuck::bytes_of(&params));
            let group = bind_group(
                ctx,
                "pyramid pass",
                &pipelines.layout,
                &[&buf, &analysis, &synthesis, layer_images],
            );
            let d = params.dst;
            passes.push(Pass {
                kind,
                group,
                _params: buf,
                size: [d.width.div_ceil(TILE), d.height.div_ceil(TILE), planes_u],
            });
        };
        let base = PassParams {
            planes: planes_u,
            scale,
            ..Default::default()
        };
        for i in 1..levels {
            push(
                PassKind::Analysis,
                PassParams {
                    src: analysis_sets[i - 1],
                    dst: analysis_sets[i],
                    ..base
                },
            );
        }
        push(
            PassKind::Top,
            PassParams {
                src: analysis_sets[levels - 1],
                dst: synthesis_sets[levels - 1],
                ..base
            },
        );
        for i in (0..levels - 1).rev() {
            push(
                PassKind::Synthesis,
                PassParams {
                    src: synthesis_sets[i + 1],
                    dst: synthesis_sets[i],
                    aux: analysis_sets[i],
                    ..base
                },
            );
        }
        push(
            PassKind::Output,
            PassParams {
                src: synthesis_sets[0],
                dst: layer_set,
                ..base
            },
        );
        push(
            PassKind::ExactOutput,
            PassParams {
                src: synthesis_sets[0],
                dst: layer_set,
                scale: 1.0,
                ..base
            },
        );
        Ok(Self {
            width,
            height,
            planes,
            analysis_sets,
            synthesis_sets,
            analysis,
            synthesis,
            passes,
        })
    }

    /// Records every pass. The Laplacian must be in analysis level 0 (inside its `PAD` border).
    /// With `exact`, skips the pyramid and runs only an output pass with scale 1 (exact
    /// integration: the primal planes were uploaded into synthesis level 0).
    pub(crate) fn encode(
        &self,
        pipelines: &PyramidPipelines,
        pass: &mut wgpu::ComputePass<'_>,
        exact: bool,
    ) {
        for p in &self.passes {
            let pipeline = match (p.kind, exact) {
                (PassKind::ExactOutput, true) | (PassKind::Output, false) => &pipelines.output,
                (PassKind::Analysis, false) => &pipelines.analysis,
                (PassKind::Top, false) => &pipelines.top,
                (PassKind::Synthesis, false) => &pipelines.synthesis,
                _ => continue,
            };
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &p.group, &[]);
            pass.dispatch_workgroups(p.size[0], p.size[1], p.size[2]);
        }
    }

    /// Uploads `planes` (each `width x height`, unpadded) into `set`'s level of `buffer`,
    /// zeroing the `PAD` border.
    pub(crate) fn upload_padded(
        &self,
        ctx: &GpuContext,
        buffer: &wgpu::Buffer,
        set: PlaneSet,
        planes: &[&Plane],
    ) {
        let (w0, h0) = (set.width as usize, set.height as usize);
        let mut data = vec![0f32; w0 * h0 * planes.len()];
        for (p, plane) in planes.iter().enumerate() {
            for y in 0..plane.height.min(h0.saturating_sub(2 * PAD)) {
                let dst = p * w0 * h0 + (y + PAD) * w0 + PAD;
                let n = plane.width.min(w0.saturating_sub(2 * PAD));
                data[dst..dst + n].copy_from_slice(&plane.row(y)[..n]);
            }
        }
        ctx.queue
            .write_buffer(buffer, 4 * set.offset as u64, bytemuck::cast_slice(&data));
    }

    /// Reads back every plane of one level (`set` in `buffer`).
    pub(crate) fn read_level(
        &self,
        ctx: &GpuContext,
        buffer: &wgpu::Buffer,
        set: PlaneSet,
    ) -> Result<Vec<Plane>, GpuError> {
        let n = set.plane_len();
        let data = read_f32(
            ctx,
            "pyramid level",
            buffer,
            4 * set.offset as u64,
            4 * (n * self.planes) as u64,
        )?;
        Ok(data
            .chunks_exact(n.max(1))
            .take(self.planes)
            .map(|c| Plane {
                width: set.width as usize,
                height: set.height as usize,
                data: c.to_vec(),
            })
            .collect())
    }
}

/// Every level of one GPU pyramid run, for comparing with `poisson::PyramidWorkspace`.
#[derive(Clone, Debug)]
pub struct PyramidLevels {
    /// `analysis[i][p]`: analysis level `a_i` of plane `p` (padding included).
    pub analysis: Vec<Vec<Plane>>,
    /// `synthesis[i][p]`: synthesis level `f_i` of plane `p` (padding included).
    pub synthesis: Vec<Vec<Plane>>,
}

/// The convolution pyramid alone on the GPU (a stage-level entry point for tests and
/// benchmarks; [`super::GpuSynthesizer`] runs the same passes inside a frame). Buffers are kept
/// and reused while the plane size and count stay the same.
pub struct GpuPyramid {
    ctx: GpuContext,
    pipelines: PyramidPipelines,
    frame: Option<StandaloneFrame>,
}

/// A pyramid frame with its own output planes.
struct StandaloneFrame {
    frame: PyramidFrame,
    images: wgpu::Buffer,
    set: PlaneSet,
}

impl GpuPyramid {
    /// Compiles the pyramid pipelines.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Ok(Self {
            ctx: ctx.clone(),
            pipelines: PyramidPipelines::new(ctx)?,
            frame: None,
        })
    }

    /// Integrates each Laplacian plane (all the same size) like `poisson::integrate_pyramid`.
    pub fn integrate(&mut self, laplacians: &[Plane]) -> Result<Vec<Plane>, GpuError> {
        let Some(first) = laplacians.first() else {
            return Ok(Vec::new());
        };
        let (w, h, n) = (first.width, first.height, laplacians.len());
        if w == 0 || h == 0 {
            return Err(GpuError::Input("empty plane".into()));
        }
        if laplacians
            .iter()
            .any(|p| (p.width, p.height) != (w, h) || p.data.len() != w * h)
        {
            return Err(GpuError::Input("planes of different sizes".into()));
        }
        let reuse = matches!(&self.frame, Some(f) if (f.frame.width, f.frame.height, f.frame.planes) == (w, h, n));
        if !reuse {
            let set = PlaneSet::packed(w, h, 0);
            let images = storage_zeroed(&self.ctx, "pyramid output", 4 * (w * h * n) as u64)?;
            let frame = PyramidFrame::new(
                &self.ctx,
                &self.pipelines,
                w,
                h,
                n,
                (&images, set),
                PYRAMID_SCALE,
            )?;
            self.frame = Some(StandaloneFrame { frame, images, set });
        }
        let Some(StandaloneFrame { frame, images, set }) = &self.frame else {
            return Err(GpuError::Input("no frame".into()));
        };
        let refs: Vec<&Plane> = laplacians.iter().collect();
        frame.upload_padded(&self.ctx, &frame.analysis, frame.analysis_sets[0], &refs);
        let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
        encoder.clear_buffer(images, 0, None);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("pyramid"),
                timestamp_writes: None,
            });
            frame.encode(&self.pipelines, &mut pass, false);
        }
        self.ctx.queue.submit([encoder.finish()]);
        let data = read_f32(
            &self.ctx,
            "pyramid output",
            images,
            0,
            4 * (w * h * n) as u64,
        )?;
        Ok(data
            .chunks_exact(set.plane_len())
            .map(|c| Plane {
                width: w,
                height: h,
                data: c.to_vec(),
            })
            .collect())
    }

    /// Every level of the last [`GpuPyramid::integrate`] call.
    pub fn levels(&self) -> Result<PyramidLevels, GpuError> {
        let Some(StandaloneFrame { frame, .. }) = &self.frame else {
            return Ok(PyramidLevels {
                analysis: Vec::new(),
                synthesis: Vec::new(),
            });
        };
        let analysis = frame
            .analysis_sets
            .iter()
            .map(|&s| frame.read_level(&self.ctx, &frame.analysis, s))
            .collect::<Result<_, _>>()?;
        let synthesis = frame
            .synthesis_sets
            .iter()
            .map(|&s| frame.read_level(&self.ctx, &frame.synthesis, s))
            .collect::<Result<_, _>>()?;
        Ok(PyramidLevels {
            analysis,
            synthesis,
        })
    }
}
