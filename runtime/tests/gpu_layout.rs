//! The WGSL twins in `shaders/common.wgsl` have the sizes and field offsets of their Rust
//! structs (checked through naga's reflection; no GPU needed).
#![cfg(feature = "gpu")]

use std::mem::{offset_of, size_of};

use psf_db::DenseEntry;
use spreadlet::gpu::layout::{
    FilterParams, FilterPixel, KernelEntry, MicroParams, PassParams, PlaneSet, PsfFootprint,
    SplatTargets, TileGrid,
};
use spreadlet::pipeline::types::{FrameParams, SplatRecord};

fn wgsl_struct(module: &naga::Module, name: &str) -> (u32, Vec<(String, u32)>) {
    for (_, ty) in module.types.iter() {
        if ty.name.as_deref() == Some(name) {
            if let naga::TypeInner::Struct { members, span } = &ty.inner {
                let fields = members
                    .iter()
                    .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
                    .collect();
                return (*span, fields);
            }
        }
    }
    panic!("struct {name} not found in common.wgsl");
}

fn module() -> naga::Module {
    let src = concat!(
        include_str!("../../shaders/common.wgsl"),
        // Use every struct so that no front end drops one.
        "\n@group(0) @binding(0) var<storage> a: array<SplatRecord>;\n",
        "@group(0) @binding(1) var<uniform> b: FrameParams;\n",
        "@group(0) @binding(2) var<storage> c: array<DenseEntry>;\n",
        "@group(0) @binding(3) var<uniform> d: PassParams;\n",
        "@group(0) @binding(4) var<uniform> e: SplatTargets;\n",
        "@group(0) @binding(5) var<uniform> f: FilterParams;\n",
        "@group(0) @binding(6) var<storage> g: array<FilterPixel>;\n",
        "@group(0) @binding(7) var<storage> h: array<KernelEntry>;\n",
        "@group(0) @binding(8) var<uniform> i: TileGrid;\n",
        "@group(0) @binding(9) var<storage> j: array<PsfFootprint>;\n",
        "@group(0) @binding(10) var<uniform> k: MicroParams;\n",
    );
    naga::front::wgsl::parse_str(src).expect("common.wgsl parses")
}

macro_rules! check {
    ($module:expr, $ty:ty, $wgsl:literal, [$($rust:ident => $field:literal),* $(,)?]) => {{
        let (span, fields) = wgsl_struct(&$module, $wgsl);
        assert_eq!(span as usize, size_of::<$ty>(), "size of {}", $wgsl);
        let expected: Vec<(String, u32)> =
            vec![$(($field.to_string(), offset_of!($ty, $rust) as u32)),*];
        assert_eq!(fields, expected, "fields of {}", $wgsl);
    }};
}

