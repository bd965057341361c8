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


def smooth_performance(rng: np.random.Generator, frames: int, fps: float, muscles: int, *,
                       active_fraction: float = 0.4, knot_s: float = 0.5, jaw_open_max_deg: float = 30.0,
                       jaw_side_max_deg: float = 4.0, peak_max: float = 1.0):
    """A smooth random performance like the one benchmarks/drive.py simulates and drives: about
    ``active_fraction`` of the muscles follow a monotone cubic (PCHIP) through random values every
    ``knot_s`` seconds (each muscle's peak drawn in [0.3, ``peak_max``]), and so do the jaw's angles; all 0 at frame 0. Returns activations (frames,
    muscles) float32 in [0, 1] and jaw (frames, 2) [rad]."""
    from scipy.interpolate import PchipInterpolator

    t = np.arange(frames) / fps
    knots = np.arange(0.0, t[-1] + knot_s, knot_s)

    def curve(hi, lo=0.0):
        v = rng.uniform(lo, hi, len(knots))
        v[0] = 0.0
        return np.clip(PchipInterpolator(knots, v)(t), min(lo, 0.0), hi)

    A = np.zeros((frames, muscles))
    for m in np.flatnonzero(rng.uniform(size=muscles) < active_fraction):
        A[:, m] = curve(rng.uniform(0.3, peak_max))
    side = math.radians(jaw_side_max_deg)
    J = np.c_[curve(math.radians(jaw_open_max_deg)), curve(side, -side)]
    return np.clip(A, 0, 1).astype(np.float32), J
