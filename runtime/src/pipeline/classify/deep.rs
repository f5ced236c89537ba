//! Deep images as input: every deep sample is a fragment with its own colour, alpha, depth and
//! motion, so an anti-aliased edge's sub-pixel surfaces and every layer of a semi-transparent
//! one blur with their own PSFs. A pixel's samples are composited "over" one another front to
//! back (OpenEXR's deep semantics): where two of them land in the same depth layer the nearer
//! occludes the farther there ([`Fragment::source`] is the sample's index), across layers the
//! compositing does.

use formats::DeepImage;

use super::{
    classify_fragments, resolve_model, Classified, ClassifyError, ClassifyOptions, DataWindow,
    Effects, Fragment, PathCounts,
};
use crate::camera::Camera;
use crate::dbset::DbSet;

/// What `camera` and `deep` call for: depth of field from the lens, motion blur when the
/// shutter is open and some sample moves.
pub fn deep_effects(deep: &DeepImage, camera: &Camera) -> Effects {
    Effects {
        defocus: camera.has_lens(),
        motion: camera.has_shutter()
            && deep.has_motion
            && deep
                .samples
                .iter()
                .any(|s| s.motion[0] != 0.0 || s.motion[1] != 0.0),
    }
}

/// Checks that the deep image's frame (without its overscan) is the camera's.
pub fn check_deep_size(deep: &DeepImage, camera: &Camera) -> Result<(), ClassifyError> {
    super::check_frame_size(deep.frame_width(), deep.frame_height(), camera)
}

/// The fragments of a deep image: one per sample, at its pixel (frame coordinates), with the
/// depth of its front (`Z`) and its motion over the shutter.
pub fn deep_fragments(deep: &DeepImage, camera: &Camera, effects: Effects) -> Vec<Fragment> {
    let shutter = camera.shutter_frames as f32;
    let (left, top) = (deep.overscan.left as i32, deep.overscan.top as i32);
    let mut fragments = Vec::with_capacity(deep.samples.len());
    for y in 0..deep.height {
        for x in 0..deep.width {
            for (k, s) in (0u32..).zip(deep.pixel(x, y)) {
                if s.color == [0.0; 4] {
                    continue;
                }
                let motion = if effects.motion {
                    [s.motion[0] * shutter, s.motion[1] * shutter]
                } else {
                    [0.0; 2]
                };
                fragments.push(Fragment {
                    x: x as i32 - left,
                    y: y as i32 - top,
                    color: s.color,
                    weight: 1.0,
                    parallax: if s.depth.is_finite() {
                        1.0 / s.depth
                    } else {
                        0.0
                    },
                    depth: s.depth,
                    motion,
                    bend: 0.0,
                    source: k,
                });
            }
        }
    }
    fragments
}

