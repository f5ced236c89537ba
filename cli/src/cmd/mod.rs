//! The subcommands: each parses its flags into the library's options, calls
//! [`spreadlet::Renderer`] (or the harness) and writes the files.

#[cfg(feature = "gpu")]
pub(crate) mod bench;
pub(crate) mod camera_flags;
pub(crate) mod compare;
pub(crate) mod demo;
pub(crate) mod frames;
pub(crate) mod reconstruct;
pub(crate) mod study;
pub(crate) mod synth;

use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use spreadlet::{DbSource, Event, Method, RendererOptions};

/// Milliseconds since `t`.
pub(crate) fn ms_since(t: std::time::Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Writes `value` as pretty JSON to `path`, atomically.
pub(crate) fn write_json(path: &Path, value: &serde_json::Value) -> Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    formats::atomic::write_bytes_atomically(path, text.as_bytes())?;
    Ok(())
}

/// The renderer's options from the flags every rendering command shares: the device, the
/// database (a file, or the cache with the profile of databases built on demand), the method,
/// conditioning, and progress on stderr unless `quiet`.
pub(crate) fn renderer_options(
    backend: spreadlet::Backend,
    db: Option<&Path>,
    db_profile: &str,
    method: Method,
    condition: bool,
    quiet: bool,
) -> Result<RendererOptions> {
    let databases = match db {
        Some(path) => DbSource::File(path.to_path_buf()),
        None => DbSource::Cache {
            dir: spreadlet::cache_dir(),
            profile: db_profile.parse()?,
        },
    };
    let on_event: Option<spreadlet::EventSink> = if quiet {
        None
    } else {
        // The builder's own bar shows a build's progress.
        Some(Arc::new(|e: &Event| {
            if !matches!(e, Event::Cache(c) if c.fraction().is_some()) {
                eprintln!("{e}")
            }
        }))
    };
    Ok(RendererOptions {
        backend,
        databases,
        method,
        condition,
        progress: !quiet,
        on_event,
    })
}
