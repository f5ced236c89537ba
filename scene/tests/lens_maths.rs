//! The renderer against the lens and motion maths: a defocused point light's disk radius, a
//! moving point's streak length and the G-buffer's Vector pass, all from closed forms.

use glam::{DVec2, DVec3};
use scene::{render_gbuffer, render_reference, render_stochastic, RenderOptions, Scene};

/// Scene with one tiny emissive sphere (a point light) in front of a black background,
/// camera at the origin looking down -z.
#[allow(clippy::too_many_arguments)]
fn point_light_scene(
    width: u32,
    sensor_mm: f64,
    f_stop: Option<f64>,
    focus: Option<f64>,
    shutter: f64,
    centre: DVec3,
    radius: f64,
    velocity: DVec3,
) -> Scene {
    let opt = |v: Option<f64>| v.map_or("null".to_string(), |v| v.to_string());
    let text = format!(
        r#"{{
        "name": "point",
        "camera": {{"width": {width}, "height": {width}, "focal_length_mm": 50,
                   "sensor_width_mm": {sensor_mm}, "f_stop": {}, "focus_distance": {},
                   "aperture_blades": 0, "shutter_frames": {shutter}}},
        "camera_pose": {{"position": [0, 0, 0], "look_at": [0, 0, -1]}},
        "objects": [{{"shape": {{"type": "sphere", "center": [{}, {}, {}], "radius": {radius}}},
                     "material": {{"albedo": [0, 0, 0], "emission": [1, 1, 1]}},
                     "velocity": [{}, {}, {}]}}]
    }}"#,
        opt(f_stop),
        opt(focus),
        centre.x,
        centre.y,
        centre.z,
        velocity.x,
        velocity.y,
        velocity.z
    );
    Scene::from_json(&text, "point light").expect("valid test scene")
}

/// Intensity-weighted centroid and second-moment matrix of the red channel.
fn moments(image: &scene::RgbaImage) -> (f64, DVec2, [f64; 3]) {
    let mut total = 0.0;
    let mut centroid = DVec2::ZERO;
    for y in 0..image.height {
        for x in 0..image.width {
            let w = f64::from(image.at(x, y)[0]);
            total += w;
            centroid += w * DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
        }
    }
    centroid /= total;
    let mut m = [0.0; 3];
    for y in 0..image.height {
        for x in 0..image.width {
            let w = f64::from(image.at(x, y)[0]);
            let d = DVec2::new(x as f64 + 0.5, y as f64 + 0.5) - centroid;
            m[0] += w * d.x * d.x;
            m[1] += w * d.x * d.y;
            m[2] += w * d.y * d.y;
        }
    }
    (total, centroid, m.map(|v| v / total))
}

#[test]
fn defocused_point_light_is_a_disk_of_the_thin_lens_coc() {
    // 40 px over 11.25 mm: 3.56 px/mm, as a 128 px wide 36 mm sensor.
    let (width, sensor) = (40u32, 11.25);
    let (f_mm, n, s) = (50.0f64, 1.4f64, 0.3f64);
    for depth in [1.0f64, 0.17] {
        let point_radius = 0.003 * depth;
        let scene = point_light_scene(
            width,
            sensor,
            Some(n),
            Some(s),
            0.0,
            DVec3::new(0.0, 0.0, -depth),
            point_radius,
            DVec3::ZERO,
        );
        let reference = render_reference(
            &scene,
            4096,
            &RenderOptions {
                seed: 3,
                ..Default::default()
            },
        )
        .expect("render");
        // CoC diameter on the sensor (Blender's fixed field of view): A f |d - s| / (d s),
        // A = f / N, all in metres.
        let (f, a) = (f_mm * 1e-3, f_mm * 1e-3 / n);
        let diameter_mm = a * f * (depth - s).abs() / (depth * s) * 1e3;
        let expected_radius = 0.5 * diameter_mm * f64::from(width) / sensor;
        // The point's own pinhole image (radius k r / d px, k = image distance) and the pixel
        // box add their second moments to the disk's r^2 / 2.
        let k_px = f_mm * f64::from(width) / sensor;
        let point_px = k_px * point_radius / depth;
        let (total, centroid, m) = moments(&reference);
        let radial = m[0] + m[2];
        let measured = (2.0 * (radial - point_px * point_px / 2.0 - 1.0 / 6.0)).sqrt();
        println!(
            "depth {depth}: CoC radius expected {expected_radius:.3} px, measured {measured:.3} px"
        );
        assert!(
            (measured - expected_radius).abs() < 0.25,
            "depth {depth}: radius {measured} vs {expected_radius}"
        );
        // Centred on the optical axis and round.
        assert!((centroid - DVec2::splat(20.0)).length() < 0.1, "{centroid}");
        assert!((m[0] - m[2]).abs() < 0.03 * radial && m[1].abs() < 0.03 * radial);
        // A disk, not a blob: no energy beyond r + 1.5 px, flat inside.
        let mut outside = 0.0;
        let mut inner = Vec::new();
        for y in 0..reference.height {
            for x in 0..reference.width {
                let r = (DVec2::new(x as f64 + 0.5, y as f64 + 0.5) - centroid).length();
                let v = f64::from(reference.at(x, y)[0]);
                if r > expected_radius + 1.5 {
                    outside += v;
                }
                if r < 0.6 * expected_radius {
                    inner.push(v);
                }
            }
        }
        assert!(outside < 1e-3 * total, "energy outside the disk {outside}");
        let plateau = total / (std::f64::consts::PI * expected_radius * expected_radius);
        let mean_inner = inner.iter().sum::<f64>() / inner.len() as f64;
        assert!(
            (mean_inner / plateau - 1.0).abs() < 0.1,
            "plateau {mean_inner} vs {plateau}"
        );
    }
}

