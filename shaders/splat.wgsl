// Splatting (mirror of runtime::pipeline::splat): where a record's spreadlets (sparse path,
// into the Laplacian planes) and dense PSF pixels (`dense.wgsl`, into the direct planes) land.
// Shared by both accumulation schemes, which supply `add_rgba(to_laplacian, layer, x, y, v)`:
// global atomics (`splat_global.wgsl`) or per-tile sums in workgroup memory
// (`splat_tiled.wgsl`). LANES invocations share one record, striding over its samples.

// Invocations per record (a power of two dividing the workgroup; set from Rust).
override LANES: u32 = 8u;

@group(0) @binding(0) var<uniform> frame: FrameParams;
@group(0) @binding(1) var<uniform> targets: SplatTargets;
@group(0) @binding(2) var<storage, read> records: array<SplatRecord>;
@group(0) @binding(3) var<storage, read> cumulative: array<u32>;
// psf_db positions: [i16; 2] per spreadlet, packed (x low, y high).
@group(0) @binding(4) var<storage, read> positions: array<u32>;
@group(0) @binding(5) var<storage, read> values: array<f32>;
// One DenseEntry per PSF (size 0 for sparse PSFs): dense_slot resolved at upload.
@group(0) @binding(6) var<storage, read> dense_table: array<DenseEntry>;
@group(0) @binding(7) var<storage, read> dense_data: array<f32>;

// The RGBA a PSF sample contributes: grey databases scale every channel by the one value, RGB
// databases give alpha the mean of R, G, B (as the CPU's `weighted`).
fn weighted(color: vec4<f32>, data_index: u32, from_dense: bool) -> vec4<f32> {
    if targets.channels == 3u {
        var r: f32;
        var g: f32;
        var b: f32;
        if from_dense {
            r = dense_data[data_index];
            g = dense_data[data_index + 1u];
            b = dense_data[data_index + 2u];
        } else {
            r = values[data_index];
            g = values[data_index + 1u];
            b = values[data_index + 2u];
        }
        return vec4<f32>(color.x * r, color.y * g, color.z * b, color.w * (r + g + b) / 3.0);
    }
    var v: f32;
    if from_dense {
        v = dense_data[data_index];
    } else {
        v = values[data_index];
    }
    return color * v;
}

// runtime::pipeline::splat::quadratic_bspline_weights: pixels n - 1, n, n + 1 for a point at
// offset d in [-0.5, 0.5] from pixel n.
fn quadratic_bspline_weights(d: f32) -> vec3<f32> {
    return vec3<f32>(0.5 * (0.5 - d) * (0.5 - d), 0.75 - d * d, 0.5 * (0.5 + d) * (0.5 + d));
}


// Adds `v` at offset (ox, oy) from the record's centre, rotated by the record's rotation.
fn place(to_laplacian: bool, r: SplatRecord, ox: i32, oy: i32, v: vec4<f32>) {
    if r.rot_cos == 1.0 && r.rot_sin == 0.0 {
        add_rgba(to_laplacian, r.layer, r.center_x + ox, r.center_y + oy, v);
        return;
    }
    let fx = f32(ox);
    let fy = f32(oy);
    let rx = r.rot_cos * fx - r.rot_sin * fy;
    let ry = r.rot_sin * fx + r.rot_cos * fy;
    // Nearest pixel; a quarter turn maps pixels onto pixels, so the B-spline leaves it there.
    if targets.rotation == 1u || (targets.rotation == 2u && (r.rot_cos == 0.0 || r.rot_sin == 0.0)) {
        add_rgba(to_laplacian, r.layer, r.center_x + i32(round_away(rx)), r.center_y + i32(round_away(ry)), v);
        return;
    }
    if targets.rotation == 2u && to_laplacian {
        // 3x3 quadratic B-spline: every spreadlet keeps its value and centroid and gains the
        // same variance (runtime::pipeline::splat::bspline_footprint).
        let nx = round_away(rx);
        let ny = round_away(ry);
        let wx = quadratic_bspline_weights(rx - nx);
        let wy = quadratic_bspline_weights(ry - ny);
        let cx = r.center_x + i32(nx);
        let cy = r.center_y + i32(ny);
        for (var j = 0; j < 3; j++) {
            for (var i = 0; i < 3; i++) {
                add_rgba(true, r.layer, cx + i - 1, cy + j - 1, v * (wx[i] * wy[j]));
            }
        }
        return;
    }
    let flx = floor(rx);
    let fly = floor(ry);
    let tx = rx - flx;
    let ty = ry - fly;
    let x0 = r.center_x + i32(flx);
    let y0 = r.center_y + i32(fly);
    let w00 = (1.0 - tx) * (1.0 - ty);
    let w10 = tx * (1.0 - ty);
    let w01 = (1.0 - tx) * ty;
    let w11 = tx * ty;
    if w00 != 0.0 {
        add_rgba(to_laplacian, r.layer, x0, y0, v * w00);
    }
    if w10 != 0.0 {
        add_rgba(to_laplacian, r.layer, x0 + 1, y0, v * w10);
    }
    if w01 != 0.0 {
        add_rgba(to_laplacian, r.layer, x0, y0 + 1, v * w01);
    }
    if w11 != 0.0 {
        add_rgba(to_laplacian, r.layer, x0 + 1, y0 + 1, v * w11);
    }
}

// Sparse path: the record's spreadlets into its layer's Laplacian planes.
fn draw_sparse(r: SplatRecord, lane: u32) {
    let start = cumulative[r.psf_index];
    let end = cumulative[r.psf_index + 1u];
    for (var k = start + lane; k < end; k += LANES) {
        let p = positions[k];
        let v = weighted(r.color, k * targets.channels, false);
        place(true, r, unpack_i16_lo(p), unpack_i16_hi(p), v);
    }
}
