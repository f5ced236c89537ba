//! [`GpuSynthesizer`]: the whole synthesis pipeline after classification on the GPU (splat,
//! integrate, composite), mirroring `crate::pipeline` stage by stage.
//!
//! The database is uploaded once in [`GpuSynthesizer::new`]; pipelines are compiled there too.
//! Frame buffers (records, Laplacian and direct planes, pyramid levels, output, staging) are
//! created for the first frame of a size and reused by every later frame of that size.

use std::time::Instant;

use poisson::pyramid::{level_sizes, PAD, PYRAMID_SCALE};
use poisson::{ExactIntegrator, Plane};
use psf_db::{DenseEntry, PsfDatabase, SPARSE_SLOT};
use rayon::prelude::*;

use super::layout::{PassParams, PlaneSet, SplatTargets, TileGrid};
use super::pyramid::{PyramidFrame, PyramidPipelines, TILE};
use super::tiles::{self, BinSetup, TILE_META_WORDS};
use super::util::{
    bind_group, compute_pipelines, map_read, map_read_bytes, storage_entry, storage_init,
    storage_zeroed, uniform_entry, uniform_init,
};
use super::{shaders, GpuContext, GpuError};
use crate::pipeline::composite::CompositeOptions;
use crate::pipeline::integrate::Integrator;
use crate::pipeline::splat::RotationSampling;
use crate::pipeline::types::{FrameParams, SplatRecord};
use formats::RgbaImage;

/// How splats are accumulated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AtomicMode {
    /// `atomicAdd` on f32 where the device has `SHADER_FLOAT32_ATOMIC`, else compare-exchange.
    #[default]
    Auto,
    /// Always the compare-exchange loop on u32 bit patterns (for testing that path).
    CompareExchange,
}

/// How the splat stage accumulates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum SplatMode {
    /// Records binned into 16 x 16 px screen tiles; each tile sums its pixels in workgroup
    /// memory (fixed point, scaled from the tile's bound so that nothing overflows) and writes
    /// each pixel once, deterministically; records touching more than
    /// [`GpuSynthOptions::max_tiles_per_record`] tiles are added by global atomics after the
    /// tiles. Falls back to [`SplatMode::GlobalAtomic`] on a device
    /// without the workgroup memory or storage bindings it needs
    /// ([`GpuSynthesizer::splat_mode`] says which runs).
    #[default]
    Tiled,
    /// Every sample an atomic add into the planes in device memory ([`AtomicMode`]).
    GlobalAtomic,
}

impl SplatMode {
    /// `tiled` or `global-atomic`.
    pub fn name(self) -> &'static str {
        match self {
            SplatMode::Tiled => "tiled",
            SplatMode::GlobalAtomic => "global-atomic",
        }
    }
}

/// Knobs of the GPU pipeline (the same meaning as the CPU path's).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GpuSynthOptions {
    /// Placement of rotated spreadlets (as `pipeline::SplatOptions::rotation`).
    pub rotation: RotationSampling,
    /// Compositing options (as `pipeline::composite`).
    pub composite: CompositeOptions,
    /// Float atomics or compare-exchange (the global-atomic splat).
    pub atomics: AtomicMode,
    /// Tiled or global-atomic splatting.
    pub splat: SplatMode,
    /// Invocations that share one record's spreadlets (a power of two, 1 to 64; default 8:
    /// many records of small PSFs keep the device busy, 64 suits few large PSFs).
    pub lanes_per_record: u32,
    /// Tiled splat: records whose samples can touch more tiles than this are drawn with
    /// global atomics instead (each tile walks all of a record's samples; default 4).
    pub max_tiles_per_record: u32,
    /// At most this many layers are drawn together (default: all that fit the device's
    /// largest storage binding; lower only to test the chunked path).
    pub max_layers_per_chunk: u32,
}

impl Default for GpuSynthOptions {
    fn default() -> Self {
        GpuSynthOptions {
            rotation: RotationSampling::default(),
            composite: CompositeOptions::default(),
            atomics: AtomicMode::default(),
            splat: SplatMode::default(),
            lanes_per_record: 8,
            max_tiles_per_record: 4,
            max_layers_per_chunk: u32::MAX,
        }
    }
}

