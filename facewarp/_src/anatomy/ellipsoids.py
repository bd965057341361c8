"""Muscle segments as ellipsoids (Sec. 6.3, 6.4.1): cutting a fibre into equal-arc-length pieces,
surface points by parameters (u, v), the closest surface point, and the volume-keeping radii.

Every curve is cut into segments of equal arc length and each segment is an ellipsoid: x along the
chord (half-length ``1.05 x chord / 2``), y perpendicular to x in the plane of the curve's control
points, ``z = x cross y``; y and z radii ``r = 2 d_m``, tapered at the two end segments of a linear
muscle. A surface point is stored by its parameters ``(u, v)``: ``u`` the polar angle from +x,
``v`` the azimuth from +y toward +z. An ellipsoid keeps its volume when its x radius changes
(:func:`ellipsoid_radii_for_length`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from .bezier import arc_length_params, bezier_quadratic

__all__ = [
    "Ellipsoids",
    "closest_point_on_ellipsoid",
    "ellipsoid_points",
    "ellipsoid_radii_for_length",
    "segment_ellipsoids",
]


@dataclass
class Ellipsoids:
    """Muscle segments (one ellipsoid each).

    Attributes:
        centers: Centres [m], shape (s, 3), float64.
        axes: Unit axes as rows (x along the fibre chord, y in the control-point plane,
            z = x cross y), shape (s, 3, 3), float64.
        radii: Semi-axis lengths (x, y, z) [m], shape (s, 3), float64.
        curve: Index of the Bezier curve (arc) each segment lies on, shape (s,), int64.
        t: Curve parameters of each segment's two ends, shape (s, 2), float64.
    """

    centers: np.ndarray
    axes: np.ndarray
    radii: np.ndarray
    curve: np.ndarray
    t: np.ndarray

    def __len__(self) -> int:
        return len(self.centers)

    @property
    def volumes(self) -> np.ndarray:
        """Volumes 4/3 pi a b c [m^3], shape (s,)."""
        return 4.0 / 3.0 * np.pi * np.prod(self.radii, axis=1)


def ellipsoid_radii_for_length(radii, x_radius) -> np.ndarray:
    """Radii of a segment whose x radius becomes ``x_radius``, keeping its volume (Sec. 6.4.1).

    Muscle is incompressible: ``a b c`` is constant, and the cross-section scales uniformly,
    so ``b' = b sqrt(a / a')`` and ``c' = c sqrt(a / a')``.

    Args:
        radii: Rest radii (a, b, c) [m], shape (s, 3).
        x_radius: New x radii a' [m], shape (s,), > 0.

    Returns:
        New radii [m], shape (s, 3).
    """
    radii = np.asarray(radii, dtype=np.float64).reshape(-1, 3)
    a1 = np.asarray(x_radius, dtype=np.float64).reshape(-1)
    if (a1 <= 0).any():
        raise InputError("x_radius must be > 0")
    f = np.sqrt(radii[:, 0] / a1)
    return np.stack([a1, radii[:, 1] * f, radii[:, 2] * f], 1)


def ellipsoid_points(centers, axes, radii, uv) -> np.ndarray:
    """Surface points at parameters (u, v): local ``(a cos u, b sin u cos v, c sin u sin v)``.

    Args:
        centers: (k, 3) [m]; axes: (k, 3, 3) unit rows; radii: (k, 3) [m]; uv: (k, 2) [rad].

    Returns:
        Points [m], shape (k, 3).
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    u, v = uv[:, 0], uv[:, 1]
    radii = np.asarray(radii, dtype=np.float64).reshape(-1, 3)
    loc = np.stack([radii[:, 0] * np.cos(u), radii[:, 1] * np.sin(u) * np.cos(v), radii[:, 2] * np.sin(u) * np.sin(v)], 1)
    return np.asarray(centers) + np.einsum("kj,kji->ki", loc, np.asarray(axes))


