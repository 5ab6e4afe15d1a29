"""Run inside Blender (``blender -b --python blender_import.py -- IN.json OUT.json``): import a
BVH and a GLB with Blender's own importers and report bone heads and skinned vertices.

IN.json: ``{"bvh": path, "glb": path, "fps": float, "frames": [row, ...]}``; OUT.json gets
``{"bvh_heads": {frame: {bone: [x, y, z]}}, "glb_verts": {frame: {mesh: [[x, y, z], ...]}},
"cameras": n, "actions": [...]}`` in Blender's world (z-up, metres).
"""

import builtins
import json
import sys

import bpy  # type: ignore[import-not-found]

_open = builtins.open


def _open_without_u(file, mode="r", *args, **kwargs):  # type: ignore[no-untyped-def]
    # Debian's Blender 3.4 BVH importer opens files in mode "rU", which Python 3.11 removed.
    return _open(file, mode.replace("U", ""), *args, **kwargs)


builtins.open = _open_without_u
try:
    import numpy

    if not hasattr(numpy, "bool"):
        numpy.bool = bool  # type: ignore[misc,assignment]  # Debian's Blender 3.4 glTF importer uses np.bool (removed in numpy 1.24)
except ImportError:
    pass

args = sys.argv[sys.argv.index("--") + 1 :]
cfg = json.load(_open(args[0]))
out: dict = {"bvh_heads": {}, "glb_verts": {}}

bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=cfg["bvh"], global_scale=0.01, axis_forward="-Z", axis_up="Y", frame_start=1)
arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
for f in cfg["frames"]:
    bpy.context.scene.frame_set(f + 1)  # the BVH import keys its first frame at frame_start
    out["bvh_heads"][str(f)] = {pb.name: list(arm.matrix_world @ pb.head) for pb in arm.pose.bones}

bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.context.scene.render.fps = int(
    round(cfg["fps"])
)  # the glTF importer keys at the scene rate, t = 0 at frame 0
bpy.ops.import_scene.gltf(filepath=cfg["glb"])
out["cameras"] = sum(o.type == "CAMERA" for o in bpy.data.objects)
out["actions"] = sorted(a.name for a in bpy.data.actions)
for f in cfg["frames"]:
    bpy.context.scene.frame_set(f)
    dg = bpy.context.evaluated_depsgraph_get()
    out["glb_verts"][str(f)] = {}
    for o in bpy.data.objects:
        if o.type == "MESH" and o.name.endswith("_body"):
            e = o.evaluated_get(dg)
            out["glb_verts"][str(f)][o.name] = [list(e.matrix_world @ v.co) for v in e.data.vertices]
json.dump(out, _open(args[1], "w"))
