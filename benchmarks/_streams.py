"""The soak's random legal control stream, shared by benchmarks/soak.py and benchmarks/switching.py."""

from __future__ import annotations

import math

import numpy as np

ACTIVE_FRACTION = 0.4
"""Share of the muscles switched on in a frame."""
JAW_OPEN_MAX_DEG = 40.0
JAW_SIDE_MAX_DEG = 5.0
SPIN_MAX_REV_S = 5.0
SPIN_HOLD_FRAMES = 10
"""Frames between new head-spin speeds and axes."""

def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def control_stream(rng: np.random.Generator, muscles: int, fps: float):
    """The soak's controls, one frame at a time, forever: ``(activations (muscles,) in [0, 1],
    jaw opening [rad], jaw side angle [rad], head rotation of the frame (3, 3))`` (the module doc)."""
    axis, omega = np.array([0.0, 1.0, 0.0]), 0.0
    k = 0
    while True:
        a = np.where(rng.random(muscles) < ACTIVE_FRACTION, rng.random(muscles), 0.0)
        u = math.radians(rng.uniform(0.0, JAW_OPEN_MAX_DEG))
        v = math.radians(rng.uniform(-JAW_SIDE_MAX_DEG, JAW_SIDE_MAX_DEG))
        if k % SPIN_HOLD_FRAMES == 0:
            axis = rng.normal(size=3)
            omega = 2 * math.pi * rng.uniform(0.0, SPIN_MAX_REV_S)
        yield a, u, v, _rotation(axis, omega / fps)
        k += 1
