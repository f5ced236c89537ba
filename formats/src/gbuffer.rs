//! Reading pinhole G-buffers (colour, depth, forward motion) from OpenEXR.
//!
//! Two layouts:
//! - **Blender multilayer** (`<Layer>.Combined.{R,G,B,A}`, `<Layer>.Depth.Z`,
//!   `<Layer>.Vector.{X,Y,Z,W}`): the layer name is found, not assumed. Blender's vector pass
//!   has y up, `X, Y` = position in the previous frame minus position now and `Z, W` = position
//!   now minus position in the next frame, so the forward motion in image coordinates (x right,
//!   y down) is `(-Z, +W)` and the backward `(X, -Y)`. The motion read is the centred
//!   difference `((-Z - X) / 2, (W + Y) / 2)`, the tangent of the path at the frame time; a
//!   file without `X, Y`, or a pixel whose `X, Y` are both zero, gives the forward motion.
//! - **plain** single-layer files: `R, G, B` (and `A`, else 1), depth `Z` or `depth.Z` (or a
//!   name given), forward motion `forward.u/forward.v` or `motion.x/motion.y` (or a pair given)
//!   in pixels per frame, x right, y down (`motion_y_up` flips y).
//!
//! Policy for bad values (also in the stats): a pixel whose colour has a NaN or an infinity is
//! dropped (made transparent black) and counted; a NaN, zero or negative depth is an error
//! naming the pixel (+infinity is allowed: a point at infinity); a non-finite motion vector is
//! an error naming the pixel.

use std::path::Path;

pub use crate::limits::{MAX_PIXELS, MAX_SAMPLES};

/// Errors of reading G-buffers.
#[derive(Debug, thiserror::Error)]
pub enum GBufferError {
    /// The file could not be opened or decoded.
    #[error("cannot read OpenEXR {path}: {message}")]
    Exr {
        /// The file.
        path: String,
        /// The decoder's message.
        message: String,
    },
    /// A channel the layout needs is not in the file.
    #[error("{path}: missing channel {missing}; the file has: {present}")]
    MissingChannel {
        /// The file.
        path: String,
        /// The channel (or the alternatives) looked for.
        missing: String,
        /// The channels present, comma-separated.
        present: String,
    },
    /// The layout is ambiguous or does not fit the file.
    #[error("{path}: {message}")]
    Layout {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// The image is empty or larger than the limit.
    #[error("{path}: image size {width}x{height} is {reason}")]
    Size {
        /// The file.
        path: String,
        /// Declared width.
        width: usize,
        /// Declared height.
        height: usize,
        /// Why it is refused.
        reason: &'static str,
    },
    /// A depth or motion value the runtime cannot use.
    #[error("{path}: {what} at pixel ({x}, {y}) is {value}: {why}")]
    BadValue {
        /// The file.
        path: String,
        /// Which quantity.
        what: &'static str,
        /// Column.
        x: usize,
        /// Row.
        y: usize,
        /// The value found.
        value: f32,
        /// What is expected.
        why: &'static str,
    },
}

/// Which channel layout to read.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Layout {
    /// Blender multilayer when `*.Combined.R` exists, else plain.
    #[default]
    Auto,
    /// `<Layer>.Combined.*`, `<Layer>.Depth.Z`, `<Layer>.Vector.*`.
    Blender,
    /// `R, G, B, A`, `Z`/`depth.Z`, `forward.u/v` or `motion.x/y`.
    Plain,
}

/// How to find the channels.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ChannelOptions {
    /// The layout.
    pub layout: Layout,
    /// Blender view layer name; needed only when the file holds several.
    pub layer: Option<String>,
    /// Plain layout: depth channel name (default: `Z`, then `depth.Z`).
    pub depth: Option<String>,
    /// Plain layout: forward motion channel names (x, y) (default: `forward.u/forward.v`, then
    /// `motion.x/motion.y`).
    pub motion: Option<(String, String)>,
    /// Plain layout: the motion's y axis points up (negate it).
    pub motion_y_up: bool,
}

/// Pixels a G-buffer holds beyond each side of the frame it is rendered for (OpenEXR's data
/// window larger than its display window): what a renderer's overscan adds so that light from
/// just outside the frame can blur into it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Overscan {
    /// Columns left of the frame, pixels.
    pub left: usize,
    /// Rows above the frame, pixels.
    pub top: usize,
    /// Columns right of the frame, pixels.
    pub right: usize,
    /// Rows below the frame, pixels.
    pub bottom: usize,
}

impl Overscan {
    /// No pixels beyond the frame.
    pub const NONE: Overscan = Overscan {
        left: 0,
        top: 0,
        right: 0,
        bottom: 0,
    };

    /// The same overscan on every side, pixels.
    pub fn uniform(px: usize) -> Self {
        Overscan {
            left: px,
            top: px,
            right: px,
            bottom: px,
        }
    }

