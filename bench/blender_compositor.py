"""Blender compositor baseline: Vector Blur, then Defocus, on a pinhole G-buffer.

This is what a Blender user does today to fake depth of field and motion blur
after the fact, and what `shared/examples/*/blender_post.exr` were made with.

    blender -b --factory-startup --python-exit-code 1 \
        --python bench/blender_compositor.py -- \
        --input G.exr --camera camera.json --out OUT.exr [--samples 64]

Input: a multilayer OpenEXR in Blender's layout (`<Layer>.Combined.RGBA`,
`<Layer>.Depth.Z`, `<Layer>.Vector.XYZW`). Output: linear, premultiplied RGBA
float EXR of the display window (channels R, G, B, A). Made for Blender 3.4
(Debian's); the parts of the API that changed in 4.x/5.x are handled where
known, see `set_option` and `defocus_f_stop`.
"""

import argparse
import json
import math
import os
import struct
import sys
import time

PROCESS_START = time.perf_counter()

import bpy  # noqa: E402  (only importable inside Blender)

PROG = "blender_compositor"


class UsageError(Exception):
    """Bad arguments, camera.json or G-buffer: reported as one line, exit 1."""


# ---------------------------------------------------------------------------
# Arguments


def parse_args():
    # Blender passes its own arguments through sys.argv; ours follow "--".
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Blender compositor baseline (Vector Blur then Defocus).",
    )
    parser.add_argument("--input", required=True, help="multilayer G-buffer EXR")
    parser.add_argument("--camera", required=True, help="camera.json")
    parser.add_argument("--out", required=True, help="output RGBA EXR")
    parser.add_argument(
        "--samples", type=int, default=64, help="Vector Blur samples (default 64)"
    )
    parser.add_argument(
        "--layer",
        default=None,
        help="view layer to read (default: the only one with Combined, Depth, Vector)",
    )
    parser.add_argument(
        "--blur-max",
        type=float,
        default=128.0,
        help="Defocus blur limit in pixels (default 128, large enough not to clip)",
    )
    parser.add_argument(
        "--threshold",
        type=float,
        default=1.0,
        help="Defocus threshold (default 1.0, the node's own default)",
    )
    parser.add_argument(
        "--preview",
        action="store_true",
        help="Defocus low-quality preview mode (on in a new node; off here, as "
        "for the shared blender_post.exr)",
    )
    parser.add_argument(
        "--f-stop-calibration",
        choices=["fixed-fov", "focus-breathing", "none"],
        default="fixed-fov",
        help="lens model the Defocus node's f-stop is calibrated to: fixed-fov "
        "(default: Blender's own camera, as Cycles and spreadlet-scene render it), "
        "focus-breathing (a physical lens focused by moving it), or none",
    )
    parser.add_argument(
        "--skip-still-vector-blur",
        action="store_true",
        help="leave the Vector Blur node out when shutter_frames is 0 (by default "
        "it stays, with factor 0, as in the shared blender_post.exr)",
    )
    parser.add_argument(
        "--threads", type=int, default=0, help="compositor threads (0 = all)"
    )
    parser.add_argument(
        "--calls",
        type=int,
        default=1,
        help="render calls in this process (default 1): from the second on, what an add-on "
        "user waits for on each further frame; each call's time is printed",
    )
    args = parser.parse_args(argv)
    if args.calls < 1:
        raise UsageError(f"--calls must be at least 1, got {args.calls}")
    if args.samples < 1 or args.samples > 256:
        raise UsageError(f"--samples must be in 1..256 (Blender's range), got {args.samples}")
    if not args.blur_max > 0:
        raise UsageError(f"--blur-max must be positive, got {args.blur_max}")
    return args


# ---------------------------------------------------------------------------
# camera.json


