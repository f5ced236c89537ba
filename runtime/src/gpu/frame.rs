//! The frame buffers of the GPU synthesizer: everything that depends on the frame's size and
//! layer count (records, Laplacian and direct planes, pyramid levels, output, staging, the
//! tiled splat's bins) and on the options baked into uniforms; created for the first frame of
//! a size and reused by every later frame of that size.

use poisson::pyramid::{level_sizes, PAD, PYRAMID_SCALE};

use super::layout::{PassParams, PlaneSet, SplatTargets, TileGrid};
use super::pyramid::PyramidFrame;
use super::synth::{GpuSynthesizer, SplatMode};
use super::tiles::{self, BinSetup, TILE_META_WORDS};
use super::util::{bind_group, storage_zeroed, uniform_init};
use super::GpuError;
use crate::pipeline::splat::RotationSampling;
use crate::pipeline::types::{FrameParams, SplatRecord};

/// What the frame buffers are made for: the frame's size, padding and layers, and the options
/// baked into their uniforms (rotation sampling, coverage renormalisation).
pub(super) type FrameKey = (u32, u32, u32, u32, RotationSampling, bool, bool);

/// Everything that depends on the frame size and layer count (and the options in uniforms).
pub(super) struct FrameBuffers {
    pub(super) key: FrameKey,
    pub(super) frame_uniform: wgpu::Buffer,
    pub(super) records: wgpu::Buffer,
    pub(super) record_capacity: usize,
    pub(super) layer_set: PlaneSet,
    pub(super) layer_images: wgpu::Buffer,
    pub(super) pyramid: PyramidFrame,
    /// Layers drawn per chunk (all of them unless the buffers would exceed a binding).
    pub(super) chunk_layers: u32,
    pub(super) chunks: Vec<Chunk>,
    pub(super) output: wgpu::Buffer,
    /// Running coverage between chunks (bound in the composite groups).
    pub(super) _coverage: wgpu::Buffer,
    /// Running sharpness of the fill between chunks (bound in the composite groups).
    pub(super) _fill_state: wgpu::Buffer,
    pub(super) output_staging: wgpu::Buffer,
    pub(super) output_bytes: u64,
    pub(super) queries: Option<Queries>,
    /// Tiled splat: per-tile state of one chunk and the entry list (grown on demand).
    pub(super) tile_meta: wgpu::Buffer,
    pub(super) entries: wgpu::Buffer,
    pub(super) entry_capacity: u64,
}

/// A run of layers drawn, integrated and composited together in the frame buffers.
pub(super) struct Chunk {
    /// The chunk's first layer (index 0 = farthest).
    pub(super) layer_base: u32,
    pub(super) layer_count: u32,
    /// The sharpness of each of the chunk's layers (`CompositeOptions::restore_occluded`),
    /// written before every frame.
    pub(super) layer_sharpness: wgpu::Buffer,
    pub(super) splat_group: wgpu::BindGroup,
    /// Tiled splat: bind group, tile grid (its entry capacity rewritten when the list grows).
    pub(super) tiled_group: Option<wgpu::BindGroup>,
    pub(super) grid: TileGrid,
    pub(super) grid_uniform: wgpu::Buffer,
    pub(super) composite_group: wgpu::BindGroup,
    // Kept alive with the bind groups.
    pub(super) _targets: wgpu::Buffer,
    pub(super) _composite_params: wgpu::Buffer,
}

pub(super) struct Queries {
    pub(super) set: wgpu::QuerySet,
    pub(super) resolve: wgpu::Buffer,
    pub(super) staging: wgpu::Buffer,
    pub(super) count: u32,
}

/// Timestamp slots per chunk: begin/end of splat, integrate, composite, binning.
pub(super) const QUERIES_PER_CHUNK: u32 = 8;

/// Composite flags (`shaders/composite.wgsl`).
pub(super) const RENORMALIZE: u32 = 1;
pub(super) const FIRST_CHUNK: u32 = 2;
pub(super) const LAST_CHUNK: u32 = 4;
/// Make up missing coverage with the occluded layers' colour (`CompositeOptions::restore_occluded`).
pub(super) const RESTORE_OCCLUDED: u32 = 8;