#[test]
fn wgsl_structs_match_rust() {
    let m = module();
    check!(m, SplatRecord, "SplatRecord", [
        center_x => "center_x", center_y => "center_y", psf_index => "psf_index",
        layer => "layer", rot_cos => "rot_cos", rot_sin => "rot_sin", weight => "weight",
        path => "path", color => "color",
    ]);
    check!(m, FrameParams, "FrameParams", [
        width => "width", height => "height", pad => "pad", layers => "layers",
        padded_width => "padded_width", padded_height => "padded_height",
        record_count => "record_count", db_channels => "db_channels",
    ]);
    // DenseEntry's u16/i16 pairs are packed words on the WGSL side.
    check!(m, DenseEntry, "DenseEntry", [
        offset => "offset", width => "size_packed", origin_x => "origin_packed",
    ]);
    check!(m, PlaneSet, "PlaneSet", [
        width => "width", height => "height", offset => "offset", stride => "stride",
    ]);
    check!(m, PassParams, "PassParams", [
        src => "src", dst => "dst", aux => "aux", planes => "planes", scale => "scale",
        border => "border", flags => "flags",
    ]);
    check!(m, SplatTargets, "SplatTargets", [
        laplacian => "laplacian", direct => "direct", border => "border",
        rotation => "rotation", psf_count => "psf_count", channels => "channels",
        layer_base => "layer_base", layer_count => "layer_count", _pad0 => "_pad0", _pad1 => "_pad1",
    ]);
    check!(m, FilterParams, "FilterParams", [
        width => "width", height => "height", channels => "channels", rotation => "rotation",
    ]);
    check!(m, FilterPixel, "FilterPixel", [
        kernel => "kernel", rot_cos => "rot_cos", rot_sin => "rot_sin", _pad => "_pad",
    ]);
    check!(m, KernelEntry, "KernelEntry", [
        offset => "offset", width => "width", height => "height", origin_x => "origin_x",
        origin_y => "origin_y", _pad => "_pad",
    ]);
    check!(m, TileGrid, "TileGrid", [
        tiles_x => "tiles_x", tiles_y => "tiles_y", tile_count => "tile_count",
        entry_capacity => "entry_capacity",
    ]);
    check!(m, PsfFootprint, "PsfFootprint", [
        min_x => "min_x", min_y => "min_y", max_x => "max_x", max_y => "max_y",
        radius => "radius", stack => "stack", max_abs => "max_abs", l1 => "l1",
    ]);
    check!(m, MicroParams, "MicroParams", [
        elements => "elements", iterations => "iterations", mask => "mask", row => "row",
    ]);
}

/// The tile edge and the tile state's width agree between Rust and WGSL.
#[test]
fn tile_constants_match_the_shaders() {
    let common = include_str!("../../shaders/common.wgsl");
    assert!(common.contains(&format!(
        "const SPLAT_TILE: u32 = {}u;",
        spreadlet::gpu::tiles::SPLAT_TILE
    )));
    let bin = include_str!("../../shaders/bin.wgsl");
    assert!(bin.contains(&format!(
        "const TILE_META: u32 = {}u;",
        spreadlet::gpu::tiles::TILE_META_WORDS
    )));
}

#[test]
fn dense_entry_packing_is_little_endian_halves() {
    let e = DenseEntry {
        offset: 7,
        width: 3,
        height: 5,
        origin_x: -2,
        origin_y: -4,
    };
    let words: [u32; 3] = bytemuck::cast(e);
    assert_eq!(words[0], 7);
    assert_eq!(words[1], 3 | (5 << 16));
    assert_eq!(words[2] as u16 as i16, -2);
    assert_eq!((words[2] >> 16) as u16 as i16, -4);
}

#[test]
fn every_stage_shader_parses_and_validates() {
    for (name, src) in spreadlet::gpu::shader_sources_for_validation() {
        let module = naga::front::wgsl::parse_str(&src)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&src)));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{name}: {e:?}"));
    }
}

#[test]
fn every_stage_declares_the_bindings_its_host_binds() {
    use shaders::Binding;
    for (name, src, table) in shaders::shader_sources_with_bindings() {
        let module = naga::front::wgsl::parse_str(&src)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&src)));
        let mut declared: Vec<(u32, Binding)> = module
            .global_variables
            .iter()
            .filter_map(|(_, var)| {
                let binding = var.binding.as_ref()?;
                assert_eq!(binding.group, 0, "{name}: every stage binds group 0");
                let kind = match var.space {
                    naga::AddressSpace::Uniform => Binding::Uniform,
                    naga::AddressSpace::Storage { access }
                        if access.contains(naga::StorageAccess::STORE) =>
                    {
                        Binding::ReadWrite
                    }
                    naga::AddressSpace::Storage { .. } => Binding::Read,
                    other => panic!("{name}: binding {} in {other:?}", binding.binding),
                };
                Some((binding.binding, kind))
            })
            .collect();
        declared.sort_by_key(|&(b, _)| b);
        assert_eq!(
            declared, table,
            "{name}: the shader's bindings (left) differ from its host's table (right)"
        );
    }
}
