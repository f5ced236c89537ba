// Convolution pyramid (Farbman, Fattal, Lischinski 2011), Poisson kernel set: the GPU mirror of
// `poisson::pyramid` (see its module doc for the scheme). One invocation per destination pixel,
// `global_id.z` = plane (layer * 4 + channel). Filters come in as override constants from the
// Rust constants `poisson::pyramid::{H1, H2, G, PAD}`.

override h1_0: f32;
override h1_1: f32;
override h1_2: f32;
override h1_3: f32;
override h1_4: f32;
override h2_0: f32;
override h2_1: f32;
override h2_2: f32;
override h2_3: f32;
override h2_4: f32;
override g_0: f32;
override g_1: f32;
override g_2: f32;
override pad: u32;

@group(0) @binding(0) var<uniform> params: PassParams;
// All analysis levels a_i (level 0 is where the splat stage accumulates the Laplacian).
@group(0) @binding(1) var<storage, read_write> analysis: array<f32>;
// All synthesis levels f_i.
@group(0) @binding(2) var<storage, read_write> synthesis: array<f32>;
// Per-layer direct planes (dense and copied PSFs); the output pass turns them into the layer
// images.
@group(0) @binding(3) var<storage, read_write> layer_images: array<f32>;

// analysis_step: a_{i+1} = pad(even samples of H1 (x) H1 * a_i). src, dst: analysis levels.
@compute @workgroup_size(16, 16, 1)
fn analysis_step(@builtin(global_invocation_id) id: vec3<u32>) {
    let src = params.src;
    let dst = params.dst;
    if id.x >= dst.width || id.y >= dst.height || id.z >= params.planes {
        return;
    }
    let h1 = array<f32, 5>(h1_0, h1_1, h1_2, h1_3, h1_4);
    var v = 0.0;
    let xi = i32(id.x) - i32(pad);
    let yi = i32(id.y) - i32(pad);
    if xi >= 0 && yi >= 0 && xi < i32(dst.width - 2u * pad) && yi < i32(dst.height - 2u * pad) {
        let cx = 2 * xi;
        let cy = 2 * yi;
        let base = src.offset + id.z * src.stride;
        for (var ky = 0; ky < 5; ky++) {
            let sy = cy + ky - 2;
            if sy < 0 || sy >= i32(src.height) {
                continue;
            }
            let row = base + u32(sy) * src.width;
            var t = 0.0;
            for (var kx = 0; kx < 5; kx++) {
                let sx = cx + kx - 2;
                if sx >= 0 && sx < i32(src.width) {
                    t += h1[kx] * analysis[row + u32(sx)];
                }
            }
            v += h1[ky] * t;
        }
    }
    analysis[plane_index(dst, id.z, id.x, id.y)] = v;
}

// G (x) G * plane (zero outside) at (x, y), in the order of the CPU's `add_g`.
fn g_row(base: u32, w: u32, x: u32, y: u32) -> f32 {
    let row = base + y * w;
    let m = analysis[row + x];
    var l = 0.0;
    var r = 0.0;
    if x > 0u {
        l = analysis[row + x - 1u];
    }
    if x + 1u < w {
        r = analysis[row + x + 1u];
    }
    return g_0 * l + g_1 * m + g_2 * r;
}

fn add_g(s: PlaneSet, p: u32, x: u32, y: u32, start: f32) -> f32 {
    let base = s.offset + p * s.stride;
    var v = start + g_1 * g_row(base, s.width, x, y);
    if y > 0u {
        v += g_0 * g_row(base, s.width, x, y - 1u);
    }
    if y + 1u < s.height {
        v += g_2 * g_row(base, s.width, x, y + 1u);
    }
    return v;
}

// top_step: f_{L-1} = G (x) G * a_{L-1}. src: analysis level, dst: synthesis level.
@compute @workgroup_size(16, 16, 1)
fn top_step(@builtin(global_invocation_id) id: vec3<u32>) {
    let dst = params.dst;
    if id.x >= dst.width || id.y >= dst.height || id.z >= params.planes {
        return;
    }
    synthesis[plane_index(dst, id.z, id.x, id.y)] = add_g(params.src, id.z, id.x, id.y, 0.0);
}

// synthesis_step: f_i = H2 (x) H2 * zero_insert(crop_pad(f_{i+1})) + G (x) G * a_i.
// src: synthesis level i+1, aux: analysis level i, dst: synthesis level i.
@compute @workgroup_size(16, 16, 1)
fn synthesis_step(@builtin(global_invocation_id) id: vec3<u32>) {
    let dst = params.dst;
    let coarse = params.src;
    if id.x >= dst.width || id.y >= dst.height || id.z >= params.planes {
        return;
    }
    let h2 = array<f32, 5>(h2_0, h2_1, h2_2, h2_3, h2_4);
    let cw = (dst.width + 1u) / 2u;
    let ch = (dst.height + 1u) / 2u;
    let base = coarse.offset + id.z * coarse.stride;
    var up = 0.0;
    for (var ky = 0; ky < 5; ky++) {
        let i = i32(id.y) + ky - 2;
        if i < 0 || (i & 1) != 0 || u32(i / 2) >= ch {
            continue;
        }
        let row = base + (u32(i / 2) + pad) * coarse.width + pad;
        var t = 0.0;
        for (var kx = 0; kx < 5; kx++) {
            let j = i32(id.x) + kx - 2;
            if j >= 0 && (j & 1) == 0 && u32(j / 2) < cw {
                t += h2[kx] * synthesis[row + u32(j / 2)];
            }
        }
        up += h2[ky] * t;
    }
    synthesis[plane_index(dst, id.z, id.x, id.y)] = add_g(params.aux, id.z, id.x, id.y, up);
}

// output: layer image = scale * crop_pad(f_0) + direct plane. src: synthesis level 0,
// dst: the layer images (direct planes, updated in place).
@compute @workgroup_size(16, 16, 1)
fn output(@builtin(global_invocation_id) id: vec3<u32>) {
    let dst = params.dst;
    if id.x >= dst.width || id.y >= dst.height || id.z >= params.planes {
        return;
    }
    let f0 = synthesis[plane_index(params.src, id.z, id.x + pad, id.y + pad)];
    let i = plane_index(dst, id.z, id.x, id.y);
    layer_images[i] = params.scale * f0 + layer_images[i];
}
