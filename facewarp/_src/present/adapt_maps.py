"""Heat maps of an adaptation: a per-vertex scalar on a head, one or more views side by side.

Used by the ``adapt`` job (distance to the scan, curvature difference to the scan with the
folds marked, stretch of the template's edges) and by the adaptation benchmarks (total and
tangential vertex error where a truth exists).
"""

from __future__ import annotations

import numpy as np

from .render import colormap, render_mesh, save_png

__all__ = ["heat_map"]


def heat_map(path, V, F, values, *, vmax: float, unit: str, title: str, views=("front",), size: int = 450,
             vmin: float = 0.0, points=None, device: str = "cpu") -> str:
    """Render ``values`` on the mesh (V, F) from ``views`` side by side and save a PNG.

    Args:
        path: Output PNG path (written atomically by :func:`save_png`).
        V: Vertices [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.
        values: Per-vertex scalar, shape (n,), in ``unit``; NaN is drawn grey.
        vmax, vmin: Colour range, in ``unit``.
        unit: Unit label of the colour bar.
        title: Picture title.
        views: Views of :func:`render_mesh` ("front", "side", "three_quarter", or angles).
        size: Side of each view in pixels.
        points: Optional dots [m], shape (k, 3) (e.g. the centres of folded faces).
        device: Warp device of the renderer.

    Returns:
        The path written.
    """
    colors = colormap(np.asarray(values, dtype=np.float64), vmin, vmax)
    kw = {} if points is None or len(points) == 0 else {"points": np.asarray(points, dtype=np.float64)}
    imgs = [render_mesh(V, F, view=v, width=size, height=size, vertex_colors=colors, device=device, **kw) for v in views]
    return save_png(path, np.concatenate(imgs, axis=1), title=title, colorbar=(vmin, vmax, unit))
