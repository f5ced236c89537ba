//! spreadlet's WGSL compute shaders, one file per GPU stage (the table in `README.md` names
//! each file's CPU twin), embedded at compile time so the library needs no files at run time.
//!
//! WGSL has no includes: each function here assembles one pipeline's module from
//! `common.wgsl` (the structs shared with the host), the accumulation scheme and the stage.

const COMMON: &str = include_str!("common.wgsl");
const PYRAMID: &str = include_str!("pyramid.wgsl");
const ATOMIC_F32: &str = include_str!("atomic_f32.wgsl");
const ATOMIC_CAS: &str = include_str!("atomic_cas.wgsl");
const SPLAT: &str = include_str!("splat.wgsl");
const SPLAT_GLOBAL: &str = include_str!("splat_global.wgsl");
const BIN: &str = include_str!("bin.wgsl");
const SPLAT_TILED: &str = include_str!("splat_tiled.wgsl");
const MICROBENCH: &str = include_str!("microbench.wgsl");
const DENSE: &str = include_str!("dense.wgsl");
const COMPOSITE: &str = include_str!("composite.wgsl");
const FILTER: &str = include_str!("filter.wgsl");

/// The pyramid passes.
pub fn pyramid() -> String {
    format!("{COMMON}\n{PYRAMID}")
}

/// The splat stage (sparse, dense and copied records) with global atomics: float atomics or
/// compare-exchange.
pub fn splat(float_atomics: bool) -> String {
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
pub fn splat_rest(float_atomics: bool) -> String {
    let atomics = if float_atomics {
        ATOMIC_F32
    } else {
        ATOMIC_CAS
    };
    format!("{COMMON}\n{atomics}\n{SPLAT}\n{SPLAT_GLOBAL}\n{DENSE}\n{BIN}")
}

/// The tiled splat stage: binning into screen tiles and per-tile sums in workgroup memory.
pub fn splat_tiled() -> String {
    format!("{COMMON}\n{SPLAT}\n{DENSE}\n{BIN}\n{SPLAT_TILED}")
}

/// The micro-benchmarks of the device's limits (copy bandwidth, atomics), with f32 atomics
/// native or emulated.
pub fn microbench(float_atomics: bool) -> String {
    let atomics = if float_atomics {
        ATOMIC_F32
    } else {
        ATOMIC_CAS
    };
    format!("{COMMON}\n{atomics}\n{MICROBENCH}")
}

/// The composite stage.
pub fn composite() -> String {
    format!("{COMMON}\n{COMPOSITE}")
}

/// The filter baseline.
pub fn filter() -> String {
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

/// How a stage's shader reads one binding of its bind group (group 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Binding {
    /// `var<uniform>`.
    Uniform,
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
}

/// The bindings of each stage, as its WGSL declares them: the host builds its bind group
/// layout from these tables, and a test checks each table against the shader's own
/// declarations (naga's reflection).
pub mod bindings {
    use super::Binding::{self, Read, ReadWrite, Uniform};

    /// The global-atomic splat (`splat.wgsl`, `splat_global.wgsl`, `dense.wgsl`, `atomic_*`).
    pub const SPLAT: &[(u32, Binding)] = &[
        (0, Uniform),
        (1, Uniform),
        (2, Read),
        (3, Read),
        (4, Read),
        (5, Read),
        (6, Read),
        (7, Read),
        (8, ReadWrite),
        (9, ReadWrite),
    ];

    /// The tiled splat and its global-atomic rest (`bin.wgsl`, `splat_tiled.wgsl`): the
    /// splat's bindings plus the tile grid, the footprints, the tiles' state and the entries.
    pub const TILED_SPLAT: &[(u32, Binding)] = &[
        (0, Uniform),
        (1, Uniform),
        (2, Read),
        (3, Read),
        (4, Read),
        (5, Read),
        (6, Read),
        (7, Read),
        (8, ReadWrite),
        (9, ReadWrite),
        (10, Uniform),
        (11, Read),
        (12, ReadWrite),
        (13, ReadWrite),
    ];

    /// The convolution pyramid (`pyramid.wgsl`).
    pub const PYRAMID: &[(u32, Binding)] =
        &[(0, Uniform), (1, ReadWrite), (2, ReadWrite), (3, ReadWrite)];

    /// The composite (`composite.wgsl`).
    pub const COMPOSITE: &[(u32, Binding)] = &[
        (0, Uniform),
        (1, Read),
        (2, ReadWrite),
        (3, ReadWrite),
        (4, Read),
        (5, ReadWrite),
    ];

    /// The filter baseline (`filter.wgsl`).
    pub const FILTER: &[(u32, Binding)] = &[
        (0, Uniform),
        (1, Read),
        (2, Read),
        (3, Read),
        (4, Read),
        (5, ReadWrite),
    ];

    /// The device's micro-benchmarks (`microbench.wgsl` with the accumulation scheme).
    pub const MICROBENCH: &[(u32, Binding)] = &[
        (0, Uniform),
        (1, Read),
        (2, ReadWrite),
        (8, ReadWrite),
        (9, ReadWrite),
    ];
}

/// A stage's bindings: `(binding, how the shader reads it)`, in binding order.
pub type BindingTable = &'static [(u32, Binding)];

/// Every stage's full source (each atomic variant), named, with its bindings table.
pub fn shader_sources_with_bindings() -> Vec<(&'static str, String, BindingTable)> {
    use bindings::*;
    shader_sources_for_validation()
        .into_iter()
        .map(|(name, source)| {
            let table = match name {
                "pyramid" => PYRAMID,
                "composite" => COMPOSITE,
                "filter" => FILTER,
                n if n.starts_with("microbench") => MICROBENCH,
                n if n.starts_with("splat (tiled") || n.starts_with("splat (rest") => TILED_SPLAT,
                _ => SPLAT,
            };
            (name, source, table)
        })
        .collect()
}
