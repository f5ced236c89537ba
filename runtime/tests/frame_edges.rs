//! What a compositor sees at the frame's edges and around bright highlights: a blurred wall
//! keeps its brightness up to the border, overscan pixels blur into the frame, and the
//! anti-aliased rim of an HDR emitter is not blurred as the background behind it.

mod support;

use formats::image::RgbaImage;
use psf_db::PsfModel;
use spreadlet::camera::Camera;
use spreadlet::dbset::DbSet;
use spreadlet::gbuffer::{ChannelOptions, GBuffer, Overscan};
use spreadlet::pipeline::{ClassifyOptions, FrameEdges, Integrator};
use spreadlet::synth::{synthesize, SynthOptions};
use support::{camera, depth_for_coc, test_db};

fn thin_lens() -> DbSet {
    DbSet::single(test_db(PsfModel::ThinLens).clone()).expect("set")
}

/// The options of `spreadlet synth` (exact integration) with the given frame edges.
fn with_edges(frame_edges: FrameEdges) -> SynthOptions {
    SynthOptions {
        classify: ClassifyOptions {
            frame_edges,
            ..ClassifyOptions::default()
        },
        integrator: Integrator::Exact,
        ..SynthOptions::default()
    }
}

/// A camera of `n x n` pixels focused close (0.2 m, f/1.4, 50 mm on a 9 mm sensor), so that a
/// wall behind the focus plane can be far out of focus.
fn close_focus_camera(n: u32) -> Camera {
    Camera {
        sensor_width_mm: 9.0,
        f_stop: Some(1.4),
        focus_distance: Some(0.2),
        ..camera(n, n, true, 0.0)
    }
}

/// The depth (scene units) behind the focus plane at which `camera` gives a CoC radius of
/// `coc_px`: the signed radius `k (1 - s / d)` solved for `d`.
fn depth_behind_focus(camera: &Camera, coc_px: f64) -> f32 {
    let lens = camera.thin_lens().expect("lens");
    assert!(
        coc_px < lens.coc_scale_px,
        "no depth behind focus blurs that much"
    );
    (lens.focus_distance / (1.0 - coc_px / lens.coc_scale_px)) as f32
}

/// A uniform grey wall far out of focus (CoC radius 10 px) filling a 64x64 frame.
fn grey_wall(n: usize, grey: f32, coc_px: f64) -> (GBuffer, spreadlet::camera::Camera) {
    let cam = camera(n as u32, n as u32, true, 0.0);
    let depth = depth_for_coc(&cam, coc_px) as f32;
    let g = GBuffer::from_planes(
        n,
        n,
        vec![[grey, grey, grey, 1.0]; n * n],
        Some(vec![depth; n * n]),
        None,
    )
    .expect("g-buffer");
    (g, cam)
}

#[test]
fn a_blurred_wall_keeps_its_brightness_to_the_frame_edges_and_corners() {
    let (n, grey) = (64, 0.5f32);
    let (g, cam) = grey_wall(n, grey, 10.0);
    let dbs = thin_lens();
    let (out, stats) =
        synthesize(&g, &cam, &dbs, &with_edges(FrameEdges::Extend)).expect("synthesis");
    assert_eq!(stats.frame_edges, FrameEdges::Extend);
    assert!(stats.counts.edge_extended > 0, "{:?}", stats.counts);
    for (i, p) in out.pixels.iter().enumerate() {
        for &v in &p[..3] {
            assert!(
                (v / grey - 1.0).abs() < 0.01,
                "pixel ({}, {}) is {v}, not within 1 % of {grey}",
                i % n,
                i / n
            );
        }
    }
    // Without the extension the border loses light: the corner keeps about a quarter.
    let (black, _) = synthesize(&g, &cam, &dbs, &with_edges(FrameEdges::Black)).expect("synthesis");
    let corner = black.pixels[0][0];
    assert!(
        corner < 0.5 * grey,
        "corner {corner}: black edges should lose light"
    );
    let side = black.pixels[(n / 2) * n][0];
    assert!(
        side < 0.75 * grey,
        "left edge {side}: black edges should lose light"
    );
}

