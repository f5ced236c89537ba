//! `study.png`: SSIM against milliseconds, log scale, the Pareto front marked.

use super::*;
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// Registers a system sans-serif font for the plot's text, when one is found
/// (`$SPREADLET_FONT`, else DejaVu Sans or Liberation Sans in the usual places).
pub(super) fn font_available() -> bool {
    static FONT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *FONT.get_or_init(|| {
        let mut candidates: Vec<PathBuf> = std::env::var_os("SPREADLET_FONT")
            .map(PathBuf::from)
            .into_iter()
            .collect();
        candidates.extend(
            [
                "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/TTF/DejaVuSans.ttf",
                "/usr/share/fonts/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
                "/Library/Fonts/Arial.ttf",
                "C:\\Windows\\Fonts\\arial.ttf",
            ]
            .iter()
            .map(PathBuf::from),
        );
        for p in candidates {
            if let Ok(bytes) = std::fs::read(&p) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font(
                    "sans-serif",
                    plotters::style::FontStyle::Normal,
                    bytes,
                )
                .is_ok()
                {
                    return true;
                }
            }
        }
        false
    })
}

/// SSIM against milliseconds (log scale), one colour per method, the Pareto front joined.
pub fn plot(rows: &[StudyRow], path: &Path, title: &str) -> Result<()> {
    use plotters::prelude::*;
    if rows.is_empty() {
        bail!("nothing to plot");
    }
    let text = font_available();
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, (960, 640)).into_drawing_area();
        root.fill(&WHITE)?;
        let (mut lo_ms, mut hi_ms) = (f64::INFINITY, 0.0f64);
        let (mut lo_s, mut hi_s) = (f64::INFINITY, f64::NEG_INFINITY);
        for r in rows.iter().filter(|r| r.ms.is_finite() && r.ms > 0.0) {
            lo_ms = lo_ms.min(r.ms);
            hi_ms = hi_ms.max(r.ms);
            lo_s = lo_s.min(r.ssim);
            hi_s = hi_s.max(r.ssim);
        }
        if !(lo_ms.is_finite() && lo_s.is_finite()) {
            bail!("no finite times to plot");
        }
        let pad_s = ((hi_s - lo_s) * 0.08).max(0.002);
        let mut builder = ChartBuilder::on(&root);
        builder.margin(16);
        if text {
            builder
                .caption(format!("accuracy vs time: {title}"), ("sans-serif", 20))
                .x_label_area_size(44)
                .y_label_area_size(64);
        } else {
            builder.x_label_area_size(8).y_label_area_size(8);
        }
        let mut chart = builder.build_cartesian_2d(
            ((lo_ms * 0.8)..(hi_ms * 1.25)).log_scale(),
            (lo_s - pad_s)..(hi_s + pad_s),
        )?;
        let mut mesh = chart.configure_mesh();
        if text {
            mesh.x_desc("time per frame, ms (log)")
                .y_desc("SSIM against the reference")
                .label_style(("sans-serif", 14));
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw()?;
        let colour = |m: &str| match m {
            "dense" => RGBColor(200, 40, 40),
            "filter" => RGBColor(30, 150, 60),
            "spreadlet-sparse" => RGBColor(120, 170, 240),
            _ => RGBColor(40, 80, 200),
        };
        for method in ["spreadlet", "spreadlet-sparse", "dense", "filter"] {
            let c = colour(method);
            let pts: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.method == method && r.ms > 0.0)
                .map(|r| (r.ms, r.ssim))
                .collect();
            let series = chart.draw_series(pts.iter().map(|&p| Circle::new(p, 5, c.filled())))?;
            if text {
                series
                    .label(method)
                    .legend(move |(x, y)| Circle::new((x, y), 5, c.filled()));
            }
        }
        let mut front: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.pareto && r.ms > 0.0)
            .map(|r| (r.ms, r.ssim))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        let series = chart.draw_series(LineSeries::new(front.clone(), BLACK.stroke_width(2)))?;
        if text {
            series
                .label("Pareto front")
                .legend(|(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], BLACK));
        }
        chart.draw_series(
            front
                .iter()
                .map(|&p| Circle::new(p, 8, BLACK.stroke_width(2))),
        )?;
        if text {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .position(SeriesLabelPosition::LowerRight)
                .label_font(("sans-serif", 14))
                .draw()?;
        }
        root.present()?;
    }
    std::fs::rename(&tmp, path)
        .with_context(|| format!("moving the plot to {}", path.display()))?;
    Ok(())
}
