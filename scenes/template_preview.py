"""The default template head (skin, eyes, teeth, tongue) rendered from several views into PNGs.

By default the five named views (front, side, three-quarter, back, from below); with
``--num-frames N`` a turntable of N views instead, ``N`` azimuths evenly round the head.

    python -m scenes.template_preview --device cpu --out out/views [--level 0] [--num-frames 12] [--size 800]

Public names only; :class:`TemplatePreview` steps from one view to the next.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import facewarp as fw

VIEWS = {"front": "front", "side": "side", "three_quarter": "three_quarter", "back": (180.0, 0.0),
         "below": (0.0, -35.0)}
"""Named views: a name of :data:`facewarp.render.VIEWS` or (azimuth, elevation) [deg]."""

PART_COLOR = (0.96, 0.96, 0.94)


def turntable(frames: int, *, elevation: float = 10.0) -> dict:
    """``frames`` views evenly round the head, ``{"turn_000": (azimuth_deg, elevation_deg), ...}``."""
    return {f"turn_{k:03d}": (360.0 * k / frames, elevation) for k in range(frames)}


class TemplatePreview:
    """The default template at ``level``, one view per :meth:`step`.

    Args:
        level: Template level (0..4).
        views: View name -> view (see :data:`VIEWS`, :func:`turntable`).
        size: Image side [px].
        device: Warp device, ``"cpu"`` or ``"cuda[:N]"``.
    """

    def __init__(self, *, level: int = 0, views: dict | None = None, size: int = 800, device: str = "cpu"):
        self.template = fw.default_template(level)
        self.views = dict(VIEWS if views is None else views)
        self.names = list(self.views)
        self.size, self.device = int(size), device
        self.extra = [(V, F, PART_COLOR) for V, F in self.template.parts.values()]
        self.frame = 0

    @property
    def view_name(self) -> str:
        """The current view's name."""
        return self.names[self.frame % len(self.names)]

    def step(self) -> None:
        """Go on to the next view (after the last, back to the first)."""
        self.frame += 1

    def render(self) -> np.ndarray:
        """The head in the current view, RGB image (size, size, 3) uint8."""
        t = self.template
        return fw.render_mesh(t.vertices, t.faces, view=self.views[self.view_name], width=self.size,
                              height=self.size, extra_meshes=self.extra, device=self.device)

    def export(self, out: Path) -> Path:
        """Write the current view as ``<out>/<view name>.png``; returns the path."""
        out.mkdir(parents=True, exist_ok=True)
        path = out / f"{self.view_name}.png"
        fw.save_png(path, self.render(), title=f"level {self.template.level}: {self.view_name}")
        return path


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--num-frames", type=int, default=None,
                    help="views of a turntable round the head (default: the five named views)")
    ap.add_argument("--out", type=Path, default=Path("out/views"), help="output folder")
    ap.add_argument("--level", type=int, default=0, help="template level 0..4")
    ap.add_argument("--size", type=int, default=800, help="image side [px]")
    args = ap.parse_args(argv)
    if args.num_frames is not None and args.num_frames < 1:
        ap.error(f"--num-frames: expected >= 1, got {args.num_frames}")
    views = None if args.num_frames is None else turntable(args.num_frames)
    scene = TemplatePreview(level=args.level, views=views, size=args.size, device=args.device)
    for _ in range(len(scene.names)):
        print("wrote", scene.export(args.out))
        scene.step()


if __name__ == "__main__":
    main()
