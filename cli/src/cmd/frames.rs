//! Frame ranges: `--frames A-B` with a run of `#` in the paths standing for the frame number,
//! and `--shard K/N` (or `auto/N` from the batch engine) for a render farm's share of them.

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};

pub(crate) struct FrameJob {
    pub(crate) input: PathBuf,
    pub(crate) out: PathBuf,
    pub(crate) camera: Option<PathBuf>,
    pub(crate) preview: Option<PathBuf>,
    pub(crate) stats: Option<PathBuf>,
    /// The frame number, in a frame range.
    pub(crate) frame: Option<u32>,
}

/// Replaces the run of `#` in `path` by `frame`, zero-padded to the run's length.
pub(crate) fn frame_path(path: &Path, frame: u32) -> Result<PathBuf> {
    let text = path.to_string_lossy();
    let Some(start) = text.find('#') else {
        return Ok(path.to_path_buf());
    };
    let len = text[start..].chars().take_while(|c| *c == '#').count();
    if text[start + len..].contains('#') {
        bail!("{}: only one run of # is allowed", path.display());
    }
    Ok(PathBuf::from(format!(
        "{}{frame:0len$}{}",
        &text[..start],
        &text[start + len..]
    )))
}

/// The path arguments of a run that may cover a frame range.
pub(crate) struct FramePaths<'a> {
    pub(crate) input: &'a Path,
    pub(crate) out: &'a Path,
    pub(crate) camera: &'a Option<PathBuf>,
    pub(crate) preview: &'a Option<PathBuf>,
    pub(crate) stats: &'a Option<PathBuf>,
    pub(crate) frames: &'a Option<String>,
    pub(crate) shard: &'a Option<String>,
}

/// The frames of a run: one, or the range `--frames A-B` (its `--shard K/N` share) with `#` in
/// the paths replaced by the frame number.
pub(crate) fn frame_jobs(args: &FramePaths) -> Result<Vec<FrameJob>> {
    let has_hash = |p: &Path| p.to_string_lossy().contains('#');
    let Some(range) = &args.frames else {
        if has_hash(args.input) || has_hash(args.out) {
            bail!("the paths hold # but no --frames A-B was given");
        }
        if args.shard.is_some() {
            bail!("--shard splits a frame range: give --frames A-B too");
        }
        return Ok(vec![FrameJob {
            input: args.input.to_path_buf(),
            out: args.out.to_path_buf(),
            camera: args.camera.clone(),
            preview: args.preview.clone(),
            stats: args.stats.clone(),
            frame: None,
        }]);
    };
    let bad = || anyhow::anyhow!("--frames takes A-B (first and last frame), got '{range}'");
    let (a, b) = range.split_once('-').ok_or_else(bad)?;
    let (a, b): (u32, u32) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if b < a {
        return Err(bad());
    }
    if !has_hash(args.input) || !has_hash(args.out) {
        bail!("with --frames, --input and --out need a run of # for the frame number (frames/####.exr)");
    }
    let all: Vec<u32> = (a..=b).collect();
    let frames = match &args.shard {
        Some(spec) => {
            let (k, n) = parse_shard(spec)?;
            let r = psf_db::ShardRange::of(k, n, all.len() as u32)?;
            all[r.first_psf as usize..(r.first_psf + r.len) as usize].to_vec()
        }
        None => all,
    };
    let opt = |p: &Option<PathBuf>, f| p.as_deref().map(|p| frame_path(p, f)).transpose();
    frames
        .into_iter()
        .map(|f| {
            Ok(FrameJob {
                input: frame_path(args.input, f)?,
                out: frame_path(args.out, f)?,
                camera: opt(args.camera, f)?,
                preview: opt(args.preview, f)?,
                stats: opt(args.stats, f)?,
                frame: Some(f),
            })
        })
        .collect()
}

/// `K/N`, or `auto/N` with K from the batch engine (SLURM_ARRAY_TASK_ID, JOB_COMPLETION_INDEX).
pub(crate) fn parse_shard(spec: &str) -> Result<(u32, u32)> {
    let spec = match spec.strip_prefix("auto/") {
        Some(count) => {
            let k = ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"]
                .iter()
                .find_map(|v| std::env::var(v).ok())
                .ok_or_else(|| {
                    anyhow::anyhow!(
                        "--shard auto/{count}: neither SLURM_ARRAY_TASK_ID nor JOB_COMPLETION_INDEX is set"
                    )
                })?;
            format!("{k}/{count}")
        }
        None => spec.to_string(),
    };
    Ok(psf_db::ShardRange::parse_spec(&spec)?)
}
