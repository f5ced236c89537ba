// Accumulation without float atomics: a compare-exchange loop on the u32 bit pattern.

@group(0) @binding(8) var<storage, read_write> laplacian: array<atomic<u32>>;
@group(0) @binding(9) var<storage, read_write> direct: array<atomic<u32>>;

fn add_laplacian(i: u32, v: f32) {
    var old = atomicLoad(&laplacian[i]);
    loop {
        let r = atomicCompareExchangeWeak(&laplacian[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if r.exchanged {
            break;
        }
        old = r.old_value;
    }
}

fn add_direct(i: u32, v: f32) {
    var old = atomicLoad(&direct[i]);
    loop {
        let r = atomicCompareExchangeWeak(&direct[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if r.exchanged {
            break;
        }
        old = r.old_value;
    }
}