    /// Whether there is any.
    pub fn is_none(&self) -> bool {
        *self == Overscan::NONE
    }
}

/// A pinhole G-buffer, all planes row-major from the top-left pixel of the data window (the
/// frame plus its [`Overscan`]).
#[derive(Clone, Debug, PartialEq)]
pub struct GBuffer {
    /// Width of the data window, pixels (the frame's width plus the left and right overscan).
    pub width: usize,
    /// Height of the data window, pixels (the frame's height plus the top and bottom overscan).
    pub height: usize,
    /// Pixels beyond the frame on each side; the output is the frame alone.
    pub overscan: Overscan,
    /// Linear premultiplied RGBA.
    pub color: Vec<[f32; 4]>,
    /// Planar depth in scene units, when the file has it.
    pub depth: Option<Vec<f32>>,
    /// Motion per frame at the frame time in pixels (x right, y down), when the file has it:
    /// the centred difference of the previous and next frames' positions where the file has
    /// both (Blender's vector pass), else the forward motion.
    pub motion: Option<Vec<[f32; 2]>>,
    /// Acceleration per frame squared at the frame time in pixels (x right, y down),
    /// `(next - now) + (previous - now)`, where the file has both of Blender's vectors for every
    /// moving pixel: with the motion it gives the path's bend over the shutter, also where the
    /// motion field itself moves (a rolling wheel). `None` where the file has the forward
    /// vector alone.
    pub acceleration: Option<Vec<[f32; 2]>>,
    /// Pixels whose colour was NaN or infinite, dropped (made transparent black).
    pub dropped_pixels: usize,
    /// The names of the channels in the file (for messages).
    pub channels_present: Vec<String>,
}

impl GBuffer {
    /// A G-buffer from planes already in memory; validates depth and motion and drops
    /// non-finite colours (counted), as the reader does.
    pub fn from_planes(
        width: usize,
        height: usize,
        color: Vec<[f32; 4]>,
        depth: Option<Vec<f32>>,
        motion: Option<Vec<[f32; 2]>>,
    ) -> Result<Self, GBufferError> {
        let mut g = GBuffer {
            width,
            height,
            overscan: Overscan::NONE,
            color,
            depth,
            motion,
            acceleration: None,
            dropped_pixels: 0,
            channels_present: Vec::new(),
        };
        g.sanitize("<memory>")?;
        Ok(g)
    }

    /// This G-buffer with each pixel's acceleration at the frame time (px per frame squared, x
    /// right, y down; see [`GBuffer::acceleration`]); an error for a plane of the wrong size or
    /// with a non-finite value.
    pub fn with_acceleration(mut self, acceleration: Vec<[f32; 2]>) -> Result<Self, GBufferError> {
        self.acceleration = Some(acceleration);
        self.sanitize("<memory>")?;
        Ok(self)
    }

    /// Declares the outer `overscan` pixels of this G-buffer to lie outside the frame (the
    /// frame is what remains inside); an error if nothing would remain.
    pub fn with_overscan(mut self, overscan: Overscan) -> Result<Self, GBufferError> {
        if overscan.left + overscan.right >= self.width
            || overscan.top + overscan.bottom >= self.height
        {
            return Err(GBufferError::Layout {
                path: "<memory>".into(),
                message: format!(
                    "an overscan of {overscan:?} leaves no frame inside {}x{} pixels",
                    self.width, self.height
                ),
            });
        }
        self.overscan = overscan;
        Ok(self)
    }

    /// Width of the frame (the display window), pixels.
    pub fn frame_width(&self) -> usize {
        self.width - self.overscan.left - self.overscan.right
    }

    /// Height of the frame (the display window), pixels.
    pub fn frame_height(&self) -> usize {
        self.height - self.overscan.top - self.overscan.bottom
    }

    /// The frame alone: the G-buffer without its overscan (for methods that cannot use it).
    pub fn frame_only(&self) -> GBuffer {
        if self.overscan.is_none() {
            return self.clone();
        }
        let (fw, fh) = (self.frame_width(), self.frame_height());
        let (x0, y0) = (self.overscan.left, self.overscan.top);
        let pick = |i: usize| (y0 + i / fw) * self.width + x0 + i % fw;
        GBuffer {
            width: fw,
            height: fh,
            overscan: Overscan::NONE,
            color: (0..fw * fh).map(|i| self.color[pick(i)]).collect(),
            depth: self
                .depth
                .as_ref()
                .map(|d| (0..fw * fh).map(|i| d[pick(i)]).collect()),
            motion: self
                .motion
                .as_ref()
                .map(|m| (0..fw * fh).map(|i| m[pick(i)]).collect()),
            acceleration: self
                .acceleration
                .as_ref()
                .map(|a| (0..fw * fh).map(|i| a[pick(i)]).collect()),
            dropped_pixels: self.dropped_pixels,
            channels_present: self.channels_present.clone(),
        }
    }