/// Milliseconds per stage of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct GpuStageTimes {
    /// Writing the records and frame constants (CPU wall time of the queue writes).
    pub upload_ms: f64,
    /// Splatting (sparse, dense and copied records; binning included), ms.
    pub splat_ms: f64,
    /// The tiled splat's binning (part of `splat_ms`), ms; 0 for the global-atomic splat.
    pub bin_ms: f64,
    /// Integration (pyramid, or exact on the CPU with the transfers around it), ms.
    pub integrate_ms: f64,
    /// Compositing, ms.
    pub composite_ms: f64,
    /// Copying the image back to the host, ms (CPU wall time).
    pub readback_ms: f64,
    /// Wall time of the whole call, ms.
    pub total_ms: f64,
    /// True when splat/integrate/composite come from GPU timestamp queries; false when they
    /// are CPU wall times around separate submissions.
    pub gpu_timestamps: bool,
}

/// How often the expensive set-up work has run (to check that frames of one size reuse it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SynthCounters {
    /// Pipeline compilations (once per synthesizer).
    pub pipeline_builds: u32,
    /// Database uploads (once per synthesizer).
    pub database_uploads: u32,
    /// Frame buffer allocations (once per frame size and layer count).
    pub frame_allocations: u32,
    /// Record buffer allocations (grows when a frame has more records than any before).
    pub record_allocations: u32,
    /// Tile entry buffer allocations (tiled splat; grows like the record buffer).
    pub entry_allocations: u32,
    /// Frames run.
    pub frames: u32,
}

/// Laplacian and direct planes after the splat stage (read back for tests), index
/// `layer * 4 + channel`, each `padded_width x padded_height`.
#[derive(Clone, Debug)]
pub struct SplatPlanes {
    /// Laplacian planes.
    pub laplacian: Vec<Plane>,
    /// Direct planes.
    pub direct: Vec<Plane>,
}

/// The PSF database on the GPU.
struct DbBuffers {
    cumulative: wgpu::Buffer,
    positions: wgpu::Buffer,
    values: wgpu::Buffer,
    dense_table: wgpu::Buffer,
    dense_data: wgpu::Buffer,
    /// [`tiles::footprints`], on the GPU and here (entry counts are computed on the CPU).
    footprints: wgpu::Buffer,
    footprint_table: Vec<super::layout::PsfFootprint>,
    psf_count: u32,
    channels: u32,
    /// (PSFs, spreadlets, dense values): to tell a different database apart.
    fingerprint: (usize, usize, usize),
}

impl DbBuffers {
    fn upload(ctx: &GpuContext, db: Option<&PsfDatabase>) -> Result<Self, GpuError> {
        let Some(db) = db else {
            let empty = |l| storage_init(ctx, l, &[]);
            return Ok(Self {
                cumulative: empty("cumulative"),
                positions: empty("positions"),
                values: empty("values"),
                dense_table: empty("dense table"),
                dense_data: empty("dense data"),
                // At least one element: the binding holds 32-byte structs.
                footprints: storage_init(ctx, "footprints", &[0; 32]),
                footprint_table: Vec::new(),
                psf_count: 0,
                channels: 1,
                fingerprint: (0, 0, 0),
            });
        };
        let limit = ctx.limits().max_storage_buffer_binding_size;
        let check = |what: &'static str, bytes: usize| {
            if bytes as u64 > limit {
                Err(GpuError::TooLarge {
                    what,
                    bytes: bytes as u64,
                    limit,
                })
            } else {
                Ok(())
            }
        };
        check("database positions", 4 * db.positions().len())?;
        check("database values", 4 * db.values().len())?;
        check("database dense data", 4 * db.dense_data().len())?;
        // dense_slot resolved here: one entry per PSF, size 0 for sparse PSFs.
        let entries = db.dense_entries();
        let table: Vec<DenseEntry> = db
            .dense_slots()
            .iter()
            .map(|&s| {
                if s == SPARSE_SLOT {
                    DenseEntry::default()
                } else {
                    entries.get(s as usize).copied().unwrap_or_default()
                }
            })
            .collect();
        let footprint_table = tiles::footprints(db);
        check("footprints", 32 * footprint_table.len())?;
        Ok(Self {
            footprints: storage_init(
                ctx,
                "footprints",
                if footprint_table.is_empty() {
                    &[0; 32]
                } else {
                    bytemuck::cast_slice(&footprint_table)
                },
            ),
            footprint_table,
            cumulative: storage_init(ctx, "cumulative", bytemuck::cast_slice(db.cumulative())),
            positions: storage_init(ctx, "positions", bytemuck::cast_slice(db.positions())),
            values: storage_init(ctx, "values", bytemuck::cast_slice(db.values())),
            dense_table: storage_init(ctx, "dense table", bytemuck::cast_slice(&table)),
            dense_data: storage_init(ctx, "dense data", bytemuck::cast_slice(db.dense_data())),
            psf_count: db.psf_count() as u32,
            channels: db.channels() as u32,
            fingerprint: fingerprint(Some(db)),
        })
    }
}

