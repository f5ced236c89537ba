//! Beyond the input's pixels: the window of pixels an input holds (the frame, or more with
//! overscan) and what a blurred frame's border gathers from outside it (the outermost pixels
//! continued outwards, or nothing).

use crate::pipeline::types::SplatRecord;

/// The pixels an input holds, in frame coordinates (inclusive bounds): the frame
/// `[0, w) x [0, h)` itself, or more where the input has overscan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DataWindow {
    /// Leftmost column, pixels (0, or negative with overscan).
    pub x0: i32,
    /// Top row, pixels.
    pub y0: i32,
    /// Rightmost column, pixels (`w - 1`, or more with overscan).
    pub x1: i32,
    /// Bottom row, pixels.
    pub y1: i32,
}

impl DataWindow {
    /// The frame `w x h` and nothing beyond it.
    pub fn frame(w: usize, h: usize) -> Self {
        DataWindow {
            x0: 0,
            y0: 0,
            x1: w as i32 - 1,
            y1: h as i32 - 1,
        }
    }
}

/// What lies beyond the input's pixels, where a blurred frame's border gathers light from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum FrameEdges {
    /// The input continues beyond its outermost pixels as they are (clamp to edge, as a
    /// compositor's gather filter reads it): each outermost pixel is also splatted from the
    /// positions outside the input that clamp to it, as far as its PSF reaches into the
    /// frame. A blurred wall keeps its brightness up to the frame's edge.
    #[default]
    Extend,
    /// Nothing beyond the input (black): the border of a blurred frame loses up to half its
    /// light. Kept for comparison.
    Black,
}

/// Euclidean distance (pixels) from pixel `(x, y)` to the nearest pixel of `window`; 0 inside.
pub(super) fn distance_to(window: DataWindow, x: i32, y: i32) -> f32 {
    let dx = (window.x0 - x).max(x - window.x1).max(0) as f32;
    let dy = (window.y0 - y).max(y - window.y1).max(0) as f32;
    (dx * dx + dy * dy).sqrt()
}

/// Copies of the records on the border of `data` at every position outside it that clamps to
/// their pixel (to the side, and into the corner's quadrant), as far as each record's PSF
/// reaches into `frame` (`reach_of`, pixels). `records` are in frame coordinates.
pub(super) fn extend_beyond(
    records: &[SplatRecord],
    data: DataWindow,
    frame: DataWindow,
    reach_of: &dyn Fn(&SplatRecord) -> i32,
) -> Vec<SplatRecord> {
    let mut out = Vec::new();
    for r in records {
        let (x, y) = (r.center_x, r.center_y);
        let on_x = x == data.x0 || x == data.x1;
        let on_y = y == data.y0 || y == data.y1;
        if !(on_x || on_y) {
            continue;
        }
        let reach = reach_of(r);
        if reach <= 0 {
            continue;
        }
        let xs = (
            if x == data.x0 { x - reach } else { x },
            if x == data.x1 { x + reach } else { x },
        );
        let ys = (
            if y == data.y0 { y - reach } else { y },
            if y == data.y1 { y + reach } else { y },
        );
        for cy in ys.0..=ys.1 {
            for cx in xs.0..=xs.1 {
                let inside_data = cx >= data.x0 && cx <= data.x1 && cy >= data.y0 && cy <= data.y1;
                if inside_data || distance_to(frame, cx, cy) > reach as f32 {
                    continue;
                }
                out.push(SplatRecord {
                    center_x: cx,
                    center_y: cy,
                    ..*r
                });
            }
        }
    }
    out
}
