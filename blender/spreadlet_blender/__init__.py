"""Spreadlet depth of field and motion blur, in Blender.

Renders the scene as a pinhole (depth of field and motion blur off, Depth and Vector passes
on), hands the render with the active camera's lens and shutter to the `spreadlet` command,
and loads what it returns into the image "Spreadlet Result" (and, if asked, an EXR file).
With "Every rendered frame" on, animation renders do the same for every frame they write.
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
from bpy.app.handlers import persistent

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


#: The image settings the add-on changes to write 32-bit multilayer EXR (Blender 5 has a
#: media type beside the file format).
IMAGE_SETTINGS = ("media_type", "file_format", "color_depth", "exr_codec")


def use_multilayer_exr(settings):
    """Sets `settings` to 32-bit, ZIP-compressed multilayer OpenEXR, in any Blender."""
    if hasattr(settings, "media_type"):  # Blender 5.0 and later: the media type comes first
        settings.media_type = 'MULTI_LAYER_IMAGE'
    settings.file_format = 'OPEN_EXR_MULTILAYER'
    settings.color_depth = '32'
    settings.exr_codec = 'ZIP'


class PinholeRender:
    """Switches `scene` to a pinhole render with the passes spreadlet needs, written as 32-bit
    multilayer EXR, and restores every setting it changed on exit. `lens_on` and `blur_on`
    keep the camera's and the render's own switches for reading the lens."""

    def __init__(self, scene):
        self.scene = scene

    def __enter__(self):
        s = self.scene
        layer = getattr(bpy.context, "view_layer", None) or s.view_layers[0]
        settings = s.render.image_settings
        self.saved = dict(
            use_dof=s.camera.data.dof.use_dof,
            use_motion_blur=s.render.use_motion_blur,
            use_pass_z=layer.use_pass_z,
            use_pass_vector=layer.use_pass_vector,
            filepath=s.render.filepath,
        )
        self.saved_image = {k: getattr(settings, k) for k in IMAGE_SETTINGS if hasattr(settings, k)}
        self.layer, self.camera_data = layer, s.camera.data
        self.lens_on, self.blur_on = self.saved["use_dof"], self.saved["use_motion_blur"]
        s.camera.data.dof.use_dof = False
        # Blender writes no Vector pass while it renders motion blur itself.
        s.render.use_motion_blur = False
        layer.use_pass_z = True
        layer.use_pass_vector = True
        use_multilayer_exr(settings)
        return self

    def render_to(self, path):
        bpy.ops.render.render()
        bpy.data.images['Render Result'].save_render(path, scene=self.scene)

    def __exit__(self, *exc):
        s, v, settings = self.scene, self.saved, self.scene.render.image_settings
        self.camera_data.dof.use_dof = v["use_dof"]
        s.render.use_motion_blur = v["use_motion_blur"]
        self.layer.use_pass_z = v["use_pass_z"]
        self.layer.use_pass_vector = v["use_pass_vector"]
        s.render.filepath = v["filepath"]
        for key, value in self.saved_image.items():
            setattr(settings, key, value)
        return False


def synth(context, input_path, cam, out_path, folder, props, tag=""):
    """Runs `spreadlet synth` on `input_path` with the lens `cam` (a camera.json dict),
    keeping `camera{tag}.json` and `stats{tag}.json` in `folder`."""
    cam_path = os.path.join(folder, f"camera{tag}.json")
    with open(cam_path, "w") as f:
        json.dump(cam, f, indent=1)
    stats_path = os.path.join(folder, f"stats{tag}.json")
    command = [spreadlet_binary(context), "synth", "--input", input_path, "--camera",
               cam_path, "--out", out_path, "--stats", stats_path, "--backend", props.backend,
               "--db-profile", props.db_profile, "--quiet"]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(done.stderr.strip() or f"spreadlet exited with {done.returncode}")
    return cam_path, stats_path


def load_result(path):
    """Loads `path` as the image "Spreadlet Result", replacing the previous one."""
    old = bpy.data.images.get(RESULT_IMAGE)
    if old is not None:
        bpy.data.images.remove(old)
    image = bpy.data.images.load(path, check_existing=False)
    image.name = RESULT_IMAGE
    return image


def run_spreadlet(context, folder):
    """Renders the pinhole input into `folder`, runs spreadlet on it, loads the result."""
    global _operator_running
    scene = context.scene
    props = scene.spreadlet
    cam = camera.camera_dict(scene)
    input_path = os.path.join(folder, "input.exr")
    _operator_running = True
    try:
        with PinholeRender(scene) as pinhole:
            pinhole.render_to(input_path)
    finally:
        _operator_running = False
    out_path = bpy.path.abspath(props.output_path) if props.output_path else os.path.join(
        folder, "spreadlet.exr")
    cam_path, stats_path = synth(context, input_path, cam, out_path, folder, props)
    image = load_result(out_path)
    last_run.clear()
    last_run.update(camera=cam, camera_path=cam_path, input=input_path, output=out_path,
                    stats=stats_path, image=image.name)
    return out_path


# --- every render ------------------------------------------------------------------------
# With "Every render" on, a render (F12, Render Animation, `blender -b -a`) renders pinhole
# frames with the passes. Frames the render writes go to the work folder, and after each is
# written spreadlet writes the finished frame where the render would have put it (as EXR); a
# still render that writes nothing ends with its result in the image "Spreadlet Result".

_operator_running = False
#: The animation render being followed: its pinhole switch, the outputs, what went wrong.
animation = {}


def _work_folder(scene):
    folder = bpy.path.abspath(scene.spreadlet.work_folder) if scene.spreadlet.work_folder \
        else tempfile.mkdtemp(prefix="spreadlet-")
    os.makedirs(folder, exist_ok=True)
    return folder


@persistent
def _on_render_init(scene, *args):
    if _operator_running or animation or not scene.spreadlet.every_render:
        return
    if scene.camera is None or scene.camera.type != 'CAMERA':
        print("Spreadlet: the scene has no active camera; this render is left as it is")
        return
    pinhole = PinholeRender(scene).__enter__()
    render = scene.render
    # Where the render would have written each frame, now that the format is EXR.
    frames = range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step))
    outputs = {f: render.frame_path(frame=f) for f in frames}
    folder = _work_folder(scene)
    render.filepath = os.path.join(folder, "pinhole_####")
    animation.update(pinhole=pinhole, outputs=outputs, folder=folder, written=[], errors=[])


@persistent
def _on_render_write(scene, *args):
    if not animation:
        return
    frame = scene.frame_current
    pinhole = animation["pinhole"]
    try:
        cam = camera.camera_dict(scene, use_dof=pinhole.lens_on, use_motion_blur=pinhole.blur_on)
        out = animation["outputs"].get(frame) or scene.render.frame_path(frame=frame)
        os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
        synth(bpy.context, scene.render.frame_path(frame=frame), cam, out, animation["folder"],
              scene.spreadlet, tag=f"_{frame:04d}")
        animation["written"].append(out)
        print(f"Spreadlet: frame {frame} -> {out}")
    except (RuntimeError, ValueError, OSError) as e:
        animation["errors"].append(f"frame {frame}: {e}")
        print(f"Spreadlet: frame {frame} failed: {e}")


@persistent
def _on_render_done(scene, *args):
    if not animation:
        return
    pinhole = animation["pinhole"]
    if not animation["written"] and not animation["errors"] and args[-1:] != ("cancel",):
        # A still render that wrote no file: its result is in the Render Result.
        try:
            cam = camera.camera_dict(scene, use_dof=pinhole.lens_on,
                                     use_motion_blur=pinhole.blur_on)
            folder = animation["folder"]
            input_path = os.path.join(folder, "input.exr")
            bpy.data.images['Render Result'].save_render(input_path, scene=scene)
            out = os.path.join(folder, "spreadlet.exr")
            synth(bpy.context, input_path, cam, out, folder, scene.spreadlet)
            load_result(out)
            animation["written"].append(out)
        except (RuntimeError, ValueError, OSError, KeyError) as e:
            animation["errors"].append(f"still render: {e}")
            print(f"Spreadlet: the still render failed: {e}")
    pinhole.__exit__(None, None, None)
    last_animation.clear()
    last_animation.update(written=list(animation["written"]), errors=list(animation["errors"]),
                          folder=animation["folder"])
    animation.clear()


#: What the last animation render did: the frames written and the errors (for scripts, tests).
last_animation = {}


@persistent
def _on_render_cancel(scene, *args):
    _on_render_done(scene, "cancel")


HANDLERS = (("render_init", _on_render_init), ("render_write", _on_render_write),
            ("render_complete", _on_render_done), ("render_cancel", _on_render_cancel))


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
    every_render: bpy.props.BoolProperty(
        name="Every render",
        description="Apply to every render: F12 leaves the result in the image \"Spreadlet "
        "Result\"; an animation render writes its pinhole frames to the work folder and "
        "spreadlet writes each finished frame, as EXR, where the output path puts it",
        default=False)


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
        col.prop(props, "every_render")
        col.operator(SPREADLET_OT_render.bl_idname, icon='RENDER_STILL')


CLASSES = (SpreadletSettings, SpreadletPreferences, SPREADLET_OT_render, SPREADLET_PT_render)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.spreadlet = bpy.props.PointerProperty(type=SpreadletSettings)
    for name, handler in HANDLERS:
        getattr(bpy.app.handlers, name).append(handler)


def unregister():
    for name, handler in HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if handler in handlers:
            handlers.remove(handler)
    del bpy.types.Scene.spreadlet
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
