"""The frame stream of a simulation (what exporters consume) and its ``frames.npz`` file."""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.fileio import atomic_write

__all__ = ["Frames", "save_frames_npz"]


@dataclass
class Frames:
    """The frame stream of a simulation (what exporters consume).

    Attributes:
        times: Frame times [s], shape (f,).
        points: Head surface vertices [m], shape (f, n, 3), float32.
        faces: Head triangles, shape (m, 3).
        fdp_ids: FDP ids, shape (84,).
        fdp_points: FDP positions [m], shape (f, 84, 3).
        parts: Rigid part name -> (frames (f, k, 3), faces (l, 3)).
        muscle_names: Muscle instance names (M,).
        muscle_curves: Muscle fibre polylines [m], shape (f, M, samples, 3) (closed rings for
            sphincters repeat their first point).
        activations: Activations per frame, shape (f, M); jaw: (f, 2) [rad].
        steps_per_second: Simulated substeps per wall-clock second.
        substeps: Solver steps per frame; dt: step [s].
        frames_per_second: Frames simulated per wall-clock second (the stepping only, not the
            surface and curve read-back of each frame).
        realtime_factor: Simulated seconds per wall-clock second of stepping (1: real time).
        solver, material: The solver and material profile names.
    """

    times: np.ndarray
    points: np.ndarray
    faces: np.ndarray
    fdp_ids: np.ndarray
    fdp_points: np.ndarray
    parts: dict
    muscle_names: list
    muscle_curves: np.ndarray
    activations: np.ndarray
    jaw: np.ndarray
    steps_per_second: float = 0.0
    substeps: int = 0
    dt: float = 0.0
    frames_per_second: float = 0.0
    realtime_factor: float = 0.0
    solver: str = ""
    material: str = ""


def save_frames_npz(path, frames: Frames) -> Path:
    """``frames.npz``: points (f, n, 3) [m], times (f,), fdp_ids (84,), fdp_points (f, 84, 3), faces,
    activations (f, M), muscle_names (M,), jaw (f, 2) [rad], muscle_curves (f, M, s, 3)."""
    from ..core.checks import check_has, check_path

    check_path("path", path)
    check_has("frames", frames, ("points", "times", "fdp_points"), "Frames (FaceSimulator.run)")
    buf = io.BytesIO()
    np.savez_compressed(buf, points=frames.points, times=frames.times, fdp_ids=frames.fdp_ids,
                        fdp_points=frames.fdp_points, faces=frames.faces, activations=frames.activations,
                        muscle_names=np.array(frames.muscle_names), jaw=frames.jaw, muscle_curves=frames.muscle_curves)
    with atomic_write(path, "wb", encoding=None) as f:
        f.write(buf.getvalue())
    return Path(path)