def read_camera(path):
    try:
        with open(path, encoding="utf-8") as f:
            cam = json.load(f)
    except OSError as e:
        raise UsageError(f"cannot read camera file {path}: {e.strerror}")
    except json.JSONDecodeError as e:
        raise UsageError(f"{path} is not valid JSON: {e}")
    if not isinstance(cam, dict):
        raise UsageError(f"{path}: expected a JSON object")

    def number(key, positive=True, nullable=False, integer=False):
        if key not in cam:
            raise UsageError(f"{path}: missing field '{key}'")
        value = cam[key]
        if value is None and nullable:
            return None
        ok_type = int if integer else (int, float)
        if isinstance(value, bool) or not isinstance(value, ok_type):
            kind = "an integer" if integer else "a number"
            raise UsageError(
                f"{path}: '{key}' must be {kind}{' or null' if nullable else ''}, got {value!r}"
            )
        if not math.isfinite(value):
            raise UsageError(f"{path}: '{key}' must be finite, got {value!r}")
        if positive and not value > 0:
            raise UsageError(f"{path}: '{key}' must be positive, got {value!r}")
        if not positive and value < 0:
            raise UsageError(f"{path}: '{key}' must not be negative, got {value!r}")
        return value

    out = {
        "width": number("width", integer=True),
        "height": number("height", integer=True),
        "focal_length_mm": float(number("focal_length_mm")),
        "sensor_width_mm": float(number("sensor_width_mm")),
        "f_stop": number("f_stop", nullable=True),
        "focus_distance": number("focus_distance", nullable=True),
        "aperture_blades": number("aperture_blades", positive=False, integer=True),
        "shutter_frames": float(number("shutter_frames", positive=False)),
    }
    if out["aperture_blades"] not in (0, 3, 4, 5, 6, 7, 8):
        raise UsageError(
            f"{path}: aperture_blades must be 0 (circular) or 3..8 (the shapes the "
            f"Defocus node has), got {out['aperture_blades']}"
        )
    focus = out["focus_distance"]
    if focus is not None and focus <= out["focal_length_mm"] / 1000.0:
        raise UsageError(
            f"{path}: focus_distance {focus} is inside the focal length "
            f"({out['focal_length_mm']} mm); nothing can be focused there"
        )
    return out


# ---------------------------------------------------------------------------
# EXR header: read here rather than trusting Blender, so that missing passes and
# overscan give a clear message before any compositing happens.


def read_exr_header(path):
    try:
        with open(path, "rb") as f:
            data = f.read(1 << 20)
    except OSError as e:
        raise UsageError(f"cannot read {path}: {e.strerror}")
    if len(data) < 8 or data[:4] != b"\x76\x2f\x31\x01":
        raise UsageError(f"{path} is not an OpenEXR file")
    version = struct.unpack_from("<I", data, 4)[0]
    if version & 0x800:
        raise UsageError(f"{path} is a deep EXR; a flat G-buffer is needed")
    pos = 8
    header = {}

    def cstring(at):
        end = data.find(b"\0", at)
        if end < 0:
            raise UsageError(f"{path}: truncated EXR header")
        return data[at:end].decode("latin-1"), end + 1

    while True:
        name, pos = cstring(pos)
        if name == "":
            break
        kind, pos = cstring(pos)
        if pos + 4 > len(data):
            raise UsageError(f"{path}: truncated EXR header")
        size = struct.unpack_from("<i", data, pos)[0]
        pos += 4
        if size < 0 or pos + size > len(data):
            raise UsageError(f"{path}: corrupt EXR header (attribute '{name}')")
        value = data[pos:pos + size]
        pos += size
        if kind == "box2i" and size == 16:
            header[name] = struct.unpack("<4i", value)
        elif kind == "chlist":
            channels, at = [], 0
            while at < len(value) and value[at] != 0:
                end = value.index(b"\0", at)
                channels.append(value[at:end].decode("latin-1"))
                at = end + 1 + 16
            header[name] = channels
    for key in ("channels", "dataWindow", "displayWindow"):
        if key not in header:
            raise UsageError(f"{path}: EXR header has no '{key}'")
    return header


REQUIRED_PASSES = {
    "Combined": ("R", "G", "B", "A"),
    "Depth": ("Z",),
    "Vector": ("X", "Y", "Z", "W"),
}


def pick_layer(path, channels, wanted):
    found = {}
    for channel in channels:
        parts = channel.rsplit(".", 2)
        if len(parts) == 3:
            found.setdefault(parts[0], set()).add((parts[1], parts[2]))

    def missing(layer):
        have = found.get(layer, set())
        return [
            f"{layer}.{p}.{c}"
            for p, cs in REQUIRED_PASSES.items()
            for c in cs
            if (p, c) not in have
        ]

    if wanted is not None:
        if wanted not in found:
            raise UsageError(
                f"{path}: no layer '{wanted}' (layers: {', '.join(sorted(found)) or 'none'})"
            )
        gaps = missing(wanted)
        if gaps:
            raise UsageError(f"{path}: layer '{wanted}' lacks {', '.join(gaps)}")
        return wanted
    complete = sorted(layer for layer in found if not missing(layer))
    if len(complete) == 1:
        return complete[0]
    if not complete:
        detail = "; ".join(
            f"'{layer}' lacks {', '.join(missing(layer))}" for layer in sorted(found)
        )
        raise UsageError(
            f"{path}: no layer has Combined.RGBA, Depth.Z and Vector.XYZW "
            f"({detail or 'no <Layer>.<Pass>.<Channel> channels at all'})"
        )
    raise UsageError(
        f"{path}: several complete layers ({', '.join(complete)}); choose one with --layer"
    )