    /// Reads a G-buffer from an OpenEXR file.
    pub fn read_exr(path: &Path, options: &ChannelOptions) -> Result<Self, GBufferError> {
        Decoded::read_file(path)?.assemble(options)
    }

    /// Reads a G-buffer from the bytes of an OpenEXR file; `name` names it in messages.
    pub fn read_exr_bytes(
        bytes: &[u8],
        name: &str,
        options: &ChannelOptions,
    ) -> Result<Self, GBufferError> {
        let open = || Ok(std::io::Cursor::new(bytes));
        Self::decode_exr(name, bytes.len() as u64, open, options)
    }

    /// Decodes an OpenEXR from the source `open` gives (called twice: once for the header,
    /// checked before anything large is allocated, once for the pixels).
    fn decode_exr<R, F>(
        name: &str,
        file_len: u64,
        open: F,
        options: &ChannelOptions,
    ) -> Result<Self, GBufferError>
    where
        R: std::io::Read + std::io::Seek + Send,
        F: Fn() -> std::io::Result<R>,
    {
        let decoded = Decoded::read(name, file_len, open)?;
        decoded.assemble(options)
    }

    /// Reads the view layers of a Blender multi-view-layer EXR (`<Layer>.Combined.RGBA`,
    /// `<Layer>.Depth.Z`, `<Layer>.Vector.XYZW` per layer), decoding the file once: the layers
    /// named in `wanted`, in that order, or every layer that has Combined and Depth, in the
    /// file's (alphabetical) order (a file with one view layer: that layer). A file without
    /// Blender layers gives one layer named "".
    pub fn read_view_layers(
        path: &Path,
        wanted: Option<&[String]>,
    ) -> Result<Vec<ViewLayer>, GBufferError> {
        Decoded::read_file(path)?.view_layers(wanted)
    }

    /// Applies the bad-value policy (see the module documentation).
    fn sanitize(&mut self, name: &str) -> Result<(), GBufferError> {
        check_size(name, self.width, self.height)?;
        let n = self.width * self.height;
        let layout_err = |what: &str, len: usize| GBufferError::Layout {
            path: name.to_string(),
            message: format!("{what} has {len} values, the image {n} pixels"),
        };
        if self.color.len() != n {
            return Err(layout_err("colour", self.color.len()));
        }
        for px in &mut self.color {
            if px.iter().any(|v| !v.is_finite()) {
                *px = [0.0; 4];
                self.dropped_pixels += 1;
            }
        }
        let w = self.width;
        if let Some(depth) = &self.depth {
            if depth.len() != n {
                return Err(layout_err("depth", depth.len()));
            }
            if let Some(i) = depth.iter().position(|d| d.is_nan() || *d <= 0.0) {
                return Err(GBufferError::BadValue {
                    path: name.to_string(),
                    what: "depth",
                    x: i % w,
                    y: i / w,
                    value: depth[i],
                    why: "depth must be positive (or +inf)",
                });
            }
        }
        // Motion and acceleration: the frame's size, finite.
        let planes = [
            (&self.motion, "motion", "motion vectors must be finite"),
            (
                &self.acceleration,
                "acceleration",
                "accelerations must be finite",
            ),
        ];
        for (plane, what, why) in planes {
            let Some(plane) = plane else { continue };
            if plane.len() != n {
                return Err(layout_err(what, plane.len()));
            }
            if let Some(i) = plane
                .iter()
                .position(|m| !(m[0].is_finite() && m[1].is_finite()))
            {
                let m = plane[i];
                return Err(GBufferError::BadValue {
                    path: name.to_string(),
                    what,
                    x: i % w,
                    y: i / w,
                    value: if m[0].is_finite() { m[1] } else { m[0] },
                    why,
                });
            }
        }
        Ok(())
    }
}

/// A decoded OpenEXR: every part's channels by full name, before any plane is chosen.
struct Decoded {
    name: String,
    width: usize,
    height: usize,
    overscan: Overscan,
    channels: Vec<(String, Vec<f32>)>,
}

impl Decoded {
    fn read_file(path: &Path) -> Result<Self, GBufferError> {
        let name = path.display().to_string();
        let file_len = std::fs::metadata(path)
            .map_err(|e| GBufferError::Exr {
                path: name.clone(),
                message: e.to_string(),
            })?
            .len();
        let open = || std::fs::File::open(path).map(std::io::BufReader::new);
        Self::read(&name, file_len, open)
    }

