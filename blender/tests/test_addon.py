"""The add-on in a real Blender, headless:

    SPREADLET_BIN=target/release/spreadlet blender -b --factory-startup \
        --python-exit-code 1 --python blender/tests/test_addon.py -- OUT_FOLDER

Builds a small scene at miniature scale, so that a real lens blurs by several pixels at
128x128 (a sphere 0.25 m from the camera in front of a textured wall at 0.8 m, a cube moving
across at 0.6 m, a camera at f/2 focused on the wall, the render's motion blur shutter at 1 frame), renders it at 128x128
through the add-on's operator, renders Cycles' own depth of field and motion blur of the same
scene as the reference, and checks: the camera values the add-on read are the ones set here,
and the add-on's result is clearly closer to the reference (SSIM, `spreadlet compare`) than the
pinhole input it started from. Then "Every render": an animation render of frames 1-2 writes
both finished frames where the output path puts them (frame 1 equal to the operator's), a
still render leaves its result in "Spreadlet Result", and the scene's settings come back.
Last, the add-on's camera reading against `../shared/examples/*/camera.json`, with the scenes
built by the script that made those (`../shared/tools/blender_refs.py`), where it exists.

Runs in Blender (3.4 and later) and in the `bpy` module (`pip install bpy`; 4.x, 5.x):

    SPREADLET_BIN=target/release/spreadlet python blender/tests/test_addon.py -- OUT_FOLDER
"""

import json
import math
import os
import subprocess
import sys

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
import spreadlet_blender  # noqa: E402

OUT = sys.argv[sys.argv.index("--") + 1] if "--" in sys.argv else "/tmp/spreadlet-blender-test"
os.makedirs(OUT, exist_ok=True)
SIZE = 128


def material(name, color, checker=0.0):
    m = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):  # node materials are the only kind from 5.0 on
        m.use_nodes = True
    bsdf = m.node_tree.nodes["Principled BSDF"]
    if checker:
        tex = m.node_tree.nodes.new("ShaderNodeTexChecker")
        tex.inputs["Scale"].default_value = checker
        tex.inputs["Color1"].default_value = (*color, 1)
        tex.inputs["Color2"].default_value = (0.05, 0.05, 0.05, 1)
        m.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    else:
        bsdf.inputs["Base Color"].default_value = (*color, 1)
    return m


def build_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    # Debian's Blender is built without Open Image Denoise; the comparison wants raw samples.
    scene.cycles.use_denoising = False
    scene.render.resolution_x = SIZE
    scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    world = bpy.data.worlds.new("world")
    world.color = (0.05, 0.05, 0.05)
    scene.world = world
    # The wall, in focus, 0.8 m from the camera.
    bpy.ops.mesh.primitive_plane_add(size=1.2, location=(0, 0.8, 0), rotation=(math.radians(90), 0, 0))
    bpy.context.object.data.materials.append(material("wall", (0.9, 0.8, 0.5), checker=8))
    # A sphere 0.25 m from the camera: a CoC of about 6 px radius.
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.04, location=(-0.05, 0.25, 0.015))
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(material("sphere", (0.2, 0.4, 0.9)))
    # A cube moving across at 0.6 m, 4 cm per frame (about 12 px), linear.
    bpy.ops.mesh.primitive_cube_add(size=0.08, location=(0.08, 0.6, -0.05))
    cube = bpy.context.object
    cube.data.materials.append(material("cube", (0.9, 0.2, 0.1)))
    # Linear keys, set the way that works in every Blender (4.4 and later keep f-curves in
    # action slots, not on the action).
    bpy.context.preferences.edit.keyframe_new_interpolation_type = 'LINEAR'
    for frame, x in [(0, 0.04), (3, 0.16)]:
        scene.frame_set(frame)
        cube.location.x = x
        cube.keyframe_insert("location", index=0)
    scene.frame_set(1)
    bpy.ops.object.light_add(type='SUN', rotation=(math.radians(50), 0, math.radians(30)))
    bpy.context.object.data.energy = 4.0
    bpy.ops.object.camera_add(location=(0, -0.0, 0), rotation=(math.radians(90), 0, 0))
    cam = bpy.context.object
    scene.camera = cam
    cam.data.lens = 50.0
    cam.data.sensor_fit = 'HORIZONTAL'
    cam.data.sensor_width = 36.0
    cam.data.dof.use_dof = True
    cam.data.dof.aperture_fstop = 2.0
    cam.data.dof.focus_distance = 0.8
    cam.data.clip_start = 0.01
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = 1.0
    return scene