/// Rows `[y0, y1)` and columns `[x0, x1)` of an image, flattened RGB.
fn mean_luminance(img: &RgbaImage, x0: usize, x1: usize, y0: usize, y1: usize) -> f64 {
    let mut sum = 0.0f64;
    for y in y0..y1 {
        for x in x0..x1 {
            let p = img.at(x, y);
            sum += 0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]);
        }
    }
    sum / ((x1 - x0) * (y1 - y0)) as f64
}

#[test]
fn overscan_pixels_blur_into_the_frame_as_in_a_larger_render() {
    // A bright light 4 px outside the right edge of a 48x48 frame, whose 8-px bokeh reaches
    // into it, in front of a dim wall.
    let (n, over) = (48usize, 16usize);
    let big = n + 2 * over;
    let cam = camera(n as u32, n as u32, true, 0.0);
    let mut big_cam = cam.clone();
    big_cam.width = big as u32;
    big_cam.height = big as u32;
    big_cam.sensor_width_mm *= big as f64 / n as f64;
    let wall = depth_for_coc(&cam, 3.0) as f32;
    let light = depth_for_coc(&cam, 8.0) as f32;
    let mut color = vec![[0.05f32, 0.05, 0.05, 1.0]; big * big];
    let mut depth = vec![wall; big * big];
    let (lx, ly) = (over + n + 3, over + n / 2);
    for dy in 0..2 {
        for dx in 0..2 {
            color[(ly + dy) * big + lx + dx] = [40.0, 30.0, 12.0, 1.0];
            depth[(ly + dy) * big + lx + dx] = light;
        }
    }
    let full = GBuffer::from_planes(big, big, color, Some(depth), None).expect("g-buffer");
    let framed = full
        .clone()
        .with_overscan(Overscan::uniform(over))
        .expect("overscan");
    assert_eq!((framed.frame_width(), framed.frame_height()), (n, n));
    let dbs = thin_lens();
    let mut options = with_edges(FrameEdges::Extend);
    // The continuous lookup's dither is anchored to the frame's own pixel grid, which the
    // large frame shifts; compare the same PSFs.
    options.classify.continuous_lookup = false;
    let (out, stats) = synthesize(&framed, &cam, &dbs, &options).expect("synthesis");
    assert_eq!((out.width, out.height), (n, n));
    assert_eq!(stats.overscan, Overscan::uniform(over));
    // The same pixels rendered as one large frame, cropped: what the frame should show.
    let (whole, _) = synthesize(&full, &big_cam, &dbs, &options).expect("synthesis");
    let mut max_diff = 0.0f32;
    for y in 0..n {
        for x in 0..n {
            let (a, b) = (out.at(x, y), whole.at(x + over, y + over));
            for c in 0..4 {
                max_diff = max_diff.max((a[c] - b[c]).abs());
            }
        }
    }
    assert!(
        max_diff < 1e-3,
        "overscan result differs from the large frame by {max_diff}"
    );
    // The light's bokeh is in the frame's right band, and without the overscan it is not.
    let band = mean_luminance(&out, n - 4, n, n / 2 - 4, n / 2 + 4);
    let crop = framed.frame_only();
    let (without, _) = synthesize(&crop, &cam, &dbs, &options).expect("synthesis");
    let band_without = mean_luminance(&without, n - 4, n, n / 2 - 4, n / 2 + 4);
    assert!(
        band > 2.0 * band_without && band > 0.2,
        "right band {band} with overscan, {band_without} without: the light did not bleed in"
    );
}

