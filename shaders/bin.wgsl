// Binning for the tiled splat stage (mirror of runtime::gpu::tiles): every record of the chunk
// goes into each screen tile its samples can touch (SPLAT_TILE px square tiles of the padded
// layer), and each tile learns a bound on the largest |sum| any of its pixels can reach, from
// which `splat_tiled.wgsl` picks its fixed-point scale. Three passes: count (and bound), an
// exclusive scan of the counts, scatter of record indices.

@group(0) @binding(10) var<uniform> grid: TileGrid;
@group(0) @binding(11) var<storage, read> footprints: array<PsfFootprint>;
// TILE_META words per tile (see the META_* offsets).
@group(0) @binding(12) var<storage, read_write> tile_meta: array<atomic<u32>>;
// Record indices, tile by tile (tile t's are [start, start + count)).
@group(0) @binding(13) var<storage, read_write> entries: array<u32>;

const TILE_META: u32 = 8u;
// Records whose samples can touch more tiles than this are not binned: every tile would walk
// all their samples, so they are drawn with global atomics instead (`splat_global.wgsl` with
// SKIP_TILED). Set from Rust (GpuSynthOptions::max_tiles_per_record).
override MAX_TILES: u32 = 4u;
// Records binned into the tile.
const META_COUNT: u32 = 0u;
// Bound on any Laplacian accumulator's sum of |added values| (f32 bits).
const META_LAP_BOUND: u32 = 1u;
// The same for the direct planes (f32 bits).
const META_DIRECT_BOUND: u32 = 2u;
// Bound on the number of adds into any one accumulator.
const META_ADDS: u32 = 3u;
// First entry of the tile (written by the scan).
const META_START: u32 = 4u;
// Fill position of the scatter pass.
const META_CURSOR: u32 = 5u;

struct Span {
    ok: bool,
    // Chunk layer.
    layer: u32,
    // Tiles, inclusive.
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
    to_laplacian: bool,
    // Bound on what the record adds to any one accumulator (sum of |values|).
    bound: f32,
    // Bound on how many of its samples land on any one pixel.
    adds: u32,
    // Few enough tiles: drawn by the tiles (else by global atomics).
    tiled: bool,
}

// Samples of one rotated record that can reach one pixel: offsets of a PSF are distinct
// integer points, so rotated they stay at least 1 px apart, and a square of side s holds at
// most (s + 1)^2 / (pi / 4) of them. Nearest: s = 1 (5); bilinear: s = 2 (11); quadratic
// B-spline: s = 3 (20).
fn rotated_samples_per_pixel(to_laplacian: bool) -> u32 {
    if targets.rotation == 1u {
        return 5u;
    }
    if targets.rotation == 2u && to_laplacian {
        return 20u;
    }
    return 11u;
}

fn record_span(i: u32) -> Span {
    var s: Span;
    s.ok = false;
    let r = records[i];
    if r.layer >= frame.layers || r.layer < targets.layer_base
        || r.layer - targets.layer_base >= targets.layer_count {
        return s;
    }
    let cmax = max(max(abs(r.color.x), abs(r.color.y)), max(abs(r.color.z), abs(r.color.w)));
    var lo = vec2<i32>(r.center_x, r.center_y);
    var hi = lo;
    if r.path == PATH_COPY {
        s.to_laplacian = false;
        s.bound = cmax;
        s.adds = 1u;
    } else {
        if r.psf_index >= targets.psf_count || (r.path != PATH_SPARSE && r.path != PATH_DENSE) {
            return s;
        }
        s.to_laplacian = r.path == PATH_SPARSE;
        let f = footprints[2u * r.psf_index + select(1u, 0u, s.to_laplacian)];
        // `stack`: the most samples at one offset (0: the part is empty).
        if f.stack == 0u {
            return s;
        }
        var k = f.stack;
        if r.rot_cos == 1.0 && r.rot_sin == 0.0 {
            lo += vec2<i32>(f.min_x, f.min_y);
            hi += vec2<i32>(f.max_x, f.max_y);
        } else {
            // Rotation keeps the distance to the centre; placement spreads by under 2 px.
            k = k * rotated_samples_per_pixel(s.to_laplacian);
            lo -= vec2<i32>(f.radius + 2);
            hi += vec2<i32>(f.radius + 2);
        }
        s.adds = k;
        s.bound = cmax * min(f.l1, f32(k) * f.max_abs);
    }
    lo = max(lo, vec2<i32>(0));
    hi = min(hi, vec2<i32>(i32(frame.padded_width) - 1, i32(frame.padded_height) - 1));
    if lo.x > hi.x || lo.y > hi.y {
        return s;
    }
    s.layer = r.layer - targets.layer_base;
    s.x0 = u32(lo.x) / SPLAT_TILE;
    s.y0 = u32(lo.y) / SPLAT_TILE;
    s.x1 = u32(hi.x) / SPLAT_TILE;
    s.y1 = u32(hi.y) / SPLAT_TILE;
    s.ok = true;
    s.tiled = (s.x1 - s.x0 + 1u) * (s.y1 - s.y0 + 1u) <= MAX_TILES;
    return s;
}

