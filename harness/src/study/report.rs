//! What the study reports: the Pareto front, the findings, `study.csv`, `study.md` and
//! `study.json`.

use super::*;
use anyhow::Result;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// Marks the rows no other row beats in both SSIM (higher) and time (lower).
pub fn mark_pareto(rows: &mut [StudyRow]) {
    let flags: Vec<bool> = rows
        .iter()
        .map(|r| {
            !rows
                .iter()
                .any(|o| (o.ssim >= r.ssim && o.ms < r.ms) || (o.ssim > r.ssim && o.ms <= r.ms))
        })
        .collect();
    for (r, f) in rows.iter_mut().zip(flags) {
        r.pareto = f;
    }
}

/// The headline figures of a study, computed from the rows (CPU only).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Findings {
    /// SSIM and ms of the dense splat (CPU, base settings).
    pub dense: Option<(f64, f64)>,
    /// SSIM and ms of the base spreadlet configuration (CPU).
    pub spreadlet_base: Option<(f64, f64)>,
    /// The fastest CPU spreadlet row that draws most of its records as spreadlets (not
    /// through the fast track), layers as the dense splat does (8 soft layers), and scores SSIM
    /// at least the dense splat's minus 0.005: its configuration, SSIM and ms.
    pub spreadlet_at_dense_ssim: Option<(String, f64, f64)>,
    /// The best-scoring CPU spreadlet row that draws most of its records as spreadlets: its
    /// configuration, SSIM and ms.
    pub best_mostly_sparse: Option<(String, f64, f64)>,
    /// Dense ms over that row's ms (the speed-up at equal SSIM).
    pub speedup_at_equal_ssim: Option<f64>,
    /// Dense ms over the base spreadlet's ms.
    pub speedup_base: Option<f64>,
    /// SSIM and ms of the filter (CPU).
    pub filter: Option<(f64, f64)>,
    /// SSIM of the pinhole input itself against the reference (doing nothing).
    pub pinhole_ssim: Option<f64>,
}

/// Computes the [`Findings`] of `rows`.
pub fn findings(rows: &[StudyRow]) -> Findings {
    let cpu = |m: &str, knob: &str, value: &str| {
        rows.iter()
            .find(|r| r.method == m && r.backend == "cpu" && r.knob == knob && r.value == value)
    };
    let dense = cpu("dense", "baseline", "dense");
    let base = cpu("spreadlet", "base", "-");
    let filter_row = cpu("filter", "baseline", "filter");
    let mut f = Findings {
        dense: dense.map(|r| (r.ssim, r.ms)),
        spreadlet_base: base.map(|r| (r.ssim, r.ms)),
        filter: filter_row.map(|r| (r.ssim, r.ms)),
        ..Findings::default()
    };
    // Only rows that really splat spreadlets count: a row whose records mostly go through the
    // fast track is a dense splat itself.
    let mostly_sparse = |r: &&StudyRow| {
        r.method.starts_with("spreadlet") && r.backend == "cpu" && r.sparse > r.dense
    };
    // The speed-up at equal SSIM compares like with like: the dense splat's layering (the
    // base's 8 soft layers), so that fewer layers are not counted as the spreadlets' gain.
    let same_layering = |r: &&StudyRow| {
        !(r.knob == "layers"
            || r.knob == "soft_layers"
            || (r.knob == "joint" && !r.value.contains("layers=8")))
    };
    f.best_mostly_sparse = rows
        .iter()
        .filter(mostly_sparse)
        .max_by(|a, b| a.ssim.total_cmp(&b.ssim))
        .map(|b| (format!("{} {}={}", b.method, b.knob, b.value), b.ssim, b.ms));
    if let Some(d) = dense {
        let best = rows
            .iter()
            .filter(mostly_sparse)
            .filter(same_layering)
            .filter(|r| r.ssim >= d.ssim - 0.005)
            .min_by(|a, b| a.ms.total_cmp(&b.ms));
        if let Some(b) = best {
            f.spreadlet_at_dense_ssim =
                Some((format!("{} {}={}", b.method, b.knob, b.value), b.ssim, b.ms));
            f.speedup_at_equal_ssim = Some(d.ms / b.ms);
        }
        if let Some(b) = base {
            f.speedup_base = Some(d.ms / b.ms);
        }
    }
    f
}

/// The CSV columns, in order.
pub const CSV_COLUMNS: [&str; 19] = [
    "method",
    "knob",
    "value",
    "backend",
    "ssim",
    "psnr",
    "flip_mean",
    "flip_p99",
    "ms",
    "classify_ms",
    "splat_ms",
    "integrate_ms",
    "composite_ms",
    "sparse",
    "dense",
    "copied",
    "db_spreadlets",
    "pareto",
    "note",
];

pub(super) fn csv_text(rows: &[StudyRow]) -> String {
    let mut s = CSV_COLUMNS.join(",");
    s.push('\n');
    for r in rows {
        let note = match r.method.as_str() {
            "filter" => "gathering; splat_ms holds the gathering",
            "dense" => "every PSF dense (pre-filtered)",
            "spreadlet-sparse" => "fast track off: every PSF sparse",
            _ => "",
        };
        let _ = writeln!(
            s,
            "{},{},{},{},{:.5},{:.3},{:.5},{:.5},{:.2},{:.2},{:.2},{:.2},{:.2},{},{},{},{},{},{}",
            r.method,
            r.knob,
            r.value,
            r.backend,
            r.ssim,
            r.psnr,
            r.flip_mean,
            r.flip_p99,
            r.ms,
            r.classify_ms,
            r.splat_ms,
            r.integrate_ms,
            r.composite_ms,
            r.sparse,
            r.dense,
            r.copied,
            r.db_spreadlets,
            r.pareto,
            note
        );
    }
    s
}

