"""Blendshape rigs baked from the physics: bake, save, load and play them back (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.bake.blendshapes import bake_blendshapes, BlendshapeRig, static_surface  # noqa: F401
__all__ = ["bake_blendshapes", "BlendshapeRig", "static_surface"]
