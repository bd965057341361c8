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

__all__ = ["ARKIT_NAMES", "MAX_TAKE_FPS", "MIN_TAKE_FPS", "ArkitTrack", "MarkerTrack"]

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


MIN_TAKE_FPS = 1.0
"""Slowest frame rate [1/s] of a take: below it the frames are stills, not a performance (a
MediaPipe take whose timestamps in microseconds were read as milliseconds comes out at 0.03 fps)."""

MAX_TAKE_FPS = 1000.0
"""Fastest frame rate [1/s] of a take: the simulator's own bound (``MAX_FPS``)."""


def _check_fps(fps) -> float:
    fps = check_number("fps", fps)
    if not MIN_TAKE_FPS <= fps <= MAX_TAKE_FPS:
        raise InputError(f"fps: {fps:g} frames/s is outside a take's {MIN_TAKE_FPS:g}..{MAX_TAKE_FPS:g} "
                         "(timestamps in other units than the file says?)")
    return fps


@dataclass
class MarkerTrack:
    """Skin points over time: a motion-capture take, landmarks from a tracker, or FDPs of a run.

    Attributes:
        fps: Frames per second of the take [1/s].
        names: The K point names: an FDP id (``"2.1"``), ``"v<index>"`` (a head vertex of the
            build) or any label a map file turns into one.
        positions: (T, K, 3) float64 [m], NaN where a point is missing in a frame.
        source: Where the track came from (a path, or a short description), for reports.
        neutral: (K, 3) float64 [m], the actor's face at rest (NaN where a point was never seen
            there), or None: the first frame. Retargeting (:func:`~facewarp.drive` with
            ``retarget=True``) carries the displacements from it to the head.
        notes: What the loader changed or filled in (frames interpolated over gaps, a cut), one line each.
        info: The same as numbers, for reports (e.g. ``{"frames_filled": 12, "start_s": 2.0}``).
    """

    fps: float
    names: list
    positions: np.ndarray
    source: str = ""
    neutral: np.ndarray | None = None
    notes: list = field(default_factory=list)
    info: dict = field(default_factory=dict)

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
        if self.neutral is not None:
            self.neutral = check_array("neutral", self.neutral, shape=(len(self.names), 3),
                                       finite=False).astype(np.float64)
            if np.isinf(self.neutral).any():
                raise InputError("neutral: infinite values (use NaN for a missing point)")
        self.notes = [str(n) for n in self.notes]
        self.info = dict(self.info)

    def neutral_points(self) -> np.ndarray:
        """(K, 3) float64 [m]: :attr:`neutral`, or the first frame when the track has none."""
        return (self.neutral if self.neutral is not None else self.positions[0]).copy()

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
        eye_rotation: (T, 2, 2) float64 [rad], yaw and pitch of the left and right eyeball (Live
            Link Face's LeftEyeYaw, LeftEyePitch, RightEyeYaw, RightEyePitch), or None when the
            source has none (or records none: all zero).
        notes: What the loader changed or filled in (weights clamped, frames interpolated, a
            category the source lacks), one line each.
        info: The same as numbers, for reports.
    """

    fps: float
    weights: np.ndarray
    head_rotation: np.ndarray | None = None
    source: str = ""
    eye_rotation: np.ndarray | None = None
    notes: list = field(default_factory=list)
    info: dict = field(default_factory=dict)
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
        if self.eye_rotation is not None:
            self.eye_rotation = check_array("eye_rotation", self.eye_rotation,
                                            shape=(len(w), 2, 2)).astype(np.float64)
        self.notes = [str(n) for n in self.notes]
        self.info = dict(self.info)

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
