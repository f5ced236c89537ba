//! Micro-benchmarks of the device (`shaders/microbench.wgsl`), so that each stage's time can
//! be stated as a fraction of what the hardware allows for its bytes and atomics: copy
//! bandwidth (a buffer-to-buffer copy and a copy in a shader), f32 atomic adds to global
//! memory at random and at coalesced addresses (the accumulation the global-atomic splat uses:
//! native where the device has float atomics, else compare-exchange) and i32 atomic adds to
//! workgroup memory (the tiled splat's).
//!
//! Kernels are timed with timestamp queries where the adapter has them, else by wall time
//! around a submission (which includes submission overhead: say which in reports). The
//! benchmarks are interleaved (A B C A B C ...) and medians reported with their spread.

use spreadlet::synth::ms_since;
use std::time::Instant;

use spreadlet::gpu::layout::MicroParams;
use spreadlet::gpu::util::{compute_pipelines, layout_entries, map_read_bytes};
use spreadlet::gpu::{GpuContext, GpuError};

/// Sizes of the micro-benchmarks.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct MicroConfig {
    /// Bytes copied per copy (a multiple of 16).
    pub copy_bytes: u64,
    /// Atomic adds per atomic benchmark run.
    pub atomics: u64,
    /// Elements (f32) of the global atomic target, a power of two (e.g. 2^22: 16 MiB, larger
    /// than the caches, like a frame's Laplacian planes).
    pub target_elements: u32,
    /// Runs of each benchmark (medians reported); at least 1.
    pub runs: usize,
}

impl MicroConfig {
    /// Sizes for a large GPU (256 MiB copies, 2^26 atomics).
    pub fn full() -> Self {
        MicroConfig {
            copy_bytes: 256 << 20,
            atomics: 1 << 26,
            target_elements: 1 << 22,
            runs: 10,
        }
    }

    /// Small sizes (a software device, a smoke test).
    pub fn quick() -> Self {
        MicroConfig {
            copy_bytes: 8 << 20,
            atomics: 1 << 20,
            target_elements: 1 << 18,
            runs: 3,
        }
    }
}

/// One micro-benchmark's result.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MicroResult {
    /// `copy-buffer`, `copy-shader`, `atomic-global-random`, `atomic-global-coalesced`,
    /// `atomic-workgroup`.
    pub name: String,
    /// Median time of one run, ms.
    pub median_ms: f64,
    /// Fastest run, ms.
    pub min_ms: f64,
    /// Slowest run, ms.
    pub max_ms: f64,
    /// Work per run: bytes moved (read + written) for copies, adds for atomics.
    pub work: f64,
    /// `work / median`, per second: bytes/s or adds/s.
    pub rate_per_s: f64,
    /// `GB/s` or `Gadd/s` (the unit of `rate_per_s / 1e9`).
    pub unit: String,
    /// `timestamps` or `wall`.
    pub timing: String,
}

/// All micro-benchmarks on one device.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MicroReport {
    /// Adapter name and backend.
    pub adapter: String,
    /// Device type as wgpu reports it (`DiscreteGpu`, `Cpu` for a software device, ...).
    pub device_type: String,
    /// Whether the global atomics are native f32 (else compare-exchange).
    pub float_atomics: bool,
    /// Whether kernels were timed with timestamp queries.
    pub timestamps: bool,
    /// The sizes used.
    pub config: MicroConfig,
    /// Results, in the order run.
    pub results: Vec<MicroResult>,
}

impl MicroReport {
    /// The rate of benchmark `name` (bytes/s or adds/s), if it ran.
    pub fn rate(&self, name: &str) -> Option<f64> {
        self.results
            .iter()
            .find(|r| r.name == name)
            .map(|r| r.rate_per_s)
    }
}

struct Bench {
    name: &'static str,
    pipeline: Option<wgpu::ComputePipeline>,
    group: Option<wgpu::BindGroup>,
    groups: (u32, u32),
    work: f64,
    unit: &'static str,
    times: Vec<f64>,
}

