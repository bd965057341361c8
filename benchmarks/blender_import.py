"""Import facewarp's rig (and animation) files in Blender and report what arrives.

Runs under Blender's Python (``bpy`` from PyPI: a separate environment, e.g. ``python3.11 -m venv
bpyenv && bpyenv/bin/pip install bpy==4.2.0``; not a facewarp dependency). For each file it resets
Blender, imports it (glTF: ``import_scene.gltf``; USD: ``wm.usd_import``) and reports the objects
and their types, the shape keys of each mesh, the armatures' bones, the actions and their frame
ranges, modifiers and constraints (mesh and transform caches), materials, cameras and lights, and playback: how far the skin's vertices move between the
first frame and a later one (the evaluated mesh, shape keys and armature applied).

    python -m facewarp build default --out /tmp/b
    python -m facewarp rig /tmp/b --out /tmp/rig.glb --inbetweens 1
    python -m facewarp rig /tmp/b --out /tmp/rig.usdc --inbetweens 1
    bpyenv/bin/python benchmarks/blender_import.py /tmp/rig.glb /tmp/rig.usdc \\
        --out benchmarks/results/blender_import.json

Uses no facewarp code (bpy's interpreter need not have it).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from datetime import datetime, timezone


def _skin_motion(scene, obj, frames) -> dict:
    import bpy

    out = {}
    base = None
    for f in frames:
        scene.frame_set(f)
        dg = bpy.context.evaluated_depsgraph_get()
        ev = obj.evaluated_get(dg)
        mesh = ev.to_mesh()
        co = [tuple(ev.matrix_world @ v.co) for v in mesh.vertices]
        ev.to_mesh_clear()
        if base is None:
            base = co
            continue
        d = max(sum((a - b) ** 2 for a, b in zip(p, q)) ** 0.5 for p, q in zip(co, base))
        out[str(f)] = d
    return out


def check(path: str) -> dict:
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    if path.lower().endswith((".glb", ".gltf")):
        bpy.ops.import_scene.gltf(filepath=path)
    else:
        bpy.ops.wm.usd_import(filepath=path)
    scene = bpy.context.scene
    objects = {o.name: o.type for o in scene.objects}
    shape_keys = {o.name: [k.name for k in o.data.shape_keys.key_blocks]
                  for o in scene.objects if o.type == "MESH" and o.data.shape_keys}
    armatures = {o.name: [b.name for b in o.data.bones] for o in scene.objects if o.type == "ARMATURE"}
    actions = {a.name: {"frame_range": [float(v) for v in a.frame_range], "fcurves": len(a.fcurves)}
               for a in bpy.data.actions}
    modifiers = {o.name: [m.type for m in o.modifiers] for o in scene.objects if o.modifiers}
    constraints = {o.name: [c.type for c in o.constraints] for o in scene.objects if o.constraints}
    skin = max((o for o in scene.objects if o.type == "MESH"), key=lambda o: len(o.data.vertices), default=None)
    motion = {}
    if skin is not None:
        start, end = int(scene.frame_start), int(scene.frame_end)
        if actions:
            lo = min(int(a["frame_range"][0]) for a in actions.values())
            hi = max(int(a["frame_range"][1]) for a in actions.values())
            start, end = min(start, lo), max(end, hi)
        frames = sorted({start + round(k * (end - start) / 12) for k in range(13)})
        motion = {"object": skin.name, "vertices": len(skin.data.vertices), "frames": [start, end],
                  "max_vertex_motion_m": _skin_motion(scene, skin, frames)}
    return {"file": path, "objects": objects, "shape_keys": shape_keys, "armatures": armatures, "actions": actions,
            "modifiers": modifiers, "constraints": constraints, "materials": sorted(m.name for m in bpy.data.materials),
            "cameras": [o.name for o in scene.objects if o.type == "CAMERA"],
            "lights": [o.name for o in scene.objects if o.type == "LIGHT"],
            "fps": scene.render.fps, "playback": motion}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    import bpy

    result = {"machine": {"platform": platform.platform(), "python": sys.version.split()[0],
                          "blender": bpy.app.version_string,
                          "date": datetime.now(timezone.utc).isoformat(timespec="seconds")},
              "imports": [check(f) for f in a.files]}
    text = json.dumps(result, indent=1)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text + "\n")
    for r in result["imports"]:
        keys = {k: len(v) for k, v in r["shape_keys"].items()}
        print(f"{r['file']}: {len(r['objects'])} objects, shape keys {keys}, armatures {r['armatures']}, "
              f"{len(r['actions'])} actions, playback {r['playback'].get('max_vertex_motion_m')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
