//! Rust twins of the GPU-only structs in `shaders/common.wgsl` (the records shared with the
//! CPU path are in [`crate::pipeline::types`]). Same field order; `tests/gpu_layout.rs` checks
//! sizes and offsets against the WGSL through naga.

use bytemuck::{Pod, Zeroable};

/// A set of equally sized planes inside one f32 buffer: plane `p`, pixel `(x, y)` is element
/// `offset + p * stride + y * width + x`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct PlaneSet {
    /// Plane width, px.
    pub width: u32,
    /// Plane height, px.
    pub height: u32,
    /// Element (f32) index of plane 0's first pixel.
    pub offset: u32,
    /// Elements from one plane to the next (at least `width * height`).
    pub stride: u32,
}

impl PlaneSet {
    /// Planes of `width x height` packed back to back from `offset`.
    pub fn packed(width: usize, height: usize, offset: usize) -> Self {
        PlaneSet {
            width: width as u32,
            height: height as u32,
            offset: offset as u32,
            stride: (width * height) as u32,
        }
    }

    /// Elements one plane spans.
    pub fn plane_len(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// Parameters of one pass over planes (pyramid steps, output, composite).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PassParams {
    /// What the pass reads.
    pub src: PlaneSet,
    /// What the pass writes.
    pub dst: PlaneSet,
    /// A second input (the analysis level of a synthesis step).
    pub aux: PlaneSet,
    /// Number of planes processed (`layers * 4`).
    pub planes: u32,
    /// Scale applied by the output pass (`poisson::PYRAMID_SCALE`, or 1 for exact integration).
    pub scale: f32,
    /// Border (padding) cropped by the composite pass, px.
    pub border: u32,
    /// Pass-specific flags (composite: bit 0 = renormalise coverage, bit 1 = first chunk of
    /// layers, bit 2 = last chunk, bit 3 = restore the occluded colour).
    pub flags: u32,
}

/// Where the splat stage writes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct SplatTargets {
    /// Laplacian planes (`layer * 4 + channel`): analysis level 0 of the pyramid, whose pixel
    /// `(border, border)` is the padded layer's pixel (0, 0).
    pub laplacian: PlaneSet,
    /// Direct planes (`layer * 4 + channel`), padded-layer size.
    pub direct: PlaneSet,
    /// Border of the Laplacian planes, px (`poisson::pyramid::PAD`).
    pub border: u32,
    /// Rotated offsets: 0 = bilinear split, 1 = nearest pixel, 2 = quadratic B-spline on
    /// Laplacian spreadlets and bilinear on dense pixels.
    pub rotation: u32,
    /// Number of PSFs in the database.
    pub psf_count: u32,
    /// Values per spreadlet position and per dense pixel (1 or 3).
    pub channels: u32,
    /// First layer this pass draws (frames too large for one binding go in chunks of layers).
    pub layer_base: u32,
    /// Number of layers this pass draws; plane `(layer - layer_base) * 4 + channel`.
    pub layer_count: u32,
    /// Padding to 16 bytes.
    pub _pad0: u32,
    /// Padding to 16 bytes.
    pub _pad1: u32,
}

/// Parameters of the filter baseline's pass.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct FilterParams {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Values per kernel pixel (1 or 3).
    pub channels: u32,
    /// Rotated offsets: 0 = bilinear reads, 1 = nearest pixel.
    pub rotation: u32,
}

/// [`FilterPixel::kernel`] of a pixel that keeps its input colour.
pub const NO_KERNEL: u32 = u32::MAX;

/// One output pixel of the filter baseline: the kernel it gathers with and its rotation.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct FilterPixel {
    /// Index into the kernel table, or [`NO_KERNEL`].
    pub kernel: u32,
    /// Cosine of the kernel's rotation.
    pub rot_cos: f32,
    /// Sine of the kernel's rotation.
    pub rot_sin: f32,
    /// Padding to 16 bytes.
    pub _pad: u32,
}

/// A dense kernel of the filter baseline in the kernel data buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct KernelEntry {
    /// Element (f32) offset of its first value.
    pub offset: u32,
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Offset of the top-left pixel from the centre, px (x right).
    pub origin_x: i32,
    /// Offset of the top-left pixel from the centre, px (y down).
    pub origin_y: i32,
    /// Padding to 24 bytes.
    pub _pad: u32,
}

/// The screen tiles of the tiled splat stage for one chunk of layers: tile `(tx, ty)` of chunk
/// layer `l` is tile index `(l * tiles_y + ty) * tiles_x + tx` and covers padded-layer pixels
/// `[16 tx, 16 tx + 16) x [16 ty, 16 ty + 16)`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct TileGrid {
    /// Tiles per row (padded width / 16, rounded up).
    pub tiles_x: u32,
    /// Tiles per column (padded height / 16, rounded up).
    pub tiles_y: u32,
    /// Tiles of the chunk: `tiles_x * tiles_y * layers in the chunk`.
    pub tile_count: u32,
    /// Capacity of the entry list (record indices binned into tiles), entries.
    pub entry_capacity: u32,
}

/// Where one PSF's samples (its spreadlets, or its dense image's non-zero pixels) can land and
/// how large they are: what the binning pass needs to place a record in tiles and to bound
/// each tile's sums. Two per PSF: index `2 psf` for the sparse part, `2 psf + 1` for the dense.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PsfFootprint {
    /// Bounding box of the sample offsets from the PSF centre, px (x right); `min_x > max_x`
    /// when the part is empty.
    pub min_x: i32,
    /// Bounding box, px (y down).
    pub min_y: i32,
    /// Bounding box, px.
    pub max_x: i32,
    /// Bounding box, px.
    pub max_y: i32,
    /// Largest distance of a sample from the centre, rounded up, px (rotated records).
    pub radius: i32,
    /// The most samples at one offset (1 for a well-formed PSF; 0 when the part is empty).
    pub stack: u32,
    /// Largest |value| of a sample, over its channels.
    pub max_abs: f32,
    /// Sum over the samples of their largest |value| over channels.
    pub l1: f32,
}

/// Parameters of a micro-benchmark pass (`shaders/microbench.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct MicroParams {
    /// Elements of the buffers (vec4 for the copy, f32 for the atomics).
    pub elements: u32,
    /// Operations per invocation.
    pub iterations: u32,
    /// Address mask of the atomic targets (a power of two minus one).
    pub mask: u32,
    /// Invocations per row of workgroups.
    pub row: u32,
}
