use spreadlet::motion_smear::*;
fn main() {
    let psf = PsfImage {
        origin: [0, 0],
        width: 1,
        height: 1,
        channels: 1,
        data: vec![1.0],
    };
    let mut out = vec![0f32; 1 << 20];
    let mut rows = vec![[0u16; 2]; 4096];
    for _ in 0..2 {
        for &(len, bend) in &[(45.0f32, 0.0f32), (45.0, 10.0), (20.0, 4.0), (70.0, 20.0)] {
            let t = std::time::Instant::now();
            let n = 20000;
            let mut sum = 0.0;
            for i in 0..n {
                let angle = (i % 997) as f32 * 0.003;
                let e = smear_extent(&psf, len, angle, bend).unwrap();
                let o = &mut out[..e.width * e.height];
                let r = &mut rows[..e.height];
                smear_within(&psf, len, angle, bend, e, o, r);
                sum += o[e.width * (e.height / 2) + e.width / 2];
            }
            println!(
                "len {len} bend {bend}: {:.2} us/smear ({sum})",
                t.elapsed().as_secs_f64() * 1e6 / n as f64
            );
        }
    }
}
