"""The lens and shutter of a Blender scene's camera as spreadlet's camera.json.

Conventions (docs/STOCHASTIC.md, ../shared/examples/*/camera.json): the sensor width maps to
the image width, focus distance is planar (along the camera's axis) in scene units, the
shutter is a fraction of a frame centred on the frame's time, the f-stop is the camera's
Depth of Field f-stop (null, with the focus distance, for a pinhole).
"""

import math


def sensor_width_mm(cam, width, height):
    """The sensor width (mm) that maps to the image width, from Blender's sensor fit."""
    fit = cam.sensor_fit
    if fit == 'VERTICAL':
        return cam.sensor_height * width / height
    if fit == 'HORIZONTAL' or width >= height:
        return cam.sensor_width
    # AUTO on a portrait frame: the sensor width fits the larger (vertical) dimension.
    return cam.sensor_width * width / height


def planar_distance(camera_object, point):
    """Distance of `point` (world space) from the camera along its viewing axis (-Z)."""
    m = camera_object.matrix_world
    forward = [-m[0][2], -m[1][2], -m[2][2]]
    norm = math.sqrt(sum(c * c for c in forward)) or 1.0
    rel = [point[i] - m[i][3] for i in range(3)]
    return sum(rel[i] * forward[i] for i in range(3)) / norm


def focus_distance(camera_object):
    """The focus distance Cycles uses: the focus object's planar distance when one is set."""
    dof = camera_object.data.dof
    target = dof.focus_object
    if target is not None:
        return planar_distance(camera_object, target.matrix_world.translation)
    return dof.focus_distance


def aperture_rotation_deg(dof):
    """spreadlet's blade rotation for Cycles' (`dof.aperture_rotation`, radians): both turn
    counter-clockwise on the image, but at rotation 0 Cycles has an edge facing right (its
    polygon's corners lie half a blade off the x axis) where spreadlet has a vertex, so
    spreadlet's angle is Cycles' plus half a blade (180 / blades degrees)."""
    return math.degrees(dof.aperture_rotation) + 180.0 / dof.aperture_blades


def render_size(scene):
    """The rendered image's size in pixels (resolution times its percentage)."""
    r = scene.render
    scale = r.resolution_percentage / 100.0
    return int(r.resolution_x * scale), int(r.resolution_y * scale)


def camera_dict(scene, camera_object=None, use_dof=None, use_motion_blur=None):
    """spreadlet's camera.json for `scene` seen by `camera_object` (the active camera).

    `use_dof` and `use_motion_blur` stand for the camera's and the render's own switches when
    those are off for the pinhole render (None: read them from the scene).
    """
    obj = camera_object or scene.camera
    if obj is None or obj.type != 'CAMERA':
        raise ValueError("the scene has no active camera")
    cam = obj.data
    if cam.type != 'PERSP':
        raise ValueError(f"camera {obj.name!r} is {cam.type}; spreadlet models perspective lenses")
    width, height = render_size(scene)
    dof = cam.dof
    lens = dof.use_dof if use_dof is None else use_dof
    blur = scene.render.use_motion_blur if use_motion_blur is None else use_motion_blur
    shutter = scene.render.motion_blur_shutter if blur else 0.0
    blades = dof.aperture_blades if lens and dof.aperture_blades >= 3 else 0
    return {
        "width": width,
        "height": height,
        "focal_length_mm": cam.lens,
        "sensor_width_mm": sensor_width_mm(cam, width, height),
        "f_stop": dof.aperture_fstop if lens else None,
        "focus_distance": focus_distance(obj) if lens else None,
        "aperture_blades": blades,
        "aperture_rotation_deg": aperture_rotation_deg(dof) if blades else 0.0,
        # The same squeeze as Cycles' (the aperture's width divided by it, after the turn).
        "aperture_ratio": dof.aperture_ratio if lens else 1.0,
        "shutter_frames": shutter,
        # Cycles sizes the aperture as lens (mm) * 1e-3 scene units: a scene unit is a metre.
        "scene_unit_mm": 1000.0,
        "renderer": "Blender " + _blender_version(),
    }


def _blender_version():
    try:
        import bpy

        return bpy.app.version_string
    except ImportError:  # outside Blender (tests of this module)
        return "unknown"
