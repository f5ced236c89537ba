// Micro-benchmarks of what the device allows, for stating each stage's time as a fraction of
// its limit (runtime::gpu::microbench): a copy in a shader (bandwidth), f32 atomic adds to
// global memory at random and at coalesced addresses (`atomic_f32.wgsl` or `atomic_cas.wgsl`,
// prepended: the splat's own accumulation), and i32 atomic adds to workgroup memory (the tiled
// splat's). 256 invocations per workgroup.

@group(0) @binding(0) var<uniform> micro: MicroParams;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> dst: array<vec4<f32>>;
// Bindings 8 (`laplacian`) and 9 (`direct`, unused) come with the atomics.

var<workgroup> wg_acc: array<atomic<i32>, 1024>;

fn invocation(wid: vec3<u32>, local: u32) -> u32 {
    return (wid.y * micro.row + wid.x) * 256u + local;
}

// A cheap integer hash (scatters addresses like splats of unrelated records).
fn hash(x: u32) -> u32 {
    var h = x * 0x9e3779b9u;
    h ^= h >> 16u;
    h *= 0x85ebca6bu;
    h ^= h >> 13u;
    return h;
}

@compute @workgroup_size(256, 1, 1)
fn copy_vec4(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let i = invocation(wid, local);
    if i < micro.elements {
        dst[i] = src[i];
    }
}

@compute @workgroup_size(256, 1, 1)
fn atomic_random(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let i = invocation(wid, local);
    for (var k = 0u; k < micro.iterations; k++) {
        add_laplacian(hash(i * micro.iterations + k) & micro.mask, 1.0);
    }
}

@compute @workgroup_size(256, 1, 1)
fn atomic_coalesced(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let i = invocation(wid, local);
    let threads = micro.elements;
    for (var k = 0u; k < micro.iterations; k++) {
        add_laplacian((i + k * threads) & micro.mask, 1.0);
    }
}

@compute @workgroup_size(256, 1, 1)
fn atomic_workgroup(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let i = invocation(wid, local);
    for (var c = 0u; c < 4u; c++) {
        atomicStore(&wg_acc[c * 256u + local], 0);
    }
    workgroupBarrier();
    for (var k = 0u; k < micro.iterations; k++) {
        atomicAdd(&wg_acc[hash(i * micro.iterations + k) & 1023u], 1);
    }
    workgroupBarrier();
    // One global write per invocation keeps the sums alive.
    let total = atomicLoad(&wg_acc[local]);
    if total == -1 {
        dst[i & (micro.elements - 1u)] = vec4<f32>(f32(total));
    }
}