def closest_point_on_ellipsoid(Y, radii, *, iterations: int = 80) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest surface point of axis-aligned ellipsoids to points given in their local frames.

    The closest point is ``x_i = e_i^2 y_i / (s + e_i^2)`` where s solves
    ``F(s) = sum_i (e_i y_i / (s + e_i^2))^2 - 1 = 0`` on ``s > -min e_i^2`` (F decreases
    there; s > 0 outside, s < 0 inside); solved by bisection (Eberly, "Distance from a point to
    an ellipse, an ellipsoid, or a hyperellipsoid").

    Args:
        Y: Points in the local frames [m], shape (k, 3).
        radii: Semi-axes (a, b, c) [m], shape (k, 3) or (3,).
        iterations: Bisection steps.

    Returns:
        ``(X, dist, uv)``: closest points (local) shape (k, 3); unsigned distances [m] (k,);
        surface parameters (u, v) [rad] (k, 2).
    """
    Y = np.asarray(Y, dtype=np.float64).reshape(-1, 3)
    E = np.broadcast_to(np.asarray(radii, dtype=np.float64), Y.shape)
    e2 = E * E
    emin2 = e2.min(1)
    ey = np.abs(E * Y)
    lo = -emin2 + 1e-30 * np.maximum(emin2, 1e-300)
    hi = np.maximum(np.linalg.norm(ey, axis=1), emin2)  # F(hi) <= 0
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        Fm = ((ey / (mid[:, None] + e2)) ** 2).sum(1) - 1.0
        pos = Fm > 0
        lo = np.where(pos, mid, lo)
        hi = np.where(pos, hi, mid)
    s = 0.5 * (lo + hi)
    X = e2 * Y / (s[:, None] + e2)
    # Degenerate inside case (Eberly): the root sits at s = -min e^2 when the point lies (nearly)
    # in the plane of the smallest axis; then the other coordinates follow from s = -e_min^2
    # and the smallest-axis coordinate from the ellipsoid equation.
    kmin = np.argmin(e2, axis=1)
    rows = np.arange(len(Y))
    gap = s + emin2
    deg = gap <= 1e-9 * emin2
    if deg.any():
        r, km = rows[deg], kmin[deg]
        den = e2[deg] - emin2[deg][:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            Xd = np.where(den > 0, e2[deg] * Y[deg] / np.where(den > 0, den, 1.0), 0.0)
        Xd[np.arange(len(r)), km] = 0.0
        rest = np.clip(1.0 - ((Xd / E[deg]) ** 2).sum(1), 0.0, None)
        sgn = np.where(Y[r, km] < 0, -1.0, 1.0)
        Xd[np.arange(len(r)), km] = sgn * E[r, km] * np.sqrt(rest)
        X[deg] = Xd
    # put X exactly on the surface (bisection residue)
    X /= np.sqrt(((X / E) ** 2).sum(1))[:, None]
    dist = np.linalg.norm(Y - X, axis=1)
    q = X / E
    u = np.arccos(np.clip(q[:, 0], -1.0, 1.0))
    v = np.arctan2(q[:, 2], q[:, 1])
    return X, dist, np.stack([u, v], 1)


def segment_ellipsoids(curves, weights, counts, radius: float, *, taper=None, chord_scale: float = 1.05) -> Ellipsoids:
    """Cut Bezier curves into equal-arc-length segments, one ellipsoid each (Sec. 6.3).

    Args:
        curves: Control points of each curve [m], shape (q, 3, 3).
        weights: Rational weights, shape (q, 3).
        counts: Segments per curve, shape (q,), >= 1.
        radius: y and z radius r = 2 d_m [m].
        taper: Radius factor of the first and last segment overall (None: no taper).
        chord_scale: x length / chord (1.05: 5 % longer, so neighbours overlap).

    Returns:
        :class:`Ellipsoids`.
    """
    C, A, R, cur, T = [], [], [], [], []
    for qi, (P, w, n) in enumerate(zip(np.asarray(curves, float), np.asarray(weights, float), counts)):
        t, _ = arc_length_params(P, int(n), w)
        pts = bezier_quadratic(P, t, w)
        plane = np.cross(P[1] - P[0], P[2] - P[0])
        for k in range(int(n)):
            a, b = pts[k], pts[k + 1]
            chord = b - a
            L = float(np.linalg.norm(chord))
            if L <= 0:
                raise InputError(f"curve {qi} has a zero-length segment {k}")
            x = chord / L
            y = np.cross(plane, x)
            if np.linalg.norm(y) < 1e-9 * max(np.linalg.norm(plane), 1e-30) or np.linalg.norm(plane) < 1e-20:
                # straight fibre: the plane the solver keeps for it (MuscleRig.curve_normals), normal
                # chord x +y (x +x for a fibre along y), so (u, v) name the same surface point there
                chord_all = P[2] - P[0]
                up = [0.0, 1.0, 0.0] if abs(chord_all[1]) < 0.9 * np.linalg.norm(chord_all) else [1.0, 0.0, 0.0]
                y = np.cross(np.cross(chord_all, up), x)
            y /= np.linalg.norm(y)
            z = np.cross(x, y)
            C.append(0.5 * (a + b))
            A.append(np.stack([x, y, z]))
            R.append([0.5 * chord_scale * L, radius, radius])
            cur.append(qi)
            T.append([t[k], t[k + 1]])
    R = np.asarray(R)
    if taper is not None and len(R):
        R[0, 1:] *= taper
        R[-1, 1:] *= taper
    return Ellipsoids(np.asarray(C), np.asarray(A), R, np.asarray(cur, dtype=np.int64), np.asarray(T))