# ---------------------------------------------------------------------------
# Version differences


def set_option(node, value, attributes=(), sockets=()):
    """Sets a node option that is a property in one Blender and an input
    socket in another (5.x moved many compositor options to sockets)."""
    for name in attributes:
        if hasattr(node, name):
            setattr(node, name, value)
            return True
    for name in sockets:
        socket = node.inputs.get(name)
        if socket is not None and hasattr(socket, "default_value"):
            socket.default_value = value
            return True
    return False


def socket(sockets, names, what):
    for name in names:
        found = sockets.get(name)
        if found is not None:
            return found
    raise UsageError(
        f"this Blender has no socket {' / '.join(names)} for {what} "
        f"(sockets: {', '.join(s.name for s in sockets)})"
    )


def defocus_f_stop(cam, data_w, data_h, model):
    """F-number to give the Defocus node so that its circle of confusion is
    the lens's, in pixels of the display window; and what was assumed.

    The lens that Blender's renderers (and spreadlet-scene) simulate keeps the
    image distance at the focal length whatever the focus (no focus
    breathing), so its CoC radius is, in pixels (lens L, sensor S, focus s,
    depth z, width W; metres):
        0.5 * L**2 * W / (N * S) * |1/s - 1/z|                      ("fixed-fov")
    A lens focused by moving away from the sensor has the image distance
    L s / (s - L), so its CoC is larger by s / (s - L)           ("focus-breathing").

    Blender up to 4.0 computes (ConvertDepthToRadiusOperation), for an image
    w x h pixels, with L and S in millimetres and s, z in scene units:
        0.5 * L_mm**2 * max(w, h) / (S_mm**2 * N) * |1/s - 1/z|  (+ 0.25 L/(S N), negligible)
    which is the fixed-fov CoC when N is scaled by 1000/S_mm * max(w, h)/W.
    Blender 4.1+ computes the focus-breathing CoC in metres itself, with
    pixels per metre from the image width, so only w/W (overscan) and, for
    fixed-fov, s / (s - L) remain.
    """
    n = cam["f_stop"]
    width = cam["width"]
    lens_m = cam["focal_length_mm"] / 1000.0
    focus = cam["focus_distance"]
    breathing = focus / (focus - lens_m)
    if model == "none":
        return n, "uncalibrated"
    if bpy.app.version >= (4, 1, 0):
        scale = data_w / width
        if model == "fixed-fov":
            scale *= breathing
        return n * scale, f"{model} (Blender 4.1+ thin-lens CoC, x {scale:.4f})"
    scale = (1000.0 / cam["sensor_width_mm"]) * (max(data_w, data_h) / width)
    if model == "focus-breathing":
        scale /= breathing
    return n * scale, f"{model} (Blender 3.x CoC, x {scale:.4f})"


BOKEH_BY_BLADES = {
    0: "CIRCLE",
    3: "TRIANGLE",
    4: "SQUARE",
    5: "PENTAGON",
    6: "HEXAGON",
    7: "HEPTAGON",
    8: "OCTAGON",
}


# ---------------------------------------------------------------------------
# Scene and node tree