impl GpuSynthesizer {
    pub(super) fn frame_buffers(&self) -> Result<&FrameBuffers, GpuError> {
        self.frame
            .as_ref()
            .ok_or_else(|| GpuError::Input("no frame has run".into()))
    }

    pub(super) fn validate(frame: &FrameParams, records: &[SplatRecord]) -> Result<(), GpuError> {
        let bad = |m: String| Err(GpuError::Input(m));
        if frame.width == 0 || frame.height == 0 || frame.layers == 0 {
            return bad(format!(
                "empty frame {}x{} with {} layers",
                frame.width, frame.height, frame.layers
            ));
        }
        if Some(frame.padded_width)
            != frame
                .pad
                .checked_mul(2)
                .and_then(|p| p.checked_add(frame.width))
            || Some(frame.padded_height)
                != frame
                    .pad
                    .checked_mul(2)
                    .and_then(|p| p.checked_add(frame.height))
        {
            return bad(format!(
                "padded size {}x{} is not {}x{} plus 2 x {} px",
                frame.padded_width, frame.padded_height, frame.width, frame.height, frame.pad
            ));
        }
        if frame.record_count as usize != records.len() {
            return bad(format!(
                "frame says {} records, {} given",
                frame.record_count,
                records.len()
            ));
        }
        Ok(())
    }

    /// (Re)creates the frame buffers when the size, the layer count or an option in their
    /// uniforms changed, and the record buffer (and the tiled splat's entry list) when it is
    /// too small.
    pub(super) fn ensure_frame_buffers(
        &mut self,
        frame: &FrameParams,
        records: &[SplatRecord],
    ) -> Result<(), GpuError> {
        let key = (
            frame.width,
            frame.height,
            frame.pad,
            frame.layers,
            self.options.rotation,
            self.options.composite.renormalize_coverage,
            self.options.composite.restore_occluded,
        );
        let mut rebuild = false;
        if self.frame.as_ref().is_none_or(|f| f.key != key) {
            self.frame = None;
            let fb = self.frame_buffers_for(frame, key)?;
            self.counters.frame_allocations += 1;
            self.frame = Some(fb);
            rebuild = true;
        }
        let tiled = self.splat_mode() == SplatMode::Tiled;
        let entries_needed = if tiled {
            self.entries_needed(frame, records)
        } else {
            0
        };
        let fb = self
            .frame
            .as_mut()
            .ok_or_else(|| GpuError::Input("no frame".into()))?;
        if fb.record_capacity < records.len() {
            let capacity = records.len().next_power_of_two();
            fb.records = storage_zeroed(
                &self.ctx,
                "records",
                (capacity * size_of::<SplatRecord>()) as u64,
            )?;
            fb.record_capacity = capacity;
            self.counters.record_allocations += 1;
            rebuild = true;
        }
        if entries_needed > fb.entry_capacity {
            let capacity = entries_needed.next_power_of_two();
            let too_large = |bytes: u64| GpuError::TooLarge {
                what: "tile entries",
                bytes,
                limit: 4 * u32::MAX as u64,
            };
            let capacity = if capacity > u32::MAX as u64 {
                if entries_needed > u32::MAX as u64 {
                    return Err(too_large(4 * entries_needed));
                }
                u32::MAX as u64
            } else {
                capacity
            };
            fb.entries = storage_zeroed(&self.ctx, "tile entries", 4 * capacity)?;
            fb.entry_capacity = capacity;
            self.counters.entry_allocations += 1;
            for c in &mut fb.chunks {
                c.grid.entry_capacity = capacity as u32;
                self.ctx
                    .queue
                    .write_buffer(&c.grid_uniform, 0, bytemuck::bytes_of(&c.grid));
            }
            rebuild = true;
        }
        if rebuild {
            self.rebuild_groups();
        }
        Ok(())
    }

    /// Entries the tiled splat's binning writes for the largest chunk of layers (computed on
    /// the CPU with the same spans as the GPU: the entry list is sized before the frame runs).
    pub(super) fn entries_needed(&self, frame: &FrameParams, records: &[SplatRecord]) -> u64 {
        let chunk_layers = self.frame.as_ref().map_or(frame.layers, |f| f.chunk_layers);
        (0..frame.layers.div_ceil(chunk_layers.max(1)))
            .map(|k| {
                let layer_base = k * chunk_layers;
                let setup = BinSetup {
                    frame,
                    layer_base,
                    layer_count: chunk_layers.min(frame.layers - layer_base),
                    psf_count: self.db.psf_count,
                    rotation: self.options.rotation,
                    footprints: &self.db.footprint_table,
                    max_tiles: self.options.max_tiles_per_record,
                };
                tiles::entry_count(&setup, records)
            })
            .max()
            .unwrap_or(0)
    }

