"""Performances (takes): marker and ARKit tracks, take files in and out, rigid head motion, the ARKit tables and basis, retargeting, and the sources and sinks that :func:`facewarp.play` steps (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.sim.play import PlayStats, Sink  # noqa: F401
from ._src.drive.tracks import ArkitTrack  # noqa: F401
from ._src.drive.formats import markers_from_frames, save_livelink_csv, save_markers_json  # noqa: F401
from ._src.drive.rigid import HeadMotion, remove_head_motion, STABLE_POINTS  # noqa: F401
from ._src.drive.arkit import ARKIT_OUT_OF_REACH, ArkitTable, load_arkit_table  # noqa: F401
from ._src.importers.ict_arkit import ICT_ARKIT_SHAPES, ict_shape_dirs, load_ict_displacements  # noqa: F401
from ._src.importers.ict_arkit import transfer_ict_displacements  # noqa: F401
from ._src.importers.ict_arkit import load_arkit_basis  # noqa: F401
from ._src.drive.inverse import DriveResult  # noqa: F401
__all__ = ["ARKIT_OUT_OF_REACH", "ArkitTable", "ArkitTrack", "DriveResult", "HeadMotion", "ICT_ARKIT_SHAPES",
           "ict_shape_dirs", "load_arkit_basis", "load_arkit_table", "load_ict_displacements",
           "markers_from_frames", "PlayStats", "remove_head_motion", "save_livelink_csv", "save_markers_json",
           "Sink", "STABLE_POINTS", "transfer_ict_displacements"]