#[test]
fn moving_point_streak_is_motion_times_shutter() {
    // Pinhole, 64 px over 18 mm; the point projects onto a pixel centre.
    let (width, sensor, shutter, depth) = (64u32, 18.0, 0.6, 1.0);
    let px_per_m = 50.0 / depth * f64::from(width) / sensor; // pixels per metre at depth
    let centre = DVec3::new(0.5 / px_per_m, -0.5 / px_per_m, -depth);
    let velocity = DVec3::new(0.06, -0.04, 0.0); // m per frame: right and up
    let point_radius = 0.0015;
    let render = |velocity: DVec3| {
        let scene = point_light_scene(
            width,
            sensor,
            None,
            None,
            shutter,
            centre,
            point_radius,
            velocity,
        );
        let options = RenderOptions {
            seed: 9,
            ..Default::default()
        };
        let reference = render_reference(&scene, 2048, &options).expect("reference");
        let gbuffer = render_gbuffer(&scene, 4, &options).expect("gbuffer");
        (reference, gbuffer)
    };
    let (moving, gbuffer) = render(velocity);
    let (still, _) = render(DVec3::ZERO);
    // Analytic image motion (y down) of the point's front, hit by the pixel-centre ray at
    // depth d - r: px_per_m * d / (d - r) * (vx, -vy) pixels per frame.
    let motion = DVec2::new(velocity.x, -velocity.y) * px_per_m * depth / (depth - point_radius);
    // The G-buffer's forward motion at the point's pixel (32, 32) is that motion.
    let from_gbuffer = gbuffer.forward_motion(32, 32);
    assert!(
        (from_gbuffer - motion).length() < 1e-3,
        "G-buffer motion {from_gbuffer} vs analytic {motion}"
    );
    let dir = motion.normalize();
    let along =
        |m: [f64; 3]| dir.x * dir.x * m[0] + 2.0 * dir.x * dir.y * m[1] + dir.y * dir.y * m[2];
    let across =
        |m: [f64; 3]| dir.y * dir.y * m[0] - 2.0 * dir.x * dir.y * m[1] + dir.x * dir.x * m[2];
    let (_, c_moving, m_moving) = moments(&moving);
    let (_, c_still, _) = moments(&still);
    // Sampled at pixel centres, a smooth streak's second moment along the motion is that of
    // the box of length L (L^2 / 12), the point's own disk image of radius a (a^2 / 4) and the
    // pixel box (1 / 12); across the motion only the last two remain.
    let a = px_per_m * point_radius;
    let blur = a * a / 4.0 + 1.0 / 12.0;
    let length = (12.0 * (along(m_moving) - blur)).sqrt();
    let expected = from_gbuffer.length() * shutter;
    println!(
        "streak length expected {expected:.3} px, measured {length:.3} px; across variance {:.4} (expected {blur:.4})",
        across(m_moving)
    );
    assert!((length - expected).abs() < 0.15, "{length} vs {expected}");
    assert!((across(m_moving) - blur).abs() < 0.03);
    // A centred shutter: the streak is centred on the frame-time position (up to the
    // sampling of its ends by the pixel grid).
    assert!(
        (c_moving - c_still).length() < 0.1,
        "{c_moving} vs {c_still}"
    );
    assert!(
        (c_still - DVec2::new(32.5, 32.5)).length() < 0.05,
        "{c_still}"
    );
}