    fn read<R, F>(name: &str, file_len: u64, open: F) -> Result<Self, GBufferError>
    where
        R: std::io::Read + std::io::Seek + Send,
        F: Fn() -> std::io::Result<R>,
    {
        use exr::prelude::*;
        let name = name.to_string();
        let exr_err = |e: exr::error::Error| GBufferError::Exr {
            path: name.clone(),
            message: e.to_string(),
        };
        let meta =
            exr::meta::MetaData::read_from_buffered(open().map_err(|e| exr_err(e.into()))?, false)
                .map_err(exr_err)?;
        check_header(&name, &meta, file_len)?;

        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .all_layers()
            .all_attributes()
            .from_buffered(open().map_err(|e| exr_err(e.into()))?)
            .map_err(exr_err)?;
        let first = image
            .layer_data
            .first()
            .ok_or_else(|| GBufferError::Layout {
                path: name.clone(),
                message: "the file has no image part".into(),
            })?;
        let (width, height) = (first.size.width(), first.size.height());
        check_size(&name, width, height)?;
        let overscan = overscan_of(
            &name,
            first.attributes.layer_position,
            first.size,
            image.attributes.display_window,
        )?;
        let channels = merged_channels(&name, image.layer_data)?;
        Ok(Decoded {
            name,
            width,
            height,
            overscan,
            channels,
        })
    }

    /// The G-buffer of the planes `options` select.
    fn assemble(&self, options: &ChannelOptions) -> Result<GBuffer, GBufferError> {
        let (name, width, height, overscan, channels) = (
            self.name.clone(),
            self.width,
            self.height,
            self.overscan,
            &self.channels,
        );
        let names: Vec<String> = channels.iter().map(|(n, _)| n.clone()).collect();
        let n = width * height;
        let (rgba, depth, motion, acceleration) = select_planes(&name, channels, options)?;
        // Sub-sampled channels (EXR x/y sampling above 1) hold fewer values than pixels.
        for plane in rgba.iter().flatten() {
            if plane.len() != n {
                return Err(GBufferError::Layout {
                    path: name.clone(),
                    message: format!(
                        "a colour channel has {} values for {n} pixels (sub-sampled channels \
                         are not supported)",
                        plane.len()
                    ),
                });
            }
        }
        let mut color = vec![[0.0f32, 0.0, 0.0, 1.0]; n];
        for (c, plane) in rgba.iter().enumerate() {
            if let Some(plane) = plane {
                for (px, &v) in color.iter_mut().zip(plane.iter()) {
                    px[c] = v;
                }
            }
        }
        let mut g = GBuffer {
            width,
            height,
            overscan,
            color,
            depth: depth.cloned(),
            motion,
            acceleration,
            dropped_pixels: 0,
            channels_present: names,
        };
        g.sanitize(&name)?;
        Ok(g)
    }

    /// The Blender view layers in the file (names of `<Layer>.Combined.R`).
    fn blender_layers(&self) -> Vec<String> {
        self.channels
            .iter()
            .filter_map(|(n, _)| n.strip_suffix(".Combined.R").map(str::to_string))
            .collect()
    }

    fn view_layers(&self, wanted: Option<&[String]>) -> Result<Vec<ViewLayer>, GBufferError> {
        let present = self.blender_layers();
        if present.is_empty() {
            if let Some(w) = wanted.filter(|w| !w.is_empty()) {
                return Err(GBufferError::Layout {
                    path: self.name.clone(),
                    message: format!(
                        "view layers {} were asked for, but the file has no Blender view layers",
                        w.join(", ")
                    ),
                });
            }
            let gbuffer = self.assemble(&ChannelOptions::default())?;
            return Ok(vec![ViewLayer::new(String::new(), gbuffer)]);
        }
        let has = |layer: &str, pass: &str| {
            let full = format!("{layer}.{pass}");
            self.channels.iter().any(|(n, _)| *n == full)
        };
        let names: Vec<String> = match wanted {
            Some(w) => {
                for l in w {
                    if !present.contains(l) {
                        return Err(GBufferError::Layout {
                            path: self.name.clone(),
                            message: format!(
                                "no view layer {l:?}; the file has {}",
                                present.join(", ")
                            ),
                        });
                    }
                }
                w.to_vec()
            }
            // One layer is the input whatever its passes (motion blur alone needs no depth).
            None if present.len() == 1 => present.clone(),
            None => present
                .iter()
                .filter(|l| has(l, "Depth.Z"))
                .cloned()
                .collect(),
        };
        if names.is_empty() {
            return Err(GBufferError::Layout {
                path: self.name.clone(),
                message: format!(
                    "none of the view layers ({}) has a Depth pass",
                    present.join(", ")
                ),
            });
        }
        names
            .into_iter()
            .map(|layer| {
                let options = ChannelOptions {
                    layout: Layout::Blender,
                    layer: Some(layer.clone()),
                    ..ChannelOptions::default()
                };
                Ok(ViewLayer::new(layer, self.assemble(&options)?))
            })
            .collect()
    }
}

