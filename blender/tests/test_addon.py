"""The add-on in a real Blender, headless:

    SPREADLET_BIN=target/release/spreadlet blender -b --factory-startup \
        --python-exit-code 1 --python blender/tests/test_addon.py -- OUT_FOLDER

Builds a small scene at miniature scale, so that a real lens blurs by several pixels at
128x128 (a sphere 0.25 m from the camera in front of a textured wall at 0.8 m, a cube moving
across at 0.6 m, a camera at f/2 focused on the wall, the render's motion blur shutter at 1 frame), renders it at 128x128
through the add-on's operator, renders Cycles' own depth of field and motion blur of the same
scene as the reference, and checks: the camera values the add-on read are the ones set here,
and the add-on's result is clearly closer to the reference (SSIM, `spreadlet compare`) than the
pinhole input it started from.
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
    for frame, x in [(0, 0.04), (2, 0.12)]:
        scene.frame_set(frame)
        cube.location.x = x
        cube.keyframe_insert("location", index=0)
    for fc in cube.animation_data.action.fcurves:
        for k in fc.keyframe_points:
            k.interpolation = 'LINEAR'
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
    spreadlet_blender.unregister()


main()
