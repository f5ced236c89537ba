"""Spreadlet depth of field and motion blur, in Blender.

Renders the scene as a pinhole (depth of field and motion blur off, Depth and Vector passes
on), hands the render with the active camera's lens and shutter to the `spreadlet` command,
and loads what it returns into the image "Spreadlet Result" (and, if asked, an EXR file).
It calls the `spreadlet` binary rather than a compiled Python module: Blender ships its own
Python (3.10 in Blender 3.4, 3.11 in 4.x), and a module built for another Python does not
import there; the binary works with every Blender and keeps the GPU work out of Blender's
process.
"""

bl_info = {
    "name": "Spreadlet depth of field and motion blur",
    "author": "spreadlet",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Render > Spreadlet",
    "description": "Adds depth of field and motion blur to a pinhole render by splatting "
    "sparse Laplacian PSFs (the spreadlet command)",
    "category": "Render",
}

import json
import os
import shutil
import subprocess
import tempfile

if "bpy" in locals():  # reloading the add-on
    import importlib

    importlib.reload(camera)  # noqa: F821
else:
    from . import camera

import bpy

RESULT_IMAGE = "Spreadlet Result"
#: What the last run did: paths and the camera it read (for scripts and tests).
last_run = {}


def spreadlet_binary(context):
    """The spreadlet command: the add-on's preference, $SPREADLET_BIN, else the PATH."""
    prefs = context.preferences.addons.get(__name__)
    path = prefs.preferences.binary if prefs is not None else ""
    path = path or os.environ.get("SPREADLET_BIN", "") or shutil.which("spreadlet") or ""
    if not path or not os.path.exists(path):
        raise RuntimeError(
            "the spreadlet command was not found: set its path in the add-on's preferences, "
            "or $SPREADLET_BIN, or put it on the PATH (cargo install --path cli)"
        )
    return path


class PinholeRender:
    """Renders `scene` as a pinhole with the passes spreadlet needs, restoring every setting
    it changed afterwards, and saves the render result as a multilayer EXR."""

    def __init__(self, scene):
        self.scene = scene

    def __enter__(self):
        s = self.scene
        layer = bpy.context.view_layer
        settings = s.render.image_settings
        self.saved = dict(
            use_dof=s.camera.data.dof.use_dof,
            use_motion_blur=s.render.use_motion_blur,
            use_pass_z=layer.use_pass_z,
            use_pass_vector=layer.use_pass_vector,
            file_format=settings.file_format,
            color_depth=settings.color_depth,
            exr_codec=settings.exr_codec,
        )
        self.layer = layer
        s.camera.data.dof.use_dof = False
        # Blender writes no Vector pass while it renders motion blur itself.
        s.render.use_motion_blur = False
        layer.use_pass_z = True
        layer.use_pass_vector = True
        return self

    def render_to(self, path):
        bpy.ops.render.render()
        settings = self.scene.render.image_settings
        settings.file_format = 'OPEN_EXR_MULTILAYER'
        settings.color_depth = '32'
        settings.exr_codec = 'ZIP'
        bpy.data.images['Render Result'].save_render(path, scene=self.scene)

    def __exit__(self, *exc):
        s, v, settings = self.scene, self.saved, self.scene.render.image_settings
        s.camera.data.dof.use_dof = v["use_dof"]
        s.render.use_motion_blur = v["use_motion_blur"]
        self.layer.use_pass_z = v["use_pass_z"]
        self.layer.use_pass_vector = v["use_pass_vector"]
        settings.file_format = v["file_format"]
        settings.color_depth = v["color_depth"]
        settings.exr_codec = v["exr_codec"]
        return False


