// Splatting with global atomics: each workgroup of 64 invocations takes 64 / LANES records,
// LANES invocations per record; every sample is an atomic add into the planes
// (`atomic_f32.wgsl` or `atomic_cas.wgsl`, prepended), so the sum order, unlike the CPU's, is
// not fixed: results agree to float rounding.

const GROUP: u32 = 64u;
// Leave out the records the tiled splat draws (`drawn_by_tiles`, `bin.wgsl`): the pass that
// completes the tiled splat with the records that span too many tiles.
override SKIP_TILED: bool = false;

// Adds `v` at padded-layer pixel (x, y) of `layer` (dropped outside the padded layer).
fn add_rgba(to_laplacian: bool, layer: u32, x: i32, y: i32, v: vec4<f32>) {
    if x < 0 || y < 0 || x >= i32(frame.padded_width) || y >= i32(frame.padded_height) {
        return;
    }
    for (var c = 0u; c < 4u; c++) {
        if v[c] == 0.0 {
            continue;
        }
        if to_laplacian {
            let s = targets.laplacian;
            let b = targets.border;
            add_laplacian(plane_index(s, layer * 4u + c, u32(x) + b, u32(y) + b), v[c]);
        } else {
            add_direct(plane_index(targets.direct, layer * 4u + c, u32(x), u32(y)), v[c]);
        }
    }
}

@compute @workgroup_size(64, 1, 1)
fn splat_records(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = (wid.y * groups.x + wid.x) * (GROUP / LANES) + local / LANES;
    let lane = local % LANES;
    if i >= frame.record_count {
        return;
    }
    if SKIP_TILED && drawn_by_tiles(i) {
        return;
    }
    var r = records[i];
    if r.layer >= frame.layers || r.layer < targets.layer_base
        || r.layer - targets.layer_base >= targets.layer_count {
        return;
    }
    // From here on, the layer within this chunk.
    r.layer -= targets.layer_base;
    if r.path == PATH_COPY {
        if lane == 0u {
            add_rgba(false, r.layer, r.center_x, r.center_y, r.color);
        }
        return;
    }
    if r.psf_index >= targets.psf_count {
        return;
    }
    if r.path == PATH_SPARSE {
        draw_sparse(r, lane);
    } else if r.path == PATH_DENSE {
        draw_dense(r, lane);
    }
}
