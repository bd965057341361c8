"""Pictures of the anatomy: muscle fibres over the head, attached, fixed and held nodes."""

from __future__ import annotations

import numpy as np

from .render import render_mesh

__all__ = ["render_anatomy"]


_PALETTE = np.array(
    [
        [0.85, 0.10, 0.10], [0.10, 0.45, 0.85], [0.10, 0.65, 0.20], [0.85, 0.50, 0.05], [0.55, 0.15, 0.70],
        [0.05, 0.65, 0.65], [0.75, 0.20, 0.45], [0.45, 0.35, 0.10], [0.20, 0.20, 0.60], [0.60, 0.60, 0.05],
        [0.95, 0.35, 0.60], [0.30, 0.55, 0.35], [0.70, 0.05, 0.05], [0.05, 0.30, 0.50],
    ]
)


def render_anatomy(anatomy: Anatomy, *, size: int = 900, device: str = "cpu", fixed=None, held=None) -> np.ndarray:
    """Front view of the head with the muscle fibres (by Table 6.2 number) and attached nodes;
    optionally the fixed (black) and held (grey) nodes of the boundary conditions."""
    head = anatomy.head
    lines, pts, cols = [], [], []
    for P, c in ((fixed, (0.05, 0.05, 0.05)), (held, (0.55, 0.55, 0.55))):
        if P is not None and len(P):
            pts.append(np.asarray(P))
            cols.append(np.tile(c, (len(P), 1)))
    for m in anatomy.muscles.muscles:
        c = _PALETTE[(m.number - 1) % len(_PALETTE)]
        lines.append((m.curve_points(48), c))
        if m.attachment is not None and len(m.attachment):
            pts.append(anatomy.skin.vertices[m.attachment.nodes])
            cols.append(np.tile(c * 0.6 + 0.4, (len(m.attachment), 1)))
    return render_mesh(
        head.vertices,
        head.faces,
        view="front",
        width=size,
        height=size,
        polylines=lines,
        points=np.concatenate(pts) if pts else None,
        point_color=np.concatenate(cols) if cols else (0.85, 0.1, 0.1),
        point_radius=max(1.5, size * 0.003),
        line_width=max(1.5, size * 0.004),
        depth_tolerance=float("inf"),
        device=device,
    )