def render_reference(scene, path, spp):
    scene.cycles.samples = spp
    scene.render.image_settings.file_format = 'OPEN_EXR'
    scene.render.image_settings.color_depth = '32'
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)


def compare(binary, a, b):
    out = subprocess.run([binary, "compare", a, b, "--json"], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(out.stderr)
    return json.loads(out.stdout)


def main():
    binary = os.environ.get("SPREADLET_BIN", "")
    spreadlet_blender.register()
    scene = build_scene()
    scene.cycles.samples = 32
    scene.spreadlet.work_folder = os.path.join(OUT, "work")
    scene.spreadlet.backend = "cpu"
    result = bpy.ops.spreadlet.render()
    assert result == {'FINISHED'}, f"the operator returned {result}"
    run = spreadlet_blender.last_run
    cam = json.load(open(run["camera_path"]))
    expected = dict(width=SIZE, height=SIZE, focal_length_mm=50.0, sensor_width_mm=36.0,
                    f_stop=2.0, focus_distance=0.8, aperture_blades=0, shutter_frames=1.0)
    for key, value in expected.items():
        got = cam[key]
        assert (got == value if not isinstance(value, float) else abs(got - value) < 1e-6), \
            f"camera.json {key}: {got}, expected {value}"
    # The add-on restored the scene's own settings.
    assert scene.camera.data.dof.use_dof and scene.render.use_motion_blur
    assert "Spreadlet Result" in bpy.data.images
    reference = os.path.join(OUT, "reference.exr")
    render_reference(scene, reference, 256)
    pinhole = compare(binary, run["input"], reference)
    ours = compare(binary, run["output"], reference)
    report = dict(pinhole=pinhole, spreadlet=ours, camera=cam, blender=bpy.app.version_string)
    json.dump(report, open(os.path.join(OUT, "report.json"), "w"), indent=1)
    print(f"SSIM against Cycles' depth of field and motion blur: pinhole {pinhole['ssim']:.4f}, "
          f"spreadlet {ours['ssim']:.4f}; FLIP {pinhole['flip_mean']:.4f} -> {ours['flip_mean']:.4f}")
    assert ours["ssim"] > pinhole["ssim"] + 0.015, report
    assert ours["flip_mean"] < pinhole["flip_mean"], report
    check_every_render(binary, scene, run["output"])
    check_blade_rotation(binary)
    check_anamorphic_ratio(binary)
    check_shared_cameras()
    spreadlet_blender.unregister()


def check_every_render(binary, scene, operator_output):
    """Animation and still renders with "Every render" on."""
    scene.cycles.samples = 32
    scene.spreadlet.every_render = True
    scene.spreadlet.work_folder = os.path.join(OUT, "every-render")
    scene.render.filepath = os.path.join(OUT, "animation", "shot_")
    scene.render.image_settings.file_format = 'PNG'
    scene.frame_start, scene.frame_end = 1, 2
    bpy.ops.render.render(animation=True)
    done = spreadlet_blender.last_animation
    expected = [os.path.join(OUT, "animation", f"shot_{f:04d}.exr") for f in (1, 2)]
    assert done["errors"] == [] and done["written"] == expected, done
    for path in expected:
        assert os.path.getsize(path) > 0, path
    # Frame 1 is the frame the operator rendered, with the same samples.
    same = compare(binary, expected[0], operator_output)
    assert same["ssim"] > 0.999, same
    moved = compare(binary, expected[1], expected[0])
    assert moved["ssim"] < 0.999, "frame 2 should differ from frame 1 (the cube moves)"
    # The render's own settings are back.
    assert scene.render.image_settings.file_format == 'PNG'
    assert scene.render.filepath == os.path.join(OUT, "animation", "shot_")
    assert scene.camera.data.dof.use_dof and scene.render.use_motion_blur
    # A still render that writes no file.
    bpy.data.images.remove(bpy.data.images["Spreadlet Result"])
    scene.frame_set(1)
    bpy.ops.render.render()
    done = spreadlet_blender.last_animation
    assert done["errors"] == [] and len(done["written"]) == 1, done
    assert "Spreadlet Result" in bpy.data.images
    still = compare(binary, done["written"][0], operator_output)
    assert still["ssim"] > 0.999, still
    scene.spreadlet.every_render = False
    print(f"Every render: frames {expected}; frame 1 against the operator's SSIM "
          f"{same['ssim']:.5f}; the still render's {still['ssim']:.5f}")


def emitter(location, radius, strength):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=location)
    m = bpy.data.materials.new("emitter")
    if bpy.app.version < (5, 0, 0):
        m.use_nodes = True
    nodes = m.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = strength
    m.node_tree.links.new(emission.outputs[0], nodes["Material Output"].inputs[0])
    bpy.context.object.data.materials.append(m)


