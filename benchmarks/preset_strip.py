"""The presets on the default head: a picture of each at its peak, and the table of measured
amplitudes beside the real (human) ranges for the README.

    python -m benchmarks preset_strip [--level 0] [--seconds 1.0] [--device cpu] [--table-only] [--readme]

Picture: builds the default head, plays every preset (ramped in over 0.3 s and held, the default
simulator: implicit solver, physical material, kinematic jaw) and renders the whole head at the end
of the run, front view, beside the head at rest -> ``benchmarks/results/preset_strip.png``.

Table: the README table ``preset_targets`` (:mod:`benchmarks._tables`), generated from
``benchmarks/results/expression_targets_L0.json`` (written by ``python -m benchmarks expression_targets``;
re-run that first after changing muscles or presets); printed, and with ``--readme`` rewritten in
README.md with every other table (as ``python -m benchmarks --tables``). ``--table-only`` skips the
simulation and the picture.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from benchmarks._common import RESULTS, add_case_args

COLUMNS = 4
"""Heads per row of the picture."""


# ------------------------------------------------------------------------------------- picture
def render_strip(level: int, seconds: float, device: str, face_height: int) -> Path:
    import facewarp as fw
    from facewarp.render import FaceView, label_grid
    from facewarp import save_png

    rig = fw.build_face(fw.default_template(level))
    names = [n for n in fw.PRESETS if n != "neutral"]
    shots = []
    for name in names:
        sim = fw.FaceSimulator(rig, device=device, fps=30)
        frames = sim.run(fw.Timeline([fw.expressions.Segment(fw.preset(name), 0.0, 0.3, 60.0, 0.1)]).for_head(rig), seconds)
        if not np.isfinite(frames.points).all():
            raise SystemExit(f"{name}: NaN in the frames")
        shots.append((name, frames.points[-1], {k: V[-1] for k, (V, _) in frames.parts.items()}))
        moved = np.linalg.norm(frames.points[-1] - frames.points[0], axis=1).max()
        print(f"{name:9s} largest vertex displacement {moved * 1e3:5.1f} mm", flush=True)
    rest = frames.points[0]
    lm = {str(k): frames.fdp_points[0, i] for i, k in enumerate(frames.fdp_ids)}
    parts = {k: (V[0], F) for k, (V, F) in frames.parts.items()}
    view = FaceView(rest, frames.faces, lm, parts, view="front", face_height=face_height,
                    bounds=[rest] + [P for _, P, _ in shots], device=device)
    images = [view.render(rest)] + [view.render(P, part_points=pp) for _, P, pp in shots]
    labels = ["rest"] + names
    rows = [images[i:i + COLUMNS] for i in range(0, len(images), COLUMNS)]
    grid = label_grid(rows, column_labels=None, row_labels=None, gap=8)
    grid = _captions(grid, labels, images[0].shape[:2], gap=8)
    path = RESULTS / "preset_strip.png"
    save_png(path, grid, title=f"default head (level {level}): each preset after {seconds:g} s")
    return path


def _captions(grid: np.ndarray, labels: list, tile: tuple, gap: int) -> np.ndarray:
    """Each tile's label written into its top-left corner."""
    from PIL import Image, ImageDraw, ImageFont

    h, w = tile
    img = Image.fromarray(grid)
    draw = ImageDraw.Draw(img)
    try:
        font = ImageFont.load_default(size=max(14, w // 11))
    except TypeError:  # Pillow < 10.1
        font = ImageFont.load_default()
    for i, text in enumerate(labels):
        r, c = divmod(i, COLUMNS)
        draw.text((c * (w + gap) + 6, r * (h + gap) + 4), text, fill=(0, 0, 0), font=font)
    return np.asarray(img)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_case_args(ap, level=0, device="cpu")
    ap.add_argument("--seconds", type=float, default=1.0, help="length of each run [s] (the picture)")
    ap.add_argument("--face-height", type=int, default=240, help="face height in the picture [px]")
    ap.add_argument("--table-only", action="store_true", help="only the table (no simulation, no picture)")
    ap.add_argument("--readme", action="store_true", help="also replace the table in README.md")
    args = ap.parse_args(argv)
    if not args.table_only:
        print(f"wrote {render_strip(args.level, args.seconds, args.device, args.face_height)}")
    from benchmarks import _tables

    print(_tables.preset_targets(_tables.Results(), level=args.level))
    if args.readme:
        return _tables.main([])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