/// Independent pinhole projection for a camera at `cam` looking down -z, y up, square pixels.
fn project(p: DVec3, cam: DVec3, scale_px: f64, width: f64, height: f64) -> DVec2 {
    let r = p - cam;
    DVec2::new(
        0.5 * width + scale_px * r.x / -r.z,
        0.5 * height - scale_px * r.y / -r.z,
    )
}

#[test]
fn gbuffer_vector_pass_matches_analytic_motion_with_blender_signs() {
    let (width, height) = (48usize, 32usize);
    let (f_mm, sensor, s) = (50.0, 36.0, 2.0);
    let centre = DVec3::new(0.1, 0.05, -2.5);
    let radius = 0.4;
    let velocity = DVec3::new(0.03, -0.02, 0.15); // m per frame, also towards the camera
    let camera_velocity = DVec3::new(-0.01, 0.0, 0.02);
    let text = format!(
        r#"{{
        "name": "vector",
        "camera": {{"width": {width}, "height": {height}, "focal_length_mm": {f_mm},
                   "sensor_width_mm": {sensor}, "f_stop": 2.8, "focus_distance": {s},
                   "shutter_frames": 0.5}},
        "camera_pose": {{"position": [0, 0, 0], "look_at": [0, 0, -1],
                        "velocity": [{}, {}, {}]}},
        "ambient": [1, 1, 1],
        "objects": [{{"shape": {{"type": "sphere", "center": [{}, {}, {}], "radius": {radius}}},
                     "velocity": [{}, {}, {}]}}]
    }}"#,
        camera_velocity.x,
        camera_velocity.y,
        camera_velocity.z,
        centre.x,
        centre.y,
        centre.z,
        velocity.x,
        velocity.y,
        velocity.z
    );
    let scene = Scene::from_json(&text, "vector scene").expect("scene");
    let gbuffer = render_gbuffer(&scene, 1, &RenderOptions::default()).expect("gbuffer");
    // Image scale: the focal length, in pixels (the field of view does not change with focus).
    let scale_px = f_mm * width as f64 / sensor;
    let (w, h) = (width as f64, height as f64);
    let mut checked = 0;
    for y in 0..height {
        for x in 0..width {
            // Pixel-centre ray of the pinhole at t = 0, intersected by hand.
            let dir = DVec3::new(
                (x as f64 + 0.5 - 0.5 * w) / scale_px,
                -(y as f64 + 0.5 - 0.5 * h) / scale_px,
                -1.0,
            )
            .normalize();
            let b = dir.dot(centre);
            let disc = b * b - (centre.length_squared() - radius * radius);
            let i = y * width + x;
            if disc < 0.0 {
                assert_eq!(gbuffer.depth[i], 1e10, "miss at {x},{y}");
                assert_eq!(gbuffer.vector[i], [0.0; 4]);
                continue;
            }
            let p = dir * (b - disc.sqrt());
            assert!((f64::from(gbuffer.depth[i]) - (-p.z)).abs() < 1e-5);
            let at = |t: f64| project(p + velocity * t, camera_velocity * t, scale_px, w, h);
            let (prev, now, next) = (at(-1.0), at(0.0), at(1.0));
            // Blender, y up: X,Y = previous - now; Z,W = now - next.
            let expected = [
                prev.x - now.x,
                -(prev.y - now.y),
                now.x - next.x,
                -(now.y - next.y),
            ];
            for c in 0..4 {
                assert!(
                    (f64::from(gbuffer.vector[i][c]) - expected[c]).abs() < 1e-3,
                    "pixel {x},{y} component {c}: {:?} vs {expected:?}",
                    gbuffer.vector[i]
                );
            }
            let forward = gbuffer.forward_motion(x, y);
            assert!((forward - (next - now)).length() < 1e-3);
            checked += 1;
        }
    }
    assert!(checked > 50, "the sphere covers {checked} pixels");
    // The pixel under the sphere centre moves (to first order) like the centre itself.
    let c = project(centre, DVec3::ZERO, scale_px, w, h);
    let c_next = project(centre + velocity, camera_velocity, scale_px, w, h);
    let m = gbuffer.forward_motion(c.x as usize, c.y as usize);
    assert!(
        (m - (c_next - c)).length() < 0.25 * (c_next - c).length(),
        "{m} vs centre motion {}",
        c_next - c
    );
}

