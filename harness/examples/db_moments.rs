//! Prints, per PSF of a database, the moments of its spreadlets that decide how it integrates:
//! the sum of values (monopole: must be 0 for a compact PSF), the first moments (dipole), and
//! the energy `sum v |x|^2 / 4` (the integrated PSF's sum, 1 for a normalised PSF).
//! `cargo run --release -p runtime --example db_moments -- FILE.sprdlt`

fn main() -> anyhow::Result<()> {
    let path = std::env::args()
        .nth(1)
        .ok_or_else(|| anyhow::anyhow!("usage: db_moments FILE"))?;
    let db = psf_db::PsfDatabase::read(&path)?;
    let ch = db.channels();
    println!(
        "{}: {} PSFs, model {}, max extent {} px",
        path,
        db.psf_count(),
        db.model().name(),
        db.max_extent_px()
    );
    for i in 0..db.psf_count() {
        let st = db.header().stats[i];
        if let Some(d) = db.dense(i) {
            let s: f64 = d.data.iter().map(|&v| f64::from(v)).sum::<f64>() / ch as f64;
            println!(
                "{i:4} {:?} dense {}x{} sum {s:.5}",
                st.coords, d.width, d.height
            );
            continue;
        }
        let (pos, val) = db.spreadlets(i);
        let (mut m0, mut mx, mut my, mut e) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (k, p) in pos.iter().enumerate() {
            let v = f64::from(val[k * ch]);
            let (x, y) = (f64::from(p[0]), f64::from(p[1]));
            m0 += v;
            mx += v * x;
            my += v * y;
            e += v * (x * x + y * y) / 4.0;
        }
        println!("{i:4} {:?} n {:5} sum {m0:+.2e} dipole ({mx:+.2e}, {my:+.2e}) energy {e:.5} l1 {:.4} ssim {:.4}", st.coords, pos.len(), st.l1, st.ssim);
    }
    Ok(())
}