#[test]
fn an_overscan_file_reads_its_windows_and_writes_the_frame() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = scene::builtin("bokeh")
        .and_then(|s| s.with_size(32, 32))
        .expect("scene");
    let big = scene.with_overscan(6).expect("overscan");
    let options = scene::RenderOptions::default();
    let g = scene::render_gbuffer(&big, 16, &options).expect("render");
    let path = dir.path().join("overscan.exr");
    g.write_exr_with_overscan(&path, 6).expect("write");
    let read = GBuffer::read_exr(&path, &ChannelOptions::default()).expect("read");
    assert_eq!((read.width, read.height), (44, 44));
    assert_eq!(read.overscan, Overscan::uniform(6));
    assert_eq!((read.frame_width(), read.frame_height()), (32, 32));
    // The frame of the larger render is the plain render's frame: the same surfaces at the
    // same pixels (depth at the pixel centres), the colour up to anti-aliasing noise.
    let plain = support::gbuffer_of(&scene::render_gbuffer(&scene, 16, &options).expect("render"));
    let frame = read.frame_only();
    let depths = frame
        .depth
        .as_ref()
        .zip(plain.depth.as_ref())
        .expect("depth");
    for (a, b) in depths.0.iter().zip(depths.1) {
        assert!((a / b - 1.0).abs() < 1e-4, "depth {a} against {b}");
    }
    let mean_green = |g: &GBuffer| g.color.iter().map(|p| f64::from(p[1])).sum::<f64>();
    let ratio = mean_green(&frame) / mean_green(&plain);
    assert!(
        (ratio - 1.0).abs() < 0.02,
        "the frames' mean colours differ: ratio {ratio}"
    );
    // Too much overscan for the image is refused.
    assert!(g.write_exr_with_overscan(&path, 22).is_err());
}

/// Coverage of the disc of radius `r` around `(cx, cy)` over the pixel `(x, y)`, by 8x8
/// supersampling.
fn disc_coverage(x: usize, y: usize, cx: f32, cy: f32, r: f32) -> f32 {
    let mut inside = 0;
    for j in 0..8 {
        for i in 0..8 {
            let px = x as f32 + (i as f32 + 0.5) / 8.0 - cx;
            let py = y as f32 + (j as f32 + 0.5) / 8.0 - cy;
            inside += usize::from(px * px + py * py <= r * r);
        }
    }
    inside as f32 / 64.0
}

#[test]
fn an_hdr_emitters_rim_does_not_glow_with_the_background_blur() {
    // An emitter 200x brighter than display white, in focus, over a dark wall far out of
    // focus. Its anti-aliased rim carries the wall's depth (the depth pass takes the first
    // sample), and a faint second ring two pixels out carries some of its light (a renderer's
    // pixel filter spreads it that far), as in Blender's renders.
    let n = 64usize;
    let cam = close_focus_camera(n as u32);
    let wall_depth = depth_behind_focus(&cam, 10.0);
    let focus = cam.focus_distance.expect("lens") as f32;
    let (cx, cy, r) = (32.0f32, 32.0f32, 3.2f32);
    let (wall, emitter) = (0.01f32, 200.0f32);
    let mut color = vec![[wall, wall, wall, 1.0]; n * n];
    let mut depth = vec![wall_depth; n * n];
    for y in 0..n {
        for x in 0..n {
            let mut a = disc_coverage(x, y, cx, cy, r);
            let (dx, dy) = (x as f32 + 0.5 - cx, y as f32 + 0.5 - cy);
            let dist = (dx * dx + dy * dy).sqrt();
            if a == 0.0 && dist < r + 1.8 {
                a = 0.03; // the pixel filter's tail
            }
            let v = a * emitter + (1.0 - a) * wall;
            color[y * n + x] = [v, v, v, 1.0];
            if a > 0.5 {
                depth[y * n + x] = focus;
            }
        }
    }
    let g = GBuffer::from_planes(n, n, color.clone(), Some(depth), None).expect("g-buffer");
    let dbs = thin_lens();
    let (out, stats) =
        synthesize(&g, &cam, &dbs, &with_edges(FrameEdges::Extend)).expect("synthesis");
    assert!(stats.counts.edge_split > 0);
    // The ring from 6 to 12 px around the emitter: only the wall's light belongs there.
    let mut ring = (0.0f64, 0usize);
    for y in 0..n {
        for x in 0..n {
            let (dx, dy) = (x as f32 + 0.5 - cx, y as f32 + 0.5 - cy);
            let dist = (dx * dx + dy * dy).sqrt();
            if (6.0..12.0).contains(&dist) {
                ring.0 += f64::from(out.at(x, y)[0]);
                ring.1 += 1;
            }
        }
    }
    let ring_mean = ring.0 / ring.1 as f64;
    assert!(
        ring_mean < 3.0 * f64::from(wall),
        "the ring around the emitter is {ring_mean}, the wall {wall}: the rim glows"
    );
    // No light is lost: the frame's energy is the input's (the wall continues past the edge,
    // so the sums match to the splat's accuracy).
    let sum_in: f64 = color.iter().map(|p| f64::from(p[0])).sum();
    let sum_out: f64 = out.pixels.iter().map(|p| f64::from(p[0])).sum();
    assert!(
        (sum_out / sum_in - 1.0).abs() < 0.02,
        "energy {sum_out} out of {sum_in} in"
    );
}