#[test]
fn stochastic_labels_map_samples_back_to_the_pinhole_image() {
    // Undoing each sample's lens offset and motion must land it on the sphere's pinhole
    // silhouette at the frame time: checks the signs and units of the labels.
    let text = r#"{
        "name": "labels",
        "camera": {"width": 40, "height": 40, "focal_length_mm": 50, "sensor_width_mm": 36,
                   "f_stop": 1.4, "focus_distance": 0.5, "aperture_blades": 6,
                   "shutter_frames": 1.0},
        "camera_pose": {"position": [0, 0, 0], "look_at": [0, 0, -1]},
        "ambient": [1, 1, 1],
        "objects": [{"shape": {"type": "sphere", "center": [0.0, 0.0, -1.2], "radius": 0.08},
                     "velocity": [0.05, 0.02, 0.0]}]
    }"#;
    let scene = Scene::from_json(text, "labels").expect("scene");
    let frames = render_stochastic(
        &scene,
        16,
        &RenderOptions {
            seed: 5,
            ..Default::default()
        },
    )
    .expect("render");
    let camera = &scene.camera;
    let centre = camera
        .project(DVec3::new(0.0, 0.0, -1.2), 0.0)
        .expect("in front");
    // Silhouette radius of a sphere: k r / sqrt(d^2 - r^2) (in pixels).
    let k_px = camera.spec.focal_length_mm * camera.spec.pixels_per_mm();
    let silhouette = k_px * 0.08 / (1.2f64 * 1.2 - 0.08 * 0.08).sqrt();
    let mut hits = 0;
    let mut lens_used = 0.0f64;
    for y in 0..frames.height {
        for x in 0..frames.width {
            for s in frames.pixel(x, y) {
                assert!(
                    s.time.abs() <= 0.5
                        && DVec2::new(s.lens[0].into(), s.lens[1].into()).length() <= 1.0 + 1e-6
                );
                assert!(s.jitter[0].abs() <= 0.5 && s.jitter[1].abs() <= 0.5);
                if s.color[3] == 0.0 {
                    assert_eq!(s.depth, 1e10);
                    continue;
                }
                hits += 1;
                let lens = DVec2::new(s.lens[0].into(), s.lens[1].into());
                lens_used = lens_used.max(lens.length());
                let position = DVec2::new(
                    x as f64 + 0.5 + f64::from(s.jitter[0]),
                    y as f64 + 0.5 + f64::from(s.jitter[1]),
                );
                let motion = DVec2::new(s.motion[0].into(), s.motion[1].into());
                let pinhole = position
                    - camera
                        .spec
                        .thin_lens()
                        .map_or(0.0, |l| l.signed_coc_px(f64::from(s.depth)))
                        * lens
                    - motion * f64::from(s.time);
                let r = (pinhole - centre).length();
                assert!(
                    r <= silhouette + 0.02,
                    "sample at {position} maps to {pinhole}, {r} px from the centre (silhouette {silhouette})"
                );
            }
        }
    }
    assert!(
        hits > 600 && lens_used > 0.8,
        "{hits} hits, lens {lens_used}"
    );
}

#[test]
fn spinning_square_motion_varies_across_it_as_a_rotation() {
    // A square facing the camera spins about the viewing axis: every point's next-frame
    // image position is its current one rotated about the centre's image by the angle.
    let (width, omega) = (40usize, 0.2f64);
    let text = format!(
        r#"{{
        "name": "spin",
        "camera": {{"width": {width}, "height": {width}, "focal_length_mm": 50,
                   "sensor_width_mm": 36, "f_stop": null, "focus_distance": null}},
        "camera_pose": {{"position": [0, 0, 0], "look_at": [0, 0, -1]}},
        "ambient": [1, 1, 1],
        "objects": [{{"shape": {{"type": "quad", "corner": [-0.1, -0.1, -1.0],
                                "edge_u": [0.2, 0, 0], "edge_v": [0, 0.2, 0]}},
                     "spin": {{"axis": [0, 0, 1], "radians_per_frame": {omega}}}}}]
    }}"#
    );
    let scene = Scene::from_json(&text, "spin").expect("scene");
    let gbuffer = render_gbuffer(&scene, 1, &RenderOptions::default()).expect("gbuffer");
    let scale_px = 50.0 * width as f64 / 36.0;
    let centre = DVec2::splat(width as f64 / 2.0);
    let mut speeds = Vec::new();
    for y in 0..width {
        for x in 0..width {
            let i = y * width + x;
            if gbuffer.depth[i] > 1e9 {
                continue;
            }
            let now = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
            // World rotation by +omega about +z (towards the camera) is clockwise on the
            // y-down image: (dx, dy) -> (dx cos + dy sin, -dx sin + dy cos).
            let rotate = |d: DVec2, a: f64| {
                DVec2::new(
                    d.x * a.cos() + d.y * a.sin(),
                    -d.x * a.sin() + d.y * a.cos(),
                )
            };
            let d = now - centre;
            let next = centre + rotate(d, omega);
            let previous = centre + rotate(d, -omega);
            let forward = gbuffer.forward_motion(x, y);
            assert!(
                (forward - (next - now)).length() < 1e-3,
                "{forward} vs {}",
                next - now
            );
            let v = gbuffer.vector[i];
            let backward = DVec2::new(f64::from(v[0]), -f64::from(v[1]));
            assert!((backward - (previous - now)).length() < 1e-3);
            // Depth is the plane's: 1 m everywhere.
            assert!((f64::from(gbuffer.depth[i]) - 1.0).abs() < 1e-6);
            speeds.push(forward.length());
        }
    }
    let half_px = 0.1 * scale_px;
    assert!(speeds.len() as f64 > 0.9 * (2.0 * half_px).powi(2));
    let (min, max) = speeds
        .iter()
        .fold((f64::MAX, 0.0f64), |(a, b), &s| (a.min(s), b.max(s)));
    // From near zero at the centre to 2 sin(omega / 2) times the corner radius.
    let corner = 2.0 * (omega / 2.0).sin() * half_px * 2f64.sqrt();
    assert!(
        min < 0.3 && max > 0.9 * corner && max <= corner + 1e-6,
        "{min} {max} {corner}"
    );
}