/// One render layer of a layered input: its name (the artist's view layer name, or the file's)
/// and its G-buffer. `still` declares a layer without motion vectors to be still.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewLayer {
    /// The layer's name (empty for a plain file).
    pub name: String,
    /// Its pixels.
    pub gbuffer: GBuffer,
    /// Declared still: no motion vectors needed even when the frame has motion.
    pub still: bool,
}

impl ViewLayer {
    /// A layer that is not declared still.
    pub fn new(name: String, gbuffer: GBuffer) -> Self {
        Self {
            name,
            gbuffer,
            still: false,
        }
    }
}

/// The channels of every part of a decoded file, by full name. Multi-part files (Blender 5
/// writes one part per pass: `ViewLayer.Combined`, `ViewLayer.Depth`, ...) must have every
/// part on the same data window; a channel named without its part's name (`Z` in the part
/// `ViewLayer.Depth`) gets it as a prefix, so both spellings read alike.
fn merged_channels(
    name: &str,
    layers: exr::image::Layers<exr::image::AnyChannels<exr::image::FlatSamples>>,
) -> Result<Vec<(String, Vec<f32>)>, GBufferError> {
    let Some(first) = layers.first() else {
        return Ok(Vec::new());
    };
    let (first_size, first_position) = (first.size, first.attributes.layer_position);
    let parts = layers.len();
    let mut channels: Vec<(String, Vec<f32>)> = Vec::new();
    for layer in layers {
        let part = layer.attributes.layer_name.as_ref().map(|t| t.to_string());
        if layer.size != first_size || layer.attributes.layer_position != first_position {
            return Err(GBufferError::Layout {
                path: name.to_string(),
                message: format!(
                    "part {:?} is {}x{} pixels at {:?}, the first part {}x{} at {:?}: every \
                     part must cover the same pixels",
                    part.as_deref().unwrap_or(""),
                    layer.size.width(),
                    layer.size.height(),
                    layer.attributes.layer_position,
                    first_size.width(),
                    first_size.height(),
                    first_position
                ),
            });
        }
        for c in layer.channel_data.list {
            let short = c.name.to_string();
            let full = match &part {
                Some(p) if parts > 1 && !short.starts_with(&format!("{p}.")) => {
                    format!("{p}.{short}")
                }
                _ => short,
            };
            if channels.iter().any(|(n, _)| *n == full) {
                return Err(GBufferError::Layout {
                    path: name.to_string(),
                    message: format!("channel {full} is in two parts"),
                });
            }
            let samples = match c.sample_data {
                // Already f32: moved, not copied.
                exr::image::FlatSamples::F32(values) => values,
                other => other.values_as_f32().collect(),
            };
            channels.push((full, samples));
        }
    }
    Ok(channels)
}

/// Borrowed planes of a decoded file: colour (R, G, B, optional A), depth, motion and
/// acceleration.
type Planes<'a> = (
    [Option<&'a Vec<f32>>; 4],
    Option<&'a Vec<f32>>,
    Option<Vec<[f32; 2]>>,
    Option<Vec<[f32; 2]>>,
);

/// Checks the declared size before anything is decoded (a huge size in a tiny file): every
/// part's pixel count, the samples the decoder would allocate (pixels x channels), and what the
/// file's compression could expand to.
fn check_header(name: &str, meta: &exr::meta::MetaData, file_len: u64) -> Result<(), GBufferError> {
    let name = name.to_string();
    let header = meta.headers.first().ok_or_else(|| GBufferError::Layout {
        path: name.clone(),
        message: "the file has no image part".into(),
    })?;
    let size = header.layer_size;
    check_size(&name, size.width(), size.height())?;
    let mut samples = 0usize;
    for h in meta.headers.iter() {
        let (w, ht) = (h.layer_size.width(), h.layer_size.height());
        check_size(&name, w, ht)?;
        samples = samples.saturating_add((w * ht).saturating_mul(h.channels.list.len()));
    }
    if samples > MAX_SAMPLES {
        return Err(GBufferError::Layout {
            path: name.clone(),
            message: format!(
                "the file declares {samples} samples (pixels x channels over all parts), \
                 more than the limit of {MAX_SAMPLES}"
            ),
        });
    }
    crate::exr_io::check_expansion(meta, file_len).map_err(|message| GBufferError::Layout {
        path: name.clone(),
        message,
    })?;

    Ok(())
}

/// The motion per frame at the frame time (px, x right, y down) of one pixel of Blender's
/// vector pass `[X, Y, Z, W]` (y up; `X, Y` = previous minus now, `Z, W` = now minus next):
/// the tangent, half the step from the previous frame's position to the next one's,
/// `((-Z - X) / 2, (W + Y) / 2)`. A point turning about a centre moves along its chord to the
/// next frame, `(-Z, W)`, which leans inward by half the turn; drawn along that, a spinning
/// rim's streaks leave it. A pixel whose backward vector is exactly zero keeps the forward one:
/// writers that fill only the forward vector leave it so.
pub fn blender_motion(v: [f32; 4]) -> [f32; 2] {
    let [x, y, z, w] = v;
    if x == 0.0 && y == 0.0 {
        [-z, w]
    } else {
        [0.5 * (-z - x), 0.5 * (w + y)]
    }
}

