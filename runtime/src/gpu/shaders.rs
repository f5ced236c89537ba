//! WGSL sources: `shaders/common.wgsl` prepended to each stage's file (WGSL has no includes).

const COMMON: &str = include_str!("../../../shaders/common.wgsl");
const PYRAMID: &str = include_str!("../../../shaders/pyramid.wgsl");
const ATOMIC_F32: &str = include_str!("../../../shaders/atomic_f32.wgsl");
const ATOMIC_CAS: &str = include_str!("../../../shaders/atomic_cas.wgsl");
const SPLAT: &str = include_str!("../../../shaders/splat.wgsl");
const SPLAT_GLOBAL: &str = include_str!("../../../shaders/splat_global.wgsl");
const BIN: &str = include_str!("../../../shaders/bin.wgsl");
const SPLAT_TILED: &str = include_str!("../../../shaders/splat_tiled.wgsl");
const MICROBENCH: &str = include_str!("../../../shaders/microbench.wgsl");
const DENSE: &str = include_str!("../../../shaders/dense.wgsl");
const COMPOSITE: &str = include_str!("../../../shaders/composite.wgsl");
const FILTER: &str = include_str!("../../../shaders/filter.wgsl");

/// The pyramid passes.
pub(crate) fn pyramid() -> String {
    format!("{COMMON}\n{PYRAMID}")
}

/// The splat stage (sparse, dense and copied records) with global atomics: float atomics or
/// compare-exchange.
pub(crate) fn splat(float_atomics: bool) -> String {
    let atomics = if float_atomics {
        ATOMIC_F32
    } else {
        ATOMIC_CAS
    };
    // Without the tiled stage no record is drawn by tiles.
    let none = "fn drawn_by_tiles(i: u32) -> bool { return false; }";
    format!("{COMMON}\n{atomics}\n{SPLAT}\n{SPLAT_GLOBAL}\n{DENSE}\n{none}")
}

/// The global-atomic pass that completes the tiled splat (records spanning too many tiles;
/// `SKIP_TILED` set), with the tiled stage's bindings.
pub(crate) fn splat_rest(float_atomics: bool) -> String {
    let atomics = if float_atomics {
        ATOMIC_F32
    } else {
        ATOMIC_CAS
    };
    format!("{COMMON}\n{atomics}\n{SPLAT}\n{SPLAT_GLOBAL}\n{DENSE}\n{BIN}")
}

/// The tiled splat stage: binning into screen tiles and per-tile sums in workgroup memory.
pub(crate) fn splat_tiled() -> String {
    format!("{COMMON}\n{SPLAT}\n{DENSE}\n{BIN}\n{SPLAT_TILED}")
}

/// The micro-benchmarks of the device's limits (copy bandwidth, atomics), with f32 atomics
/// native or emulated.
pub(crate) fn microbench(float_atomics: bool) -> String {
    let atomics = if float_atomics {
        ATOMIC_F32
    } else {
        ATOMIC_CAS
    };
    format!("{COMMON}\n{atomics}\n{MICROBENCH}")
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
        ("splat (tiled)", splat_tiled()),
        ("splat (rest of tiled, float atomics)", splat_rest(true)),
        ("splat (rest of tiled, compare-exchange)", splat_rest(false)),
        ("microbench (float atomics)", microbench(true)),
        ("microbench (compare-exchange)", microbench(false)),
        ("composite", composite()),
        ("filter", filter()),
    ]
}