#[test]
fn a_data_window_that_does_not_cover_the_frame_is_a_clear_error() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("border-render.exr");
    // A border render: 10x10 pixels of data at (2, 2) inside a 16x16 frame.
    let channels = SpecificChannels::rgba(|_: Vec2<usize>| (0.5f32, 0.5f32, 0.5f32, 1.0f32));
    let attributes = LayerAttributes {
        layer_position: Vec2(2, 2),
        ..LayerAttributes::default()
    };
    let layer = Layer::new((10, 10), attributes, Encoding::FAST_LOSSLESS, channels);
    let mut image = Image::from_layer(layer);
    image.attributes.display_window = IntegerBounds::new((0, 0), (16, 16));
    image.write().to_file(&path).expect("write");
    let err = GBuffer::read_exr(&path, &ChannelOptions::default()).expect_err("border render");
    let message = err.to_string();
    assert!(
        message.contains("does not cover the display window"),
        "{message}"
    );
}

#[test]
fn a_blurred_wall_does_not_darken_beside_a_sharp_box_and_the_box_stays_opaque() {
    // A box in focus in front of a uniform wall far out of focus (CoC radius 10 px): the lens
    // sees the wall past the box's edge, so the wall next to the box keeps its brightness.
    let n = 64usize;
    let cam = close_focus_camera(n as u32);
    let wall_depth = depth_behind_focus(&cam, 10.0);
    let focus = cam.focus_distance.expect("lens") as f32;
    let (wall, box_colour) = (0.4f32, 0.8f32);
    let inside = |x: usize, y: usize| (24..40).contains(&x) && (16..48).contains(&y);
    let mut color = vec![[wall, wall, wall, 1.0]; n * n];
    let mut depth = vec![wall_depth; n * n];
    for y in 0..n {
        for x in 0..n {
            if inside(x, y) {
                color[y * n + x] = [box_colour, box_colour * 0.5, 0.1, 1.0];
                depth[y * n + x] = focus;
            }
        }
    }
    // Something nearer in a far corner, so that the box lies between layer centres and soft
    // layering would split it.
    color[2 * n + 2] = [0.3, 0.3, 0.3, 1.0];
    depth[2 * n + 2] = focus * 0.8;
    let g = GBuffer::from_planes(n, n, color, Some(depth), None).expect("g-buffer");
    let dbs = thin_lens();
    let run_with = |fill_hidden: bool, edges: FrameEdges| {
        let mut options = with_edges(edges);
        options.classify.fill_hidden = fill_hidden;
        synthesize(&g, &cam, &dbs, &options).expect("synthesis")
    };
    let run = |fill_hidden: bool| run_with(fill_hidden, FrameEdges::Extend);
    let (out, stats) = run(true);
    assert!(stats.counts.hidden_filled > 0);
    // The wall from 1 to 4 px left and right of the box, rows in the box's middle.
    let band = |img: &RgbaImage| -> f64 {
        let mut sum = 0.0;
        let mut count = 0;
        for y in 24..40 {
            for x in (20..23).chain(41..44) {
                sum += f64::from(img.at(x, y)[2]);
                count += 1;
            }
        }
        sum / f64::from(count) / f64::from(wall)
    };
    let with_fill = band(&out);
    let (without, _) = run(false);
    let without_fill = band(&without);
    assert!(
        (with_fill - 1.0).abs() < 0.03,
        "the wall beside the box keeps {with_fill} of its brightness (without the fill {without_fill})"
    );
    assert!(
        without_fill < 0.9,
        "without the fill the wall should darken: {without_fill}"
    );
    // The same without the frame-edge extension: the hidden background's records are drawn
    // wherever they come in the record list.
    let (black_edges, _) = run_with(true, FrameEdges::Black);
    let with_fill_black_edges = band(&black_edges);
    assert!(
        (with_fill_black_edges - 1.0).abs() < 0.03,
        "black frame edges: the wall beside the box keeps {with_fill_black_edges}"
    );
    // The splat visits each layer's records by bands of rows: they come out in row order,
    // the hidden background's among them.
    let mut options = with_edges(FrameEdges::Black);
    options.classify.fill_hidden = true;
    let classified =
        spreadlet::pipeline::classify(&g, &cam, &dbs, &options.classify).expect("classify");
    for info in &classified.layers {
        let recs = &classified.records[info.first_record..info.first_record + info.record_count];
        assert!(
            recs.windows(2).all(|p| p[0].center_y <= p[1].center_y),
            "a layer's records are not in row order"
        );
    }
    // The box is opaque: the wall continued behind it does not show through.
    for y in 18..46 {
        for x in 26..38 {
            let p = out.at(x, y);
            assert!(
                (p[0] / box_colour - 1.0).abs() < 0.02 && (p[2] - 0.1).abs() < 0.01,
                "box pixel ({x}, {y}) is {p:?}"
            );
        }
    }
}

