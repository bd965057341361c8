"""Blendshape rigs baked from the physics: bake, save, load and play them back (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.bake.blendshapes import bake_blendshapes, BlendshapeRig, load_rig, save_rig, static_surface  # noqa: F401
from ._src.bake.blendshapes import normal_offsets  # noqa: F401
from ._src.bake.take import RigTake  # noqa: F401
from ._src.jobs.rig import rig_files  # noqa: F401
__all__ = ["bake_blendshapes", "BlendshapeRig", "load_rig", "normal_offsets", "rig_files", "RigTake", "save_rig",
           "static_surface"]
