// Compositing back to front (mirror of runtime::pipeline::composite): one invocation per output
// pixel, over the layers from 0 (farthest) to the nearest, "over" with premultiplied alpha; a
// layer whose coverage exceeds one is normalised by it, and (flag bit 0) the result's coverage is
// raised to the summed coverage, capped at one (Lee et al. 2008), by scaling the pixel, or (bit 3)
// filled with the colour "over" hid, O + f (1 - O.a) (S - O) / (S.a - O.a) with S the layers'
// plain sum and f the share the sharper side gets (hidden_fill_share of the coverage-weighted
// sharpness of the layers that hid and of what they hid; `layer_sharpness` per layer of the
// chunk),
// for reconstruction, whose samples already hold their visibility. Negative values clamp to 0.
// params.src: the layer images (padded layers); params.planes: layers; params.border: pad.
// Frames too large for one binding come in chunks of layers, back to front: the running colour
// and the layers' running sum stay in `output` and `coverage`, the running sharpness (shown,
// summed, hiding) in `fill_state`, between chunks (flags: bit 1 = first chunk, bit 2 = last chunk, where
// the renormalisation and the clamp happen).

@group(0) @binding(0) var<uniform> params: PassParams;
@group(0) @binding(1) var<storage, read> layer_images: array<f32>;
@group(0) @binding(2) var<storage, read_write> output: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> coverage: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> layer_sharpness: array<f32>;
@group(0) @binding(5) var<storage, read_write> fill_state: array<vec4<f32>>;

const RENORMALIZE: u32 = 1u;
const FIRST_CHUNK: u32 = 2u;
const LAST_CHUNK: u32 = 4u;
const RESTORE_OCCLUDED: u32 = 8u;
// runtime::pipeline::composite::FILL_MIN_HIDDEN
const FILL_MIN_HIDDEN: f32 = 1e-3;

// runtime::pipeline::composite::SMOOTH_OCCLUDERS_SHARPNESS
const SMOOTH_OCCLUDERS_SHARPNESS: f32 = 0.05;

// runtime::pipeline::composite::hidden_fill_share
fn hidden_fill_share(occluders: f32, hidden: f32) -> f32 {
    if occluders <= 0.0 {
        return 1.0;
    }
    let least = max(1.0 - occluders / SMOOTH_OCCLUDERS_SHARPNESS, 0.0);
    if hidden <= 0.0 {
        return least;
    }
    return max(clamp(0.5 + 0.5 * log2(hidden / occluders), 0.0, 1.0), least);
}

@compute @workgroup_size(16, 16, 1)
fn composite(@builtin(global_invocation_id) id: vec3<u32>) {
    let w = params.dst.width;
    if id.x >= w || id.y >= params.dst.height {
        return;
    }
    let s = params.src;
    let x = id.x + params.border;
    let y = id.y + params.border;
    let o = id.y * w + id.x;
    var acc = vec4<f32>(0.0);
    var total = vec4<f32>(0.0);
    var sharp = vec4<f32>(0.0);
    if (params.flags & FIRST_CHUNK) == 0u {
        acc = output[o];
        total = coverage[o];
        sharp = fill_state[o];
    }
    for (var l = 0u; l < params.planes; l++) {
        var c = vec4<f32>(
            layer_images[plane_index(s, l * 4u, x, y)],
            layer_images[plane_index(s, l * 4u + 1u, x, y)],
            layer_images[plane_index(s, l * 4u + 2u, x, y)],
            max(layer_images[plane_index(s, l * 4u + 3u, x, y)], 0.0),
        );
        if c.w > 1.0 {
            c = c * (1.0 / c.w);
        }
        total += c;
        let sharpness = layer_sharpness[l];
        sharp = vec4<f32>(
            sharpness * c.w + (1.0 - c.w) * sharp.x,
            sharp.y + sharpness * c.w,
            sharp.z + sharpness * c.w * acc.w,
            0.0,
        );
        acc = c + (1.0 - c.w) * acc;
    }
    if (params.flags & LAST_CHUNK) == 0u {
        output[o] = acc;
        coverage[o] = total;
        fill_state[o] = sharp;
        return;
    }
    if (params.flags & (RENORMALIZE | RESTORE_OCCLUDED)) == (RENORMALIZE | RESTORE_OCCLUDED) {
        let hidden = total.w - acc.w;
        if hidden > FILL_MIN_HIDDEN && acc.w < 1.0 {
            let share = hidden_fill_share(sharp.z / hidden, (sharp.y - sharp.x) / hidden);
            acc = acc + (share * (1.0 - acc.w) / hidden) * (total - acc);
        }
    } else if (params.flags & RENORMALIZE) != 0u {
        let target_alpha = min(total.w, 1.0);
        if acc.w > 1e-6 && target_alpha > acc.w {
            acc = acc * (target_alpha / acc.w);
            acc.w = target_alpha;
        }
    }
    output[o] = max(acc, vec4<f32>(0.0));
}