    /// Rebinds the splat stages to the current record and entry buffers.
    pub(super) fn rebuild_groups(&mut self) {
        let Some(fb) = self.frame.as_ref() else {
            return;
        };
        let groups: Vec<(wgpu::BindGroup, Option<wgpu::BindGroup>)> = fb
            .chunks
            .iter()
            .map(|c| {
                let global = self.splat_group(
                    &fb.frame_uniform,
                    &c._targets,
                    &fb.records,
                    &fb.pyramid.analysis,
                    &fb.layer_images,
                );
                let tiled = self.tiled.as_ref().map(|t| {
                    let db = &self.db;
                    bind_group(
                        &self.ctx,
                        "tiled splat",
                        &t.layout,
                        &[
                            &fb.frame_uniform,
                            &c._targets,
                            &fb.records,
                            &db.cumulative,
                            &db.positions,
                            &db.values,
                            &db.dense_table,
                            &db.dense_data,
                            &fb.pyramid.analysis,
                            &fb.layer_images,
                            &c.grid_uniform,
                            &db.footprints,
                            &fb.tile_meta,
                            &fb.entries,
                        ],
                    )
                });
                (global, tiled)
            })
            .collect();
        if let Some(fb) = self.frame.as_mut() {
            for (c, (g, t)) in fb.chunks.iter_mut().zip(groups) {
                c.splat_group = g;
                c.tiled_group = t;
            }
        }
    }

