// Accumulation with native float atomics (wgpu::Features::SHADER_FLOAT32_ATOMIC).

@group(0) @binding(8) var<storage, read_write> laplacian: array<atomic<f32>>;
@group(0) @binding(9) var<storage, read_write> direct: array<atomic<f32>>;

fn add_laplacian(i: u32, v: f32) {
    atomicAdd(&laplacian[i], v);
}

fn add_direct(i: u32, v: f32) {
    atomicAdd(&direct[i], v);
}