/// The acceleration per frame squared at the frame time (px, x right, y down) of one pixel of
/// Blender's vector pass `[X, Y, Z, W]`: `(next - now) + (previous - now) = (X - Z, W - Y)`.
pub fn blender_acceleration(v: [f32; 4]) -> [f32; 2] {
    let [x, y, z, w] = v;
    [x - z, w - y]
}

/// Whether a pixel of Blender's vector pass moves forward with no backward vector: the mark of
/// a file that fills only the forward one.
fn fills_only_forward(v: [f32; 4]) -> bool {
    let [x, y, z, w] = v;
    x == 0.0 && y == 0.0 && (z != 0.0 || w != 0.0)
}

/// The colour planes (R, G, B and A when present), depth and forward motion (pixels per frame,
/// x right, y down) of a decoded file, found by the layout `options` ask for.
fn select_planes<'a>(
    name: &str,
    channels: &'a [(String, Vec<f32>)],
    options: &ChannelOptions,
) -> Result<Planes<'a>, GBufferError> {
    let names: Vec<String> = channels.iter().map(|(n, _)| n.clone()).collect();
    let name = name.to_string();
    let find = |n: &str| channels.iter().find(|(c, _)| c == n).map(|(_, d)| d);
    let missing = |m: String| GBufferError::MissingChannel {
        path: name.clone(),
        missing: m,
        present: names.join(", "),
    };

    let blender_layers: Vec<String> = names
        .iter()
        .filter_map(|n| n.strip_suffix(".Combined.R").map(str::to_string))
        .collect();
    let layout = match options.layout {
        Layout::Auto if !blender_layers.is_empty() => Layout::Blender,
        Layout::Auto => Layout::Plain,
        l => l,
    };

    let planes = match layout {
        Layout::Blender => {
            let prefix = match &options.layer {
                Some(l) => {
                    if !blender_layers.contains(l) {
                        return Err(missing(format!("{l}.Combined.R")));
                    }
                    l.clone()
                }
                None => match blender_layers.as_slice() {
                    [one] => one.clone(),
                    [] => return Err(missing("<Layer>.Combined.R".into())),
                    many => {
                        return Err(GBufferError::Layout {
                            path: name.clone(),
                            message: format!(
                                "several view layers ({}); choose one with --layer",
                                many.join(", ")
                            ),
                        })
                    }
                },
            };
            let get = |suffix: &str| {
                let full = format!("{prefix}.{suffix}");
                find(&full).ok_or_else(|| missing(full))
            };
            let rgba = [
                Some(get("Combined.R")?),
                Some(get("Combined.G")?),
                Some(get("Combined.B")?),
                get("Combined.A").ok(),
            ];
            let depth = get("Depth.Z").ok();
            let forward = get("Vector.Z").ok().zip(get("Vector.W").ok());
            let backward = get("Vector.X").ok().zip(get("Vector.Y").ok());
            let (motion, acceleration) = match forward {
                None => (None, None),
                Some((z, w)) => {
                    // Each pixel's `[X, Y, Z, W]`, a missing backward vector read as zero.
                    let vector = |i: usize| {
                        let (x, y) = backward.map_or((0.0, 0.0), |(x, y)| (x[i], y[i]));
                        [x, y, z[i], w[i]]
                    };
                    // The shortest plane's length: a plane short of the frame is then a
                    // wrong-sized motion, which the checks name, rather than a read past its end.
                    let n = backward
                        .map_or(usize::MAX, |(x, y)| x.len().min(y.len()))
                        .min(z.len())
                        .min(w.len());
                    let motion = (0..n).map(|i| blender_motion(vector(i))).collect();
                    // Only where every moving pixel has both vectors.
                    let both = backward.is_some() && !(0..n).any(|i| fills_only_forward(vector(i)));
                    let acceleration =
                        both.then(|| (0..n).map(|i| blender_acceleration(vector(i))).collect());
                    (Some(motion), acceleration)
                }
            };
            (rgba, depth, motion, acceleration)
        }
        Layout::Plain | Layout::Auto => {
            let get = |c: &str| find(c).ok_or_else(|| missing(c.to_string()));
            let rgba = [Some(get("R")?), Some(get("G")?), Some(get("B")?), find("A")];
            let depth = match &options.depth {
                Some(d) => Some(get(d)?),
                None => find("Z").or_else(|| find("depth.Z")),
            };
            let pair = match &options.motion {
                Some((x, y)) => Some((get(x)?, get(y)?)),
                None => find("forward.u")
                    .zip(find("forward.v"))
                    .or_else(|| find("motion.x").zip(find("motion.y"))),
            };
            let flip = if options.motion_y_up { -1.0 } else { 1.0 };
            let motion = pair.map(|(u, v)| {
                u.iter()
                    .zip(v.iter())
                    .map(|(&u, &v)| [u, flip * v])
                    .collect::<Vec<_>>()
            });
            (rgba, depth, motion, None)
        }
    };
    Ok(planes)
}