/// Runs every micro-benchmark on `ctx`'s device.
pub fn run_microbenchmarks(
    ctx: &GpuContext,
    config: &MicroConfig,
) -> Result<MicroReport, GpuError> {
    if config.runs == 0
        || config.copy_bytes < 16
        || !config.copy_bytes.is_multiple_of(16)
        || config.atomics == 0
        || !config.target_elements.is_power_of_two()
    {
        return Err(GpuError::Input(format!(
            "micro-benchmark sizes: {config:?} (copy bytes a multiple of 16, target a power of two, one run at least)"
        )));
    }
    let limit = ctx
        .limits()
        .max_storage_buffer_binding_size
        .min(ctx.limits().max_buffer_size);
    let copy_bytes = config.copy_bytes.min(limit / 16 * 16);
    let target_bytes = 4 * config.target_elements as u64;
    if target_bytes > limit {
        return Err(GpuError::TooLarge {
            what: "micro-benchmark atomic target",
            bytes: target_bytes,
            limit,
        });
    }
    let float_atomics = ctx.has_float_atomics();
    let layout = ctx
        .device
        .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("microbench"),
            entries: &layout_entries(shaders::bindings::MICROBENCH),
        });
    let mut pipelines = compute_pipelines(
        ctx,
        "microbench",
        &shaders::microbench(float_atomics),
        &layout,
        &[
            "copy_vec4",
            "atomic_random",
            "atomic_coalesced",
            "atomic_workgroup",
        ],
        &[],
    )?
    .into_iter();
    let buffer = |label: &str, size: u64, usage: wgpu::BufferUsages| {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        })
    };
    let storage =
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC;
    let src = buffer("micro src", copy_bytes, storage);
    let dst = buffer("micro dst", copy_bytes, storage);
    let target = buffer("micro target", target_bytes, storage);
    let spare = buffer("micro spare", 16, storage);
    let max = ctx.limits().max_compute_workgroups_per_dimension.max(1);
    // 16 adds per invocation, as many as a record's lane makes in the splat.
    let iterations = 16u32;
    let threads_for_atomics = config.atomics.div_ceil(iterations as u64).max(256);
    let grid = |threads: u64| -> (u32, u32) {
        let groups = threads.div_ceil(256).min(u32::MAX as u64) as u32;
        let x = groups.min(max);
        (x, groups.div_ceil(x))
    };
    let make_group = |params: MicroParams| {
        let buf =
            spreadlet::gpu::util::uniform_init(ctx, "micro params", bytemuck::bytes_of(&params));
        let group = bind_group_entries(ctx, &layout, &buf, &src, &dst, &target, &spare);
        (buf, group)
    };
    let copy_threads = copy_bytes / 16;
    let copy_grid = grid(copy_threads);
    let atomic_grid = grid(threads_for_atomics);
    let atomic_threads = atomic_grid.0 as u64 * atomic_grid.1 as u64 * 256;
    let adds = (atomic_threads * iterations as u64) as f64;
    let (_p0, g_copy) = make_group(MicroParams {
        elements: copy_threads as u32,
        iterations: 1,
        mask: 0,
        row: copy_grid.0,
    });
    let (_p1, g_random) = make_group(MicroParams {
        elements: atomic_threads as u32,
        iterations,
        mask: config.target_elements - 1,
        row: atomic_grid.0,
    });
    let (_p2, g_wg) = make_group(MicroParams {
        // A power of two that fits the copy buffer (the never-taken store's address mask).
        elements: 1u32 << (31 - (copy_threads.min(u32::MAX as u64) as u32).leading_zeros()),
        iterations,
        mask: 1023,
        row: atomic_grid.0,
    });
    let mut next = || pipelines.next();
    let copy_p = next();
    let random_p = next();
    let coalesced_p = next();
    let wg_p = next();
    let mut benches = vec![
        Bench {
            name: "copy-buffer",
            pipeline: None,
            group: None,
            groups: (0, 0),
            work: 2.0 * copy_bytes as f64,
            unit: "GB/s",
            times: Vec::new(),
        },
        Bench {
            name: "copy-shader",
            pipeline: copy_p,
            group: Some(g_copy),
            groups: copy_grid,
            work: 2.0 * copy_bytes as f64,
            unit: "GB/s",
            times: Vec::new(),
        },
        Bench {
            name: "atomic-global-random",
            pipeline: random_p,
            group: Some(g_random.clone()),
            groups: atomic_grid,
            work: adds,
            unit: "Gadd/s",
            times: Vec::new(),
        },
        Bench {
            name: "atomic-global-coalesced",
            pipeline: coalesced_p,
            group: Some(g_random),
            groups: atomic_grid,
            work: adds,
            unit: "Gadd/s",
            times: Vec::new(),
        },
        Bench {
            name: "atomic-workgroup",
            pipeline: wg_p,
            group: Some(g_wg),
            groups: atomic_grid,
            work: adds,
            unit: "Gadd/s",
            times: Vec::new(),
        },
    ];
    let timer = Timer::new(ctx);
    // One untimed round first (driver compilation, first touch of the buffers).
    for round in 0..=config.runs {
        for b in &mut benches {
            let t = timer.run(
                ctx,
                |enc, ts| match (&b.pipeline, &b.group) {
                    (Some(p), Some(g)) => {
                        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                            label: Some(b.name),
                            timestamp_writes: ts,
                        });
                        pass.set_pipeline(p);
                        pass.set_bind_group(0, g, &[]);
                        pass.dispatch_workgroups(b.groups.0, b.groups.1, 1);
                    }
                    _ => enc.copy_buffer_to_buffer(&src, 0, &dst, 0, copy_bytes),
                },
                b.pipeline.is_some(),
            )?;
            if round > 0 {
                b.times.push(t);
            }
        }
    }
    let results = benches
        .into_iter()
        .map(|b| {
            let mut t = b.times.clone();
            let median = metrics::median(&mut t);
            let timing = if b.pipeline.is_some() && timer.queries.is_some() {
                "timestamps"
            } else {
                "wall"
            };
            MicroResult {
                name: b.name.into(),
                median_ms: median,
                min_ms: t[0],
                max_ms: t[t.len() - 1],
                work: b.work,
                rate_per_s: b.work / (median * 1e-3),
                unit: b.unit.into(),
                timing: timing.into(),
            }
        })
        .collect();
    Ok(MicroReport {
        adapter: ctx.adapter_name(),
        device_type: format!("{:?}", ctx.adapter_info().device_type),
        float_atomics,
        timestamps: timer.queries.is_some(),
        config: MicroConfig {
            copy_bytes,
            ..*config
        },
        results,
    })
}

