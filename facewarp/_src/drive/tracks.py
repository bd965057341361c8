"""What a performance gives the face: a :class:`MarkerTrack` (skin points over time) or an
:class:`ArkitTrack` (the 52 ARKit blendshape weights over time, with the head's rotation when
the source has it). Loaders of the file formats make these; the inverse solve and the tracker
read them. Both are in SI units (metres, seconds, radians) whatever the file held.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.checks import check_array, check_number
from ..core.errors import InputError

__all__ = ["ARKIT_NAMES", "ArkitTrack", "MarkerTrack"]

MAX_POSITION_M = 1000.0
"""Farthest a marker may be from the take's origin [m]: beyond any capture volume (a point there
is a unit or export error, which the solve would otherwise report as a metres-wide miss)."""

ARKIT_NAMES = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
    "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight", "jawForward", "jawLeft", "jawRight", "jawOpen", "mouthClose",
    "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft", "mouthSmileRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft",
    "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
    "mouthUpperUpRight", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "noseSneerLeft", "noseSneerRight", "tongueOut",
)
"""The 52 ARKit blendshape names (Apple's ``ARFaceAnchor.BlendShapeLocation`` raw values, in
the order of Live Link Face's CSV columns and MediaPipe's ``faceBlendshapes`` categories 1-52)."""


def _check_fps(fps) -> float:
    return check_number("fps", fps, low=0.0, high=10_000.0, low_open=True)


@dataclass
class MarkerTrack:
    """Skin points over time: a motion-capture take, landmarks from a tracker, or FDPs of a run.

    Attributes:
        fps: Frames per second of the take [1/s].
        names: The K point names: an FDP id (``"2.1"``), ``"v<index>"`` (a head vertex of the
            build) or any label a map file turns into one.
        positions: (T, K, 3) float64 [m], NaN where a point is missing in a frame.
        source: Where the track came from (a path, or a short description), for reports.
    """

    fps: float
    names: list
    positions: np.ndarray
    source: str = ""

    def __post_init__(self):
        self.fps = _check_fps(self.fps)
        self.names = [str(n) for n in self.names]
        if len(set(self.names)) != len(self.names):
            raise InputError("names: a point name appears twice")
        self.positions = check_array("positions", self.positions, shape=(None, len(self.names), 3),
                                     finite=False).astype(np.float64)
        if np.isinf(self.positions).any():
            raise InputError("positions: infinite values (use NaN for a missing point)")
        with np.errstate(over="ignore", invalid="ignore"):
            far = np.nan_to_num(np.linalg.norm(self.positions, axis=2), nan=0.0)  # (T, K) [m]
        if far.max(initial=0.0) > MAX_POSITION_M:
            t, k = np.unravel_index(int(np.argmax(far)), far.shape)
            raise InputError(f"positions: point {self.names[k]!r} in frame {t} is {far[t, k]:.3g} m from the origin, "
                             f"farther than any capture volume ({MAX_POSITION_M:g} m); are the units right?")
        if len(self.positions) == 0:
            raise InputError("positions: the track has no frames")

    @property
    def frames(self) -> int:
        """Number of frames T."""
        return int(self.positions.shape[0])

    @property
    def seconds(self) -> float:
        """Duration [s], frames / fps."""
        return self.frames / self.fps

    def visible(self) -> np.ndarray:
        """(T, K) bool: the point is present in the frame."""
        return np.isfinite(self.positions).all(axis=2)


@dataclass
class ArkitTrack:
    """ARKit blendshape weights over time (Live Link Face, MediaPipe Face Landmarker, a rig).

    Attributes:
        fps: Frames per second [1/s].
        weights: (T, 52) float64 in [0, 1], columns in :data:`ARKIT_NAMES` order (a curve the
            source lacks is 0).
        head_rotation: (T, 3) float64 [rad] yaw, pitch, roll of the head (ARKit's HeadYaw,
            HeadPitch, HeadRoll), or None when the source has no head channels.
        source: Where the track came from, for reports.
    """

    fps: float
    weights: np.ndarray
    head_rotation: np.ndarray | None = None
    source: str = ""
    names: tuple = field(default=ARKIT_NAMES, init=False)

    def __post_init__(self):
        self.fps = _check_fps(self.fps)
        w = check_array("weights", self.weights, shape=(None, len(ARKIT_NAMES))).astype(np.float64)
        if len(w) == 0:
            raise InputError("weights: the track has no frames")
        if w.min() < -1e-3 or w.max() > 1.0 + 1e-3:
            raise InputError(f"weights: ARKit weights lie in [0, 1], got {w.min():.3g}..{w.max():.3g}")
        self.weights = np.clip(w, 0.0, 1.0)
        if self.head_rotation is not None:
            self.head_rotation = check_array("head_rotation", self.head_rotation,
                                             shape=(len(w), 3)).astype(np.float64)

    @property
    def frames(self) -> int:
        """Number of frames T."""
        return int(self.weights.shape[0])

    @property
    def seconds(self) -> float:
        """Duration [s], frames / fps."""
        return self.frames / self.fps

    def curve(self, name: str) -> np.ndarray:
        """The (T,) weights of one ARKit shape."""
        if name not in ARKIT_NAMES:
            raise InputError(f"name: {name!r} is not an ARKit blendshape name")
        return self.weights[:, ARKIT_NAMES.index(name)]
