// Dense fast track (mirror of the CPU's `splat_dense`): every non-zero pixel of the record's
// dense PSF image, scaled by its colour and rotated like a spreadlet, into the layer's direct
// planes. Copies (PSF under one pixel) are drawn by `splat_records` itself.

fn draw_dense(r: SplatRecord, lane: u32) {
    let e = dense_table[r.psf_index];
    let w = e.size_packed & 0xffffu;
    let h = e.size_packed >> 16u;
    let ox = unpack_i16_lo(e.origin_packed);
    let oy = unpack_i16_hi(e.origin_packed);
    let ch = targets.channels;
    for (var k = lane; k < w * h; k += LANES) {
        let at = e.offset + k * ch;
        var nonzero = false;
        for (var c = 0u; c < ch; c++) {
            nonzero = nonzero || dense_data[at + c] != 0.0;
        }
        if !nonzero {
            continue;
        }
        let u = i32(k % w);
        let v = i32(k / w);
        place(false, r, ox + u, oy + v, weighted(r.color, at, true));
    }
}
