"""Render one frame of a facewarp USD file in Blender, with the file's own camera and lights.

Runs under Blender's Python (``bpy`` from PyPI, a separate environment: e.g. ``pip install --target
/opt/bpy5 bpy`` and ``PYTHONPATH=/opt/bpy5 python benchmarks/blender_render.py ...``; not a facewarp
dependency; uses no facewarp code). It resets Blender, imports the file (``wm.usd_import`` with
cameras, lights, materials and the dome light as the world), makes the imported camera the scene's,
renders frame ``--frame`` with Cycles on the CPU (``--samples`` samples, film transparent so that
only the head covers pixels) and writes the PNG and a JSON report: Blender's version, the scene's
frame rate and range as the importer set them, the lights that arrived (type, strength) and the
world's, and the mean brightness of the covered pixels (Rec. 709 luma of the sRGB-encoded render, 0..1,
over pixels with alpha > 0.5).

    PYTHONPATH=/opt/bpy5 python benchmarks/blender_render.py demo/animation.usdc --png b5.png --json b5.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def render(usd: str, png: str, *, frame: int | None = None, size: int = 256, samples: int = 16) -> dict:
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    if scene.world is None:  # the empty factory scene has none; the importer turns a dome light into it
        scene.world = bpy.data.worlds.new("World")
    kwargs = dict(filepath=str(usd), import_cameras=True, import_lights=True, import_materials=True,
                  set_frame_range=True)
    props = {p.identifier for p in bpy.ops.wm.usd_import.get_rna_type().properties}
    if "create_world_material" in props:
        kwargs["create_world_material"] = True
    bpy.ops.wm.usd_import(**kwargs)
    scene = bpy.context.scene
    cams = [o for o in scene.objects if o.type == "CAMERA"]
    if cams:
        scene.camera = cams[0]
    lights = [{"name": o.name, "type": o.data.type, "energy": float(o.data.energy),
               "angle_deg": float(getattr(o.data, "angle", 0.0)) * 57.29577951308232}
              for o in scene.objects if o.type == "LIGHT"]
    world = None
    if scene.world is not None and scene.world.use_nodes:
        bg = [n for n in scene.world.node_tree.nodes if n.type == "BACKGROUND"]
        if bg:
            world = {"strength": float(bg[0].inputs["Strength"].default_value),
                     "color": [float(c) for c in bg[0].inputs["Color"].default_value][:3],
                     "color_linked": bool(bg[0].inputs["Color"].is_linked)}
    if frame is not None:
        scene.frame_set(int(frame))
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(samples)
    if hasattr(scene.cycles, "use_denoising"):
        scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = int(size)
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.view_settings.view_transform = "Standard"
    scene.render.filepath = str(png)
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(png))
    px = list(img.pixels)  # float RGBA rows, the PNG's (sRGB-encoded) values
    lum, covered = 0.0, 0
    for i in range(0, len(px), 4):
        if px[i + 3] > 0.5:
            lum += 0.2126 * px[i] + 0.7152 * px[i + 1] + 0.0722 * px[i + 2]
            covered += 1
    return {"blender": bpy.app.version_string, "file": str(usd), "png": str(png),
            "fps": scene.render.fps / scene.render.fps_base, "frame_start": scene.frame_start,
            "frame_end": scene.frame_end, "frame": scene.frame_current, "camera": bool(cams), "lights": lights,
            "world": world, "covered_px": covered, "mean_brightness": lum / covered if covered else 0.0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("usd")
    ap.add_argument("--png", required=True)
    ap.add_argument("--json")
    ap.add_argument("--frame", type=int)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--samples", type=int, default=16)
    a = ap.parse_args(argv)
    a.png = str(Path(a.png).resolve())
    out = render(a.usd, a.png, frame=a.frame, size=a.size, samples=a.samples)
    text = json.dumps(out, indent=1)
    if a.json:
        Path(a.json).write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
