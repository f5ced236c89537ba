// Tiled splatting: one workgroup per screen tile (SPLAT_TILE x SPLAT_TILE px of one layer)
// draws every record binned into it (`bin.wgsl`), keeping only the samples that land inside the
// tile, into accumulators in workgroup memory; then each pixel of the tile is written once. A
// tile owns its pixels, so the write is a plain store (the planes were cleared).
//
// Workgroup memory has no float atomics in WGSL, so the sums are fixed point in i32, scaled per
// tile by a power of two chosen from the tile's bound on any accumulator's sum of |values|
// (runtime::gpu::tiles::tile_scale). Each value gets two words, a high part and up to 16 more
// bits of fraction in a low part: the Laplacian planes are integrated afterwards, which sums
// rounding errors over the whole plane, and a bound over many records is far above most
// pixels' sums. Integer sums do not depend on the order of the
// adds: the tiles' part of the splat is deterministic.

const TILE_PX: u32 = SPLAT_TILE * SPLAT_TILE;

// Pixel p of channel c is element c * TILE_PX + p.
var<workgroup> lap_hi: array<atomic<i32>, 1024>;
var<workgroup> lap_lo: array<atomic<i32>, 1024>;
var<workgroup> direct_hi: array<atomic<i32>, 1024>;
var<workgroup> direct_lo: array<atomic<i32>, 1024>;
var<workgroup> tile_entries: u32;

@group(0) @binding(8) var<storage, read_write> laplacian: array<f32>;
@group(0) @binding(9) var<storage, read_write> direct: array<f32>;

var<private> tile_origin: vec2<i32>;
// Fixed-point scales (powers of two): a Laplacian value v is v * lap_scale units, split into
// lap_hi (multiples of unit) and lap_lo; a direct value likewise with direct_scale.
var<private> lap_scale: f32;
var<private> unit: f32;
var<private> direct_scale: f32;

// 2^(bits - e) where bound = m 2^e, m in [0.5, 1): the largest power of two s with
// s * bound < 2^bits (runtime::gpu::tiles::tile_scale).
fn tile_scale(bound: f32, bits: i32) -> f32 {
    // Zero, subnormal (GPUs may flush them), huge or NaN: scale 1.
    if !(bound >= 1.17549435e-38) || bound > 3.0e38 {
        return 1.0;
    }
    let e = frexp(bound).exp;
    return ldexp(1.0, clamp(bits - e, -126, 127));
}

// Fraction bits of the low Laplacian words: as many (up to 16) as `adds` adds of up to
// 2^bits each keep under 2^30 (runtime::gpu::tiles::low_bits).
fn low_bits(adds: u32) -> i32 {
    if adds <= 1u {
        return 16;
    }
    let ceil_log2 = 32 - i32(countLeadingZeros(adds - 1u));
    return clamp(30 - ceil_log2, 0, 16);
}

fn add_rgba(to_laplacian: bool, layer: u32, x: i32, y: i32, v: vec4<f32>) {
    let l = vec2<i32>(x, y) - tile_origin;
    if any(l < vec2<i32>(0)) || any(l >= vec2<i32>(i32(SPLAT_TILE)))
        || x >= i32(frame.padded_width) || y >= i32(frame.padded_height) {
        return;
    }
    let p = u32(l.y) * SPLAT_TILE + u32(l.x);
    for (var c = 0u; c < 4u; c++) {
        if v[c] == 0.0 {
            continue;
        }
        let i = c * TILE_PX + p;
        let s = v[c] * (select(direct_scale, lap_scale, to_laplacian) / unit);
        let hi = floor(s);
        let lo = round((s - hi) * unit);
        if to_laplacian {
            if hi != 0.0 {
                atomicAdd(&lap_hi[i], i32(hi));
            }
            if lo != 0.0 {
                atomicAdd(&lap_lo[i], i32(lo));
            }
        } else {
            if hi != 0.0 {
                atomicAdd(&direct_hi[i], i32(hi));
            }
            if lo != 0.0 {
                atomicAdd(&direct_lo[i], i32(lo));
            }
        }
    }
}

@compute @workgroup_size(256, 1, 1)
fn splat_tiles(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let m = tile_index(wid.z, wid.x, wid.y) * TILE_META;
    if local == 0u {
        tile_entries = atomicLoad(&tile_meta[m + META_COUNT]);
    }
    let n = workgroupUniformLoad(&tile_entries);
    if n == 0u {
        return;
    }
    tile_origin = vec2<i32>(wid.xy * SPLAT_TILE);
    let bits = low_bits(atomicLoad(&tile_meta[m + META_ADDS]));
    unit = ldexp(1.0, bits);
    lap_scale = tile_scale(bitcast<f32>(atomicLoad(&tile_meta[m + META_LAP_BOUND])), 29 + bits);
    direct_scale = tile_scale(bitcast<f32>(atomicLoad(&tile_meta[m + META_DIRECT_BOUND])), 29 + bits);
    for (var c = 0u; c < 4u; c++) {
        atomicStore(&lap_hi[c * TILE_PX + local], 0);
        atomicStore(&lap_lo[c * TILE_PX + local], 0);
        atomicStore(&direct_hi[c * TILE_PX + local], 0);
        atomicStore(&direct_lo[c * TILE_PX + local], 0);
    }
    workgroupBarrier();
    let start = atomicLoad(&tile_meta[m + META_START]);
    let lane = local % LANES;
    for (var e = local / LANES; e < n; e += TILE_PX / LANES) {
        let slot = start + e;
        if slot >= grid.entry_capacity {
            break;
        }
        var r = records[entries[slot]];
        r.layer -= targets.layer_base;
        if r.path == PATH_COPY {
            if lane == 0u {
                add_rgba(false, r.layer, r.center_x, r.center_y, r.color);
            }
        } else if r.path == PATH_SPARSE {
            draw_sparse(r, lane);
        } else {
            draw_dense(r, lane);
        }
    }
    workgroupBarrier();
    let x = u32(tile_origin.x) + local % SPLAT_TILE;
    let y = u32(tile_origin.y) + local / SPLAT_TILE;
    if x >= frame.padded_width || y >= frame.padded_height {
        return;
    }
    let b = targets.border;
    for (var c = 0u; c < 4u; c++) {
        let i = c * TILE_PX + local;
        let plane = wid.z * 4u + c;
        let lap = f32(atomicLoad(&lap_hi[i])) * unit + f32(atomicLoad(&lap_lo[i]));
        laplacian[plane_index(targets.laplacian, plane, x + b, y + b)] = lap / lap_scale;
        let dir = f32(atomicLoad(&direct_hi[i])) * unit + f32(atomicLoad(&direct_lo[i]));
        direct[plane_index(targets.direct, plane, x, y)] = dir / direct_scale;
    }
}
