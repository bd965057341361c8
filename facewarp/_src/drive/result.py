"""What :func:`~facewarp.drive` returns (its own module: the marker solve and the ARKit table both
make one, and neither imports the other for it)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["DriveResult"]


@dataclass
class DriveResult:
    """What :func:`drive` solved for a track.

    Attributes:
        fps: Frames per second [1/s].
        names: The K point names of the track.
        muscle_names: The M muscle names, column order of ``activations``.
        activations: (T, M) float32 in [0, 1], per frame.
        jaw: (T, 2) float32 [rad], (opening, side) per frame.
        error: (T, K) float64 [m], distance of each simulated point from its target (NaN where missing).
        rms: (T,) float64 [m], RMS of ``error`` over the frame's present points (NaN: none present).
        unreachable: Notes on what the face could not match (frames and points off by more than ``unreachable_limit``).
        seconds: Wall time of the whole solve [s].
        frames_per_second: Frames solved per wall-clock second.
        mode: The tracker's mode.
        stats: The tracker's :class:`TrackerStats` as a dict.
        head_poses: (T, 4, 4) float64 rigid head poses removed from the targets, when the caller gives them
            (an ARKit track: its head rotation as played); else None.
        warnings: What the take asked for that the face cannot show (ARKit shapes not mapped on this head).
        gaze: (T, 2, 2) float64 [rad], the eyes' (yaw, pitch) per frame (left, right) for an ARKit
            track; else None.
    """

    fps: float
    names: list
    muscle_names: list
    activations: np.ndarray
    jaw: np.ndarray
    error: np.ndarray
    rms: np.ndarray
    unreachable: list
    seconds: float
    frames_per_second: float
    mode: str
    stats: dict = field(default_factory=dict)
    head_poses: np.ndarray | None = None
    warnings: list = field(default_factory=list)
    gaze: np.ndarray | None = None

    @property
    def frames(self) -> int:
        """T, the number of frames."""
        return int(self.activations.shape[0])
