"""Frame strips: renders of simulated frames side by side, over a row of displacement heat maps."""

from __future__ import annotations

import numpy as np

from .render import colormap, render_mesh
from .template import LIPS, SKIN, vermilion_weight

__all__ = ["displacement_max", "render_strip"]


def render_strip(frames, idx, *, size: int = 360, device: str = "cpu", view="front",
                 heat_max: float | None = None) -> np.ndarray:
    """Renders of the face (cropped below the chin and behind the ears) for frames ``idx``,
    side by side, with eyes and teeth; the lips (between FDPs 8.1, 8.2 and the corners) tinted.

    With ``heat_max`` [m], a second row shows each frame's displacement from frame 0 as a
    heat map from 0 to ``heat_max`` (turbo), which makes a few millimetres of motion visible.
    """
    P0 = frames.points[0]
    ids = list(map(str, frames.fdp_ids))
    lm0 = {k: frames.fdp_points[0, i] for i, k in enumerate(ids)}
    c = P0[frames.faces].mean(1)
    keep = (c[:, 1] > lm0["2.1"][1] - 0.03) & (c[:, 2] > lm0["3.7"][2] - 0.06) & (c[:, 1] < lm0["11.1"][1] + 0.02)
    F = frames.faces[keep]
    # vertex colours: skin, with the vermilion tinted on the front of the face
    front = P0[:, 2] > 0.5 * (lm0["2.2"][2] + lm0["2.3"][2]) - 0.02
    w = vermilion_weight(P0, lm0, front)[:, None]
    col = SKIN * (1 - w) + LIPS * w
    extra_of = lambda k: [(V[k], Fp, (0.96, 0.96, 0.94) if n.startswith(("eye", "teeth")) else (0.8, 0.45, 0.45))  # noqa: E731
                          for n, (V, Fp) in frames.parts.items()]
    row = [render_mesh(frames.points[k], F, view=view, width=size, height=size, vertex_colors=col,
                       extra_meshes=extra_of(k), device=device) for k in idx]
    img = np.concatenate(row, axis=1)
    if heat_max is None:
        return img
    heat = []
    for k in idx:
        d = np.linalg.norm(frames.points[k] - P0, axis=1)
        heat.append(render_mesh(frames.points[k], F, view=view, width=size, height=size,
                                vertex_colors=colormap(d, 0.0, max(float(heat_max), 1e-9)),
                                extra_meshes=extra_of(k), device=device))
    return np.concatenate([img, np.concatenate(heat, axis=1)], axis=0)


def displacement_max(frames, idx) -> float:
    """Largest displacement [m] of a head vertex from frame 0 over frames ``idx`` (the heat
    map's top, rounded up to a whole millimetre)."""
    d = max(float(np.linalg.norm(frames.points[k] - frames.points[0], axis=1).max()) for k in idx)
    return max(1e-3, float(np.ceil(d * 1e3)) * 1e-3)
