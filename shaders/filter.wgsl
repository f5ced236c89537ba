// The filter baseline (mirror of the CPU's `runtime::baseline::filter` and its `gather`): every
// output pixel gathers the input with its own dense PSF, `out(x) = sum_o k(o) in(x - R o)`,
// rotated offsets read bilinearly (the adjoint of the splat's bilinear split) or from the
// nearest pixel. One invocation per output pixel, kernel rows outer and columns inner as on
// the CPU, so the sums run in the same order.

@group(0) @binding(0) var<uniform> params: FilterParams;
@group(0) @binding(1) var<storage, read> pixels: array<FilterPixel>;
@group(0) @binding(2) var<storage, read> colour_in: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> kernel_table: array<KernelEntry>;
@group(0) @binding(4) var<storage, read> kernel_data: array<f32>;
@group(0) @binding(5) var<storage, read_write> colour_out: array<vec4<f32>>;

fn fetch(sx: i32, sy: i32) -> vec4<f32> {
    if sx < 0 || sy < 0 || sx >= i32(params.width) || sy >= i32(params.height) {
        return vec4<f32>(0.0);
    }
    return colour_in[u32(sy) * params.width + u32(sx)];
}

// The kernel value(s) at element `at` applied to colour `c`: grey kernels scale every channel;
// RGB kernels scale R, G, B apart and alpha by their mean.
fn weigh(c: vec4<f32>, at: u32) -> vec4<f32> {
    if params.channels == 1u {
        return c * kernel_data[at];
    }
    let r = kernel_data[at];
    let g = kernel_data[at + 1u];
    let b = kernel_data[at + 2u];
    return vec4<f32>(c.x * r, c.y * g, c.z * b, c.w * (r + g + b) / 3.0);
}

@compute @workgroup_size(8, 8)
fn filter_pixels(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= params.width || id.y >= params.height {
        return;
    }
    let i = id.y * params.width + id.x;
    let p = pixels[i];
    var acc = colour_in[i];
    if p.kernel != NO_KERNEL {
        let k = kernel_table[p.kernel];
        let x = i32(id.x);
        let y = i32(id.y);
        let identity = p.rot_cos == 1.0 && p.rot_sin == 0.0;
        acc = vec4<f32>(0.0);
        for (var v = 0u; v < k.height; v++) {
            let oy = k.origin_y + i32(v);
            for (var u = 0u; u < k.width; u++) {
                let at = k.offset + (v * k.width + u) * params.channels;
                var nonzero = false;
                for (var c = 0u; c < params.channels; c++) {
                    nonzero = nonzero || kernel_data[at + c] != 0.0;
                }
                if !nonzero {
                    continue;
                }
                let ox = k.origin_x + i32(u);
                var gathered = vec4<f32>(0.0);
                if identity {
                    gathered = fetch(x - ox, y - oy);
                } else {
                    let rx = p.rot_cos * f32(ox) - p.rot_sin * f32(oy);
                    let ry = p.rot_sin * f32(ox) + p.rot_cos * f32(oy);
                    if params.rotation == 1u {
                        gathered = fetch(x - i32(round_away(rx)), y - i32(round_away(ry)));
                    } else {
                        let fx = floor(rx);
                        let fy = floor(ry);
                        let tx = rx - fx;
                        let ty = ry - fy;
                        let bx = x - i32(fx);
                        let by = y - i32(fy);
                        let w00 = (1.0 - tx) * (1.0 - ty);
                        let w10 = tx * (1.0 - ty);
                        let w01 = (1.0 - tx) * ty;
                        let w11 = tx * ty;
                        if w00 != 0.0 {
                            gathered += w00 * fetch(bx, by);
                        }
                        if w10 != 0.0 {
                            gathered += w10 * fetch(bx - 1, by);
                        }
                        if w01 != 0.0 {
                            gathered += w01 * fetch(bx, by - 1);
                        }
                        if w11 != 0.0 {
                            gathered += w11 * fetch(bx - 1, by - 1);
                        }
                    }
                }
                acc += weigh(gathered, at);
            }
        }
    }
    // As on the CPU: a gathered alpha above one divides the pixel; negatives are clamped.
    if acc.w > 1.0 {
        acc = acc * (1.0 / acc.w);
    }
    colour_out[i] = max(acc, vec4<f32>(0.0));
}
