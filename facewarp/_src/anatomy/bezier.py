"""Quadratic (rational) Bezier curves, the fibres of the muscles of Sec. 6.3, and their arc length.

A linear muscle is one regular quadratic curve (all weights 1); a sphincter is a closed ring of
4 rational quadratic arcs whose middle weights ``cos 45deg`` give exact circular quarters.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError

__all__ = ["arc_length_params", "bezier_quadratic"]


def bezier_quadratic(P, t, weights=None) -> np.ndarray:
    """Points of a (rational) quadratic Bezier curve.

    ``C(t) = sum_i B_i(t) w_i P_i / sum_i B_i(t) w_i`` with the Bernstein polynomials
    ``B = ((1 - t)^2, 2 t (1 - t), t^2)``; all weights 1 is the regular curve of a linear muscle.

    Args:
        P: Control points [m], shape (3, 3) float64.
        t: Parameters in [0, 1], shape (k,).
        weights: Weights, shape (3,), positive (default ones).

    Returns:
        Curve points [m], shape (k, 3), float64.
    """
    P = np.asarray(P, dtype=np.float64)
    if P.shape != (3, 3):
        raise InputError(f"P must have shape (3, 3), got {P.shape}")
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    w = np.ones(3) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (3,) or (w <= 0).any():
        raise InputError(f"weights must be 3 positive numbers, got {w}")
    B = np.stack([(1 - t) ** 2, 2 * t * (1 - t), t**2], 1) * w
    return (B @ P) / B.sum(1, keepdims=True)


def arc_length_params(P, count: int, weights=None, *, samples: int = 512) -> tuple[np.ndarray, float]:
    """Parameters cutting a quadratic Bezier curve into ``count`` pieces of equal arc length.

    Args:
        P: Control points [m], shape (3, 3).
        count: Number of pieces (>= 1).
        weights: Rational weights, shape (3,) (default ones).
        samples: Polyline samples used to measure the arc length.

    Returns:
        ``(t, length)``: parameters shape (count + 1,) from 0 to 1, and the curve length [m].
    """
    ts = np.linspace(0.0, 1.0, samples + 1)
    C = bezier_quadratic(P, ts, weights)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(C, axis=0), axis=1))])
    length = float(s[-1])
    t = np.interp(np.linspace(0.0, length, int(count) + 1), s, ts)
    t[0], t[-1] = 0.0, 1.0
    return t, length