/// The overscan of a data window (origin `data_origin`, `data_size` pixels) around a display
/// window; an error naming both windows when the data does not cover the whole frame.
fn overscan_of(
    name: &str,
    data_origin: exr::math::Vec2<i32>,
    data_size: exr::math::Vec2<usize>,
    display: exr::meta::attribute::IntegerBounds,
) -> Result<Overscan, GBufferError> {
    let (dx0, dy0) = (i64::from(data_origin.x()), i64::from(data_origin.y()));
    let (dx1, dy1) = (
        dx0 + data_size.width() as i64,
        dy0 + data_size.height() as i64,
    );
    let (fx0, fy0) = (
        i64::from(display.position.x()),
        i64::from(display.position.y()),
    );
    let (fx1, fy1) = (
        fx0 + display.size.width() as i64,
        fy0 + display.size.height() as i64,
    );
    let sides = [fx0 - dx0, fy0 - dy0, dx1 - fx1, dy1 - fy1];
    if sides.iter().any(|&s| s < 0) || display.size.width() == 0 || display.size.height() == 0 {
        return Err(GBufferError::Layout {
            path: name.to_string(),
            message: format!(
                "the data window ({dx0}, {dy0})..({dx1}, {dy1}) does not cover the display \
                 window ({fx0}, {fy0})..({fx1}, {fy1}); render the whole frame (a crop or \
                 border render cannot be blurred correctly)"
            ),
        });
    }
    Ok(Overscan {
        left: sides[0] as usize,
        top: sides[1] as usize,
        right: sides[2] as usize,
        bottom: sides[3] as usize,
    })
}

