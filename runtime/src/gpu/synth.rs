//! [`GpuSynthesizer`]: the whole synthesis pipeline after classification on the GPU (splat,
//! integrate, composite), mirroring `crate::pipeline` stage by stage. This file holds the
//! pipelines and the frame's order of passes; each stage's encoding lives beside its CPU twin's
//! name (`splat.rs`, `splat_tiled.rs`, `integrate.rs`, `composite.rs`), the database upload in
//! `database.rs` and the frame buffers in `frame.rs`.
//!
//! The database is uploaded once in [`GpuSynthesizer::new`]; pipelines are compiled there too.
//! Frame buffers (records, Laplacian and direct planes, pyramid levels, output, staging) are
//! created for the first frame of a size and reused by every later frame of that size.

use crate::synth::ms_since;
use std::time::Instant;

use poisson::pyramid::PAD;
use poisson::Plane;
use psf_db::PsfDatabase;

use super::database::{fingerprint, DbBuffers};
use super::frame::{Chunk, FrameBuffers, QUERIES_PER_CHUNK};
use super::pyramid::PyramidPipelines;
use super::splat_tiled::TiledPipelines;
use super::tiles::{self, TILE_META_WORDS};
use super::util::{compute_pipelines, layout_entries, map_read, map_read_bytes};
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

/// The synthesis pipeline on the GPU: compiled pipelines and the uploaded database, reused for
/// every frame.
pub struct GpuSynthesizer {
    pub(super) ctx: GpuContext,
    pub(super) options: GpuSynthOptions,
    pub(super) float_atomics: bool,
    pub(super) db: DbBuffers,
    pub(super) splat_layout: wgpu::BindGroupLayout,
    pub(super) splat: wgpu::ComputePipeline,
    /// The tiled splat's pipelines, when the device can run them.
    pub(super) tiled: Option<TiledPipelines>,
    pub(super) pyramid: PyramidPipelines,
    pub(super) composite_layout: wgpu::BindGroupLayout,
    pub(super) composite: wgpu::ComputePipeline,
    pub(super) frame: Option<FrameBuffers>,
    pub(super) counters: SynthCounters,
    /// The sharpness of each layer for the composite's fill (index 0 = farthest;
    /// `crate::pipeline::composite::layer_sharpness`), set for one frame; missing layers count
    /// as 1.
    pub(super) layer_sharpness: Vec<f32>,
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
                entries: &layout_entries(shaders::bindings::SPLAT),
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
                    entries: &layout_entries(shaders::bindings::COMPOSITE),
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
            layer_sharpness: Vec::new(),
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
        times.readback_ms = ms_since(t);
        times.total_ms = ms_since(t0);
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
            upload_ms: ms_since(t_upload),
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
                Ok(ms_since(t))
            };
        for chunk in &fb.chunks {
            let sharpness: Vec<f32> = (chunk.layer_base..chunk.layer_base + chunk.layer_count)
                .map(|l| self.layer_sharpness.get(l as usize).copied().unwrap_or(1.0))
                .collect();
            ctx.queue
                .write_buffer(&chunk.layer_sharpness, 0, bytemuck::cast_slice(&sharpness));
        }
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
            self.encode_splat(
                &mut enc,
                fb,
                chunk,
                records.len() as u32,
                tiled,
                [ts(3), ts(0)],
            );
            if wall {
                times.splat_ms += finish(std::mem::replace(&mut enc, new_encoder()), "splat", t)?;
            }
            if until == Until::Splat {
                readback(ctx, fb, chunk)?;
                continue;
            }

            // Integrate.
            let t = Instant::now();
            self.encode_integrate(&mut enc, fb, frame, integrator, ts(1))?;
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
            self.encode_composite(&mut enc, frame, chunk, ts(2));
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
