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
