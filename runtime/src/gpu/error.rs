//! Errors of the GPU path.

/// Everything that can go wrong on the GPU path. Never a panic: wgpu validation errors are
/// captured and returned here.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// `SPREADLET_REQUIRE_GPU=1` is set (CI) but no adapter was found.
    #[error("no GPU adapter found, and SPREADLET_REQUIRE_GPU=1 requires one (install mesa-vulkan-drivers for a software Vulkan device): {0}")]
    NoAdapter(String),
    /// The adapter refused to create a device.
    #[error("the GPU adapter '{adapter}' refused to create a device: {source}")]
    RequestDevice {
        /// Adapter name.
        adapter: String,
        /// wgpu's reason.
        #[source]
        source: wgpu::RequestDeviceError,
    },
    /// A wgpu validation or out-of-memory error (a bug in the GPU path, or a frame too big).
    #[error("GPU error during {stage}: {message}")]
    Wgpu {
        /// What was being done.
        stage: &'static str,
        /// wgpu's message.
        message: String,
    },
    /// Reading a buffer back failed.
    #[error("reading GPU buffer '{what}' back failed: {message}")]
    Readback {
        /// Which buffer.
        what: &'static str,
        /// Why.
        message: String,
    },
    /// A buffer would exceed what the device allows.
    #[error("GPU buffer '{what}' needs {bytes} bytes but the device allows at most {limit} per binding; use fewer layers, a smaller frame or --backend cpu")]
    TooLarge {
        /// Which buffer.
        what: &'static str,
        /// Bytes needed.
        bytes: u64,
        /// The device limit, bytes.
        limit: u64,
    },
    /// The input records do not fit the frame or the database.
    #[error("invalid GPU input: {0}")]
    Input(String),
}
