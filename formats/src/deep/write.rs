//! The deep scanline writer: FLOAT channels in the header's alphabetical order, one chunk per
//! scanline, each part compressed where that makes it smaller.

use super::compression::compress;
use super::*;

/// A channel the writer writes: its name and how to get its value from a sample.
type WrittenChannel = (&'static str, fn(&DeepSample) -> f32);

impl DeepImage {
    /// The bytes [`DeepImage::write`] writes.
    pub fn to_bytes(&self, compression: DeepCompression) -> Vec<u8> {
        let volumes = self.samples.iter().any(|s| s.depth_back != s.depth);
        let mut channels: Vec<WrittenChannel> = vec![
            ("A", |s| s.color[3]),
            ("B", |s| s.color[2]),
            ("G", |s| s.color[1]),
            ("R", |s| s.color[0]),
            ("Z", |s| s.depth),
        ];
        if volumes {
            channels.push(("ZBack", |s| s.depth_back));
        }
        // OpenEXR lists channels sorted by name, bytewise: upper case first.
        if self.has_motion {
            channels.push(("motion.x", |s| s.motion[0]));
            channels.push(("motion.y", |s| s.motion[1]));
        }
        let (w, h) = (self.width, self.height);
        let data_window = [0i32, 0, w as i32 - 1, h as i32 - 1];
        let o = self.overscan;
        let display_window = [
            o.left as i32,
            o.top as i32,
            (w - o.right) as i32 - 1,
            (h - o.bottom) as i32 - 1,
        ];
        let mut out = Vec::new();
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&(VERSION_2 | FLAG_DEEP).to_le_bytes());
        let mut attribute = |name: &str, kind: &str, value: &[u8]| {
            out.extend_from_slice(name.as_bytes());
            out.push(0);
            out.extend_from_slice(kind.as_bytes());
            out.push(0);
            out.extend_from_slice(&(value.len() as i32).to_le_bytes());
            out.extend_from_slice(value);
        };
        let mut chlist = Vec::new();
        for (channel, _) in &channels {
            chlist.extend_from_slice(channel.as_bytes());
            chlist.push(0);
            chlist.extend_from_slice(&2i32.to_le_bytes()); // FLOAT
            chlist.extend_from_slice(&[0, 0, 0, 0]); // pLinear, reserved
            chlist.extend_from_slice(&1i32.to_le_bytes());
            chlist.extend_from_slice(&1i32.to_le_bytes());
        }
        chlist.push(0);
        let box2i = |b: [i32; 4]| b.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>();
        attribute("channels", "chlist", &chlist);
        attribute("chunkCount", "int", &(h as i32).to_le_bytes());
        attribute("compression", "compression", &[compression.code()]);
        attribute("dataWindow", "box2i", &box2i(data_window));
        attribute("displayWindow", "box2i", &box2i(display_window));
        attribute("lineOrder", "lineOrder", &[0]);
        let max_samples = self.max_samples_per_pixel() as i32;
        attribute("maxSamplesPerPixel", "int", &max_samples.to_le_bytes());
        attribute("pixelAspectRatio", "float", &1f32.to_le_bytes());
        attribute("screenWindowCenter", "v2f", &[0; 8]);
        attribute("screenWindowWidth", "float", &1f32.to_le_bytes());
        attribute("type", "string", b"deepscanline");
        attribute("version", "int", &1i32.to_le_bytes());
        out.push(0);

        let table_at = out.len();
        out.resize(table_at + 8 * h, 0);
        for y in 0..h {
            let chunk_at = out.len() as u64;
            out[table_at + 8 * y..table_at + 8 * y + 8].copy_from_slice(&chunk_at.to_le_bytes());
            let row = &self.offsets[y * w..=(y + 1) * w];
            let mut counts = Vec::with_capacity(4 * w);
            for &end in &row[1..] {
                counts.extend_from_slice(&((end - row[0]) as i32).to_le_bytes());
            }
            let samples = &self.samples[row[0]..row[w]];
            let mut data = Vec::with_capacity(4 * channels.len() * samples.len());
            for (_, value) in &channels {
                for s in samples {
                    data.extend_from_slice(&value(s).to_le_bytes());
                }
            }
            let packed_counts = compress(compression, &counts);
            let packed_data = compress(compression, &data);
            out.extend_from_slice(&(y as i32).to_le_bytes());
            out.extend_from_slice(&(packed_counts.len() as u64).to_le_bytes());
            out.extend_from_slice(&(packed_data.len() as u64).to_le_bytes());
            out.extend_from_slice(&(data.len() as u64).to_le_bytes());
            out.extend_from_slice(&packed_counts);
            out.extend_from_slice(&packed_data);
        }
        out
    }
}
