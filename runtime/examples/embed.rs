//! Embedding spreadlet: read a pinhole G-buffer and its camera, add depth of field and motion
//! blur, write the result. `cargo run --release -p spreadlet --example embed -- input.exr
//! camera.json out.exr`; databases missing from the cache are built on first use.

use std::path::Path;

use spreadlet::{Camera, GBuffer, Renderer, RendererOptions, SynthOptions};

/// Synthesises `input` as `camera` sees it into `out`; returns the device that ran it.
pub fn run(input: &Path, camera: &Path, out: &Path) -> Result<String, spreadlet::Error> {
    let gbuffer = GBuffer::read_exr(input, &Default::default())?;
    let camera = Camera::from_json_file(camera)?;
    let mut renderer = Renderer::new(RendererOptions::default())?;
    let frame = renderer.synthesize(&gbuffer, &camera, &SynthOptions::default())?;
    frame.image.write_exr(out)?;
    Ok(frame.device)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [input, camera, out] = args.as_slice() else {
        eprintln!("usage: embed INPUT.exr CAMERA.json OUT.exr");
        std::process::exit(2);
    };
    match run(input.as_ref(), camera.as_ref(), out.as_ref()) {
        Ok(device) => println!("wrote {out} on the {device}"),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