#[test]
fn bladed_aperture_gives_a_polygon_with_a_vertex_on_plus_u() {
    // Six blades, vertex 0 on +u (image +x): the defocused point is a hexagon whose chord
    // through the centre is 2r along x (vertex to vertex) and sqrt(3) r along y (edge to edge).
    let (width, sensor, depth) = (48u32, 13.5, 1.0f64);
    let text = format!(
        r#"{{
        "name": "hexagon",
        "camera": {{"width": {width}, "height": {width}, "focal_length_mm": 50,
                   "sensor_width_mm": {sensor}, "f_stop": 1.4, "focus_distance": 0.3,
                   "aperture_blades": 6}},
        "camera_pose": {{"position": [0, 0, 0], "look_at": [0, 0, -1]}},
        "objects": [{{"shape": {{"type": "sphere", "center": [0, 0, -{depth}], "radius": 0.006}},
                     "material": {{"albedo": [0, 0, 0], "emission": [1, 1, 1]}}}}]
    }}"#
    );
    let scene = Scene::from_json(&text, "hexagon").expect("scene");
    let r = scene
        .camera
        .spec
        .thin_lens()
        .map_or(0.0, |l| l.coc_px(depth));
    let image = render_reference(
        &scene,
        4096,
        &RenderOptions {
            seed: 2,
            ..Default::default()
        },
    )
    .expect("render");
    let (total, centroid, _) = moments(&image);
    assert!((centroid - DVec2::splat(24.0)).length() < 0.1);
    // Plateau from the hexagon's area (3 sqrt(3) / 2) r^2; chords as row and column sums.
    let plateau = total / (1.5 * 3f64.sqrt() * r * r);
    let sum_row = |y: usize| (0..48).map(|x| f64::from(image.at(x, y)[0])).sum::<f64>();
    let sum_col = |x: usize| (0..48).map(|y| f64::from(image.at(x, y)[0])).sum::<f64>();
    // Rows/columns 23 and 24 straddle the centre (24.0): average them.
    let chord_x = 0.5 * (sum_row(23) + sum_row(24)) / plateau;
    let chord_y = 0.5 * (sum_col(23) + sum_col(24)) / plateau;
    // Row strips centred 0.5 px off the axis: the chord through the vertex shrinks there to
    // 2 (r - 0.5 / sqrt(3)); the edge-to-edge chord stays sqrt(3) r.
    let expected_x = 2.0 * (r - 0.5 / 3f64.sqrt());
    let expected_y = 3f64.sqrt() * r;
    println!(
        "hexagon r {r:.2} px: chord x {chord_x:.2} (expected {expected_x:.2}), chord y {chord_y:.2} (expected {expected_y:.2})"
    );
    let ratio = chord_x / chord_y;
    // Rotated by 90 degrees (vertex on +v) the ratio would be about 0.9.
    assert!(
        (ratio - expected_x / expected_y).abs() < 0.03,
        "chord ratio {ratio}: the polygon is not oriented with a vertex on +u"
    );
}
