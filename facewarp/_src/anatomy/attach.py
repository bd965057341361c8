"""Skin attachment of a muscle (Fig. 6.4, 6.5): which inner-layer nodes connect to which segment.

An inner-layer node connects to the muscle when the distance to the nearest ellipsoid surface
point is below ``lambda`` and the angle ``theta`` between the connection and the fibre's
cross-section plane is below ``phi``. ``theta`` is measured from the plane normal to the fibre (0
for a node right above the fibre, 90deg for one beyond its end), so a wide ``phi`` (frontalis)
takes nodes far along the ends and a narrow one (depressor anguli oris) only nodes over the muscle
body. The attachment point is stored by its ellipsoid surface parameters ``(u, v)``
(:func:`facewarp.anatomy.ellipsoid_points`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .ellipsoids import Ellipsoids, closest_point_on_ellipsoid

__all__ = ["MuscleAttachment", "attach_nodes"]


@dataclass
class MuscleAttachment:
    """Skin nodes connected to a muscle (Fig. 6.4, 6.5).

    Attributes:
        nodes: Tet-mesh node indices (inner layer), shape (a,), int64.
        segment: Ellipsoid each node connects to, shape (a,), int64.
        uv: Surface parameters (u, v) [rad] of the attachment point, shape (a, 2), float64.
        rest_length: Rest length l0 of the connection [m], shape (a,), float64.
        angle: theta [rad] of each connection (see the module docstring), shape (a,).
    """

    nodes: np.ndarray
    segment: np.ndarray
    uv: np.ndarray
    rest_length: np.ndarray
    angle: np.ndarray

    def __len__(self) -> int:
        return len(self.nodes)


def attach_nodes(X, ell: Ellipsoids, lam: float, phi: float, *, candidates=None, directions=None) -> MuscleAttachment:
    """Connect nodes to a muscle's ellipsoids (Fig. 6.4).

    For each node x: the nearest surface point p over all segments; x connects when
    ``|x - p| < lam`` and ``theta < phi``, theta the angle between ``x - p`` and the plane
    normal to the segment's fibre axis. With ``directions``, x must also lie on the skin side
    of the muscle, ``(p - x) . direction > 0``: on a head whose skin is thinner than the muscle
    depth (the lips of an adapted scan) part of a muscle can lie in or above the skin layer, and
    a spring from there would pull its inner node out through the skin.

    Args:
        X: Node positions [m], shape (p, 3).
        ell: The muscle's segments.
        lam: Distance threshold lambda [m].
        phi: Angle threshold [rad].
        candidates: Node indices to test (default all).
        directions: Unit inward (skin to deep) direction of every node, shape (p, 3).

    Returns:
        :class:`MuscleAttachment` with indices into X.
    """
    X = np.asarray(X, dtype=np.float64)
    idx = np.arange(len(X)) if candidates is None else np.asarray(candidates, dtype=np.int64)
    s = len(ell)
    if len(idx) == 0 or s == 0:
        z = np.zeros(0)
        return MuscleAttachment(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)), z, z)
    P = X[idx]
    best_d = np.full(len(idx), np.inf)
    best_s = np.zeros(len(idx), np.int64)
    best_uv = np.zeros((len(idx), 2))
    best_sin = np.zeros(len(idx))
    best_deeper = np.ones(len(idx), bool)
    D = None if directions is None else np.asarray(directions, dtype=np.float64)[idx]
    for k in range(s):
        Y = (P - ell.centers[k]) @ ell.axes[k].T  # local coordinates
        Xl, d, uv = closest_point_on_ellipsoid(Y, ell.radii[k])
        conn = Y - Xl
        n = np.linalg.norm(conn, axis=1)
        sin_t = np.divide(np.abs(conn[:, 0]), n, out=np.zeros_like(n), where=n > 0)
        better = d < best_d
        best_d[better] = d[better]
        best_s[better] = k
        best_uv[better] = uv[better]
        best_sin[better] = sin_t[better]
        if D is not None:
            deeper = np.einsum("ij,ij->i", conn @ ell.axes[k], D) < 0  # world x - p against inward
            best_deeper[better] = deeper[better]
    theta = np.arcsin(np.clip(best_sin, 0.0, 1.0))
    ok = (best_d < lam) & (theta < phi) & best_deeper
    return MuscleAttachment(idx[ok], best_s[ok], best_uv[ok], best_d[ok], theta[ok])