/// What the frame buffers are made for: the frame's size, padding and layers, and the options
/// baked into their uniforms (rotation sampling, coverage renormalisation).
type FrameKey = (u32, u32, u32, u32, RotationSampling, bool);

/// Everything that depends on the frame size and layer count (and the options in uniforms).
struct FrameBuffers {
    key: FrameKey,
    frame_uniform: wgpu::Buffer,
    records: wgpu::Buffer,
    record_capacity: usize,
    layer_set: PlaneSet,
    layer_images: wgpu::Buffer,
    pyramid: PyramidFrame,
    /// Layers drawn per chunk (all of them unless the buffers would exceed a binding).
    chunk_layers: u32,
    chunks: Vec<Chunk>,
    output: wgpu::Buffer,
    /// Running coverage between chunks (bound in the composite groups).
    _coverage: wgpu::Buffer,
    output_staging: wgpu::Buffer,
    output_bytes: u64,
    queries: Option<Queries>,
    /// Tiled splat: per-tile state of one chunk and the entry list (grown on demand).
    tile_meta: wgpu::Buffer,
    entries: wgpu::Buffer,
    entry_capacity: u64,
}

/// A run of layers drawn, integrated and composited together in the frame buffers.
struct Chunk {
    layer_count: u32,
    splat_group: wgpu::BindGroup,
    /// Tiled splat: bind group, tile grid (its entry capacity rewritten when the list grows).
    tiled_group: Option<wgpu::BindGroup>,
    grid: TileGrid,
    grid_uniform: wgpu::Buffer,
    composite_group: wgpu::BindGroup,
    // Kept alive with the bind groups.
    _targets: wgpu::Buffer,
    _composite_params: wgpu::Buffer,
}

struct Queries {
    set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    staging: wgpu::Buffer,
    count: u32,
}

/// Timestamp slots per chunk: begin/end of splat, integrate, composite, binning.
const QUERIES_PER_CHUNK: u32 = 8;

/// Composite flags (`shaders/composite.wgsl`).
const RENORMALIZE: u32 = 1;
const FIRST_CHUNK: u32 = 2;
const LAST_CHUNK: u32 = 4;

/// The synthesis pipeline on the GPU: compiled pipelines and the uploaded database, reused for
/// every frame.
pub struct GpuSynthesizer {
    ctx: GpuContext,
    options: GpuSynthOptions,
    float_atomics: bool,
    db: DbBuffers,
    splat_layout: wgpu::BindGroupLayout,
    splat: wgpu::ComputePipeline,
    /// The tiled splat's pipelines, when the device can run them.
    tiled: Option<TiledPipelines>,
    pyramid: PyramidPipelines,
    composite_layout: wgpu::BindGroupLayout,
    composite: wgpu::ComputePipeline,
    frame: Option<FrameBuffers>,
    counters: SynthCounters,
}