def run_spreadlet(context, folder):
    """Renders the pinhole input into `folder`, runs spreadlet on it, loads the result."""
    scene = context.scene
    props = scene.spreadlet
    cam = camera.camera_dict(scene)
    cam_path = os.path.join(folder, "camera.json")
    with open(cam_path, "w") as f:
        json.dump(cam, f, indent=1)
    input_path = os.path.join(folder, "input.exr")
    with PinholeRender(scene) as pinhole:
        pinhole.render_to(input_path)
    out_path = bpy.path.abspath(props.output_path) if props.output_path else os.path.join(
        folder, "spreadlet.exr")
    stats_path = os.path.join(folder, "stats.json")
    command = [spreadlet_binary(context), "synth", "--input", input_path, "--camera", cam_path,
               "--out", out_path, "--stats", stats_path, "--backend", props.backend,
               "--db-profile", props.db_profile, "--quiet"]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(done.stderr.strip() or f"spreadlet exited with {done.returncode}")
    old = bpy.data.images.get(RESULT_IMAGE)
    if old is not None:
        bpy.data.images.remove(old)
    image = bpy.data.images.load(out_path, check_existing=False)
    image.name = RESULT_IMAGE
    last_run.clear()
    last_run.update(camera=cam, camera_path=cam_path, input=input_path, output=out_path,
                    stats=stats_path, image=image.name)
    return out_path


class SPREADLET_OT_render(bpy.types.Operator):
    """Render the scene as a pinhole and add the camera's depth of field and motion blur
    with spreadlet"""

    bl_idname = "spreadlet.render"
    bl_label = "Render with Spreadlet depth of field and motion blur"

    def execute(self, context):
        folder = bpy.path.abspath(context.scene.spreadlet.work_folder) or tempfile.mkdtemp(
            prefix="spreadlet-")
        os.makedirs(folder, exist_ok=True)
        try:
            out = run_spreadlet(context, folder)
        except (RuntimeError, ValueError, OSError) as e:
            self.report({'ERROR'}, f"Spreadlet: {e}")
            return {'CANCELLED'}
        self.report({'INFO'}, f"Spreadlet: {out}")
        return {'FINISHED'}


class SpreadletSettings(bpy.types.PropertyGroup):
    backend: bpy.props.EnumProperty(
        name="Device",
        items=[("auto", "Auto", "The GPU when there is one, else the CPU"),
               ("gpu", "GPU", "The GPU"), ("cpu", "CPU", "The CPU")],
        default="auto")
    db_profile: bpy.props.EnumProperty(
        name="Database profile",
        description="Profile of PSF databases built on first use (quick: seconds to minutes)",
        items=[("quick", "Quick", ""), ("paper", "Paper", ""), ("test", "Test", "")],
        default="quick")
    output_path: bpy.props.StringProperty(
        name="Output EXR", subtype='FILE_PATH',
        description="Also keep the result here (empty: the work folder only)")
    work_folder: bpy.props.StringProperty(
        name="Work folder", subtype='DIR_PATH',
        description="Where the pinhole input, camera.json and statistics go (empty: a "
        "temporary folder)")


class SpreadletPreferences(bpy.types.AddonPreferences):
    bl_idname = __name__
    binary: bpy.props.StringProperty(
        name="spreadlet command", subtype='FILE_PATH',
        description="Path of the spreadlet binary (empty: $SPREADLET_BIN or the PATH)")

    def draw(self, context):
        self.layout.prop(self, "binary")


class SPREADLET_PT_render(bpy.types.Panel):
    bl_label = "Spreadlet depth of field and motion blur"
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "render"

    def draw(self, context):
        props = context.scene.spreadlet
        col = self.layout.column()
        col.label(text="Lens and shutter: the active camera's Depth of Field and the "
                  "render's Motion Blur shutter")
        col.prop(props, "backend")
        col.prop(props, "db_profile")
        col.prop(props, "output_path")
        col.prop(props, "work_folder")
        col.operator(SPREADLET_OT_render.bl_idname, icon='RENDER_STILL')


CLASSES = (SpreadletSettings, SpreadletPreferences, SPREADLET_OT_render, SPREADLET_PT_render)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.spreadlet = bpy.props.PointerProperty(type=SpreadletSettings)


def unregister():
    del bpy.types.Scene.spreadlet
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