pub(super) fn markdown_text(
    rows: &[StudyRow],
    f: &Findings,
    label: &str,
    runs: usize,
    elapsed_s: f64,
    full: bool,
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# spreadlet study\n");
    let _ = writeln!(
        s,
        "Input: {label}. Times: median of {runs} runs in one process, {} CPU threads; database \
         loading excluded. SSIM/PSNR against the reference (sRGB, DEVELOPERS.md). Base: \
         spreadlet, budget 1, profile PSF count, pre-filtered, fast-track ratio 0.5, 8 layers, \
         soft layering 1, exact integration, CPU. Study took {elapsed_s:.0} s{}.\n",
        rayon::current_num_threads(),
        if full { " (--full)" } else { "" }
    );
    let _ = writeln!(s, "## Findings\n");
    if let Some(p) = f.pinhole_ssim {
        let _ = writeln!(
            s,
            "- The pinhole input itself scores SSIM {p:.4} (doing nothing)."
        );
    }
    match (
        f.dense,
        f.spreadlet_at_dense_ssim.as_ref(),
        f.speedup_at_equal_ssim,
    ) {
        (Some((ds, dm)), Some((cfg, ss, sm)), Some(x)) => {
            let _ = writeln!(
                s,
                "- Dense splat: SSIM {ds:.4} in {dm:.0} ms. Fastest configuration drawing mostly \
                 spreadlets within 0.005 SSIM of it: {cfg} (SSIM {ss:.4}, {sm:.0} ms): \
                 **{x:.1}x faster** on the CPU."
            );
        }
        (Some((ds, dm)), _, _) => {
            let _ = writeln!(
                s,
                "- Dense splat: SSIM {ds:.4} in {dm:.0} ms. **No configuration drawing mostly \
                 spreadlets comes within 0.005 SSIM of it.**"
            );
        }
        _ => {}
    }
    if let (Some((cfg, bs, bm)), Some((ds, dm))) = (&f.best_mostly_sparse, f.dense) {
        let _ = writeln!(
            s,
            "- Best configuration drawing mostly spreadlets: {cfg}: SSIM {bs:.4} ({:+.4} against \
             dense) in {bm:.0} ms ({:.1}x faster than dense).",
            bs - ds,
            dm / bm
        );
    }
    if let (Some(x), Some((bs, bm))) = (f.speedup_base, f.spreadlet_base) {
        let _ = writeln!(
            s,
            "- Base spreadlet (as shipped, fast track on): SSIM {bs:.4} in {bm:.0} ms ({x:.1}x \
             faster than dense; look at its sparse/dense record counts below)."
        );
    }
    if let (Some((fs, fm)), Some((ds, _))) = (f.filter, f.dense) {
        let verdict = if fs < ds { "lower" } else { "not lower" };
        let _ = writeln!(
            s,
            "- Filter (gathering with the same pre-filtered PSFs): SSIM {fs:.4} in {fm:.0} ms, \
             {verdict} than the dense splat's {ds:.4} (difference {:+.4}).",
            fs - ds
        );
    }
    if let Some((bs, _)) = f.spreadlet_base {
        if let Some((fs, _)) = f.filter {
            let verdict = if fs < bs { "lower" } else { "not lower" };
            let _ = writeln!(
                s,
                "- Filter vs splatting (base spreadlet): {fs:.4} vs {bs:.4}, {verdict} \
                 (difference {:+.4}).",
                fs - bs
            );
        }
    }
    let _ = writeln!(s, "\n## All configurations\n");
    let _ = writeln!(
        s,
        "| method | knob | value | backend | SSIM | PSNR dB | FLIP mean | FLIP p99 | ms | classify | splat | integrate | composite | sparse | dense | copied | Pareto |"
    );
    let _ = writeln!(
        s,
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.4} | {:.2} | {:.4} | {:.4} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {} | {} | {} | {} |",
            r.method,
            r.knob,
            r.value.replace(';', "; "),
            r.backend,
            r.ssim,
            r.psnr,
            r.flip_mean,
            r.flip_p99,
            r.ms,
            r.classify_ms,
            r.splat_ms,
            r.integrate_ms,
            r.composite_ms,
            r.sparse,
            r.dense,
            r.copied,
            if r.pareto { "yes" } else { "" }
        );
    }
    let _ = writeln!(
        s,
        "\nFilter rows: `splat` is the gathering time, `dense` the pixels filtered. Rows with the \
         same configuration under several knobs are measured once."
    );
    s
}

pub(super) fn write_text(path: &Path, text: &str) -> Result<()> {
    formats::atomic::write_bytes_atomically(path, text.as_bytes())?;
    Ok(())
}

pub(super) fn write_outputs(
    rows: &[StudyRow],
    options: &StudyOptions,
    label: &str,
    runs: usize,
    elapsed_s: f64,
    pinhole_ssim: f64,
) -> Result<()> {
    let dir = &options.out_dir;
    let mut f = findings(rows);
    f.pinhole_ssim = Some(pinhole_ssim);
    write_text(&dir.join("study.csv"), &csv_text(rows))?;
    write_text(
        &dir.join("study.md"),
        &markdown_text(rows, &f, label, runs, elapsed_s, options.full),
    )?;
    let json = serde_json::json!({
        "input": label, "runs": runs, "threads": rayon::current_num_threads(),
        "seconds": elapsed_s, "findings": f, "rows": rows,
    });
    write_text(
        &dir.join("study.json"),
        &serde_json::to_string_pretty(&json)?,
    )?;
    plot(rows, &dir.join("study.png"), label)?;
    Ok(())
}
