"""Import facewarp's rig (and animation) files in Blender and report what arrives.

Runs under Blender's Python (``bpy`` from PyPI: a separate environment, e.g. ``python3.11 -m venv
bpyenv && bpyenv/bin/pip install bpy==4.2.0``; not a facewarp dependency). For each file it resets
Blender, imports it (glTF: ``import_scene.gltf``; USD: ``wm.usd_import``) and reports the objects
and their types, the shape keys of each mesh, the armatures' bones, the actions and their frame
ranges, modifiers and constraints (mesh and transform caches), materials, cameras and lights, and
playback: how far the skin's vertices move between the first frame and a later one (the evaluated mesh, shape keys and armature applied). Per mesh, its
UV maps and its materials' base colour: a Principled BSDF whose Base Color is linked from an Image
Texture node (the image's file name, size in pixels, whether its pixels loaded, colour space),
or the flat colour when nothing is linked; ``skin_texture`` says whether the skin (the mesh with
the most vertices) shows an image that loaded.

    python -m facewarp build default --out /tmp/b
    python -m facewarp rig /tmp/b --out /tmp/rig.glb --inbetweens 1
    python -m facewarp rig /tmp/b --out /tmp/rig.usdc --inbetweens 1
    bpyenv/bin/python benchmarks/blender_import.py /tmp/rig.glb /tmp/rig.usdc \\
        --out benchmarks/results/blender_import.json

    python -m facewarp demo --out /tmp/demo --quick     # the skin's texture: animation.usdc + animation_skin.png
    bpyenv/bin/python benchmarks/blender_import.py /tmp/demo/animation.usdc \\
        --out benchmarks/results/blender_texture.json

Uses no facewarp code (bpy's interpreter need not have it).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from datetime import datetime, timezone
from pathlib import Path


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


def _base_color(mat) -> dict:
    """What feeds a material's Principled BSDF Base Color: an image (file, size, loaded) or a flat colour."""
    out: dict = {"material": mat.name, "use_nodes": bool(mat.use_nodes)}
    if not mat.use_nodes or mat.node_tree is None:
        out["base_color"] = [float(c) for c in mat.diffuse_color]
        return out
    bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None:
        out["nodes"] = sorted(n.type for n in mat.node_tree.nodes)
        return out
    sock = bsdf.inputs["Base Color"]
    if not sock.is_linked:
        out["base_color"] = [float(c) for c in sock.default_value]
        return out
    node = sock.links[0].from_node
    while node.type != "TEX_IMAGE" and any(i.is_linked for i in node.inputs):  # through mix / colour nodes
        node = next(i for i in node.inputs if i.is_linked).links[0].from_node
    out["linked_from"] = node.type
    if node.type == "TEX_IMAGE" and node.image is not None:
        img = node.image
        out["image"] = {"name": img.name, "file": bpy_path_name(img.filepath), "filepath": img.filepath,
                        "size_px": [int(v) for v in img.size], "has_data": bool(img.has_data),
                        "packed": img.packed_file is not None, "colorspace": img.colorspace_settings.name}
        uv_in = node.inputs["Vector"]
        out["image"]["uv_input"] = uv_in.links[0].from_node.type if uv_in.is_linked else "default UV map"
    return out


def bpy_path_name(path: str) -> str:
    """The file name of a Blender path (``//`` relative or absolute)."""
    return path.replace("\\", "/").rsplit("/", 1)[-1]


def _mesh_looks(scene) -> dict:
    """Per mesh object: its UV maps and what each material slot's base colour comes from."""
    out = {}
    for o in scene.objects:
        if o.type != "MESH":
            continue
        counts = [0] * len(o.material_slots)
        for poly in o.data.polygons:
            if poly.material_index < len(counts):
                counts[poly.material_index] += 1
        mats = []
        for i, slot in enumerate(o.material_slots):
            if slot.material is not None:
                mats.append({**_base_color(slot.material), "faces": counts[i]})
        out[o.name] = {"uv_maps": [uv.name for uv in o.data.uv_layers], "faces": len(o.data.polygons),
                       "materials": mats}
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
    looks = _mesh_looks(scene)
    skin_look = looks.get(skin.name, {}) if skin is not None else {}
    images = [m["image"] for m in skin_look.get("materials", []) if "image" in m]
    loaded = any(i["has_data"] and min(i["size_px"]) > 0 for i in images)
    skin_texture = {"object": skin.name if skin is not None else None, "uv_maps": skin_look.get("uv_maps", []),
                    "images": images, "ok": bool(skin_look.get("uv_maps")) and loaded}
    return {"file": path, "objects": objects, "looks": looks, "skin_texture": skin_texture, "shape_keys": shape_keys,
            "armatures": armatures, "actions": actions,
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

    result = {"blender": bpy.app.version_string, "imports": [check(f) for f in a.files]}
    if a.out:
        out = Path(a.out)
        try:  # the one result schema (benchmarks/_common.py needs only the standard library to import)
            sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
            from benchmarks import _common
        except ImportError:
            result["machine"] = {"platform": platform.platform(), "python": sys.version.split()[0],
                                 "date": datetime.now(timezone.utc).isoformat(timespec="seconds")}
            out.write_text(json.dumps(result, indent=1) + "\n")
        else:
            _common.command_line = " ".join(["bpyenv/bin/python benchmarks/blender_import.py", *sys.argv[1:]])
            _common.save(out.stem, result, benchmark="blender_import", folder=out.parent,
                         machine_extra={"blender": bpy.app.version_string})
    for r in result["imports"]:
        keys = {k: len(v) for k, v in r["shape_keys"].items()}
        print(f"{r['file']}: {len(r['objects'])} objects, shape keys {keys}, armatures {r['armatures']}, "
              f"{len(r['actions'])} actions, playback {r['playback'].get('max_vertex_motion_m')}; skin texture "
              f"{r['skin_texture']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
