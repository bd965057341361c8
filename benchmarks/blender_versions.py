"""One USD file rendered by several Blender versions with its own camera and lights: the face's mean brightness in each.

Each Blender is a ``bpy`` install folder named in ``FACEWARP_BPY`` (``os.pathsep``-separated; e.g.
``pip install --target /opt/bpy42 bpy==4.2.0`` and ``pip install --target /opt/bpy5 bpy``; a folder
``np1`` beside them with NumPy 1.x is put first on the path where present, for bpy's own modules).
``benchmarks/blender_render.py`` runs under each (Cycles, CPU, film transparent) at ``--frame``; the
result holds each version's report (the lights and world the importer made, the frame rate it set,
the mean brightness of the covered pixels) and the ratio of the brightest to the darkest, and the
renders side by side as a small PNG.

    FACEWARP_BPY=/opt/bpy5:/opt/bpy42 python -m benchmarks blender_versions DEMO/animation.usdc --frame 21 \\
        --name blender_demo
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks._common import RESULTS, save

SCRIPT = Path(__file__).resolve().parent / "blender_render.py"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("usd", type=Path)
    ap.add_argument("--frame", type=int, default=None)
    ap.add_argument("--size", type=int, default=320)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--name", default="blender_versions")
    a = ap.parse_args(argv)
    from PIL import Image

    folders = [d for d in os.environ.get("FACEWARP_BPY", "").split(os.pathsep) if d and (Path(d) / "bpy").is_dir()]
    if not folders:
        print("no Blender: set FACEWARP_BPY to bpy install folders", file=sys.stderr)
        return 2
    runs, pics = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k, d in enumerate(folders):
            np1 = Path(d).parent / "np1"
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(([str(np1)] if np1.is_dir() else []) + [d])}
            png, js = Path(tmp) / f"{k}.png", Path(tmp) / f"{k}.json"
            cmd = [sys.executable, str(SCRIPT), str(a.usd), "--png", str(png), "--json", str(js), "--size",
                   str(a.size), "--samples", str(a.samples)] + ([] if a.frame is None else ["--frame", str(a.frame)])
            r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1200)
            if r.returncode:
                print(r.stderr[-2000:], file=sys.stderr)
                return 1
            runs.append(json.loads(js.read_text()))
            im = Image.open(png).convert("RGBA")
            bg = Image.new("RGB", im.size, (255, 255, 255))
            bg.paste(im, mask=im.split()[3])
            pics.append((bg, im.getbbox()))
        boxes = [b for _, b in pics if b]
        box = (min(b[0] for b in boxes) - 8, min(b[1] for b in boxes) - 8, max(b[2] for b in boxes) + 8,
               max(b[3] for b in boxes) + 8) if boxes else None
        crops = [p.crop(box) if box else p for p, _ in pics]
        sheet = Image.new("RGB", (sum(c.width for c in crops) + 8 * (len(crops) - 1), crops[0].height), "white")
        x = 0
        for c in crops:
            sheet.paste(c, (x, 0))
            x += c.width + 8
        sheet.save(RESULTS / f"{a.name}.png", optimize=True)
    b = [r["mean_brightness"] for r in runs]
    figures = {"file": a.usd.name, "frame": a.frame, "renders": runs, "brightness_ratio_max_over_min": max(b) / min(b),
               "picture": f"{a.name}.png"}
    for r in runs:
        r.pop("png", None)
        r["file"] = a.usd.name
    print(" ".join(f"Blender {r['blender']}: {r['mean_brightness']:.3f}" for r in runs)
          + f"; ratio {figures['brightness_ratio_max_over_min']:.3f}")
    save(a.name, figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