/// The tiled splat: binning (count, scan, scatter) and the per-tile sums.
struct TiledPipelines {
    layout: wgpu::BindGroupLayout,
    count: wgpu::ComputePipeline,
    scan: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    splat: wgpu::ComputePipeline,
    /// The records that span too many tiles, with global atomics.
    rest: wgpu::ComputePipeline,
}

impl TiledPipelines {
    /// `None` when the device lacks the workgroup memory, invocations or storage bindings.
    fn new(
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
        let mut entries: Vec<wgpu::BindGroupLayoutEntry> = vec![uniform_entry(0), uniform_entry(1)];
        entries.extend((2..=9).map(|b| storage_entry(b, b < 8)));
        entries.push(uniform_entry(10));
        entries.push(storage_entry(11, true));
        entries.push(storage_entry(12, false));
        entries.push(storage_entry(13, false));
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

/// How far [`GpuSynthesizer::execute`] goes.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Until {
    Splat,
    Integrate,
    Composite,
}

impl GpuSynthesizer {
    /// Compiles the pipelines and uploads `db` (once).
    pub fn new(
        ctx: &GpuContext,
        db: &PsfDatabase,
        options: GpuSynthOptions,
    ) -> Result<Self, GpuError> {
        Self::build(ctx, Some(db), options)
    }

    /// A synthesizer without a database: only copied records draw anything (pinhole, still
    /// frames), as on the CPU path with `db = None`.
    pub fn without_database(ctx: &GpuContext, options: GpuSynthOptions) -> Result<Self, GpuError> {
        Self::build(ctx, None, options)
    }