def build(args, cam, header, layer):
    dx0, dy0, dx1, dy1 = header["dataWindow"]
    wx0, wy0, wx1, wy1 = header["displayWindow"]
    data_w, data_h = dx1 - dx0 + 1, dy1 - dy0 + 1
    disp_w, disp_h = wx1 - wx0 + 1, wy1 - wy0 + 1
    if (disp_w, disp_h) != (cam["width"], cam["height"]):
        raise UsageError(
            f"{args.input} display window is {disp_w}x{disp_h} but {args.camera} says "
            f"{cam['width']}x{cam['height']}"
        )
    if dx0 > wx0 or dy0 > wy0 or dx1 < wx1 or dy1 < wy1:
        raise UsageError(
            f"{args.input}: data window {header['dataWindow']} does not cover the "
            f"display window {header['displayWindow']}"
        )

    scene = bpy.context.scene
    for obj in list(scene.objects):
        bpy.data.objects.remove(obj, do_unlink=True)

    # The Defocus node reads lens, sensor and focus distance from the scene
    # camera; it renders nothing.
    camera = bpy.data.cameras.new("spreadlet_camera")
    camera.lens = cam["focal_length_mm"]
    camera.sensor_fit = "HORIZONTAL"
    camera.sensor_width = cam["sensor_width_mm"]
    defocus = cam["f_stop"] is not None and cam["focus_distance"] is not None
    if defocus:
        camera.dof.use_dof = True
        camera.dof.focus_distance = cam["focus_distance"]
        camera.dof.aperture_fstop = cam["f_stop"]
    camera_object = bpy.data.objects.new("spreadlet_camera", camera)
    scene.collection.objects.link(camera_object)
    scene.camera = camera_object

    render = scene.render
    # The compositor works on the whole data window (overscan gives Vector Blur
    # and Defocus real pixels beyond the frame edge); the Composite node then
    # keeps the centred display-size frame.
    render.resolution_x = disp_w
    render.resolution_y = disp_h
    render.resolution_percentage = 100
    render.pixel_aspect_x = render.pixel_aspect_y = 1.0
    render.use_compositing = True
    render.use_sequencer = False
    render.use_border = False
    render.film_transparent = True
    if args.threads > 0:
        render.threads_mode = "FIXED"
        render.threads = args.threads
    if hasattr(render, "compositor_device"):
        render.compositor_device = "CPU"
    # Output stays scene-linear: no view transform or look on the way out.
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    settings = render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_mode = "RGBA"
    settings.color_depth = "32"
    settings.exr_codec = "ZIP"
    if hasattr(settings, "use_preview"):
        settings.use_preview = False
    render.use_file_extension = False

    image = bpy.data.images.load(os.path.abspath(args.input), check_existing=False)
    len(image.pixels)  # forces the load, which makes Blender see the layers
    if image.type != "MULTILAYER":
        raise UsageError(f"Blender does not read {args.input} as a multilayer EXR")

    if hasattr(scene, "compositing_node_group"):  # 5.x: compositor is a node group
        tree = bpy.data.node_groups.new("spreadlet", "CompositorNodeTree")
        scene.compositing_node_group = tree
    else:
        scene.use_nodes = True
        tree = scene.node_tree
    for node in list(tree.nodes):
        tree.nodes.remove(node)
    links = tree.links

    source = tree.nodes.new("CompositorNodeImage")
    source.image = image
    source.layer = layer
    combined = socket(source.outputs, ("Combined", "Image"), "Combined")
    depth = socket(source.outputs, ("Depth", "Z"), "Depth")
    vector = socket(source.outputs, ("Vector", "Speed"), "Vector")
    colour = combined
    report = {"layer": layer, "data_window": (data_w, data_h), "display": (disp_w, disp_h)}

    # The node stays in the chain with a still shutter (factor 0) unless asked
    # not to: that is how the shared blender_post.exr files were made, and it
    # is not a no-op (it re-rasterises depth edges).
    if cam["shutter_frames"] > 0 or not args.skip_still_vector_blur:
        blur = tree.nodes.new("CompositorNodeVecBlur")
        links.new(colour, socket(blur.inputs, ("Image",), "Vector Blur image"))
        links.new(depth, socket(blur.inputs, ("Z", "Depth"), "Vector Blur depth"))
        links.new(vector, socket(blur.inputs, ("Speed", "Vector", "Velocity"), "Vector Blur speed"))
        if not set_option(blur, args.samples, ("samples",), ("Samples",)):
            raise UsageError("cannot set the Vector Blur node's samples in this Blender")
        # Blender's vectors are per frame and the blur spans factor x motion,
        # centred on the frame: the same as camera.json's shutter_frames.
        if not set_option(blur, cam["shutter_frames"], ("factor",), ("Shutter", "Blur", "Factor")):
            raise UsageError("cannot set the Vector Blur node's factor in this Blender")
        # No speed clamping, straight (not curved) streaks; gone in 4.2+.
        set_option(blur, 0, ("speed_min",))
        set_option(blur, 0, ("speed_max",))
        set_option(blur, False, ("use_curved",))
        colour = blur.outputs[0]
        report["vector_blur"] = {"samples": args.samples, "factor": cam["shutter_frames"]}

    if defocus:
        f_stop, how = defocus_f_stop(cam, data_w, data_h, args.f_stop_calibration)
        lens_scale = 1.0
        if f_stop > 128.0:
            # The node's f-stop stops at 128 ("perfect focus"). Blender 3.x's
            # radius goes as (lens/sensor)^2 / N, and the camera exists for
            # the Defocus node alone, so the rest is taken by a shorter lens.
            if bpy.app.version >= (4, 1, 0):
                raise UsageError(
                    f"f-stop {cam['f_stop']} needs {f_stop:.1f} on the Defocus node, "
                    "beyond its limit of 128"
                )
            lens_scale = math.sqrt(128.0 / f_stop)
            camera.lens = cam["focal_length_mm"] * lens_scale
            f_stop = 128.0
        node = tree.nodes.new("CompositorNodeDefocus")
        links.new(colour, socket(node.inputs, ("Image",), "Defocus image"))
        links.new(depth, socket(node.inputs, ("Z", "Depth"), "Defocus depth"))
        set_option(node, True, ("use_zbuffer",))
        set_option(node, BOKEH_BY_BLADES[cam["aperture_blades"]], ("bokeh",))
        set_option(node, 0.0, ("angle",))
        set_option(node, False, ("use_gamma_correction",))
        set_option(node, args.preview, ("use_preview",))
        set_option(node, args.threshold, ("threshold",))
        if not set_option(node, f_stop, ("f_stop",), ("F-Stop", "F Stop")):
            raise UsageError("cannot set the Defocus node's f-stop in this Blender")
        set_option(node, args.blur_max, ("blur_max",), ("Max Blur", "Maximum Blur"))
        if hasattr(node, "scene"):
            node.scene = scene
        colour = node.outputs[0]
        report["defocus"] = {
            "f_stop_real": cam["f_stop"],
            "f_stop_node": round(f_stop, 4),
            "calibration": how,
            "lens_scale": lens_scale,
            "blur_max": args.blur_max,
            "threshold": args.threshold,
            "preview": args.preview,
        }

    # Centre of the display window relative to the centre of the data window,
    # in Blender's y-up pixels: the Composite node keeps the centred frame.
    shift_x = ((dx0 + dx1) - (wx0 + wx1)) / 2.0
    shift_y = -((dy0 + dy1) - (wy0 + wy1)) / 2.0
    if shift_x or shift_y:
        translate = tree.nodes.new("CompositorNodeTranslate")
        links.new(colour, socket(translate.inputs, ("Image",), "Translate image"))
        socket(translate.inputs, ("X",), "Translate x").default_value = shift_x
        socket(translate.inputs, ("Y",), "Translate y").default_value = shift_y
        colour = translate.outputs[0]
        report["translate"] = (shift_x, shift_y)

    if hasattr(scene, "compositing_node_group"):
        tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        out = tree.nodes.new("NodeGroupOutput")
        links.new(colour, out.inputs[0])
    else:
        out = tree.nodes.new("CompositorNodeComposite")
        if hasattr(out, "use_alpha"):
            out.use_alpha = True  # keep premultiplied alpha, not alpha = 1
        links.new(colour, out.inputs[0])
    return scene, report


