"""Coupling the face to rigid bodies (public): the head as MJCF (cranium, mandible on two hinges,
optional neck), the two-way MuJoCo jaw coupler, the moving-head pose, the kinematic jaw stages,
and the jaw drivers :func:`facewarp.play` steps a frame with (kinematic or MuJoCo).

Re-exports of ``facewarp._src.coupling``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.coupling.drivers import JAWS, KinematicJawDriver, MujocoJawDriver, jaw_driver  # noqa: F401
from ._src.coupling.head_pose import GRAVITY, HEAD_MOTION_LIMITS, HeadPose, check_pose  # noqa: F401
from ._src.coupling.kinematic import CarryStage, JawStage  # noqa: F401
from ._src.coupling.mjcf import (  # noqa: F401
    BONE_DENSITY,
    HEAD_MASS,
    JAW_OPEN_RANGE,
    JAW_SIDE_RANGE,
    MANDIBLE_PLATE,
    SCENE_NAME,
    UPS,
    Z_UP,
    MandibleInertia,
    mandible_geometry,
    mandible_inertia,
    scene_mjcf,
    skin_vertex_split,
    up_rotation,
    write_head_mjcf,
)
from ._src.coupling.mujoco import STIFF_SKIN_RATIO, mujoco_warnings  # noqa: F401
from ._src.coupling.mujoco_view import MujocoView  # noqa: F401

__all__ = ["BONE_DENSITY", "CarryStage", "check_pose", "GRAVITY", "HEAD_MASS", "HEAD_MOTION_LIMITS", "HeadPose",
           "jaw_driver", "JAW_OPEN_RANGE", "JAW_SIDE_RANGE", "JAWS", "JawStage", "KinematicJawDriver",
           "mandible_geometry", "mandible_inertia", "MANDIBLE_PLATE", "MandibleInertia", "mujoco_warnings",
           "MujocoJawDriver", "MujocoView", "scene_mjcf", "SCENE_NAME", "STIFF_SKIN_RATIO", "up_rotation", "UPS",
           "write_head_mjcf", "Z_UP"]
