//! The GPU context: an adapter is found where one exists, and its features are reported.
#![cfg(feature = "gpu")]

use spreadlet::gpu::GpuContext;

#[test]
fn context_reports_adapter_and_features() {
    let Some(ctx) = GpuContext::new().expect("GPU context") else {
        eprintln!("no GPU adapter: skipped (set SPREADLET_REQUIRE_GPU=1 to fail instead)");
        return;
    };
    let name = ctx.adapter_name();
    eprintln!(
        "adapter: {name}, float atomics: {}, timestamps: {}",
        ctx.has_float_atomics(),
        ctx.has_timestamps()
    );
    assert!(!name.is_empty());
}

/// `auto` sets a software adapter (lavapipe) aside without opening a device on it; asked to,
/// the same adapter gets one. A hardware adapter is opened either way.
#[test]
fn a_software_adapter_is_set_aside_without_a_device_and_opened_when_asked() {
    use spreadlet::gpu::{Opened, SoftwareAdapter, REQUIRE_GPU_ENV};
    let set_aside = GpuContext::open(false, SoftwareAdapter::SetAside).expect("adapter");
    let opened = GpuContext::open(false, SoftwareAdapter::Open).expect("device");
    match (set_aside, opened) {
        (Opened::Software(info), Opened::Context(ctx)) => {
            assert_eq!(info.device_type, wgpu::DeviceType::Cpu);
            assert_eq!(ctx.adapter_info().name, info.name);
        }
        (Opened::Context(a), Opened::Context(b)) => {
            assert_ne!(a.adapter_info().device_type, wgpu::DeviceType::Cpu);
            assert_eq!(a.adapter_info().name, b.adapter_info().name);
        }
        (Opened::NoAdapter, Opened::NoAdapter) => {
            let required = std::env::var(REQUIRE_GPU_ENV).is_ok_and(|v| v.trim() == "1");
            assert!(!required, "no GPU adapter, and {REQUIRE_GPU_ENV}=1");
            eprintln!("no GPU adapter: skipped");
        }
        _ => panic!("setting a software adapter aside changed which adapter was found"),
    }
}
