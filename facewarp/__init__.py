"""facewarp: personalized, physically simulated faces.

The pipeline, in the order data flows (thesis chapters 4-6):

1. a head: :func:`default_template` (authored in code, levels 0-4), :func:`load_head` (a template
   folder, an ``adapt`` output, ``"default:LEVEL"``), :func:`import_ict`;
2. adaptation to a range scan: :func:`adapt` (FDP calibration, global RBF, multi-level CSRBF);
3. anatomy: :func:`build_anatomy` (skin tetrahedra, Bezier muscles), or :func:`build_face`
   which also packs the solver inputs (:class:`FaceRig`);
4. simulation: :class:`FaceSimulator` (``set_activations``, ``set_jaw``, ``step``, ``reset``,
   ``surface``, ``fdp``), :class:`FaceBatch` (N heads stepped together) and expressions (:func:`preset`, :class:`Timeline`, ...);
5. output: :func:`play` (a timeline on a simulator, each frame to sinks: :class:`FrameRecorder`
   -> :class:`Frames`, :class:`UsdAnimation`), :func:`save_frames_npz`, pictures (:func:`render_mesh`, ...), and
   the ``usd_export`` package.

Lower level, after Newton's layout: :class:`ModelBuilder` -> :class:`Model` / :class:`State` /
:class:`Control` -> :class:`SolverImplicit` (backward Euler, the default: :class:`SolverHostImplicit`'s
factorised L-BFGS / Newton or :class:`SolverDeviceNewtonPCG`, sharing one :class:`IncrementalPotential`)
or :class:`SolverVerlet` (the explicit reference) with their stages; material profiles :class:`MaterialPhysical` (default) and
:class:`MaterialThesis` (Table 6.3). Detailed free functions live in the
public submodules :mod:`facewarp.geometry`, :mod:`facewarp.adaptation`, :mod:`facewarp.anatomy`,
:mod:`facewarp.physics`, :mod:`facewarp.coupling` and :mod:`facewarp.render`. Everything under ``facewarp._src`` is
private and may change.

Units are SI inside (metres, seconds, radians); convert at file edges with ``units=``. Names
are imported lazily, so ``import facewarp`` is fast and Warp starts only when first used.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.2.0"

# public name -> private module that defines it
_NAMES = {
    # errors
    "FacewarpError": "core.errors", "InputError": "core.errors", "SimulationError": "core.errors",
    # meshes, geometry, landmarks
    "Mesh": "geometry.mesh",
    "load_mesh": "geometry.mesh",
    # heads
    "Template": "template.head", "default_template": "template.head",
    "load_head": "adapt.transfer",
    # a synthetic scan of another face (the demo's input)
    "synthetic_scan": "template.synthetic",
    # adaptation
    "adapt": "adapt.pipeline", "AdaptResult": "adapt.pipeline",
    "AdaptOptions": "adapt.pipeline",
    # anatomy
    "build_anatomy": "anatomy.build",
    # expressions
    "MUSCLES": "expressions", "PRESETS": "expressions", "Expression": "expressions",
    "Timeline": "expressions", "preset": "expressions",
    "thesis_sequence": "expressions", "timeline_for": "expressions",
    # simulation
    "FaceRig": "physics.face_rig", "build_face": "anatomy.rig",
    "load_face_rig": "physics.face_rig", "save_face_rig": "physics.face_rig",
    "FaceSimulator": "sim.simulator", "Frames": "sim.simulator",
    # many heads, each its own person, stepped together
    "FaceBatch": "sim.batch",
    # one playback path: a timeline played on a simulator, each frame handed to sinks
    "play": "sim.play", "FrameRecorder": "sim.play",
    # USD animations streamed while simulating (a sink of play)
    "UsdAnimation": "jobs.animation",
    # lower level
    "MarkerTrack": "drive.tracks", "ARKIT_NAMES": "drive.tracks",
    # performance files in and out, rigid head motion out of a take
    "load_markers": "drive.formats", "load_arkit": "drive.formats",
    "arkit_table": "drive.arkit",
    "Tracker": "drive.inverse", "drive": "drive.inverse",
    "LiveLink": "drive.livelink",
    # MuJoCo coupling, moving head
    "MujocoJaw": "coupling.mujoco", "head_mjcf": "coupling.mjcf",
    "MujocoSkin": "coupling.mujoco_skin",
    # pictures
    "render_mesh": "present.render", "save_png": "present.render",
}

_SUBMODULES = ("geometry", "adaptation", "anatomy", "physics", "coupling", "render", "heads", "expressions", "takes", "blendshapes")

__all__ = sorted([*_NAMES, "__version__"])


def __getattr__(name: str):
    if name in _NAMES:
        value = getattr(importlib.import_module(f"._src.{_NAMES[name]}", __name__), name)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'facewarp' has no attribute {name!r}")


def __dir__():
    # the public names only (not this module's own helpers such as importlib or TYPE_CHECKING)
    return sorted({*__all__, *_SUBMODULES, "__doc__", "__file__", "__name__", "__path__", "__version__"})


if TYPE_CHECKING:  # static analysers and IDEs see the real definitions
    from ._src.adapt.pipeline import AdaptOptions, AdaptResult, adapt
    from ._src.adapt.transfer import load_head
    from ._src.anatomy.build import build_anatomy
    from ._src.core.errors import FacewarpError, InputError, SimulationError
    from ._src.coupling.mjcf import head_mjcf
    from ._src.coupling.mujoco import MujocoJaw
    from ._src.coupling.mujoco_skin import MujocoSkin
    from ._src.expressions import MUSCLES, PRESETS, Expression, Timeline, preset, thesis_sequence, timeline_for
    from ._src.geometry.mesh import Mesh, load_mesh
    from ._src.jobs.animation import UsdAnimation
    from ._src.anatomy.rig import build_face
    from ._src.physics.face_rig import FaceRig, load_face_rig, save_face_rig
    from ._src.drive.inverse import Tracker, drive
    from ._src.drive.livelink import LiveLink
    from ._src.drive.tracks import ARKIT_NAMES, MarkerTrack
    from ._src.drive.formats import load_arkit, load_markers
    from ._src.drive.arkit import arkit_table
    from ._src.present.render import render_mesh, save_png
    from ._src.sim.play import FrameRecorder, play
    from ._src.sim.batch import FaceBatch
    from ._src.sim.simulator import FaceSimulator, Frames
    from ._src.template.head import Template, default_template
    from ._src.template.synthetic import synthetic_scan
