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

/// Frames of at most this many pixels keep the memory a stage frees for the next stage
/// ([`keep_freed_memory_below`]); larger ones hand it back, so that their peak stays low.
pub(crate) const KEEP_FREED_MEMORY_MAX_PX: u64 = 4 << 20;

/// For a frame of `width x height` pixels up to [`KEEP_FREED_MEMORY_MAX_PX`], keeps the memory
/// a stage frees for the next stage instead of handing it back to the kernel. glibc maps each
/// buffer over 32 MiB (a million samples' arrays, the merge's taps, layers, records) on its
/// own and unmaps it when freed, so the next stage's buffer was faulted in again 4 KiB at a
/// time: a reconstruction from 1 M samples spent a quarter of its CPU time on 150,000 page
/// faults, a 512x512 synthesis a tenth. A command runs and exits, so its peak is all it
/// holds; but kept memory fragments, and a 3840x2160 frame's peak rose from 3.3 to 3.8 GB with
/// it, so big frames are left as they were.
pub(crate) fn keep_freed_memory_below(width: u32, height: u32) {
    if u64::from(width) * u64::from(height) > KEEP_FREED_MEMORY_MAX_PX {
        return;
    }
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets two of glibc's allocator parameters, under its own lock.
    unsafe {
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

/// For a frame's summary line: how many fragments were drawn at a reduced resolution (their
/// blur beyond the database's range, or their streaks beyond the frame's budget), or nothing.
pub(crate) fn reduced_note(reduced: usize) -> String {
    if reduced > 0 {
        format!(", {reduced} at a reduced resolution")
    } else {
        String::new()
    }
}

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
