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
    "Mesh": "geometry.mesh", "SurfacePoints": "geometry.mesh", "closest_surface_points": "geometry.mesh",
    "load_mesh": "geometry.mesh", "mesh_report": "geometry.mesh", "save_obj": "geometry.mesh",
    "save_glb": "geometry.mesh",
    "MeshQuery": "geometry.surface", "mean_curvature": "geometry.surface", "vertex_normals": "geometry.surface",
    "FDP_CATALOGUE": "geometry.landmarks", "FDP_IDS": "geometry.landmarks", "fapu": "geometry.landmarks",
    "load_landmarks": "geometry.landmarks", "save_landmarks_json": "geometry.landmarks",
    "landmarks_from_scheme": "geometry.landmarks", "IBUG68_TO_FDP": "geometry.landmarks",
    "IBUG68_TEMPLATE": "template.ibug68",
    "Similarity": "geometry.similarity", "fit_similarity": "geometry.similarity",
    # heads
    "FRONTAL_REGIONS": "template.head", "REGIONS": "template.head", "THICKNESS_FACTOR": "template.head",
    "Template": "template.head", "default_template": "template.head", "load_template_dir": "template.files",
    "save_template": "template.files", "export_template": "jobs.template", "import_ict": "importers.ict",
    "load_head": "adapt.transfer", "human_likeness": "template.likeness",
    "UVLayout": "template.uv", "face_uv_layout": "template.uv", "uv_distortion": "template.uv",
    # a synthetic scan of another face (the demo's input)
    "FaceProportions": "template.synthetic", "SyntheticScan": "template.synthetic",
    "synthetic_scan": "template.synthetic",
    # the ICT-FaceKit layout (vertex ranges and the FDPs on its vertices)
    "ICT_FDP_VERTICES": "template.likeness", "ICT_INNER_LIP_VERTICES": "importers.ict",
    "ICT_PART_RANGES": "importers.ict", "ICT_SKIN_VERTICES": "importers.ict",
    # adaptation
    "adapt": "adapt.pipeline", "AdaptResult": "adapt.pipeline", "calibrate": "adapt.calibrate",
    "Calibration": "adapt.calibrate", "distance_error": "adapt.metrics", "vertex_error": "adapt.metrics",
    "AdaptOptions": "adapt.pipeline", "detect_landmarks": "adapt.detect",
    # anatomy
    "Anatomy": "anatomy.build", "build_anatomy": "anatomy.build", "write_anatomy": "anatomy.build",
    "JawKinematic": "geometry.jaw",
    # expressions
    "MUSCLES": "expressions", "PRESETS": "expressions", "Expression": "expressions", "Segment": "expressions",
    "Timeline": "expressions", "blend": "expressions", "load_sequence": "expressions", "preset": "expressions",
    "thesis_sequence": "expressions", "timeline_for": "expressions", "timeline_from_spec": "expressions",
    "jaw_angle_for_drop": "expressions", "jaw_lever": "expressions", "expression_from_activations": "expressions",
    "REFERENCE_JAW_LEVER": "expressions",
    # simulation
    "FaceRig": "physics.face_rig", "build_face": "anatomy.rig", "face_rig_from_anatomy": "anatomy.rig",
    "load_face_rig": "physics.face_rig", "save_face_rig": "physics.face_rig",
    "FaceSimulator": "sim.simulator", "Frames": "sim.simulator", "save_frames_npz": "sim.simulator",
    # many heads, each its own person, stepped together
    "FaceBatch": "sim.batch",
    # one playback path: a timeline played on a simulator, each frame handed to sinks
    "play": "sim.play", "FrameRecorder": "sim.play", "PlayStats": "sim.play", "Sink": "sim.play",
    # USD animations streamed while simulating (a sink of play)
    "UsdAnimation": "jobs.animation", "play_timeline": "jobs.animation",
    # lower level
    "ModelBuilder": "physics.builder", "Model": "physics.model", "State": "physics.state", "Control": "physics.state",
    "SolverVerlet": "physics.solvers.verlet", "SolverStage": "physics.solvers.base",
    "SolverImplicit": "physics.solvers.implicit", "SolverHostImplicit": "physics.solvers.host_implicit",
    "SolverDeviceNewtonPCG": "physics.solvers.newton_pcg", "IncrementalPotential": "physics.solvers.incremental",
    "MaterialPhysical": "physics.materials",
    "MarkerTrack": "drive.tracks", "ArkitTrack": "drive.tracks", "ARKIT_NAMES": "drive.tracks",
    # performance files in and out, rigid head motion out of a take
    "load_markers": "drive.formats", "load_arkit": "drive.formats", "save_markers_json": "drive.formats",
    "save_livelink_csv": "drive.formats", "markers_from_frames": "drive.formats",
    "remove_head_motion": "drive.rigid", "HeadMotion": "drive.rigid", "STABLE_POINTS": "drive.rigid",
    "ArkitTable": "drive.arkit", "arkit_table": "drive.arkit", "load_arkit_table": "drive.arkit",
    "ARKIT_OUT_OF_REACH": "drive.arkit", "ICT_ARKIT_SHAPES": "importers.ict_arkit",
    "load_ict_displacements": "importers.ict_arkit", "transfer_ict_displacements": "importers.ict_arkit",
    "ict_shape_dirs": "importers.ict_arkit", "load_arkit_basis": "importers.ict_arkit",
    "Tracker": "drive.inverse", "drive": "drive.inverse", "DriveResult": "drive.inverse",
    "LiveLink": "drive.livelink",
    "MaterialThesis": "physics.materials",
    "MuscleRig": "physics.muscle_rig", "MuscleStage": "physics.muscle_stage", "SupportStage": "physics.muscle_stage",
    "JawStage": "coupling.kinematic", "CarryStage": "coupling.kinematic",
    # MuJoCo coupling, moving head
    "MujocoJaw": "coupling.mujoco", "HeadPose": "coupling.head_pose", "head_mjcf": "coupling.mjcf",
    "write_head_mjcf": "coupling.mjcf", "scene_mjcf": "coupling.mjcf", "MujocoSkin": "coupling.mujoco_skin",
    # blendshape rigs baked from the physics
    "BlendshapeRig": "bake.blendshapes", "bake_blendshapes": "bake.blendshapes", "static_surface": "bake.blendshapes",
    # pictures
    "colormap": "present.render", "render_mesh": "present.render", "save_png": "present.render",
    "render_strip": "present.strips", "render_anatomy": "present.anatomy", "render_previews": "present.template",
}

