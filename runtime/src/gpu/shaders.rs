//! WGSL sources: `shaders/common.wgsl` prepended to each stage's file (WGSL has no includes).

const COMMON: &str = include_str!("../../../shaders/common.wgsl");
const PYRAMID: &str = include_str!("../../../shaders/pyramid.wgsl");
const ATOMIC_F32: &str = include_str!("../../../shaders/atomic_f32.wgsl");
const ATOMIC_CAS: &str = include_str!("../../../shaders/atomic_cas.wgsl");
const SPLAT: &str = include_str!("../../../shaders/splat.wgsl");
const DENSE: &str = include_str!("../../../shaders/dense.wgsl");
const COMPOSITE: &str = include_str!("../../../shaders/composite.wgsl");
const FILTER: &str = include_str!("../../../shaders/filter.wgsl");

/// The pyramid passes.
pub(crate) fn pyramid() -> String {
    format!("{COMMON}\n{PYRAMID}")
}

/// The splat stage (sparse, dense and copied records), with float atomics or compare-exchange.
pub(crate) fn splat(float_atomics: bool) -> String {
    let atomics = if float_atomics {
        ATOMIC_F32
    } else {
        ATOMIC_CAS
    };
    format!("{COMMON}\n{atomics}\n{SPLAT}\n{DENSE}")
}

/// The composite stage.
pub(crate) fn composite() -> String {
    format!("{COMMON}\n{COMPOSITE}")
}

/// The filter baseline.
pub(crate) fn filter() -> String {
    format!("{COMMON}\n{FILTER}")
}

/// Every stage's full source (each atomic variant), named, for validation in tests.
pub fn shader_sources_for_validation() -> Vec<(&'static str, String)> {
    vec![
        ("pyramid", pyramid()),
        ("splat (float atomics)", splat(true)),
        ("splat (compare-exchange)", splat(false)),
        ("composite", composite()),
        ("filter", filter()),
    ]
}