/// The background hidden behind sharper occluders and moving ones, continued from the visible
/// background beside them (but for a background brighter than `hdr_threshold` behind a moving
/// one), as for a flat G-buffer ([`super::hidden::hidden_background`]): deep data holds
/// what shows through an edge or a transparent surface, not what an opaque one hides. Each
/// pixel stands for its dominant sample (the one contributing most after "over") when deciding
/// what is nearer and sharper; a pixel with several visible samples (an edge) is treated as
/// a split edge pixel; the copies are of a background pixel's farthest sample, behind every
/// sample of the pixels they fill (their source is past any sample index).
fn hidden_behind_deep(
    deep: &DeepImage,
    camera: &Camera,
    fragments: &[Fragment],
    motion_blur: bool,
    hdr_threshold: f32,
) -> Vec<Fragment> {
    if fragments.is_empty() {
        return Vec::new();
    }
    let n = deep.width * deep.height;
    let lens = camera.thin_lens();
    let signed_coc = |d: f32| -> f32 { lens.map_or(0.0, |l| l.signed_coc_px(f64::from(d)) as f32) };
    let flat = deep.flatten();
    let mut depth = vec![f32::INFINITY; n];
    let mut motion = vec![[0.0f32; 2]; n];
    let mut several = vec![false; n];
    let shutter = camera.shutter_frames as f32;
    for i in 0..n {
        let samples = &deep.samples[deep.offsets[i]..deep.offsets[i + 1]];
        let mut through = 1.0f32;
        let mut best = (0.0f32, f32::INFINITY, [0.0f32; 2]);
        let mut visible = 0;
        for s in samples {
            let share = through * s.color[3];
            if share > 0.02 {
                visible += 1;
            }
            if share > best.0 {
                best = (share, s.depth, s.motion);
            }
            through *= 1.0 - s.color[3];
        }
        depth[i] = best.1;
        motion[i] = best.2.map(|m| m * shutter);
        several[i] = visible > 1;
    }
    let proxy = crate::gbuffer::GBuffer {
        width: deep.width,
        height: deep.height,
        overscan: deep.overscan,
        color: flat,
        depth: None,
        motion: None,
        acceleration: None,
        dropped_pixels: 0,
        channels_present: Vec::new(),
    };
    // Each pixel's farthest fragment ([`deep_fragments`] keeps pixel order, front to back).
    let mut farthest: Vec<Option<usize>> = vec![None; n];
    let (left, top) = (deep.overscan.left as i32, deep.overscan.top as i32);
    for (k, f) in fragments.iter().enumerate() {
        let i = (f.y + top) as usize * deep.width + (f.x + left) as usize;
        farthest[i] = Some(k);
    }
    let depth_at = |i: usize| depth[i];
    let coc_at = |i: usize| signed_coc(depth[i]);
    // Walks start only at pixels with colour, which have a fragment; a pixel without one
    // would give a fragment of no weight.
    let own = |i: usize| match farthest[i] {
        Some(k) => Fragment {
            source: super::hidden::HIDDEN_SOURCE,
            ..fragments[k]
        },
        None => Fragment {
            weight: 0.0,
            source: super::hidden::HIDDEN_SOURCE,
            ..fragments[0]
        },
    };
    // Behind sharper occluders, and behind opaque ones that move more along the walk than the
    // background, as for a flat G-buffer: a deep image seen through a pinhole at the frame time
    // holds what shows through a silhouette's own pixels, not the background that a moving
    // occluder's smear uncovers beyond them. (Blurrier by defocus alone is left to the deep
    // samples, as before.) A background brighter than `hdr_threshold` is not continued behind
    // a moving occluder, as on a flat G-buffer: a small emitter does not go on behind what
    // passes in front of it.
    let blur_along = |i: usize, d: (i32, i32)| -> f32 {
        let m = if motion_blur { motion[i] } else { [0.0; 2] };
        0.5 * (m[0] * d.0 as f32 + m[1] * d.1 as f32).abs()
    };
    super::hidden::hidden_background(
        &proxy,
        &several,
        &[],
        &coc_at,
        &depth_at,
        &|i: usize| if motion_blur { motion[i] } else { [0.0; 2] },
        &blur_along,
        hdr_threshold,
        &own,
    )
}

/// Classifies a deep image: its samples as fragments ([`deep_fragments`]), layered and
/// turned into splat records as a G-buffer's pixels are.
pub fn classify_deep(
    deep: &DeepImage,
    camera: &Camera,
    dbs: &DbSet,
    options: &ClassifyOptions,
) -> Result<Classified, ClassifyError> {
    classify_deep_with(deep, camera, deep_effects(deep, camera), dbs, options)
}

/// [`classify_deep`] with the effects already found ([`deep_effects`]).
pub(crate) fn classify_deep_with(
    deep: &DeepImage,
    camera: &Camera,
    effects: Effects,
    dbs: &DbSet,
    options: &ClassifyOptions,
) -> Result<Classified, ClassifyError> {
    check_deep_size(deep, camera)?;
    let model = resolve_model(effects, dbs, options.smear_motion)?;
    let mut fragments = deep_fragments(deep, camera, effects);
    let mut counts = PathCounts {
        dropped: deep.dropped_samples,
        ..PathCounts::default()
    };
    if options.fill_hidden && model.is_some() {
        let filled = hidden_behind_deep(
            deep,
            camera,
            &fragments,
            effects.motion,
            options.hdr_dense_threshold,
        );
        counts.hidden_filled += filled.len();
        fragments.extend(filled);
    }
    // A deep pixel's samples are not one surface per source: nothing to continue.
    let options = &ClassifyOptions {
        continue_layers: false,
        ..options.clone()
    };
    let o = deep.overscan;
    let data = DataWindow {
        x0: -(o.left as i32),
        y0: -(o.top as i32),
        x1: (deep.width - o.left) as i32 - 1,
        y1: (deep.height - o.top) as i32 - 1,
    };
    classify_fragments(
        fragments,
        deep.frame_width(),
        deep.frame_height(),
        data,
        camera,
        dbs,
        model,
        options,
        counts,
    )
}