# ---------------------------------------------------------------------------


def process_age_s():
    """Seconds since this Blender process started (Linux), so the baseline's
    timing includes Blender's own start-up; None where /proc is missing."""
    try:
        with open("/proc/self/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        with open("/proc/uptime", encoding="ascii") as f:
            uptime_s = float(f.read().split()[0])
        return uptime_s - int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def main():
    args = parse_args()
    cam = read_camera(args.camera)
    header = read_exr_header(args.input)
    layer = pick_layer(args.input, header["channels"], args.layer)
    out_dir = os.path.dirname(os.path.abspath(args.out))
    if not os.path.isdir(out_dir):
        raise UsageError(f"output folder {out_dir} does not exist")

    scene, report = build(args, cam, header, layer)
    tmp = os.path.join(out_dir, f".{os.path.basename(args.out)}.{os.getpid()}.tmp")
    scene.render.filepath = tmp
    print(f"{PROG}: Blender {bpy.app.version_string}; {json.dumps(report)}", flush=True)

    calls_s = []
    for _ in range(args.calls):
        composite_start = time.perf_counter()
        try:
            bpy.ops.render.render(write_still=True)
        except RuntimeError as e:
            if os.path.exists(tmp):
                os.remove(tmp)
            raise UsageError(f"Blender failed to composite: {e}")
        calls_s.append(time.perf_counter() - composite_start)
    composite_s = calls_s[0]
    if not os.path.isfile(tmp):
        raise UsageError("Blender composited but wrote no image")
    os.replace(tmp, args.out)
    script_s = time.perf_counter() - PROCESS_START
    age_s = process_age_s()
    process = f"{age_s:.2f} s" if age_s is not None else "unknown"
    print(
        f"{PROG}: wrote {args.out}; composite {composite_s:.3f} s (render call), "
        f"script {script_s:.3f} s, process {process} (since Blender started)",
        flush=True,
    )
    if len(calls_s) > 1:
        warm = " ".join(f"{c:.3f}" for c in calls_s[1:])
        print(f"{PROG}: further render calls {warm} s", flush=True)


if __name__ == "__main__":
    try:
        main()
    except UsageError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr, flush=True)
        sys.exit(1)
