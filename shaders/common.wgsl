// Shared structs of the GPU path. Every struct here has a Rust twin with the same field order
// (`runtime::pipeline::types` for the records, `runtime::gpu::layout` for the pass parameters,
// `psf_db::DenseEntry` for dense PSFs); `runtime/tests/gpu_layout.rs` checks sizes and offsets.
// This file is prepended to every stage's source.

// One classified pixel (twin of runtime::pipeline::types::SplatRecord, 48 bytes).
struct SplatRecord {
    center_x: i32,
    center_y: i32,
    psf_index: u32,
    layer: u32,
    rot_cos: f32,
    rot_sin: f32,
    weight: f32,
    path: u32,
    color: vec4<f32>,
}

// Per-frame constants (twin of runtime::pipeline::types::FrameParams, 32 bytes).
struct FrameParams {
    width: u32,
    height: u32,
    pad: u32,
    layers: u32,
    padded_width: u32,
    padded_height: u32,
    record_count: u32,
    db_channels: u32,
}

// Twin of psf_db::DenseEntry (12 bytes): WGSL has no 16-bit integers, so the u16/i16 pairs are
// read as packed words, low half first (little endian).
struct DenseEntry {
    offset: u32,
    // width (low 16 bits, u16) and height (high 16 bits, u16), px.
    size_packed: u32,
    // origin_x (low, i16) and origin_y (high, i16), px from the PSF centre.
    origin_packed: u32,
}

// A set of equally sized planes inside one f32 buffer (twin of runtime::gpu::layout::PlaneSet):
// plane p, pixel (x, y) is element `offset + p * stride + y * width + x`.
struct PlaneSet {
    width: u32,
    height: u32,
    offset: u32,
    stride: u32,
}

// Parameters of one pass over planes (twin of runtime::gpu::layout::PassParams, 64 bytes).
struct PassParams {
    src: PlaneSet,
    dst: PlaneSet,
    aux: PlaneSet,
    planes: u32,
    scale: f32,
    border: u32,
    // Pass-specific flags (composite: bit 0 = renormalise coverage, bit 1 = first chunk of
    // layers, bit 2 = last chunk).
    flags: u32,
}

// Splat path codes (twin of runtime::pipeline::types::SplatPath).
const PATH_SPARSE: u32 = 0u;
const PATH_DENSE: u32 = 1u;
const PATH_COPY: u32 = 2u;
// psf_db::SPARSE_SLOT.
const SPARSE_SLOT: u32 = 0xffffffffu;

fn plane_index(s: PlaneSet, p: u32, x: u32, y: u32) -> u32 {
    return s.offset + p * s.stride + y * s.width + x;
}

// Low and high signed 16-bit halves of a packed word.
fn unpack_i16_lo(w: u32) -> i32 {
    return (bitcast<i32>(w) << 16u) >> 16u;
}
fn unpack_i16_hi(w: u32) -> i32 {
    return bitcast<i32>(w) >> 16u;
}

// Where the splat stage writes (twin of runtime::gpu::layout::SplatTargets, 64 bytes).
struct SplatTargets {
    // Laplacian planes (layer * 4 + channel): analysis level 0 of the pyramid, whose pixel
    // (border, border) is the padded layer's pixel (0, 0).
    laplacian: PlaneSet,
    // Direct planes (layer * 4 + channel), padded-layer size.
    direct: PlaneSet,
    // Border of the Laplacian planes, px (poisson::pyramid::PAD).
    border: u32,
    // Rotated offsets: 0 = bilinear split, 1 = nearest pixel, 2 = quadratic B-spline for Laplacian
    // spreadlets and bilinear for dense pixels (runtime::pipeline::RotationSampling).
    rotation: u32,
    // Number of PSFs in the database (records with a larger index draw nothing).
    psf_count: u32,
    // Spreadlet values (and dense pixels) per position: 1 or 3.
    channels: u32,
    // The layers this pass draws, [layer_base, layer_base + layer_count) (frames too large for
    // one binding go in chunks of layers); plane (layer - layer_base) * 4 + channel.
    layer_base: u32,
    layer_count: u32,
    _pad0: u32,
    _pad1: u32,
}

// Rust's f32::round: half away from zero (WGSL's round() is half to even).
fn round_away(v: f32) -> f32 {
    return sign(v) * floor(abs(v) + 0.5);
}

// Parameters of the filter baseline (twin of runtime::gpu::layout::FilterParams, 16 bytes).
struct FilterParams {
    width: u32,
    height: u32,
    // Values per kernel pixel: 1 or 3.
    channels: u32,
    // Rotated offsets: 0 = bilinear reads, 1 = nearest pixel.
    rotation: u32,
}

// One output pixel of the filter baseline (twin of runtime::gpu::layout::FilterPixel,
// 16 bytes): its kernel (NO_KERNEL: keep the input colour) and rotation.
struct FilterPixel {
    kernel: u32,
    rot_cos: f32,
    rot_sin: f32,
    _pad: u32,
}

const NO_KERNEL: u32 = 0xffffffffu;

// A dense kernel of the filter baseline (twin of runtime::gpu::layout::KernelEntry, 24 bytes):
// element offset into the kernel data, size (px) and the top-left pixel's offset from the
// centre (px).
struct KernelEntry {
    offset: u32,
    width: u32,
    height: u32,
    origin_x: i32,
    origin_y: i32,
    _pad: u32,
}

// The screen tiles of the tiled splat stage (twin of runtime::gpu::layout::TileGrid, 16 bytes):
// tile (tx, ty) of chunk layer l is index (l * tiles_y + ty) * tiles_x + tx and covers padded-
// layer pixels [16 tx, 16 tx + 16) x [16 ty, 16 ty + 16).
struct TileGrid {
    tiles_x: u32,
    tiles_y: u32,
    tile_count: u32,
    entry_capacity: u32,
}

// Where one PSF part's samples can land and how large they are (twin of
// runtime::gpu::layout::PsfFootprint, 32 bytes); index 2 psf (sparse) and 2 psf + 1 (dense).
struct PsfFootprint {
    min_x: i32,
    min_y: i32,
    max_x: i32,
    max_y: i32,
    radius: i32,
    stack: u32,
    max_abs: f32,
    l1: f32,
}

// Edge of a splat tile, px (runtime::gpu::tiles::SPLAT_TILE).
const SPLAT_TILE: u32 = 16u;

// Parameters of a micro-benchmark pass (twin of runtime::gpu::layout::MicroParams, 16 bytes).
struct MicroParams {
    // Elements of the buffers (vec4 for the copy, f32 for the atomics).
    elements: u32,
    // Operations per invocation.
    iterations: u32,
    // Address mask of the atomic targets (a power of two minus one).
    mask: u32,
    // Invocations per row of workgroups (the grid is 2D beyond 65535 workgroups).
    row: u32,
}