// Whether the tiles draw record i (the global-atomic pass then skips it).
fn drawn_by_tiles(i: u32) -> bool {
    let s = record_span(i);
    return s.ok && s.tiled;
}

fn tile_index(layer: u32, tx: u32, ty: u32) -> u32 {
    return (layer * grid.tiles_y + ty) * grid.tiles_x + tx;
}

// f32 add on a u32 bit pattern (the bounds are few adds per record: no float atomics needed).
fn add_bound(i: u32, v: f32) {
    var old = atomicLoad(&tile_meta[i]);
    loop {
        let r = atomicCompareExchangeWeak(&tile_meta[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if r.exchanged {
            break;
        }
        old = r.old_value;
    }
}

fn record_id(wid: vec3<u32>, groups: vec3<u32>, local: u32) -> u32 {
    return (wid.y * groups.x + wid.x) * 64u + local;
}

@compute @workgroup_size(64, 1, 1)
fn bin_count(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = record_id(wid, groups, local);
    if i >= frame.record_count {
        return;
    }
    let s = record_span(i);
    if !s.ok || !s.tiled {
        return;
    }
    let bound_word = select(META_DIRECT_BOUND, META_LAP_BOUND, s.to_laplacian);
    for (var ty = s.y0; ty <= s.y1; ty++) {
        for (var tx = s.x0; tx <= s.x1; tx++) {
            let m = tile_index(s.layer, tx, ty) * TILE_META;
            atomicAdd(&tile_meta[m + META_COUNT], 1u);
            atomicAdd(&tile_meta[m + META_ADDS], s.adds);
            if s.bound != 0.0 {
                add_bound(m + bound_word, s.bound);
            }
        }
    }
}

var<workgroup> partial_counts: array<u32, 256>;

// One workgroup: each invocation sums a run of tiles, then offsets its run by the runs before.
@compute @workgroup_size(256, 1, 1)
fn bin_scan(@builtin(local_invocation_index) j: u32) {
    let n = grid.tile_count;
    let per = (n + 255u) / 256u;
    let a = min(j * per, n);
    let b = min(a + per, n);
    var sum = 0u;
    for (var t = a; t < b; t++) {
        sum += atomicLoad(&tile_meta[t * TILE_META + META_COUNT]);
    }
    partial_counts[j] = sum;
    workgroupBarrier();
    var start = 0u;
    for (var k = 0u; k < j; k++) {
        start += partial_counts[k];
    }
    for (var t = a; t < b; t++) {
        atomicStore(&tile_meta[t * TILE_META + META_START], start);
        atomicStore(&tile_meta[t * TILE_META + META_CURSOR], start);
        start += atomicLoad(&tile_meta[t * TILE_META + META_COUNT]);
    }
}

@compute @workgroup_size(64, 1, 1)
fn bin_scatter(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = record_id(wid, groups, local);
    if i >= frame.record_count {
        return;
    }
    let s = record_span(i);
    if !s.ok || !s.tiled {
        return;
    }
    for (var ty = s.y0; ty <= s.y1; ty++) {
        for (var tx = s.x0; tx <= s.x1; tx++) {
            let m = tile_index(s.layer, tx, ty) * TILE_META;
            let slot = atomicAdd(&tile_meta[m + META_CURSOR], 1u);
            if slot < grid.entry_capacity {
                entries[slot] = i;
            }
        }
    }
}