    pub(super) fn frame_buffers_for(
        &self,
        frame: &FrameParams,
        key: FrameKey,
    ) -> Result<FrameBuffers, GpuError> {
        let ctx = &self.ctx;
        let (pw, ph) = (frame.padded_width as usize, frame.padded_height as usize);
        // Layers per chunk: the most whose planes fit one binding (the pyramid levels are the
        // largest buffer), capped by the option.
        let limit = ctx
            .limits()
            .max_storage_buffer_binding_size
            .min(ctx.limits().max_buffer_size);
        let level_px: u64 = level_sizes(pw, ph)
            .iter()
            .map(|&(w, h)| (w * h) as u64)
            .sum();
        let per_layer = 16 * level_px.max((pw * ph) as u64);
        let fit = u32::try_from(limit / per_layer).unwrap_or(u32::MAX);
        let chunk_layers = frame
            .layers
            .min(fit)
            .min(self.options.max_layers_per_chunk.max(1));
        if chunk_layers == 0 {
            return Err(GpuError::TooLarge {
                what: "one layer's planes",
                bytes: per_layer,
                limit,
            });
        }
        let planes = chunk_layers as usize * 4;
        let layer_set = PlaneSet::packed(pw, ph, 0);
        let layer_images = storage_zeroed(ctx, "layer images", 4 * (pw * ph * planes) as u64)?;
        let pyramid = PyramidFrame::new(
            ctx,
            &self.pyramid,
            pw,
            ph,
            planes,
            (&layer_images, layer_set),
            PYRAMID_SCALE,
        )?;
        let (w, h) = (frame.width as usize, frame.height as usize);
        let output_bytes = 16 * (w * h) as u64;
        let output = storage_zeroed(ctx, "output image", output_bytes)?;
        // The layers' running sum of colour and coverage, one vec4 per pixel.
        let coverage = storage_zeroed(ctx, "output coverage", 16 * (w * h) as u64)?;
        // The running sharpness of what "over" shows, of all layers and of what hid something,
        // one vec4 per pixel.
        let fill_state = storage_zeroed(ctx, "fill sharpness", 16 * (w * h) as u64)?;
        let output_staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("output staging"),
            size: output.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let frame_uniform = uniform_init(ctx, "frame", bytemuck::bytes_of(frame));
        let records = storage_zeroed(ctx, "records", 16)?;
        let tile_meta = storage_zeroed(
            ctx,
            "tile state",
            4 * TILE_META_WORDS as u64 * tiles::tile_grid(frame, chunk_layers).tile_count as u64,
        )?;
        let entries = storage_zeroed(ctx, "tile entries", 16)?;
        let n_chunks = frame.layers.div_ceil(chunk_layers);
        let renormalize = match (
            self.options.composite.renormalize_coverage,
            self.options.composite.restore_occluded,
        ) {
            (true, true) => RENORMALIZE | RESTORE_OCCLUDED,
            (true, false) => RENORMALIZE,
            (false, _) => 0,
        };
        let chunks = (0..n_chunks)
            .map(|k| {
                let layer_base = k * chunk_layers;
                let layer_count = chunk_layers.min(frame.layers - layer_base);
                let targets = SplatTargets {
                    laplacian: pyramid.analysis_sets[0],
                    direct: layer_set,
                    border: PAD as u32,
                    rotation: match self.options.rotation {
                        RotationSampling::Bilinear => 0,
                        RotationSampling::Nearest => 1,
                        RotationSampling::Bspline => 2,
                    },
                    psf_count: self.db.psf_count,
                    channels: self.db.channels,
                    layer_base,
                    layer_count,
                    ..Default::default()
                };
                let targets = uniform_init(ctx, "splat targets", bytemuck::bytes_of(&targets));
                let splat_group = self.splat_group(
                    &frame_uniform,
                    &targets,
                    &records,
                    &pyramid.analysis,
                    &layer_images,
                );
                let grid = tiles::tile_grid(frame, layer_count);
                let grid_uniform = uniform_init(ctx, "tile grid", bytemuck::bytes_of(&grid));
                let first = if k == 0 { FIRST_CHUNK } else { 0 };
                let last = if k + 1 == n_chunks { LAST_CHUNK } else { 0 };
                let params = uniform_init(
                    ctx,
                    "composite",
                    bytemuck::bytes_of(&PassParams {
                        src: layer_set,
                        dst: PlaneSet::packed(w, h, 0),
                        planes: layer_count,
                        border: frame.pad,
                        flags: renormalize | first | last,
                        ..Default::default()
                    }),
                );
                let layer_sharpness =
                    storage_zeroed(ctx, "layer sharpness", 4 * u64::from(layer_count.max(1)))?;
                let composite_group = bind_group(
                    ctx,
                    "composite",
                    &self.composite_layout,
                    &[
                        &params,
                        &layer_images,
                        &output,
                        &coverage,
                        &layer_sharpness,
                        &fill_state,
                    ],
                );
                Ok(Chunk {
                    layer_base,
                    layer_count,
                    layer_sharpness,
                    splat_group,
                    tiled_group: None,
                    grid,
                    grid_uniform,
                    composite_group,
                    _targets: targets,
                    _composite_params: params,
                })
            })
            .collect::<Result<Vec<_>, GpuError>>()?;
        let count = QUERIES_PER_CHUNK * n_chunks;
        let queries =
            (ctx.has_timestamps() && count <= wgpu::QUERY_SET_MAX_QUERIES).then(|| Queries {
                set: ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("stage timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count,
                }),
                resolve: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("timestamps"),
                    size: 8 * count as u64,
                    usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                }),
                staging: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("timestamps staging"),
                    size: 8 * count as u64,
                    usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
                count,
            });
        Ok(FrameBuffers {
            key,
            frame_uniform,
            records,
            record_capacity: 0,
            layer_set,
            layer_images,
            pyramid,
            chunk_layers,
            chunks,
            output,
            _coverage: coverage,
            _fill_state: fill_state,
            output_staging,
            output_bytes,
            queries,
            tile_meta,
            entries,
            entry_capacity: 0,
        })
    }

    pub(super) fn splat_group(
        &self,
        frame_uniform: &wgpu::Buffer,
        targets: &wgpu::Buffer,
        records: &wgpu::Buffer,
        laplacian: &wgpu::Buffer,
        direct: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let db = &self.db;
        bind_group(
            &self.ctx,
            "splat",
            &self.splat_layout,
            &[
                frame_uniform,
                targets,
                records,
                &db.cumulative,
                &db.positions,
                &db.values,
                &db.dense_table,
                &db.dense_data,
                laplacian,
                direct,
            ],
        )
    }
}
