"""View-layer renders of a scene, as a compositing artist splits a frame to get round partial
occlusion: `layers.exr` beside the scene's `input.exr`, laid out as
../shared/examples/README.md describes the shared examples' `layers.exr`.

Run inside Blender 3.4 (`cycles_layers.sh` does this):

    blender -b -noaudio --python blender_layers.py -- OUT SCENE --tools DIR --scenes FILE \
        --foreground PREFIX[,PREFIX...] [--res N] [--spp N]

The scene comes from DIR/blender_refs.py's builders and FILE's `EXTRA_SCENES`
(bench/cycles/scenes.py), built and scaled exactly as blender_refs.py builds `input.exr`
(pinhole, 64 spp, seed 0, its pixel filter). An object whose material's name starts with one of
the prefixes goes to the `Foreground` layer, every other object to `Background`; lights stay in
both.
- `Background` renders its objects with the foreground set to indirect only: not seen, but
  still casting its shadows and light.
- `Foreground` renders its objects with the background held out on a transparent film:
  premultiplied colour and anti-aliased alpha edges.
Each layer carries Combined, Depth and Vector. Written to OUT/SCENE/layers.exr (multilayer,
32-bit float, ZIP).
"""
import bpy, sys, os, time

argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []


def take(name, default):
    if name in argv:
        i = argv.index(name); v = argv[i + 1]; del argv[i:i + 2]; return type(default)(v)
    return default


tools = take("--tools", "")
scenes = take("--scenes", "")
prefixes = [p for p in take("--foreground", "").split(",") if p]
res = take("--res", 512)
spp = take("--spp", 64)
if len(argv) != 2 or not tools or not scenes or not prefixes:
    raise SystemExit("blender_layers: usage: -- OUT SCENE --tools DIR --scenes FILE --foreground P[,P...]")
out, name = argv

# The builder's helpers and scene table, without its render loop; it reads its own options
# from sys.argv, so it is handed only the output folder, the resolution and the scene.
source = open(os.path.join(tools, "blender_refs.py")).read()
loop = source.find("\nfor name in (WANT")
if loop < 0:
    raise SystemExit("blender_layers: blender_refs.py has no render loop where it is expected")
sys.argv = [sys.argv[0], "--", out, name, "--res", str(res)]
exec(source[:loop])
exec(open(scenes).read())
SCENES.update(EXTRA_SCENES)
if name not in SCENES:
    raise SystemExit(f"blender_layers: no scene {name!r} (have {', '.join(sorted(SCENES))})")

scn = reset()
cam, eff = SCENES[name](scn)
# blender_refs.py's miniature scale, as for input.exr.
bpy.ops.object.empty_add(location=(0, 0, 0)); root = bpy.context.object
for o in list(scn.objects):
    if o not in (root, cam): o.parent = root
root.scale = (SCALE, SCALE, SCALE)
cam.location = cam.location * SCALE
cam.data.dof.focus_distance *= SCALE
cam.data.clip_start = 0.005
bpy.context.view_layer.update()

fg = bpy.data.collections.new("Foreground"); bg = bpy.data.collections.new("Background")
scn.collection.children.link(fg); scn.collection.children.link(bg)
split = {"Foreground": [], "Background": []}
for o in list(scn.objects):
    if o.type != 'MESH':
        continue
    names = [s.material.name for s in o.material_slots if s.material]
    front = any(n.startswith(p) for n in names for p in prefixes)
    dest = fg if front else bg
    for c in list(o.users_collection):
        c.objects.unlink(o)
    dest.objects.link(o)
    split[dest.name].append(names[0] if names else o.name)
if not split["Foreground"] or not split["Background"]:
    raise SystemExit(f"blender_layers: the prefixes {prefixes} split {name} into {split}")

front = scn.view_layers[0]; front.name = "Foreground"
back = scn.view_layers.new("Background")
for vl in (front, back):
    vl.use_pass_z = True; vl.use_pass_vector = True
    vl.use_pass_combined = True
front.layer_collection.children["Background"].holdout = True
back.layer_collection.children["Foreground"].indirect_only = True
scn.render.film_transparent = True
scn.render.use_motion_blur = False
cam.data.dof.use_dof = False
scn.cycles.samples = spp
scn.render.image_settings.file_format = 'OPEN_EXR_MULTILAYER'
scn.render.image_settings.color_depth = '32'
scn.render.image_settings.exr_codec = 'ZIP'
d = os.path.join(out, name); os.makedirs(d, exist_ok=True)
path = os.path.join(d, "layers.exr")
scn.render.filepath = path
t = time.time(); bpy.ops.render.render(write_still=True)
print(f"LAYERS {name} {path} {time.time() - t:.1f} s foreground={split['Foreground']} "
      f"background={split['Background']}", flush=True)