fn bind_group_entries(
    ctx: &GpuContext,
    layout: &wgpu::BindGroupLayout,
    params: &wgpu::Buffer,
    src: &wgpu::Buffer,
    dst: &wgpu::Buffer,
    target: &wgpu::Buffer,
    spare: &wgpu::Buffer,
) -> wgpu::BindGroup {
    fn entry(binding: u32, b: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
        wgpu::BindGroupEntry {
            binding,
            resource: b.as_entire_binding(),
        }
    }
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("microbench"),
        layout,
        entries: &[
            entry(0, params),
            entry(1, src),
            entry(2, dst),
            entry(8, target),
            entry(9, spare),
        ],
    })
}

/// Times one submission: by a pair of timestamps around the pass where available, else wall
/// time around submit and wait.
struct Timer {
    queries: Option<(wgpu::QuerySet, wgpu::Buffer, wgpu::Buffer)>,
}

impl Timer {
    fn new(ctx: &GpuContext) -> Self {
        let queries = ctx.has_timestamps().then(|| {
            (
                ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("micro timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count: 2,
                }),
                ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("micro resolve"),
                    size: 16,
                    usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                }),
                ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("micro staging"),
                    size: 16,
                    usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
            )
        });
        Timer { queries }
    }

    /// Records the work with `record(encoder, timestamp writes)`; `in_pass`: the work is a
    /// compute pass that takes the timestamp writes (else wall time).
    fn run<'a>(
        &'a self,
        ctx: &GpuContext,
        record: impl FnOnce(&mut wgpu::CommandEncoder, Option<wgpu::ComputePassTimestampWrites<'a>>),
        in_pass: bool,
    ) -> Result<f64, GpuError> {
        let queries = self.queries.as_ref().filter(|_| in_pass);
        let mut enc = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("microbench"),
            });
        record(
            &mut enc,
            queries.map(|(set, _, _)| wgpu::ComputePassTimestampWrites {
                query_set: set,
                beginning_of_pass_write_index: Some(0),
                end_of_pass_write_index: Some(1),
            }),
        );
        if let Some((set, resolve, staging)) = queries {
            enc.resolve_query_set(set, 0..2, resolve, 0);
            enc.copy_buffer_to_buffer(resolve, 0, staging, 0, 16);
        }
        let t = Instant::now();
        ctx.queue.submit([enc.finish()]);
        ctx.wait("microbench")?;
        let wall = ms_since(t);
        match queries {
            Some((_, _, staging)) => {
                let raw = map_read_bytes(ctx, "micro timestamps", staging, 16)?;
                let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&raw);
                let period = ctx.queue.get_timestamp_period() as f64;
                Ok(ticks[1].saturating_sub(ticks[0]) as f64 * period * 1e-6)
            }
            None => Ok(wall),
        }
    }
}
