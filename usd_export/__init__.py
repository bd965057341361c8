"""USD export for facewarp: the only package that imports ``pxr`` (usd-core).

Meshes are written as ``UsdGeom.Mesh`` prims in a Y-up stage with ``metersPerUnit = 1`` (facewarp
works in metres). Animated heads are written with time-sampled ``points``: pass ``frames``
(frames, n, 3) and ``times`` in seconds, and the stage's time codes run at ``fps``.
"""

from __future__ import annotations

from .stage import write_meshes_usd

__all__ = ["write_meshes_usd"]
