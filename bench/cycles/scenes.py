"""Scenes of our own for Blender Cycles, in the builder style of ../shared/tools/blender_refs.py.

`cycles_frames.sh` runs this file inside a copy of blender_refs.py (before its scene table),
so `bpy`, `math` and the builder's helpers (`sun`, `mat`, `add`, `animate`, `camera`) are in
scope, and adds `EXTRA_SCENES` to the table. Units are the builder's: it scales every scene
by 0.1 (a miniature), so 8.0 here is a focus distance of 0.8 m.
"""

def area(loc, size, energy, rot=(0, 0, 0)):
    bpy.ops.object.light_add(type='AREA', location=loc, rotation=rot)
    o = bpy.context.object; o.data.size = size; o.data.energy = energy
    return o

def street(scn):
    # Night street: textured ground and facade, a soft area light (soft shadows, one bounce
    # on the ground), a pillar and a ball in focus, two cars passing with lamps at two depths.
    sun(0.2)
    area((2.5, -6, 6), 4.0, 3.0, rot=(math.radians(25), math.radians(15), 0))
    bpy.ops.mesh.primitive_plane_add(size=60, location=(0, 10, 0))
    add(bpy.context.object, mat("asphalt", (0.35, 0.33, 0.3), checker=60))
    bpy.ops.mesh.primitive_plane_add(size=60, location=(0, 10, 0), rotation=(math.radians(90), 0, 0))
    add(bpy.context.object, mat("facade", (0.7, 0.45, 0.3), checker=60))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-1.3, -2, 1.25))
    o = bpy.context.object; o.scale = (0.4, 0.4, 2.5); add(o, mat("pillar", (0.8, 0.8, 0.75), checker=8))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(1.0, -2, 0.5))
    add(bpy.context.object, mat("ball", (0.2, 0.5, 0.8)))
    for i, (x, y, d, body, lamp, sx) in enumerate([(-0.5, -4.5, (1.2, 0, 0), (0.6, 0.1, 0.1), (1, .95, .8), 1),
                                                   (1.0, 5.0, (-2.0, 0, 0), (0.2, 0.3, 0.5), (1, .2, .1), -1)]):
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(x, y, 0.6))
        car = bpy.context.object; car.scale = (2.0, 0.8, 0.6); add(car, mat(f"car{i}", body, checker=6))
        animate(car, delta=d)
        for k in (0.45, 0.75):
            bpy.ops.mesh.primitive_uv_sphere_add(radius=0.08, location=(x + sx * 1.02, y - 0.42, k))
            o = bpy.context.object; add(o, mat(f"lamp{i}{k}", lamp, emit=120)); animate(o, delta=d)
    return camera(scn, fstop=1.8, focus=8.0), dict(dof=True, motion=True)


def lights(scn):
    # A still with large bokeh: a checkered cube and a ball in focus on a table, and a string
    # of small lamps far behind them, under a soft area light.
    sun(0.3)
    area((-3, -8, 5), 3.0, 2.5, rot=(math.radians(50), math.radians(-20), 0))
    bpy.ops.mesh.primitive_plane_add(size=60, location=(0, 10, 0))
    add(bpy.context.object, mat("table", (0.5, 0.4, 0.3), checker=80))
    bpy.ops.mesh.primitive_plane_add(size=60, location=(0, 25, 0), rotation=(math.radians(90), 0, 0))
    add(bpy.context.object, mat("backdrop", (0.25, 0.3, 0.35), checker=30))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-0.7, -4, 0.5), rotation=(0, 0, math.radians(30)))
    add(bpy.context.object, mat("cube", (0.85, 0.8, 0.7), checker=5))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=(0.7, -4.2, 0.45))
    add(bpy.context.object, mat("ball", (0.7, 0.25, 0.2)))
    for i in range(9):
        x = -4.0 + i
        z = 1.6 + 0.35 * math.sin(i * 1.3)
        c = [(1, .8, .4), (.4, .7, 1), (1, .4, .6)][i % 3]
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.06, location=(x, 14 + 2 * (i % 2), z))
        add(bpy.context.object, mat(f"bulb{i}", c, emit=150))
    return camera(scn, fstop=1.4, focus=6.0), dict(dof=True, motion=False)

def disc(scn):
    # A textured disc spinning 30 degrees per frame in front of a wall, no emitters.
    sun(2.0)
    area((3, -6, 5), 2.0, 1.5, rot=(math.radians(40), math.radians(25), 0))
    bpy.ops.mesh.primitive_plane_add(size=60, location=(0, 6, 0), rotation=(math.radians(90), 0, 0))
    add(bpy.context.object, mat("wall", (0.6, 0.6, 0.55), checker=40))
    bpy.ops.mesh.primitive_cylinder_add(radius=2.0, depth=0.1, location=(0, 0, 1.5), rotation=(math.radians(90), 0, 0))
    d = bpy.context.object; add(d, mat("disc", (0.9, 0.6, 0.1), checker=8))
    p = d.location.copy(); r = d.rotation_euler.copy()
    for f, sgn in ((0, -0.5), (2, 0.5)):
        d.rotation_euler = (r[0], r[1] + sgn * math.radians(60), r[2])
        d.keyframe_insert("rotation_euler", frame=f)
    for fc in d.animation_data.action.fcurves:
        for k in fc.keyframe_points: k.interpolation = 'LINEAR'
    d.rotation_euler = r
    return camera(scn, fstop=2.8, focus=10.0), dict(dof=True, motion=True)

