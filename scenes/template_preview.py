"""Render the default template head from several views into PNGs.

    python scenes/template_preview.py --level 0 --output out/views [--device cpu]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import warp as wp

from facewarp import default_template, render_mesh, save_png

VIEWS = {"front": "front", "side": "side", "three_quarter": "three_quarter", "back": (180.0, 0.0), "below": (0.0, -35.0)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--level", type=int, default=0)
    ap.add_argument("--output", type=Path, default=Path("out/views"))
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", type=int, default=800)
    args = ap.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    t = default_template(args.level)
    extra = [(V, F, (0.96, 0.96, 0.94)) for k, (V, F) in t.parts.items()]
    with wp.ScopedDevice(args.device):
        for name, view in VIEWS.items():
            img = render_mesh(t.vertices, t.faces, view=view, width=args.size, height=args.size,
                              extra_meshes=extra, device=args.device)
            print("wrote", save_png(args.output / f"{name}.png", img, title=f"level {args.level}: {name}"))


if __name__ == "__main__":
    main()