fn check_size(name: &str, width: usize, height: usize) -> Result<(), GBufferError> {
    let err = |reason| GBufferError::Size {
        path: name.to_string(),
        width,
        height,
        reason,
    };
    if width == 0 || height == 0 {
        return Err(err("empty"));
    }
    if width.checked_mul(height).is_none_or(|n| n > MAX_PIXELS) {
        return Err(err("larger than the limit of 8192x8192 pixels"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nan_colour_is_dropped_and_nan_depth_is_an_error() {
        let color = vec![[1.0, f32::NAN, 0.0, 1.0], [0.5, 0.5, 0.5, 1.0]];
        let g =
            GBuffer::from_planes(2, 1, color.clone(), Some(vec![1.0, 2.0]), None).expect("valid");
        assert_eq!(g.dropped_pixels, 1);
        assert_eq!(g.color[0], [0.0; 4]);
        let err = GBuffer::from_planes(2, 1, color.clone(), Some(vec![1.0, f32::NAN]), None)
            .expect_err("nan depth");
        assert!(err.to_string().contains("(1, 0)"), "{err}");
        assert!(GBuffer::from_planes(2, 1, color.clone(), Some(vec![0.0, 1.0]), None).is_err());
        assert!(GBuffer::from_planes(2, 1, color, Some(vec![f32::INFINITY, 1.0]), None).is_ok());
        assert!(GBuffer::from_planes(0, 1, vec![], None, None).is_err());
    }

    /// A Blender-style G-buffer as EXR bytes: one part holding every channel, or (as Blender 5
    /// writes it) one part per pass named `ViewLayer.<Pass>`; `short_names` writes the
    /// channels of a part without the part's name (`Z` in `ViewLayer.Depth`).
    fn blender_exr(parts: bool, short_names: bool, depth_size: (usize, usize)) -> Vec<u8> {
        use exr::prelude::*;
        let (w, h) = (4usize, 3usize);
        let plane = |seed: f32, n: usize| -> Vec<f32> { (0..n).map(|i| seed + i as f32).collect() };
        let pass = |name: &str, chans: &[&str], size: (usize, usize)| {
            let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = chans
                .iter()
                .enumerate()
                .map(|(k, c)| {
                    let full = if short_names {
                        c.to_string()
                    } else {
                        format!("{name}.{c}")
                    };
                    AnyChannel::new(
                        Text::from(full.as_str()),
                        FlatSamples::F32(plane(1.0 + k as f32, size.0 * size.1)),
                    )
                })
                .collect();
            let attributes = LayerAttributes::named(Text::from(name));
            Layer::new(
                size,
                attributes,
                Encoding::UNCOMPRESSED,
                AnyChannels::sort(list),
            )
        };
        let combined = ["R", "G", "B", "A"];
        let layers = if parts {
            vec![
                pass("ViewLayer.Combined", &combined, (w, h)),
                pass("ViewLayer.Depth", &["Z"], depth_size),
            ]
        } else {
            let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
            for (k, c) in combined.iter().enumerate() {
                list.push(AnyChannel::new(
                    Text::from(format!("ViewLayer.Combined.{c}").as_str()),
                    FlatSamples::F32(plane(1.0 + k as f32, w * h)),
                ));
            }
            list.push(AnyChannel::new(
                Text::from("ViewLayer.Depth.Z"),
                FlatSamples::F32(plane(1.0, w * h)),
            ));
            vec![Layer::new(
                (w, h),
                LayerAttributes::default(),
                Encoding::UNCOMPRESSED,
                AnyChannels::sort(list),
            )]
        };
        let image = Image::from_layers(
            ImageAttributes::new(IntegerBounds::from_dimensions((w, h))),
            SmallVec::<[_; 2]>::from_vec(layers),
        );
        let mut bytes = std::io::Cursor::new(Vec::new());
        image.write().to_buffered(&mut bytes).expect("write");
        bytes.into_inner()
    }

    /// Blender's vector pass gives the motion at the frame time, the centred difference of the
    /// previous and next positions: for a point turning about a centre, the tangent, where the
    /// forward vector alone is the chord to the next frame. A pixel without a backward vector,
    /// and a file without one, keep the forward motion.
    #[test]
    fn the_vector_pass_gives_the_centred_motion() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("g.exr");
        let ones = vec![1.0f32; 2];
        let mut channels: Vec<(String, Vec<f32>)> = ["R", "G", "B", "A"]
            .iter()
            .map(|c| (format!("ViewLayer.Combined.{c}"), ones.clone()))
            .collect();
        // Pixel 0 (x right, y down): previous frame at (-4, 1) from now, next at (4, 1): the
        // path bends downwards and its tangent now is (4, 0). In Blender's signs (y up):
        // X, Y = previous - now, Z, W = now - next.
        // Pixel 1: no backward vector, forward (2, 3).
        channels.push(("ViewLayer.Vector.Z".to_string(), vec![-4.0, -2.0]));
        channels.push(("ViewLayer.Vector.W".to_string(), vec![1.0, 3.0]));
        let without_backward = channels.clone();
        channels.push(("ViewLayer.Vector.X".to_string(), vec![-4.0, 0.0]));
        channels.push(("ViewLayer.Vector.Y".to_string(), vec![-1.0, 0.0]));
        let options = ChannelOptions::default();
        crate::exr_io::write_channels(&path, 2, 1, channels.clone(), None).expect("write");
        let g = GBuffer::read_exr(&path, &options).expect("read");
        assert_eq!(g.motion, Some(vec![[4.0, 0.0], [2.0, 3.0]]));
        // Pixel 1 moves with no backward vector: the file fills only the forward one.
        assert_eq!(g.acceleration, None);
        // Both vectors on every moving pixel: pixel 0's path bends downwards by 2 px per
        // frame squared.
        let mut both = channels;
        for (name, plane) in both.iter_mut() {
            if name.ends_with("Vector.X") || name.ends_with("Vector.Y") {
                // Pixel 1 moving steadily: previous - now = -(2, 3), so X = -2, Y = 3.
                plane[1] = if name.ends_with('X') { -2.0 } else { 3.0 };
            }
        }
        crate::exr_io::write_channels(&path, 2, 1, both, None).expect("write");
        let g = GBuffer::read_exr(&path, &options).expect("read");
        assert_eq!(g.acceleration, Some(vec![[0.0, 2.0], [0.0, 0.0]]));
        crate::exr_io::write_channels(&path, 2, 1, without_backward, None).expect("write");
        let g = GBuffer::read_exr(&path, &options).expect("read");
        assert_eq!(g.motion, Some(vec![[4.0, 1.0], [2.0, 3.0]]));
    }

    #[test]
    fn a_multi_part_file_reads_like_the_single_part_one() {
        let options = ChannelOptions::default();
        let single = GBuffer::read_exr_bytes(&blender_exr(false, false, (4, 3)), "one", &options)
            .expect("one part");
        for short_names in [false, true] {
            let parts = blender_exr(true, short_names, (4, 3));
            let multi = GBuffer::read_exr_bytes(&parts, "parts", &options).expect("parts");
            assert_eq!(multi.color, single.color, "short names: {short_names}");
            assert_eq!(multi.depth, single.depth, "short names: {short_names}");
            assert!(multi.depth.is_some());
        }
        let err = GBuffer::read_exr_bytes(&blender_exr(true, false, (2, 3)), "bad", &options)
            .expect_err("parts of different sizes");
        assert!(err.to_string().contains("ViewLayer.Depth"), "{err}");
        assert!(err.to_string().contains("same pixels"), "{err}");
    }
}