def turn_about(obj, centre, spin):
    """Turns `obj` about the vertical axis through `centre` by `spin` radians over frames 0 to 2
    (half of it per frame), centred on frame 1, like `animate`: location keyed on the chord,
    rotation added to its Euler z (the last of Blender's XYZ Euler rotations)."""
    p = obj.location.copy(); r = obj.rotation_euler.copy()
    for f, s in ((0, -0.5), (2, 0.5)):
        a = s * spin; dx, dy = p[0] - centre[0], p[1] - centre[1]
        obj.location = (centre[0] + math.cos(a) * dx - math.sin(a) * dy,
                        centre[1] + math.sin(a) * dx + math.cos(a) * dy, p[2])
        obj.rotation_euler = (r[0], r[1], r[2] + a)
        obj.keyframe_insert("location", frame=f); obj.keyframe_insert("rotation_euler", frame=f)
    for fc in obj.animation_data.action.fcurves:
        for k in fc.keyframe_points: k.interpolation = 'LINEAR'
    obj.location = p; obj.rotation_euler = r

def pan(scn):
    # The camera pans 3 degrees per frame along a street at dusk: every pixel moves (about
    # 37 px per frame at 512 px) and the depth runs from a near post to a far facade, with
    # small lamps at four depths. The world turns about the camera instead of the camera
    # turning: the stochastic tool moves its camera over the lens aperture, and an animated
    # camera would lose that offset (and the builder re-parents every object, so a turning
    # parent would be dropped).
    sun(0.15)
    area((2.5, -6, 6), 4.0, 2.0, rot=(math.radians(25), math.radians(15), 0))
    bpy.ops.mesh.primitive_plane_add(size=80, location=(0, 10, 0))
    add(bpy.context.object, mat("pavement", (0.4, 0.37, 0.33), checker=80))
    bpy.ops.mesh.primitive_plane_add(size=80, location=(0, 14, 0), rotation=(math.radians(90), 0, 0))
    add(bpy.context.object, mat("shopfront", (0.75, 0.5, 0.3), checker=70))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-0.9, -6.0, 1.0))
    o = bpy.context.object; o.scale = (0.15, 0.15, 2.0); add(o, mat("post", (0.8, 0.8, 0.75), checker=6))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.8, -1.5, 0.6))
    add(bpy.context.object, mat("ball", (0.2, 0.5, 0.8)))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-2.5, 4.0, 0.6))
    o = bpy.context.object; o.scale = (2.0, 0.8, 0.6); add(o, mat("parked", (0.6, 0.1, 0.1), checker=6))
    for i, (x, y, z, c) in enumerate([(-1.8, -4.0, 1.8, (1, .85, .6)), (1.6, 2.0, 2.2, (1, .6, .3)),
                                      (0.2, 9.0, 2.6, (.7, .8, 1)), (3.5, 12.0, 1.4, (1, .9, .7))]):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.07, location=(x, y, z))
        add(bpy.context.object, mat(f"lamp{i}", c, emit=150))
    cam = camera(scn, fstop=2.0, focus=8.0)
    for o in list(scn.objects):
        if o != cam:
            turn_about(o, cam.location, -math.radians(6.0))
    return cam, dict(dof=True, motion=True)

def approach(scn):
    # A car driving towards the camera at night, its lamps growing from small disks into large
    # bokeh as it leaves the focus plane, along a textured road, a near post out of focus
    # across it and a lit facade far behind: motion in depth (the car's distance falls by a
    # fifth within the frame) with defocus changing over the shutter.
    sun(0.15)
    area((-3, -5, 6), 3.0, 2.5, rot=(math.radians(30), math.radians(-20), 0))
    bpy.ops.mesh.primitive_plane_add(size=80, location=(0, 10, 0))
    add(bpy.context.object, mat("road", (0.35, 0.33, 0.3), checker=70))
    bpy.ops.mesh.primitive_plane_add(size=80, location=(0, 18, 0), rotation=(math.radians(90), 0, 0))
    add(bpy.context.object, mat("facade", (0.65, 0.5, 0.35), checker=50))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(-0.35, -7.0, 1.0))
    o = bpy.context.object; o.scale = (0.08, 0.08, 2.0); add(o, mat("post", (0.8, 0.8, 0.75), checker=4))
    d = (0.3, -2.5, 0)
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.4, 1.5, 0.55))
    car = bpy.context.object; car.scale = (1.0, 2.0, 0.55); add(car, mat("car", (0.15, 0.35, 0.6), checker=6))
    animate(car, delta=d)
    for sx in (-0.35, 0.35):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.07, location=(0.4 + sx, 1.5 - 1.02, 0.6))
        o = bpy.context.object; add(o, mat(f"lamp{sx}", (1, .93, .8), emit=150)); animate(o, delta=d)
    for i in range(5):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.06, location=(-3.0 + 1.5 * i, 17.5, 2.2 + 0.3 * (i % 2)))
        add(bpy.context.object, mat(f"window{i}", (1, .7, .4), emit=120))
    return camera(scn, fstop=2.0, focus=9.0), dict(dof=True, motion=True)

EXTRA_SCENES = dict(street=street, lights=lights, disc=disc, pan=pan, approach=approach)
