//! Adapter and device acquisition, and what the device can do.

use std::sync::{Arc, Mutex};

use super::GpuError;

/// Environment variable: when set to `1`, a missing adapter is an error instead of `None`
/// (CI sets it so that GPU tests fail rather than skip).
pub const REQUIRE_GPU_ENV: &str = "SPREADLET_REQUIRE_GPU";

/// A wgpu device and queue with what the runtime needs to know about them.
///
/// Create one per process and share it: every [`super::GpuSynthesizer`] borrows it.
#[derive(Clone)]
pub struct GpuContext {
    /// The logical device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    float_atomics: bool,
    timestamps: bool,
    /// Validation errors wgpu reports outside an error scope; taken after each submission.
    uncaptured: Arc<Mutex<Option<String>>>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &self.info.name)
            .field("backend", &self.info.backend)
            .field("float_atomics", &self.float_atomics)
            .field("timestamps", &self.timestamps)
            .finish()
    }
}

/// Whether `SPREADLET_REQUIRE_GPU=1` is set.
pub fn gpu_required() -> bool {
    std::env::var(REQUIRE_GPU_ENV).is_ok_and(|v| v.trim() == "1")
}

/// An adapter's name and backend, for reports (e.g. `llvmpipe (LLVM 15.0.7, 256 bits) (Vulkan)`).
pub fn adapter_label(info: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?})", info.name, info.backend)
}

/// What [`GpuContext::open`] does with a software adapter (lavapipe, llvmpipe), which draws
/// slower than the CPU path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SoftwareAdapter {
    /// Opens a device on it as on any other (the GPU tests run on lavapipe).
    Open,
    /// Reports it without opening a device: `auto` sets it aside, and opening one cost
    /// lavapipe's 5 ms, and more to tear down, per process.
    SetAside,
}

/// What [`GpuContext::open`] found.
pub enum Opened {
    /// A device on the best adapter.
    Context(Box<GpuContext>),
    /// The best adapter is a software one, and no device was opened on it.
    Software(Box<wgpu::AdapterInfo>),
    /// No adapter (and none was required).
    NoAdapter,
}

impl GpuContext {
    /// The first adapter wgpu offers (any backend, high-performance preferred), with
    /// `SHADER_FLOAT32_ATOMIC` and `TIMESTAMP_QUERY` enabled where the adapter has them.
    ///
    /// Returns `Ok(None)` when there is no adapter, unless `SPREADLET_REQUIRE_GPU=1` is set, in
    /// which case that is [`GpuError::NoAdapter`].
    pub fn new() -> Result<Option<Self>, GpuError> {
        Self::with_requirement(gpu_required())
    }

    /// As [`GpuContext::new`], with the requirement given explicitly instead of read from the
    /// environment.
    pub fn with_requirement(require: bool) -> Result<Option<Self>, GpuError> {
        match Self::open(require, SoftwareAdapter::Open)? {
            Opened::Context(ctx) => Ok(Some(*ctx)),
            Opened::Software(_) | Opened::NoAdapter => Ok(None),
        }
    }

    /// The best adapter's context, as [`GpuContext::with_requirement`] opens it; where that
    /// adapter is a software one and `software` says [`SoftwareAdapter::SetAside`], its
    /// information alone.
    pub fn open(require: bool, software: SoftwareAdapter) -> Result<Opened, GpuError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY),
            ..wgpu::InstanceDescriptor::new_without_display_handle_from_env()
        });
        let adapter =
            match pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                ..Default::default()
            })) {
                Ok(a) => a,
                Err(e) if require => return Err(GpuError::NoAdapter(e.to_string())),
                Err(_) => return Ok(Opened::NoAdapter),
            };
        let info = adapter.get_info();
        if software == SoftwareAdapter::SetAside && info.device_type == wgpu::DeviceType::Cpu {
            return Ok(Opened::Software(Box::new(info)));
        }
        let available = adapter.features();
        let wanted = wgpu::Features::SHADER_FLOAT32_ATOMIC | wgpu::Features::TIMESTAMP_QUERY;
        let features = available & wanted;
        // The largest frames need big storage bindings: ask for everything the adapter has.
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("spreadlet"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|source| GpuError::RequestDevice {
            adapter: info.name.clone(),
            source,
        })?;
        let uncaptured = Arc::new(Mutex::new(None::<String>));
        let slot = Arc::clone(&uncaptured);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut s) = slot.lock() {
                s.get_or_insert_with(|| e.to_string());
            }
        }));
        Ok(Opened::Context(Box::new(Self {
            device,
            queue,
            info,
            limits,
            float_atomics: features.contains(wgpu::Features::SHADER_FLOAT32_ATOMIC),
            timestamps: features.contains(wgpu::Features::TIMESTAMP_QUERY),
            uncaptured,
        })))
    }

    /// The adapter's name and backend, for reports (e.g. `llvmpipe (LLVM 15.0.7, 256 bits) (Vulkan)`).
    pub fn adapter_name(&self) -> String {
        adapter_label(&self.info)
    }

    /// Full adapter information.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }

    /// Whether the device has `SHADER_FLOAT32_ATOMIC` (atomicAdd on f32 in storage buffers).
    pub fn has_float_atomics(&self) -> bool {
        self.float_atomics
    }

    /// Whether the device has timestamp queries at pass boundaries.
    pub fn has_timestamps(&self) -> bool {
        self.timestamps
    }

    /// The device limits (as requested: the adapter's own).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// Takes the first wgpu error reported since the last call, as a [`GpuError::Wgpu`].
    pub fn take_error(&self, stage: &'static str) -> Result<(), GpuError> {
        let message = self.uncaptured.lock().ok().and_then(|mut s| s.take());
        match message {
            Some(message) => Err(GpuError::Wgpu { stage, message }),
            None => Ok(()),
        }
    }

    /// Blocks until all submitted work is done, then reports any captured wgpu error.
    pub fn wait(&self, stage: &'static str) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Wgpu {
                stage,
                message: e.to_string(),
            })?;
        self.take_error(stage)
    }
}
