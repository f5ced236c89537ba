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

// Analysis level value at signed (x, y) of the plane starting at `base`, zero outside.
fn a_at(base: u32, w: u32, h: u32, x: i32, y: i32) -> f32 {
    if x < 0 || y < 0 || x >= i32(w) || y >= i32(h) {
        return 0.0;
    }
    return analysis[base + u32(y) * w + u32(x)];
}

// H1 along x at (cx, y), zero outside (the CPU's `filter5_row`).
fn h1_row(base: u32, w: u32, h: u32, cx: i32, y: i32) -> f32 {
    return h1_0 * a_at(base, w, h, cx - 2, y) + h1_1 * a_at(base, w, h, cx - 1, y)
        + h1_2 * a_at(base, w, h, cx, y) + h1_3 * a_at(base, w, h, cx + 1, y)
        + h1_4 * a_at(base, w, h, cx + 2, y);
}

// analysis_step: a_{i+1} = pad(even samples of H1 (x) H1 * a_i). src, dst: analysis levels.
@compute @workgroup_size(16, 16, 1)
fn analysis_step(@builtin(global_invocation_id) id: vec3<u32>) {
    let src = params.src;
    let dst = params.dst;
    if id.x >= dst.width || id.y >= dst.height || id.z >= params.planes {
        return;
    }
    var v = 0.0;
    let xi = i32(id.x) - i32(pad);
    let yi = i32(id.y) - i32(pad);
    if xi >= 0 && yi >= 0 && xi < i32(dst.width - 2u * pad) && yi < i32(dst.height - 2u * pad) {
        let cx = 2 * xi;
        let cy = 2 * yi;
        let b = src.offset + id.z * src.stride;
        let w = src.width;
        let h = src.height;
        v = h1_0 * h1_row(b, w, h, cx, cy - 2) + h1_1 * h1_row(b, w, h, cx, cy - 1)
            + h1_2 * h1_row(b, w, h, cx, cy) + h1_3 * h1_row(b, w, h, cx, cy + 1)
            + h1_4 * h1_row(b, w, h, cx, cy + 2);
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

// H2 along x of the zero-inserted coarse row `yc` at fine column x: only the taps landing on
// even positions count (x even: taps 0, 2, 4; x odd: taps 1, 3), in the CPU's tap order.
fn up_row(row: u32, cw: u32, x: u32) -> f32 {
    var s = 0.0;
    let xc = x / 2u;
    if (x & 1u) == 0u {
        if xc >= 1u && xc - 1u < cw {
            s += h2_0 * synthesis[row + xc - 1u];
        }
        if xc < cw {
            s += h2_2 * synthesis[row + xc];
        }
        if xc + 1u < cw {
            s += h2_4 * synthesis[row + xc + 1u];
        }
    } else {
        if xc < cw {
            s += h2_1 * synthesis[row + xc];
        }
        if xc + 1u < cw {
            s += h2_3 * synthesis[row + xc + 1u];
        }
    }
    return s;
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
    let cw = (dst.width + 1u) / 2u;
    let ch = (dst.height + 1u) / 2u;
    // Coarse row yc (inside the coarse level's PAD border) starts at row_start(yc).
    let base = coarse.offset + id.z * coarse.stride + pad * coarse.width + pad;
    let y = id.y;
    let yc = y / 2u;
    var up = 0.0;
    if (y & 1u) == 0u {
        if yc >= 1u && yc - 1u < ch {
            up += h2_0 * up_row(base + (yc - 1u) * coarse.width, cw, id.x);
        }
        if yc < ch {
            up += h2_2 * up_row(base + yc * coarse.width, cw, id.x);
        }
        if yc + 1u < ch {
            up += h2_4 * up_row(base + (yc + 1u) * coarse.width, cw, id.x);
        }
    } else {
        if yc < ch {
            up += h2_1 * up_row(base + yc * coarse.width, cw, id.x);
        }
        if yc + 1u < ch {
            up += h2_3 * up_row(base + (yc + 1u) * coarse.width, cw, id.x);
        }
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