    fn build(
        ctx: &GpuContext,
        db: Option<&PsfDatabase>,
        options: GpuSynthOptions,
    ) -> Result<Self, GpuError> {
        let lanes = options.lanes_per_record;
        if !(1..=64).contains(&lanes) || !lanes.is_power_of_two() {
            return Err(GpuError::Input(format!(
                "lanes per record must be a power of two in 1..=64, not {lanes}"
            )));
        }
        let float_atomics = ctx.has_float_atomics() && options.atomics == AtomicMode::Auto;
        let splat_layout = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("splat"),
                entries: &[
                    uniform_entry(0),
                    uniform_entry(1),
                    storage_entry(2, true),
                    storage_entry(3, true),
                    storage_entry(4, true),
                    storage_entry(5, true),
                    storage_entry(6, true),
                    storage_entry(7, true),
                    storage_entry(8, false),
                    storage_entry(9, false),
                ],
            });
        let splat = compute_pipelines(
            ctx,
            "splat",
            &shaders::splat(float_atomics),
            &splat_layout,
            &["splat_records"],
            &[("LANES", lanes as f64)],
        )?
        .pop()
        .ok_or_else(|| GpuError::Wgpu {
            stage: "splat",
            message: "no pipeline".into(),
        })?;
        let composite_layout =
            ctx.device
                .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some("composite"),
                    entries: &[
                        uniform_entry(0),
                        storage_entry(1, true),
                        storage_entry(2, false),
                        storage_entry(3, false),
                    ],
                });
        let composite = compute_pipelines(
            ctx,
            "composite",
            &shaders::composite(),
            &composite_layout,
            &["composite"],
            &[],
        )?
        .pop()
        .ok_or_else(|| GpuError::Wgpu {
            stage: "composite",
            message: "no pipeline".into(),
        })?;
        let tiled = TiledPipelines::new(ctx, lanes, options.max_tiles_per_record, float_atomics)?;
        let pyramid = PyramidPipelines::new(ctx)?;
        let db = DbBuffers::upload(ctx, db)?;
        ctx.take_error("database upload")?;
        Ok(Self {
            ctx: ctx.clone(),
            options,
            float_atomics,
            db,
            splat_layout,
            splat,
            tiled,
            pyramid,
            composite_layout,
            composite,
            frame: None,
            counters: SynthCounters {
                pipeline_builds: 1,
                database_uploads: 1,
                ..Default::default()
            },
        })
    }

    /// An error unless this synthesizer was made for `db` (same PSF, spreadlet and dense
    /// value counts).
    pub fn check_database(&self, db: Option<&PsfDatabase>) -> Result<(), GpuError> {
        if fingerprint(db) != self.db.fingerprint {
            return Err(GpuError::Input(format!(
                "the GPU synthesizer holds a database of {} PSFs / {} spreadlets, not {} / {}",
                self.db.fingerprint.0,
                self.db.fingerprint.1,
                fingerprint(db).0,
                fingerprint(db).1
            )));
        }
        Ok(())
    }

    /// Whether splats use native float atomics (else the compare-exchange loop).
    pub fn uses_float_atomics(&self) -> bool {
        self.float_atomics
    }

    /// Takes the options of one call that the pipelines do not bake in (rotation sampling,
    /// compositing), so every call runs with its own, as on the CPU.
    pub fn apply_call_options(&mut self, options: &crate::synth::SynthOptions) {
        self.options.rotation = options.splat.rotation;
        self.options.composite = options.composite;
    }

    /// The options.
    pub fn options(&self) -> &GpuSynthOptions {
        &self.options
    }

    /// The splat stage that runs: the option's, or global atomics where the device cannot
    /// run the tiled one.
    pub fn splat_mode(&self) -> SplatMode {
        self.effective_splat_mode(self.options.splat)
    }

    /// The splat stage that would run with `mode` set.
    pub fn effective_splat_mode(&self, mode: SplatMode) -> SplatMode {
        match mode {
            SplatMode::Tiled if self.tiled.is_some() => SplatMode::Tiled,
            _ => SplatMode::GlobalAtomic,
        }
    }

    /// Switches the splat stage for the next frames (both are compiled; for comparisons).
    pub fn set_splat_mode(&mut self, mode: SplatMode) {
        self.options.splat = mode;
    }

    /// Set-up counters (pipelines, database uploads, frame allocations, frames).
    pub fn counters(&self) -> SynthCounters {
        self.counters
    }

    /// The adapter this runs on.
    pub fn adapter_name(&self) -> String {
        self.ctx.adapter_name()
    }

    /// Synthesises one frame: splat `records`, integrate with `integrator`, composite. The
    /// records and frame come from `pipeline::classify` (the same input as the CPU path).
    pub fn run(
        &mut self,
        frame: &FrameParams,
        records: &[SplatRecord],
        integrator: Integrator,
    ) -> Result<(RgbaImage, GpuStageTimes), GpuError> {
        let t0 = Instant::now();
        let mut times = self.execute(frame, records, integrator, Until::Composite, |_, _, _| {
            Ok(())
        })?;
        let t = Instant::now();
        let fb = self.frame_buffers()?;
        let data = map_read(&self.ctx, "output", &fb.output_staging, fb.output_bytes)?;
        let (w, h) = (frame.width as usize, frame.height as usize);
        let pixels: Vec<[f32; 4]> = data
            .chunks_exact(4)
            .take(w * h)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect();
        if times.gpu_timestamps {
            self.read_timestamps(&mut times)?;
        }
        times.readback_ms = ms(t);
        times.total_ms = ms(t0);
        Ok((
            RgbaImage {
                width: w,
                height: h,
                pixels,
            },
            times,
        ))
    }

    /// Stage-level entry point: splat only, and read back the Laplacian and direct planes.
    pub fn splat_planes(
        &mut self,
        frame: &FrameParams,
        records: &[SplatRecord],
    ) -> Result<SplatPlanes, GpuError> {
        let (pw, ph) = (frame.padded_width as usize, frame.padded_height as usize);
        let mut out = SplatPlanes {
            laplacian: Vec::new(),
            direct: Vec::new(),
        };
        self.execute(
            frame,
            records,
            Integrator::Pyramid,
            Until::Splat,
            |ctx, fb, chunk| {
                let n = chunk.layer_count as usize * 4;
                let pyr = &fb.pyramid;
                let padded = pyr.read_level(ctx, &pyr.analysis, pyr.analysis_sets[0])?;
                out.laplacian.extend(
                    padded
                        .iter()
                        .take(n)
                        .map(|p| p.crop(PAD as isize, PAD as isize, pw, ph)),
                );
                out.direct.extend(
                    pyr.read_level(ctx, &fb.layer_images, fb.layer_set)?
                        .into_iter()
                        .take(n),
                );
                Ok(())
            },
        )?;
        Ok(out)
    }

    /// Stage-level entry point: splat and integrate, and read back the layer images (primal
    /// plus direct), index `layer * 4 + channel`, padded-layer size.
    pub fn layer_images(
        &mut self,
        frame: &FrameParams,
        records: &[SplatRecord],
        integrator: Integrator,
    ) -> Result<Vec<Plane>, GpuError> {
        let mut out = Vec::new();
        self.execute(
            frame,
            records,
            integrator,
            Until::Integrate,
            |ctx, fb, chunk| {
                let n = chunk.layer_count as usize * 4;
                out.extend(
                    fb.pyramid
                        .read_level(ctx, &fb.layer_images, fb.layer_set)?
                        .into_iter()
                        .take(n),
                );
                Ok(())
            },
        )?;
        Ok(out)
    }

    /// The tiled splat's per-tile state after the last frame's binning (its last chunk of
    /// layers), to compare with [`tiles::bin_tiles`]; empty after a global-atomic frame.
    pub fn tile_bins(&self) -> Result<Vec<tiles::TileBin>, GpuError> {
        let fb = self.frame_buffers()?;
        let Some(chunk) = fb.chunks.last() else {
            return Ok(Vec::new());
        };
        if self.splat_mode() != SplatMode::Tiled {
            return Ok(Vec::new());
        }
        let words = TILE_META_WORDS as usize;
        let bytes = 4 * (words * chunk.grid.tile_count as usize) as u64;
        let data = super::util::read_f32(&self.ctx, "tile state", &fb.tile_meta, 0, bytes)?;
        Ok(data
            .chunks_exact(words)
            .map(|w| tiles::TileBin {
                count: w[0].to_bits(),
                laplacian_bound: w[1],
                direct_bound: w[2],
                adds: w[3].to_bits(),
            })
            .collect())
    }

    /// Layers drawn together in the last frame (fewer than the frame's when its buffers would
    /// exceed the device's binding size: the frame then runs in chunks of layers).
    pub fn layers_per_chunk(&self) -> Option<u32> {
        self.frame.as_ref().map(|f| f.chunk_layers)
    }

    fn frame_buffers(&self) -> Result<&FrameBuffers, GpuError> {
        self.frame
            .as_ref()
            .ok_or_else(|| GpuError::Input("no frame has run".into()))
    }

    fn validate(frame: &FrameParams, records: &[SplatRecord]) -> Result<(), GpuError> {
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
    fn ensure_frame_buffers(
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
    fn entries_needed(&self, frame: &FrameParams, records: &[SplatRecord]) -> u64 {
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
    fn rebuild_groups(&mut self) {
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

    fn frame_buffers_for(
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
        let coverage = storage_zeroed(ctx, "output coverage", 4 * (w * h) as u64)?;
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
        let renormalize = if self.options.composite.renormalize_coverage {
            RENORMALIZE
        } else {
            0
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
                let composite_group = bind_group(
                    ctx,
                    "composite",
                    &self.composite_layout,
                    &[&params, &layer_images, &output, &coverage],
                );
                Chunk {
                    layer_count,
                    splat_group,
                    tiled_group: None,
                    grid,
                    grid_uniform,
                    composite_group,
                    _targets: targets,
                    _composite_params: params,
                }
            })
            .collect();
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
            output_staging,
            output_bytes,
            queries,
            tile_meta,
            entries,
            entry_capacity: 0,
        })
    }

    fn splat_group(
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

    /// Runs the stages up to `until`, chunk of layers by chunk; after each chunk's last stage
    /// (when `until` is not `Composite`) the work is finished and `readback` called. With
    /// `Until::Composite` the image is copied into the output staging buffer (and the
    /// timestamps resolved), all submitted.
    fn execute(
        &mut self,
        frame: &FrameParams,
        records: &[SplatRecord],
        integrator: Integrator,
        until: Until,
        mut readback: impl FnMut(&GpuContext, &FrameBuffers, &Chunk) -> Result<(), GpuError>,
    ) -> Result<GpuStageTimes, GpuError> {
        Self::validate(frame, records)?;
        let t_upload = Instant::now();
        self.ensure_frame_buffers(frame, records)?;
        let tiled = match (self.splat_mode(), self.tiled.as_ref()) {
            (SplatMode::Tiled, Some(t)) => Some(t),
            _ => None,
        };
        let ctx = &self.ctx;
        let fb = self
            .frame
            .as_ref()
            .ok_or_else(|| GpuError::Input("no frame".into()))?;
        ctx.queue
            .write_buffer(&fb.frame_uniform, 0, bytemuck::bytes_of(frame));
        if !records.is_empty() {
            ctx.queue
                .write_buffer(&fb.records, 0, bytemuck::cast_slice(records));
        }
        let mut times = GpuStageTimes {
            upload_ms: ms(t_upload),
            ..Default::default()
        };
        // GPU timestamps only when every stage runs in one submission.
        let queries = fb
            .queries
            .as_ref()
            .filter(|_| integrator == Integrator::Pyramid && until == Until::Composite);
        times.gpu_timestamps = queries.is_some();
        let wall = !times.gpu_timestamps;
        let new_encoder = || {
            ctx.device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("frame"),
                })
        };
        let finish =
            |enc: wgpu::CommandEncoder, stage: &'static str, t: Instant| -> Result<f64, GpuError> {
                ctx.queue.submit([enc.finish()]);
                ctx.wait(stage)?;
                Ok(ms(t))
            };
        let lap = fb.pyramid.analysis_sets[0];
        let (pw, ph) = (frame.padded_width as usize, frame.padded_height as usize);
        let n = (records.len() as u32).div_ceil(64 / self.options.lanes_per_record);
        let max = ctx.limits().max_compute_workgroups_per_dimension.max(1);
        let mut enc = new_encoder();
        for (k, chunk) in fb.chunks.iter().enumerate() {
            let ts = |stage: u32| {
                queries.map(|q| wgpu::ComputePassTimestampWrites {
                    query_set: &q.set,
                    beginning_of_pass_write_index: Some(QUERIES_PER_CHUNK * k as u32 + 2 * stage),
                    end_of_pass_write_index: Some(QUERIES_PER_CHUNK * k as u32 + 2 * stage + 1),
                })
            };

            // Splat.
            let t = Instant::now();
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
                // Binning (tiled splat only; an empty pass otherwise, so that every
                // timestamp slot is written).
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("bin"),
                    timestamp_writes: ts(3),
                });
                let n64 = (records.len() as u32).div_ceil(64);
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
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("splat"),
                    timestamp_writes: ts(0),
                });
                match (tiled, chunk.tiled_group.as_ref()) {
                    (Some(t), Some(group)) => {
                        if n > 0 {
                            pass.set_bind_group(0, group, &[]);
                            // The tiles store their sums; the records they leave out are
                            // added on top afterwards.
                            pass.set_pipeline(&t.splat);
                            pass.dispatch_workgroups(
                                chunk.grid.tiles_x,
                                chunk.grid.tiles_y,
                                chunk.layer_count,
                            );
                            let x = n.min(max);
                            pass.set_pipeline(&t.rest);
                            pass.dispatch_workgroups(x, n.div_ceil(x), 1);
                        }
                    }
                    _ => {
                        if n > 0 {
                            let x = n.min(max);
                            pass.set_pipeline(&self.splat);
                            pass.set_bind_group(0, &chunk.splat_group, &[]);
                            pass.dispatch_workgroups(x, n.div_ceil(x), 1);
                        }
                    }
                }
            }
            if wall {
                times.splat_ms += finish(std::mem::replace(&mut enc, new_encoder()), "splat", t)?;
            }
            if until == Until::Splat {
                readback(ctx, fb, chunk)?;
                continue;
            }

            // Integrate.
            let t = Instant::now();
            if integrator == Integrator::Exact {
                // Exact integration is an FFT on the CPU (as `poisson::ExactIntegrator`): read
                // the Laplacian back, integrate, upload into synthesis level 0, run the output
                // pass with scale 1. (`wall` holds here: the splat above has finished.)
                let padded = fb.pyramid.read_level(ctx, &fb.pyramid.analysis, lap)?;
                let exact = ExactIntegrator::new(pw, ph);
                let primal: Vec<Plane> = padded
                    .par_iter()
                    .map(|p| {
                        let lap = p.crop(PAD as isize, PAD as isize, pw, ph);
                        if lap.data.iter().all(|&v| v == 0.0) {
                            Plane::new(pw, ph)
                        } else {
                            exact.integrate(&lap)
                        }
                    })
                    .collect();
                let refs: Vec<&Plane> = primal.iter().collect();
                fb.pyramid.upload_padded(
                    ctx,
                    &fb.pyramid.synthesis,
                    fb.pyramid.synthesis_sets[0],
                    &refs,
                );
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("integrate"),
                    timestamp_writes: None,
                });
                fb.pyramid.encode(&self.pyramid, &mut pass, true);
            } else {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("integrate"),
                    timestamp_writes: ts(1),
                });
                fb.pyramid.encode(&self.pyramid, &mut pass, false);
            }
            if wall {
                times.integrate_ms +=
                    finish(std::mem::replace(&mut enc, new_encoder()), "integrate", t)?;
            }
            if until == Until::Integrate {
                readback(ctx, fb, chunk)?;
                continue;
            }

            // Composite (back to front: chunk by chunk, layers in order within each).
            let t = Instant::now();
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("composite"),
                    timestamp_writes: ts(2),
                });
                pass.set_pipeline(&self.composite);
                pass.set_bind_group(0, &chunk.composite_group, &[]);
                pass.dispatch_workgroups(
                    frame.width.div_ceil(TILE),
                    frame.height.div_ceil(TILE),
                    1,
                );
            }
            if wall {
                times.composite_ms +=
                    finish(std::mem::replace(&mut enc, new_encoder()), "composite", t)?;
            }
        }
        if until == Until::Composite {
            enc.copy_buffer_to_buffer(&fb.output, 0, &fb.output_staging, 0, fb.output_bytes);
            if let Some(q) = queries {
                enc.resolve_query_set(&q.set, 0..q.count, &q.resolve, 0);
                enc.copy_buffer_to_buffer(&q.resolve, 0, &q.staging, 0, 8 * q.count as u64);
            }
        }
        ctx.queue.submit([enc.finish()]);
        self.counters.frames += 1;
        Ok(times)
    }

    fn read_timestamps(&self, times: &mut GpuStageTimes) -> Result<(), GpuError> {
        let Some(q) = self.frame.as_ref().and_then(|f| f.queries.as_ref()) else {
            return Ok(());
        };
        let raw = map_read_bytes(&self.ctx, "timestamps", &q.staging, 8 * q.count as u64)?;
        let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&raw);
        let period_ns = self.ctx.queue.get_timestamp_period() as f64;
        let span = |stage: usize| -> f64 {
            ticks
                .chunks_exact(QUERIES_PER_CHUNK as usize)
                .map(|c| c[2 * stage + 1].saturating_sub(c[2 * stage]) as f64 * period_ns * 1e-6)
                .sum()
        };
        times.bin_ms = span(3);
        times.splat_ms = span(0) + times.bin_ms;
        times.integrate_ms = span(1);
        times.composite_ms = span(2);
        Ok(())
    }
}

fn fingerprint(db: Option<&PsfDatabase>) -> (usize, usize, usize) {
    db.map_or((0, 0, 0), |d| {
        (d.psf_count(), d.spreadlet_count(), d.dense_data().len())
    })
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}