_SUBMODULES = ("geometry", "adaptation", "anatomy", "physics", "coupling", "render")

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
    from ._src.adapt.calibrate import Calibration, calibrate
    from ._src.adapt.metrics import distance_error, vertex_error
    from ._src.adapt.detect import detect_landmarks
    from ._src.adapt.pipeline import AdaptOptions, AdaptResult, adapt
    from ._src.adapt.transfer import load_head
    from ._src.anatomy.build import Anatomy, build_anatomy, write_anatomy
    from ._src.geometry.jaw import JawKinematic
    from ._src.core.errors import FacewarpError, InputError, SimulationError
    from ._src.coupling.head_pose import HeadPose
    from ._src.coupling.kinematic import CarryStage, JawStage
    from ._src.coupling.mjcf import head_mjcf, scene_mjcf, write_head_mjcf
    from ._src.coupling.mujoco import MujocoJaw
    from ._src.coupling.mujoco_skin import MujocoSkin
    from ._src.bake.blendshapes import BlendshapeRig, bake_blendshapes, static_surface
    from ._src.expressions import REFERENCE_JAW_LEVER, expression_from_activations, jaw_angle_for_drop, jaw_lever
    from ._src.expressions import (MUSCLES, PRESETS, Expression, Segment, Timeline, blend, load_sequence, preset,
                                   thesis_sequence, timeline_for, timeline_from_spec)
    from ._src.geometry.landmarks import FDP_CATALOGUE, FDP_IDS, fapu, load_landmarks, save_landmarks_json
    from ._src.geometry.landmarks import IBUG68_TO_FDP, landmarks_from_scheme
    from ._src.template.ibug68 import IBUG68_TEMPLATE
    from ._src.geometry.mesh import (Mesh, SurfacePoints, closest_surface_points, load_mesh, mesh_report, save_glb,
                                     save_obj)
    from ._src.geometry.similarity import Similarity, fit_similarity
    from ._src.geometry.surface import MeshQuery, mean_curvature, vertex_normals
    from ._src.importers.ict import ICT_INNER_LIP_VERTICES, ICT_PART_RANGES, ICT_SKIN_VERTICES, import_ict
    from ._src.jobs.animation import UsdAnimation, play_timeline
    from ._src.jobs.template import export_template
    from ._src.anatomy.rig import build_face, face_rig_from_anatomy
    from ._src.physics.face_rig import FaceRig, load_face_rig, save_face_rig
    from ._src.physics.builder import ModelBuilder
    from ._src.physics.model import Model
    from ._src.physics.state import Control, State
    from ._src.physics.muscle_rig import MuscleRig
    from ._src.physics.muscle_stage import MuscleStage, SupportStage
    from ._src.physics.materials import MaterialPhysical, MaterialThesis
    from ._src.drive.inverse import DriveResult, Tracker, drive
    from ._src.drive.livelink import LiveLink
    from ._src.drive.tracks import ARKIT_NAMES, ArkitTrack, MarkerTrack
    from ._src.drive.formats import (load_arkit, load_markers, markers_from_frames, save_livelink_csv,
                                     save_markers_json)
    from ._src.drive.rigid import STABLE_POINTS, HeadMotion, remove_head_motion
    from ._src.drive.arkit import ARKIT_OUT_OF_REACH, ArkitTable, arkit_table, load_arkit_table
    from ._src.importers.ict_arkit import (ICT_ARKIT_SHAPES, ict_shape_dirs, load_arkit_basis, load_ict_displacements,
                                           transfer_ict_displacements)
    from ._src.physics.solvers.base import SolverStage
    from ._src.physics.solvers.host_implicit import SolverHostImplicit
    from ._src.physics.solvers.implicit import SolverImplicit
    from ._src.physics.solvers.incremental import IncrementalPotential
    from ._src.physics.solvers.newton_pcg import SolverDeviceNewtonPCG
    from ._src.physics.solvers.verlet import SolverVerlet
    from ._src.present.anatomy import render_anatomy
    from ._src.present.render import colormap, render_mesh, save_png
    from ._src.present.strips import render_strip
    from ._src.present.template import render_previews
    from ._src.sim.play import FrameRecorder, PlayStats, Sink, play
    from ._src.sim.batch import FaceBatch
    from ._src.sim.simulator import FaceSimulator, Frames, save_frames_npz
    from ._src.template.files import load_template_dir, save_template
    from ._src.template.head import FRONTAL_REGIONS, REGIONS, THICKNESS_FACTOR, Template, default_template
    from ._src.template.likeness import ICT_FDP_VERTICES, human_likeness
    from ._src.template.synthetic import FaceProportions, SyntheticScan, synthetic_scan
    from ._src.template.uv import UVLayout, face_uv_layout, uv_distortion