#[test]
fn a_small_highlights_bokeh_keeps_its_own_size() {
    // One pixel 100x brighter than display white at CoC 4 px, on black. The test database's
    // coarse cell around it (centred on 3 px) mixes much smaller disks: drawn with a twin
    // pre-filtered over the whole cell, its second moment comes out at 0.69 of its own disk's;
    // the twin of its sub-cell is within 15 % of it (1.10).
    let n = 64usize;
    let cam = close_focus_camera(n as u32);
    let coc = 4.0;
    let depth = depth_behind_focus(&cam, coc);
    let mut color = vec![[0.0f32; 4]; n * n];
    color[32 * n + 32] = [100.0, 100.0, 100.0, 1.0];
    let g = GBuffer::from_planes(n, n, color, Some(vec![depth; n * n]), None).expect("g-buffer");
    let dbs = thin_lens();
    let (out, stats) =
        synthesize(&g, &cam, &dbs, &with_edges(FrameEdges::Extend)).expect("synthesis");
    assert_eq!(stats.counts.hdr_dense, 1, "{:?}", stats.counts);
    let (mut sum, mut moment) = (0.0f64, 0.0f64);
    for y in 0..n {
        for x in 0..n {
            let v = f64::from(out.at(x, y)[0].max(0.0));
            let (dx, dy) = (x as f64 - 32.0, y as f64 - 32.0);
            sum += v;
            moment += v * (dx * dx + dy * dy);
        }
    }
    // A uniform disk of radius r has E[x^2 + y^2] = r^2 / 2.
    let ratio = moment / sum / (coc * coc / 2.0);
    assert!(
        (0.85..1.25).contains(&ratio),
        "the highlight's second moment is {ratio} times its disk's"
    );
}