def check_blade_rotation(binary):
    """Pentagonal bokeh turned by 20 degrees: the add-on's result must match Cycles' own
    turned bokeh, clearly better than the same input with the turn the other way (Cycles' 20
    degrees is spreadlet's 56; the other way, 36 - 20 = 16)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    world = bpy.data.worlds.new("black")
    world.color = (0, 0, 0)
    if world.node_tree is not None and "Background" in world.node_tree.nodes:  # Blender 5
        world.node_tree.nodes["Background"].inputs[0].default_value = (0, 0, 0, 1)
    scene.world = world
    # Two small emitters 2 m away, the lens focused at 0.2 m: bokeh about 28 px across.
    emitter((0.0, 2.0, 0.0), 0.008, 50.0)
    emitter((-0.35, 2.0, 0.25), 0.008, 50.0)
    bpy.ops.object.camera_add(location=(0, 0, 0), rotation=(math.radians(90), 0, 0))
    cam = bpy.context.object
    scene.camera = cam
    cam.data.lens = 50.0
    cam.data.sensor_fit = 'HORIZONTAL'
    cam.data.sensor_width = 36.0
    cam.data.clip_start = 0.01
    dof = cam.data.dof
    dof.use_dof, dof.aperture_fstop, dof.focus_distance = True, 1.4, 0.2
    dof.aperture_blades, dof.aperture_rotation = 5, math.radians(20.0)
    scene.cycles.samples = 16
    scene.spreadlet.work_folder = os.path.join(OUT, "bokeh")
    scene.spreadlet.backend = "cpu"
    scene.spreadlet.output_path = ""
    assert bpy.ops.spreadlet.render() == {'FINISHED'}
    run = spreadlet_blender.last_run
    assert abs(run["camera"]["aperture_rotation_deg"] - 56.0) < 1e-4, run["camera"]
    reference = os.path.join(OUT, "bokeh", "reference.exr")
    render_reference(scene, reference, 2048)
    ours = compare(binary, run["output"], reference)
    mirrored = os.path.join(OUT, "bokeh", "mirrored.exr")
    subprocess.run([binary, "synth", "--input", run["input"], "--camera", run["camera_path"],
                    "--aperture-rotation-deg", "16", "--out", mirrored, "--backend", "cpu", "-q"],
                   check=True)
    other = compare(binary, mirrored, reference)
    print(f"Blade rotation 20 degrees against Cycles' bokeh: PSNR {ours['psnr_db']:.2f} dB, "
          f"FLIP {ours['flip_mean']:.4f}; turned the other way {other['psnr_db']:.2f} dB, "
          f"FLIP {other['flip_mean']:.4f}")
    # PSNR and FLIP: on a black frame SSIM mostly scores the reference's noise.
    assert ours["psnr_db"] > other["psnr_db"] + 1.5, (ours, other)
    assert ours["flip_mean"] < 0.9 * other["flip_mean"], (ours, other)


def check_anamorphic_ratio(binary):
    """The blade-rotation scene with a round aperture squeezed 2x (Blender's aperture_ratio):
    the add-on's oval bokeh must match Cycles', clearly better than round bokeh."""
    scene = bpy.context.scene
    dof = scene.camera.data.dof
    dof.aperture_blades, dof.aperture_rotation, dof.aperture_ratio = 0, 0.0, 2.0
    scene.spreadlet.work_folder = os.path.join(OUT, "anamorphic")
    assert bpy.ops.spreadlet.render() == {'FINISHED'}
    run = spreadlet_blender.last_run
    assert run["camera"]["aperture_ratio"] == 2.0, run["camera"]
    reference = os.path.join(OUT, "anamorphic", "reference.exr")
    render_reference(scene, reference, 1024)
    ours = compare(binary, run["output"], reference)
    round_ = os.path.join(OUT, "anamorphic", "round.exr")
    subprocess.run([binary, "synth", "--input", run["input"], "--camera", run["camera_path"],
                    "--aperture-ratio", "1", "--out", round_, "--backend", "cpu", "-q"],
                   check=True)
    other = compare(binary, round_, reference)
    print(f"Anamorphic ratio 2 against Cycles' bokeh: PSNR {ours['psnr_db']:.2f} dB, "
          f"FLIP {ours['flip_mean']:.4f}; round bokeh {other['psnr_db']:.2f} dB, "
          f"FLIP {other['flip_mean']:.4f}")
    assert ours["psnr_db"] > other["psnr_db"] + 1.5, (ours, other)
    assert ours["flip_mean"] < 0.9 * other["flip_mean"], (ours, other)


def shared_folder():
    for d in (os.environ.get("SPREADLET_SHARED", ""),
              os.path.join(os.path.dirname(os.path.dirname(HERE)), "..", "shared")):
        if d and os.path.exists(os.path.join(d, "tools", "blender_refs.py")):
            return d
    return None


def check_shared_cameras():
    """The add-on reads the lens of the scenes that made `../shared/examples` as their
    camera.json says: the script's scene builders run here, as that script runs them."""
    shared = shared_folder()
    if shared is None:
        assert os.environ.get("SPREADLET_REQUIRE_SHARED") != "1", "no ../shared/tools"
        print("no ../shared/tools/blender_refs.py: the shared cameras are not checked")
        return
    source = open(os.path.join(shared, "tools", "blender_refs.py")).read()
    # Its definitions only: the render loop at the end is what this replaces.
    definitions = source[:source.index("\nfor name in (WANT")]
    refs = {"__name__": "blender_refs"}
    saved_argv = sys.argv
    sys.argv = ["blender_refs", "--", os.path.join(OUT, "refs")]
    try:
        exec(compile(definitions, "blender_refs.py", "exec"), refs)
    finally:
        sys.argv = saved_argv
    # Materials and animation do not touch the lens, and the script's use Blender 3.4's API
    # (socket names, f-curves on the action).
    refs["mat"] = lambda name, *args, **kwargs: bpy.data.materials.new(name)
    refs["animate"] = lambda *args, **kwargs: None
    from spreadlet_blender import camera as addon_camera
    checked = []
    for name, build in refs["SCENES"].items():
        path = os.path.join(shared, "examples", name, "camera.json")
        if not os.path.exists(path):
            continue
        scn = refs["reset"]()
        cam, effects = build(scn)
        # As the script's loop does: the miniature scale, then the reference's switches.
        cam.location = cam.location * refs["SCALE"]
        cam.data.dof.focus_distance *= refs["SCALE"]
        cam.data.dof.use_dof = effects["dof"]
        scn.render.use_motion_blur = effects["motion"]
        scn.render.motion_blur_shutter = 1.0
        got = addon_camera.camera_dict(scn)
        want = json.load(open(path))
        for key in ("width", "height", "focal_length_mm", "sensor_width_mm", "f_stop",
                    "focus_distance", "aperture_blades", "shutter_frames"):
            a, b = got[key], want[key]
            ok = a == b if a is None or b is None else abs(a - b) <= 1e-5 * max(1.0, abs(b))
            assert ok, f"{name}: the add-on reads {key} = {a}, camera.json says {b}"
        checked.append(name)
    assert checked, f"no camera.json in {shared}/examples"
    print(f"The add-on's camera reading matches camera.json of {', '.join(checked)}")


main()
